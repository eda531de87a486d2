"""Recorded joint states as arrays, and the offline signal chain of :mod:`sim.identify`.

:class:`Recording` holds ``t, q, dq, tau`` of a recording. :func:`filtered` puts it on a
uniform grid at its own median rate (linear interpolation over the time stamps it has, so lost
cycles shift nothing), takes out spikes (:func:`despike`), filters ``q``, ``dq`` and ``tau``
with a zero-phase Butterworth low-pass (order 4, ``scipy.signal.sosfiltfilt``), derives
``ddq`` and ``dtau`` by central differences and samples the result at ``rate_hz`` (the
low-pass is the anti-alias filter). :func:`lag` finds the time shift between two recordings of
one motion (cross-correlation of the filtered joint velocities, sub-sample), :func:`sample`
reads filtered signals at any instants.

numpy at import; scipy when a recording is filtered.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import InvalidInputError
from ..types import N_JOINTS

SPIKE_WINDOW = 11
"""Window of the local quadratic fit that spikes are measured against, samples."""
SPIKE_SIGMAS = 6.0
"""Deviation from the local fit, in robust standard deviations, that marks a spike."""


@dataclass(frozen=True)
class Recording:
    """Recorded joint states as arrays.

    Attributes:
        t: controller time stamps, s (N), increasing.
        q: joint positions, rad (N, 7).
        dq: joint velocities, rad/s (N, 7).
        tau: measured link-side joint torques, N·m (N, 7).
    """

    t: np.ndarray
    q: np.ndarray
    dq: np.ndarray
    tau: np.ndarray

    def __post_init__(self) -> None:
        t = np.asarray(self.t, dtype=float).reshape(-1)
        arrays = {}
        for name in ("q", "dq", "tau"):
            a = np.asarray(getattr(self, name), dtype=float)
            if a.ndim != 2 or a.shape != (t.shape[0], N_JOINTS):
                raise InvalidInputError(f"recording: {name} must have shape ({t.shape[0]}, "
                                        f"{N_JOINTS}) to match t, got {a.shape}")
            arrays[name] = a
        if t.shape[0] < 2:
            raise InvalidInputError(f"recording: needs at least 2 samples, got {t.shape[0]}")
        if not (np.all(np.isfinite(t)) and all(np.all(np.isfinite(a)) for a in arrays.values())):
            raise InvalidInputError("recording: t, q, dq and tau must be finite")
        if np.any(np.diff(t) <= 0.0):
            k = int(np.flatnonzero(np.diff(t) <= 0.0)[0])
            raise InvalidInputError(f"recording: t must increase strictly; sample {k + 1} "
                                    f"({t[k + 1]!r} s) does not follow {t[k]!r} s")
        object.__setattr__(self, "t", t)
        for name, a in arrays.items():
            object.__setattr__(self, name, a)

    def __len__(self) -> int:
        return self.t.shape[0]

    @property
    def duration(self) -> float:
        return float(self.t[-1] - self.t[0])

    @classmethod
    def from_states(cls, states) -> Recording:
        """From :class:`iem.types.JointState` values (e.g. a replay source's)."""
        states = list(states)
        if not states:
            raise InvalidInputError("recording: no joint states")
        return cls(t=np.array([s.t for s in states]), q=np.array([s.q for s in states]),
                   dq=np.array([s.dq for s in states]), tau=np.array([s.tau_J for s in states]))


def as_recording(x) -> Recording:
    """A :class:`Recording` from one, from anything with ``t, q, dq, tau`` attributes (a
    :class:`sim.plant.Rollout`), from a tuple ``(t, q, dq, tau)`` or from joint states."""
    if isinstance(x, Recording):
        return x
    if all(hasattr(x, a) for a in ("t", "q", "dq", "tau")):
        return Recording(x.t, x.q, x.dq, x.tau)
    if isinstance(x, tuple) and len(x) == 4:
        return Recording(*x)
    return Recording.from_states(x)



@dataclass
class Signals:
    """A recording filtered and sampled: t (n), q, dq, ddq, tau (n, 7)."""

    t: np.ndarray
    q: np.ndarray
    dq: np.ndarray
    ddq: np.ndarray
    tau: np.ndarray
    dtau: np.ndarray
    rate: float  # the uniform grid's rate before decimation, Hz
    fine_t: np.ndarray  # the uniform grid and its filtered signals (for alignment)
    fine: dict
    spikes: int  # samples replaced as spikes


def despike(x: np.ndarray) -> tuple[np.ndarray, int]:
    """Spikes out: samples further than ``SPIKE_SIGMAS`` robust standard deviations (1.4826
    MAD, per column) from a local quadratic fit (Savitzky-Golay, ``SPIKE_WINDOW`` samples) are
    replaced by that fit. Two passes: the first fit is pulled toward a spike, so its neighbours
    are only candidates; the second fit, over the candidates interpolated out, decides."""
    from scipy.signal import savgol_filter

    def deviation(y):
        fit = savgol_filter(y, SPIKE_WINDOW, 2, axis=0, mode="interp")
        return y - fit, fit

    dev, _ = deviation(x)
    scale = np.maximum(1.4826 * np.median(np.abs(dev), axis=0), 1e-12)
    candidate = np.abs(dev) > SPIKE_SIGMAS * scale
    if not candidate.any():
        return x, 0
    idx = np.arange(x.shape[0])
    clean = x.copy()
    for j in np.flatnonzero(candidate.any(axis=0)):
        good = ~candidate[:, j]
        clean[:, j] = np.interp(idx, idx[good], x[good, j])
    _, fit = deviation(clean)
    bad = np.abs(x - fit) > SPIKE_SIGMAS * scale
    return np.where(bad, fit, x), int(bad.sum())


def filtered(rec: Recording, cutoff_hz: float, rate_hz: float, edge_s: float,
              what: str) -> Signals:
    from scipy.signal import butter, sosfiltfilt

    dt = float(np.median(np.diff(rec.t)))
    rate = 1.0 / dt
    if cutoff_hz >= 0.45 * rate or rate_hz > rate:
        raise InvalidInputError(f"{what}: recorded at {rate:.0f} Hz; the cutoff "
                                f"({cutoff_hz:g} Hz) must be below 0.45 of it and the "
                                f"equation rate ({rate_hz:g} Hz) at most that")
    n = math.floor((rec.t[-1] - rec.t[0]) / dt) + 1
    grid = rec.t[0] + dt * np.arange(n)
    sos = butter(4, cutoff_hz / (rate / 2.0), output="sos")
    pad = min(n - 1, int(3 * rate / cutoff_hz))
    if n < 4 * int(rate / cutoff_hz):
        raise InvalidInputError(f"{what}: {rec.duration:.3f} s of recording is too short to "
                                f"filter at {cutoff_hz:g} Hz")
    fine = {}
    spikes = 0
    for name in ("q", "dq", "tau"):
        src = getattr(rec, name)
        on_grid = np.column_stack([np.interp(grid, rec.t, src[:, j]) for j in range(N_JOINTS)])
        on_grid, found = despike(on_grid)
        spikes += found
        fine[name] = sosfiltfilt(sos, on_grid, axis=0, padlen=pad)
    fine["ddq"] = np.gradient(fine["dq"], dt, axis=0)
    fine["dtau"] = np.gradient(fine["tau"], dt, axis=0)
    stride = max(1, round(rate / rate_hz))
    edge = round(edge_s * rate)
    pick = np.arange(edge, n - edge, stride)
    if pick.size < 2:
        raise InvalidInputError(f"{what}: {rec.duration:.3f} s of recording leaves no samples "
                                f"after trimming {edge_s:g} s at both ends")
    return Signals(spikes=spikes, t=grid[pick], q=fine["q"][pick], dq=fine["dq"][pick],
                    ddq=fine["ddq"][pick], tau=fine["tau"][pick], dtau=fine["dtau"][pick],
                    rate=rate,
                    fine_t=grid, fine=fine)


def lag(loaded: Signals, bare: Signals) -> float:
    """Time to add to the bare recording's clock to put it on the loaded one's, s: the peak
    of the cross-correlation of the filtered joint velocities (both on the loaded grid)."""
    dt = 1.0 / loaded.rate
    t_b = bare.fine_t
    n_b = math.floor((t_b[-1] - t_b[0]) / dt) + 1
    grid_b = t_b[0] + dt * np.arange(n_b)
    a = loaded.fine["dq"]
    b = np.column_stack([np.interp(grid_b, t_b, bare.fine["dq"][:, j])
                         for j in range(N_JOINTS)])
    size = 1 << math.ceil(math.log2(a.shape[0] + b.shape[0]))
    fa = np.fft.rfft(a - a.mean(axis=0), size, axis=0)
    fb = np.fft.rfft(b - b.mean(axis=0), size, axis=0)
    xc = np.fft.irfft((fa * np.conj(fb)).sum(axis=1), size)
    k = int(np.argmax(xc))
    y0, y1, y2 = xc[k - 1], xc[k], xc[(k + 1) % size]
    den = y0 - 2.0 * y1 + y2
    frac = 0.5 * (y0 - y2) / den if den < 0.0 else 0.0
    shift = (k if k <= size // 2 else k - size) + frac  # a[i] ~ b[i - shift]
    return loaded.fine_t[0] + shift * dt - grid_b[0]


def sample(sig: Signals, times: np.ndarray) -> dict:
    return {name: np.column_stack([np.interp(times, sig.fine_t, sig.fine[name][:, j])
                                   for j in range(N_JOINTS)])
            for name in ("q", "dq", "ddq", "tau", "dtau")}

