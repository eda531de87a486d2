"""The sensor model: the one place that says how noisy a joint-state measurement is.

A Franka-style controller reports ``q``, ``dq`` and the link-side torque ``tau_J`` every
cycle. The figures this project reports are measured against white Gaussian noise,
independent per joint and per sample, with the standard deviations of :class:`SensorModel`
(its defaults). The plant (:mod:`sim.plant`) draws its measurement noise from it, the
estimators size their noise models and training noise from it, and the benchmarks record it.
numpy only: the learning core imports it without the simulation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class SensorModel:
    """White Gaussian measurement noise, independent per joint and per sample.

    Attributes:
        sigma_q: joint position noise, rad (default 1e-4).
        sigma_dq: joint velocity noise, rad/s (default 2e-3).
        sigma_tau: joint torque noise, N·m (default 0.05).
    """

    sigma_q: float = 1e-4
    sigma_dq: float = 2e-3
    sigma_tau: float = 0.05

    @classmethod
    def noiseless(cls) -> SensorModel:
        """Exact readings (every standard deviation 0)."""
        return cls(0.0, 0.0, 0.0)

    @property
    def sigmas(self) -> np.ndarray:
        """The 21 standard deviations in the order ``[q (rad), dq (rad/s), tau (N·m)]`` x 7."""
        return np.repeat([self.sigma_q, self.sigma_dq, self.sigma_tau], 7)


DEFAULT_SENSOR = SensorModel()
"""The default sensor model (the one every reported figure is measured against)."""
