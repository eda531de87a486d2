"""Tandem samples at a bag's own poses with other velocities and accelerations, and the
same motions driven backwards.

A bag's learner is trained on the tandem samples of the motions that formed the bag; a later
motion through the same poses at other velocities (another direction, another speed) gives
inputs it never saw (``iem bench longrun``: the first minute driven backwards, IEM mass MAE
about 3 kg). :class:`OtherVelocities` gives, at a pose ``q``, the training payloads' samples
``[q, dq', tau_k(q, dq', ddq')]`` at a random state ``(dq', ddq')`` uniform within
``fraction`` of the arm's velocity and acceleration limits, through the public API of
:class:`sim.tandem.TandemSimulators`; the ensemble adds them to a bag's training
(:class:`iem.ensemble.IncrementalEnsemble`, ``coverage="sim.coverage:other_velocities"``).

:class:`ReversedVelocities` maps samples to those of the same motion driven backwards
(``q(T - t)``: every velocity reversed, the acceleration the same). Rigid-body torques are
even in the velocities (``M(q) ddq + h(q, dq)``, ``h`` quadratic in ``dq``, and the payload
regressor likewise), so the reversed sample's torques are the sample's own, up to the arm's
friction, which is odd: with an arm (an arm file), its joint torque at ``dq`` is replaced by
that at ``-dq``. Exact, no simulation; the ensemble adds them to a bag's training
(``reversal="sim.coverage:reversed_velocities"``, ``...@arm:CRC32`` for a calibrated arm,
given at run time: :mod:`iem.factories`).
Training on random other velocities instead (``other_velocities``) cost the closed bags
their fit to their own motion: its single-layer learners read the first minute of
``iem bench longrun`` (seed 1) 0.20 kg off driven forwards and backwards alike, against
0.021 kg both ways with the reversed samples alone.
"""

from __future__ import annotations

import numpy as np

from .robot import ArmModel
from .tandem import TandemSimulators


class OtherVelocities:
    """``(q, phi (K, 10), rng) -> X (K, 21)``: the family's samples at pose ``q`` and a random
    velocity and acceleration within ``fraction`` of the limits.

    Not thread-safe (it owns a Pinocchio model): one per thread.
    """

    def __init__(self, fraction: float = 0.9, model: ArmModel | None = None) -> None:
        self.model = ArmModel() if model is None else model
        self.fraction = float(fraction)
        self.dq_max = self.fraction * self.model.dq_max
        self.ddq_max = self.fraction * self.model.ddq_max

    def __call__(self, q, phi, rng: np.random.Generator) -> np.ndarray:
        dq = rng.uniform(-self.dq_max, self.dq_max)
        ddq = rng.uniform(-self.ddq_max, self.ddq_max)
        X, _ = TandemSimulators(np.asarray(phi, dtype=float), model=self.model).samples(
            np.asarray(q, dtype=float), dq, ddq)
        return X


class ReversedVelocities:
    """``X (N, 21) -> X (N, 21)``: the samples ``[q, dq, tau]`` of the motion driven
    backwards, ``[q, -dq, tau - f(dq) + f(-dq)]`` with ``f`` the arm's friction and offset
    (:meth:`sim.arm.ArmParams.joint_torque`; none on the nominal arm).

    Args:
        arm: the arm the samples were simulated on (None: the nominal arm).
    """

    def __init__(self, arm=None) -> None:
        self.arm = arm

    def __call__(self, X: np.ndarray) -> np.ndarray:
        X = np.asarray(X, dtype=float)
        out = X.copy()
        dq = X[:, 7:14]
        out[:, 7:14] = -dq
        if self.arm is not None:
            # the samples of one state share their velocities (the tandem simulators'): one
            # row's friction then serves all, the same numbers elementwise
            if dq.shape[0] > 1 and bool((dq == dq[0]).all()):
                friction = self.arm.joint_torque  # one velocity: its torque is kept
                out[:, 14:] += friction(-dq[0]) - friction(dq[0])
            else:
                both = self.arm.joint_torque(np.concatenate((-dq, dq)))
                out[:, 14:] += both[:len(dq)] - both[len(dq):]
        return out


def reversed_velocities(arm=None) -> ReversedVelocities:
    """The factory the ensemble names: ``"sim.coverage:reversed_velocities"`` (the nominal
    arm) or ``"sim.coverage:reversed_velocities@arm:CRC32"`` (``arm``, the
    :class:`sim.arm.ArmParams` of that content given at run time)."""
    return ReversedVelocities(arm)


def reversal_spec(arm=None) -> str:
    """The ensemble's ``reversal`` for ``arm`` (a :class:`sim.arm.ArmParams`, referenced by
    content and provided to this process, :func:`iem.factories.provide`; None: the nominal
    arm)."""
    if arm is None:
        return "sim.coverage:reversed_velocities"
    from iem.factories import provide

    return f"sim.coverage:reversed_velocities@{provide('arm', arm)}"


def other_velocities() -> OtherVelocities:
    """The factory the ensemble names (``"sim.coverage:other_velocities"``)."""
    return OtherVelocities()
