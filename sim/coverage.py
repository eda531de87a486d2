"""Tandem samples at a bag's own poses with other velocities and accelerations.

A bag's learner is trained on the tandem samples of the motions that formed the bag; a later
motion through the same poses at other velocities (another direction, another speed) gives
inputs it never saw (``iem bench longrun``: the first minute driven backwards, IEM mass MAE
about 3 kg). :class:`OtherVelocities` gives, at a pose ``q``, the training payloads' samples
``[q, dq', tau_k(q, dq', ddq')]`` at a random state ``(dq', ddq')`` uniform within
``fraction`` of the arm's velocity and acceleration limits, through the public API of
:class:`sim.tandem.TandemSimulators`; the ensemble adds them to a bag's training
(:class:`iem.ensemble.IncrementalEnsemble`, ``coverage="sim.coverage:other_velocities"``).
"""

from __future__ import annotations

import numpy as np

from .robot import PandaModel
from .tandem import TandemSimulators


class OtherVelocities:
    """``(q, phi (K, 10), rng) -> X (K, 21)``: the family's samples at pose ``q`` and a random
    velocity and acceleration within ``fraction`` of the limits.

    Not thread-safe (it owns a Pinocchio model): one per thread.
    """

    def __init__(self, fraction: float = 0.9, model: PandaModel | None = None) -> None:
        self.model = PandaModel() if model is None else model
        self.fraction = float(fraction)
        self.dq_max = self.fraction * self.model.dq_max
        self.ddq_max = self.fraction * self.model.ddq_max

    def __call__(self, q, phi, rng: np.random.Generator) -> np.ndarray:
        dq = rng.uniform(-self.dq_max, self.dq_max)
        ddq = rng.uniform(-self.ddq_max, self.ddq_max)
        X, _ = TandemSimulators(np.asarray(phi, dtype=float), model=self.model).samples(
            np.asarray(q, dtype=float), dq, ddq)
        return X


def other_velocities() -> OtherVelocities:
    """The factory the ensemble names (``"sim.coverage:other_velocities"``)."""
    return OtherVelocities()
