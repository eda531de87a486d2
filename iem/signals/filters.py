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

from ..errors import InvalidInputError
from ..types import NOMINAL_POINT_RATE_HZ, NOMINAL_RATE_HZ
from .gaps import DEFAULT_MAX_BRIDGE_S, RESTART, SKIP, GapRule

DEFAULT_CUTOFF_HZ = 25.0
"""Default cut-off of :class:`StateFilter`'s low-pass on ``dq``, Hz (the plug-in's
``[estimate] filter_cutoff_hz``): a quarter of the 100 Hz block-point rate (the block mean
is itself a low-pass, with its first zero at 100 Hz)."""


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
    """A 2nd-order Butterworth low-pass on ``channels`` signals, one sample at a time.

    ``steps`` (see :mod:`iem.signals.gaps`) says how many nominal cycles the sample comes after the
    last one: the ``steps - 1`` missing inputs are interpolated linearly between the last
    input and this one and filtered first, so the filter always runs at its design rate.
    ``previous`` is the output one nominal cycle before the latest (for a backward
    difference over exactly one cycle).
    """

    def __init__(self, cutoff_hz: float, rate_hz: float = NOMINAL_RATE_HZ,
                 channels: int = 7) -> None:
        self.cutoff_hz = float(cutoff_hz)
        self.rate_hz = float(rate_hz)
        self.channels = int(channels)
        self.b, self.a = butterworth2(self.cutoff_hz, self.rate_hz)
        b0, b1, b2 = self.b
        _, a1, a2 = self.a
        # one sample as one product: [y, z1', z2'] = M @ [x, z1, z2] (transposed direct
        # form II; each small numpy call costs about a µs, so one product beats nine)
        self._m = np.array([[b0, 1.0, 0.0], [b1 - a1 * b0, -a1, 1.0], [b2 - a2 * b0, -a2, 0.0]])
        self._s = np.zeros((3, self.channels))  # rows: the input, z1, z2
        self._x: np.ndarray | None = None  # the last input
        self.previous: np.ndarray | None = None
        """The output one nominal cycle before the latest (None right after a start)."""
        self._y: np.ndarray | None = None
        self._started = False

    def reset(self) -> None:
        self._started = False
        self._x = self._y = self.previous = None

    @property
    def state(self) -> list[np.ndarray]:
        """The filter's two states ``[z1, z2]`` (channels each, copies): what a saved
        filter needs besides its coefficients."""
        return [self._s[1].copy(), self._s[2].copy()]

    @state.setter
    def state(self, value) -> None:
        self._s[1], self._s[2] = value

    def _step(self, x: np.ndarray) -> np.ndarray:
        if x.shape != (self.channels,):
            raise InvalidInputError(f"the filter takes {self.channels} channels, got "
                                    f"{x.shape}")
        s = self._s
        s[0] = x
        out = self._m @ s
        s[1:] = out[1:]
        return out[0]

    def __call__(self, x, steps: int = 1) -> np.ndarray:
        x = np.asarray(x, dtype=float)
        if not self._started:
            # steady state for a constant input x: y = x
            _, b1, b2 = self.b
            _, a1, a2 = self.a
            self._s[2] = (b2 - a2) * x
            self._s[1] = (b1 - a1) * x + self._s[2]
            self._started = True
            self.previous = None
        else:
            self.previous = self._y
            if steps > 1 and self._x is not None:  # bridge: interpolate between the inputs
                x0 = self._x
                for j in range(1, steps):
                    self.previous = self._step(x0 + (x - x0) * (j / steps))
        y = self._step(x)
        self._x, self._y = x, y
        return y


USABLE_SHARE = 0.45
"""The largest cut-off :class:`StateFilter` is given, as a share of its rate (below Nyquist,
with room for the bilinear transform's warping)."""


def usable_cutoff(cutoff_hz: float, rate_hz: float) -> float:
    """``cutoff_hz``, or :data:`USABLE_SHARE` of ``rate_hz`` if that is lower: the cut-off a
    state filter at ``rate_hz`` can have (a configured 50 Hz at 100 block points a second is
    45 Hz)."""
    return min(float(cutoff_hz), USABLE_SHARE * float(rate_hz))


class StateFilter:
    """Causal estimate of ``(q, dq, ddq)`` from measured ``q, dq`` at a nominal rate.

    The time stamps go through the one gap rule (:class:`iem.signals.gaps.GapRule`), which the
    online loop then applies to every other filter of the estimation path (``steps`` tells
    what it decided for the last sample): lost cycles up to ``max_gap_s`` are bridged, so
    ``ddq`` is always a difference over one cycle; a sample that is not newer than the last
    one used is not filtered (``steps == SKIP``: the last state is returned again); a longer
    gap, or time going back, restarts the filter (``restarted``).

    Args:
        cutoff_hz: low-pass cut-off for ``dq``, Hz (default 25).
        rate_hz: nominal sample rate, Hz (default 100, the block points of a 1 kHz
            controller).
        max_gap_s: the longest gap bridged; a longer one restarts the filter, s.
    """

    def __init__(self, cutoff_hz: float = DEFAULT_CUTOFF_HZ,
                 rate_hz: float = NOMINAL_POINT_RATE_HZ,
                 max_gap_s: float = DEFAULT_MAX_BRIDGE_S) -> None:
        self.cutoff_hz = float(cutoff_hz)
        self.rate_hz = float(rate_hz)
        self.max_gap_s = float(max_gap_s)
        self._lp = LowPass2(cutoff_hz, rate_hz, channels=7)
        self.gaps = GapRule(rate_hz, max_gap_s)
        self.steps = RESTART
        """The gap rule's verdict on the last sample (``RESTART``, ``SKIP`` or cycles)."""
        self._last: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None

    @property
    def restarted(self) -> bool:
        """True if the last sample started the filter afresh (the first, or after a gap)."""
        return self.steps == RESTART

    def reset(self) -> None:
        """The next sample starts the filter afresh."""
        self._lp.reset()
        self.gaps.reset()
        self._last = None

    def __call__(self, q, dq, t: float | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        self.steps = steps = self.gaps(t)
        if steps == SKIP and self._last is not None:
            return self._last
        if steps == RESTART:
            self._lp.reset()
        dq_f = self._lp(dq, max(steps, 1))
        prev = self._lp.previous
        ddq = np.zeros(7) if prev is None else (dq_f - prev) * self.rate_hz
        self._last = (np.asarray(q, dtype=float), dq_f, ddq)
        return self._last
