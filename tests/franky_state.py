"""A franky ``RobotState`` as a program hands it to the plug-in: the fields the ``program``
link reads (:mod:`firmware_bridge.program_link`), as numpy arrays, from a simulated joint
state and the load its robot's controller holds."""

from __future__ import annotations

import numpy as np


class Duration:
    """franky's ``Duration``: ``to_sec()``."""

    def __init__(self, t: float) -> None:
        self._t = t

    def to_sec(self) -> float:
        return self._t


class RobotState:
    """``q``, ``dq``, ``tau_J``, ``time`` of joint state ``s`` (an :class:`iem.types.
    JointState`); ``m_load``, ``F_x_Cload`` (3, 1) and ``I_load`` (3, 3) of ``load``, a
    ``(mass, com, inertia as 9 values column-major)`` triple."""

    def __init__(self, s, load) -> None:
        self.q, self.dq, self.tau_J, self.time = s.q, s.dq, s.tau_J, Duration(s.t)
        mass, com, inertia = load
        self.m_load = mass
        self.F_x_Cload = np.reshape(com, (3, 1))
        self.I_load = np.reshape(inertia, (3, 3), order="F")
