"""Value types that cross the seams between the packages.

The payload parameter vector ``phi`` follows the paper (Eq. 9)::

    phi = [m, m*rx, m*ry, m*rz, Ixx, Ixy, Ixz, Iyy, Iyz, Izz]

in kg, kg·m and kg·m², with the inertia taken about the flange origin in flange axes.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .errors import InvalidInputError

PARAMS: tuple[str, ...] = ("m", "mrx", "mry", "mrz", "Ixx", "Ixy", "Ixz", "Iyy", "Iyz", "Izz")
"""Names of the ten payload parameters, in the paper's order."""

GROUPS: dict[str, tuple[int, ...]] = {
    "mass": (0,),
    "com": (1, 2, 3),
    "inertia": (4, 5, 6, 7, 8, 9),
}
"""Parameter groups used for the paper's summary figures (indices into ``PARAMS``)."""

N_JOINTS = 7

NOMINAL_RATE_HZ = 1000.0
"""The controller's nominal joint-state rate, Hz: a Franka's 1 kHz cycle (libfranka's
RobotState, franka_ros2's ``/franka/joint_states``, the ``fd`` wire profile of
``protocol.dbc``). What a link really delivers is ``firmware_bridge.links.rate_hz`` (the
``classic`` profile's is 500 Hz)."""

DEFAULT_BLOCK_FRAMES = 10
"""Frames per block point (:mod:`iem.signals.blocks`): the estimator works on the means of this many
consecutive frames (the plug-in's ``[estimate] block_frames``)."""

NOMINAL_POINT_RATE_HZ = NOMINAL_RATE_HZ / DEFAULT_BLOCK_FRAMES
"""Block points per second from a 1 kHz controller: the default rate of every filter and
estimator of the estimation path (100 Hz)."""


def _vec7(name: str, value) -> np.ndarray:
    if type(value) is np.ndarray and value.dtype == np.float64 and value.shape == (N_JOINTS,) \
            and not value.flags.writeable:
        return value  # already what we keep: read-only float64 (7)
    arr = np.array(value, dtype=float).reshape(-1)
    if arr.shape != (N_JOINTS,):
        raise InvalidInputError(f"{name} must have {N_JOINTS} entries, got shape {arr.shape}")
    arr.flags.writeable = False
    return arr


@dataclass(frozen=True)
class JointState:
    """One controller cycle as a Franka reports it.

    Attributes:
        t: controller time stamp in s.
        q: measured joint positions in rad (7).
        dq: measured joint velocities in rad/s (7).
        tau_J: measured link-side joint torques in N·m (7), after the gears.
        cycle: controller cycle counter (wraps as the wire protocol defines).
    """

    t: float
    q: np.ndarray
    dq: np.ndarray
    tau_J: np.ndarray
    cycle: int = 0

    def __post_init__(self) -> None:
        object.__setattr__(self, "q", _vec7("q", self.q))
        object.__setattr__(self, "dq", _vec7("dq", self.dq))
        object.__setattr__(self, "tau_J", _vec7("tau_J", self.tau_J))

    def features(self) -> np.ndarray:
        """The learner input ``X = [q, dq, tau]`` (21 values), as in the paper (Eq. 10-12)."""
        return np.concatenate((self.q, self.dq, self.tau_J))


@dataclass(frozen=True)
class PayloadEstimate:
    """An estimate of the payload parameters at one instant, with what the safety gate needs
    to judge it.

    The gate fails closed: it writes only an estimate that reports its standard deviations,
    its data's verdict and its out-of-distribution verdict (``std``, ``nis``, ``ood`` not
    None), unless the cell allows writing without them (``[gate]
    allow_without_uncertainty``). A model that cannot say one of them passes None for it,
    explicitly: the fields are typed, so a misspelt or forgotten one is an error where the
    estimate is made, never a write let through.

    Attributes:
        t: time of the joint state it was made from, in s.
        phi: parameters in the paper's order (see module docstring), units kg, kg·m, kg·m².
        std: one standard deviation per parameter, same units; None: the model has none.
        bag: index of the bag whose learner made it, or -1 if no bag was involved.
        learning: True if the learner was trained on this instant before predicting.
        nis: the mean normalised innovation squared per degree of freedom of the model's
            recent equations (about 1 while the data agree with it; NaN: no verdict yet);
            None: the model does not test its data.
        ood: True if the estimate comes from an input beyond what its learner was trained
            on; None: the model cannot say.
        unverified: True while an estimate started from a payload file has not yet been
            tested against enough live data.
        determined: the parameter groups (:data:`GROUPS`) the data determine; the others are
            the prior's; None: the model cannot say.
        extra: diagnostics that no safety decision reads (``change``, ``reset``,
            ``ood_score``, ``velocity_score``, ``held``).
    """

    t: float
    phi: np.ndarray
    std: np.ndarray | None = None
    bag: int = -1
    learning: bool = False
    nis: float | None = None
    ood: bool | None = None
    unverified: bool = False
    determined: tuple[str, ...] | None = None
    extra: dict = field(default_factory=dict, compare=False)
