"""The causal smoothing applied to every model's output, the same for all of them.

An exponential moving average with time constant ``tau_s`` (default 0.2 s): at each sample
``s <- s + w (phi - s)`` with ``w = max(1 / n, alpha)``, ``n`` the number of estimates so far
and ``alpha = 1 - exp(-dt / tau_s)``: the plain mean of the estimates while there are fewer
than ``1 / alpha`` of them (20 at the 100 Hz of block points), the exponential average from
then on, so the first (single-sample) estimate does not dominate the start. It uses only
samples up to now.
Its noise bandwidth is ``1 / (4 tau_s)`` (1.25 Hz at 0.2 s), so white estimate noise shrinks
by ``sqrt(dt / (2 tau_s))`` (x 0.16 at 100 Hz); a step in the estimate is 95 % through after
``3 tau_s`` (0.6 s).
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import InvalidInputError
from ..types import NOMINAL_POINT_RATE_HZ

DEFAULT_TAU_S = 0.2
"""Default time constant of the output smoothing, s."""


class ExponentialSmoother:
    """Exponential moving average of a vector signal sampled every ``dt`` s."""

    def __init__(self, tau_s: float = DEFAULT_TAU_S,
                 dt: float = 1.0 / NOMINAL_POINT_RATE_HZ) -> None:
        if not tau_s >= 0.0 or not dt > 0.0:
            raise InvalidInputError(f"tau_s must be >= 0 s and dt > 0 s, got {tau_s}, {dt}")
        self.tau_s = float(tau_s)
        self.dt = float(dt)
        self.alpha = 1.0 if tau_s == 0.0 else 1.0 - math.exp(-dt / tau_s)
        self._s: np.ndarray | None = None
        self._n = 0

    def reset(self) -> None:
        self._s = None
        self._n = 0

    @property
    def value(self) -> np.ndarray | None:
        return None if self._s is None else self._s.copy()

    def __call__(self, x, steps: int = 1) -> np.ndarray:
        """Add the estimate ``x`` made ``steps`` samples of ``dt`` after the last one (a
        stream that lost ``steps - 1`` cycles decays the average by their time too)."""
        x = np.asarray(x, dtype=float)
        if self._s is None:
            if np.isfinite(x).all():
                self._s = x.copy()  # start at the first finite estimate
                self._n = 1
            return x.copy()
        if x.shape != self._s.shape:
            raise InvalidInputError(f"the smoothing averages {self._s.shape[0]} values, got "
                                    f"{x.shape}")
        alpha = self.alpha if steps <= 1 else 1.0 - (1.0 - self.alpha) ** steps
        if np.isfinite(x).all():
            self._n += 1
            self._s += max(1.0 / self._n, alpha) * (x - self._s)
        return self._s.copy()

    def run(self, X) -> np.ndarray:
        """Smooth a whole ``(N, d)`` sequence from the current state (causal, row by row)."""
        X = np.asarray(X, dtype=float)
        out = np.empty_like(X)
        for i, x in enumerate(X):
            out[i] = self(x)
        return out
