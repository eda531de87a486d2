"""Causal filters for measured joint signals (numpy only).

:class:`LowPass2` is a 2nd-order Butterworth low-pass (bilinear transform with frequency
pre-warping, the design of ``scipy.signal.butter(2, fc / (fs / 2))``) run sample by sample on
several channels at once, in transposed direct form II, started in steady state at the
first sample so there is no start-up transient.

:class:`StateFilter` turns the measured ``q, dq`` of each cycle into the state the tandem
simulators and the physics estimators need: ``q`` as measured (its noise, 1e-4 rad, is far
below anything that matters here), ``dq`` low-passed, and ``ddq`` the backward difference of
the low-passed ``dq``. Default cut-off 50 Hz at 1 kHz: it passes the motion of a task path
(a few Hz) with about 5 ms of lag and cuts the velocity noise's contribution to ``ddq``.
"""

from __future__ import annotations

import math

import numpy as np

from .errors import InvalidInputError


def butterworth2(cutoff_hz: float, rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """Numerator ``b`` and denominator ``a`` (``a[0] = 1``) of the 2nd-order low-pass."""
    if not 0.0 < cutoff_hz < rate_hz / 2.0:
        raise InvalidInputError(f"cut-off must be in (0, {rate_hz / 2:g}) Hz (Nyquist), "
                                f"got {cutoff_hz:g} Hz")
    k = math.tan(math.pi * cutoff_hz / rate_hz)
    norm = 1.0 / (1.0 + math.sqrt(2.0) * k + k * k)
    b0 = k * k * norm
    b = np.array([b0, 2.0 * b0, b0])
    a = np.array([1.0, 2.0 * (k * k - 1.0) * norm, (1.0 - math.sqrt(2.0) * k + k * k) * norm])
    return b, a


class LowPass2:
    """A 2nd-order Butterworth low-pass on ``channels`` signals, one sample at a time."""

    def __init__(self, cutoff_hz: float, rate_hz: float = 1000.0, channels: int = 7) -> None:
        self.cutoff_hz = float(cutoff_hz)
        self.rate_hz = float(rate_hz)
        self.channels = int(channels)
        self.b, self.a = butterworth2(self.cutoff_hz, self.rate_hz)
        self._z1 = np.zeros(self.channels)
        self._z2 = np.zeros(self.channels)
        self._started = False

    def reset(self) -> None:
        self._started = False

    def __call__(self, x) -> np.ndarray:
        x = np.asarray(x, dtype=float)
        b0, b1, b2 = self.b
        _, a1, a2 = self.a
        if not self._started:
            # steady state for a constant input x: y = x
            self._z2 = (b2 - a2) * x
            self._z1 = (b1 - a1) * x + self._z2
            self._started = True
        y = b0 * x + self._z1
        self._z1 = b1 * x - a1 * y + self._z2
        self._z2 = b2 * x - a2 * y
        return y


class StateFilter:
    """Causal estimate of ``(q, dq, ddq)`` from measured ``q, dq`` at a nominal rate.

    Given the samples' time stamps, the derivative divides by the real interval, so a lost
    cycle does not double ``ddq``; a gap longer than ``max_gap_s`` (a silent controller)
    restarts the filter.

    Args:
        cutoff_hz: low-pass cut-off for ``dq``, Hz (default 50).
        rate_hz: nominal sample rate, Hz (default 1000, the controller's cycle).
        max_gap_s: a longer interval between two samples restarts the filter, s.
    """

    def __init__(self, cutoff_hz: float = 50.0, rate_hz: float = 1000.0,
                 max_gap_s: float = 0.05) -> None:
        self.cutoff_hz = float(cutoff_hz)
        self.rate_hz = float(rate_hz)
        self.max_gap_s = float(max_gap_s)
        self._lp = LowPass2(cutoff_hz, rate_hz, channels=7)
        self._prev: np.ndarray | None = None
        self._t: float | None = None
        self.restarted = False
        """True if the last sample started the filter afresh (the first, or after a gap)."""

    def reset(self) -> None:
        self._lp.reset()
        self._prev = None
        self._t = None

    def __call__(self, q, dq, t: float | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        dt = 1.0 / self.rate_hz
        if t is not None:
            if self._t is not None:
                gap = t - self._t
                if gap > self.max_gap_s or gap <= 0.0:
                    self.reset()  # a silence, or time went backwards: start again
                else:
                    dt = gap
            self._t = t
        self.restarted = self._prev is None
        dq_f = self._lp(dq)
        ddq = np.zeros(7) if self._prev is None else (dq_f - self._prev) / dt
        self._prev = dq_f
        return np.asarray(q, dtype=float), dq_f, ddq
