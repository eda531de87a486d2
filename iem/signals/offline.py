"""The offline signal chain: a whole recording made into the signals of an offline fit, one
way for ``iem calibrate`` (:mod:`sim.calibration`) and ``iem identify`` (:mod:`sim.identify`).

The whole recording is there, so the filtering is zero-phase. :func:`prepare`, in order:

1. **Gaps split.** Where the time stamps jump by more than :data:`MAX_GAP_S` (50 ms) the
   recording is split (:func:`segments`), and each piece goes through the chain on its own;
   a piece shorter than ``min_s`` is dropped. Nobody measured the arm during a longer gap, so
   nothing is invented there: interpolated across, half a second of a commissioning motion
   is a straight line 0.1 rad off the path it took, which the fit would read as measured
   (``iem identify`` refused such a recording as "not the same motion" as its bare one, and
   against an arm file it read the invented samples as noise and refused the motion as
   unexciting). A shorter gap (lost cycles, a late burst) holds no detail the 10 Hz low-pass
   would keep (half its period is 50 ms), so it is interpolated over.
2. **Resampled where the clock jitters.** A piece whose time steps depart from their median
   by more than :data:`JITTER_TOL` (1 %) is interpolated linearly onto the uniform grid of
   its median step, so that the filter and the derivatives see the time stamps, not the
   sample count (a real Panda log, filtered sample by sample, had ``ddq`` 12 % off). A piece
   within 1 % is filtered on its own samples: interpolating it onto a grid a fraction of a
   step away would change nothing but smooth it once more.
3. **Spikes out** (:func:`despike`): single corrupt samples (a bad frame), more than
   :data:`SPIKE_SIGMAS` robust standard deviations from a local quadratic fit, are replaced
   by that fit. Through a zero-phase low-pass a spike becomes a bump of about 0.1 s that a
   least-squares fit follows; the calibration's fit has no robust weights against it.
   Simulated traffic loses nothing; on the real Panda recording's last 10 s it replaces 2,826
   of 204,000 samples (2,733 in ``q``: mostly the chords the interpolation draws across the
   logger's 9 ms steps, which the local fit puts back on the curve), and the calibration's
   residual there moves by at most 0.0004 N·m.
4. **Low-pass.** ``q``, ``dq`` and ``tau`` through a 4th-order Butterworth forwards and
   backwards (``scipy.signal.sosfiltfilt``, odd extension over three periods of the
   cut-off), so every signal lines up with every other. The recorded rate is the median
   step's inverse (:func:`iem.signals.rate.detect_rate`) unless the caller gives it. A
   cut-off at or above 0.45 of the recorded rate, or an equation rate above it (by more
   than :data:`iem.signals.rate.RATE_TOL`: a 100 Hz logger's clock may run a little slow),
   is refused naming the rate: moved in silence, the filter would not be the one the
   result's report states.
5. **Derivatives, decimation.** ``ddq`` and ``dtau`` are the central differences of the
   filtered ``dq`` and ``tau`` over the time stamps; the first and last ``edge_s`` of each
   piece are dropped (the filter's edges) and the rest taken every ``1/rate_hz`` s (the
   low-pass is the anti-alias filter).

:func:`lag` finds the time shift between two recordings of one motion; :func:`piece_of`,
:func:`covered` and :func:`sample` read the filtered signals at any instants inside their
pieces.

numpy at import; scipy when a recording is prepared.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import InvalidInputError
from ..types import N_JOINTS
from .rate import MAX_GAP_S, RATE_TOL, detect_rate
from .recording import Recording

JITTER_TOL = 0.01
"""Time steps that depart from their median by more than this share make :func:`prepare`
resample a piece onto a uniform grid before it filters."""
MAX_CUTOFF_SHARE = 0.45
"""The highest cut-off, as a share of the recorded rate."""
SPIKE_WINDOW = 11
"""Window of the local quadratic fit that spikes are measured against, samples."""
SPIKE_SIGMAS = 6.0
"""Deviation from the local fit, in robust standard deviations, that marks a spike."""
SIGNALS = ("q", "dq", "ddq", "tau", "dtau")


@dataclass
class Signals:
    """A recording prepared: its pieces filtered, trimmed and decimated, one after another.

    Attributes:
        t: instants of the equations, s (n); q, dq, ddq, tau, dtau: there (n, 7).
        rate: the recorded rate (the median step's inverse, or as given), Hz.
        fine_t: every filtered sample's instant, s, pieces one after another.
        fine: the filtered ``q, dq, ddq, tau, dtau`` at ``fine_t``.
        starts: where each piece begins in ``fine_t``.
        t_starts: where each piece begins in ``t``.
        spikes: samples replaced as spikes.
        dropped: pieces shorter than ``min_s`` left out.
    """

    t: np.ndarray
    q: np.ndarray
    dq: np.ndarray
    ddq: np.ndarray
    tau: np.ndarray
    dtau: np.ndarray
    rate: float
    fine_t: np.ndarray
    fine: dict
    starts: np.ndarray
    t_starts: np.ndarray
    spikes: int
    dropped: int

    @property
    def pieces(self) -> int:
        return int(self.starts.shape[0])

    @property
    def duration(self) -> float:
        """The time the equations span, the gaps between pieces left out, s."""
        return float(sum(p[-1] - p[0] for p in np.split(self.t, self.t_starts[1:]) if p.size))


def segments(t, q, dq, tau, min_s: float = 3.0) -> list[tuple]:
    """``(t, q, dq, tau)`` split where the time stamps jump by more than :data:`MAX_GAP_S`
    (lost cycles, a restart); pieces shorter than ``min_s`` (s) or 10 samples are dropped."""
    t = np.asarray(t, dtype=float)
    cuts = np.flatnonzero(np.diff(t) > MAX_GAP_S) + 1
    out = []
    for a, b in zip(np.r_[0, cuts], np.r_[cuts, t.shape[0]], strict=True):
        if b - a >= 10 and t[b - 1] - t[a] >= min_s:
            out.append((t[a:b], *(np.asarray(x)[a:b] for x in (q, dq, tau))))
    return out


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


def prepare(rec: Recording, cutoff_hz: float, rate_hz: float, edge_s: float,
            min_s: float | None = None, what: str = "recording",
            recorded_rate_hz: float | None = None) -> Signals:
    """``rec`` through the offline chain (the module docstring's steps 1-5).

    Args:
        rec: the recording (:class:`iem.signals.recording.Recording`).
        cutoff_hz: the zero-phase low-pass's cut-off, Hz.
        rate_hz: the rate of the equations after decimation, Hz.
        edge_s: dropped at both ends of each piece after filtering, s.
        min_s: the shortest piece used, s (None: ``2 edge_s + 4 / cutoff_hz``, what the filter
            needs to settle and leave samples).
        what: the recording's name in errors.
        recorded_rate_hz: the recording's rate, Hz (None: detected from its time stamps,
            :func:`iem.signals.rate.detect_rate`).

    Raises:
        InvalidInputError: the cut-off or the rate does not suit the recorded rate, or no
            piece is ``min_s`` long.
    """
    from scipy.signal import butter

    if not (cutoff_hz > 0.0 and rate_hz > 0.0 and edge_s >= 0.0):
        raise InvalidInputError(f"{what}: cutoff_hz and rate_hz must be > 0 and edge_s >= 0, "
                                f"got {cutoff_hz}, {rate_hz}, {edge_s}")
    min_s = 2.0 * edge_s + 4.0 / cutoff_hz if min_s is None else min_s
    rate = detect_rate(rec.t) if recorded_rate_hz is None else float(recorded_rate_hz)
    if cutoff_hz >= MAX_CUTOFF_SHARE * rate or rate_hz > rate * (1.0 + RATE_TOL):
        raise InvalidInputError(
            f"{what}: recorded at {rate:.1f} Hz; valid is a cut-off below "
            f"{MAX_CUTOFF_SHARE:g} of that ({MAX_CUTOFF_SHARE * rate:.1f} Hz, got "
            f"{cutoff_hz:g} Hz) and an equation rate at most that (got {rate_hz:g} Hz)")
    every = segments(rec.t, rec.q, rec.dq, rec.tau, min_s=0.0)
    pieces = [p for p in every if p[0][-1] - p[0][0] >= min_s]
    if not pieces:
        longest = max((p[0][-1] - p[0][0] for p in every), default=0.0)
        raise InvalidInputError(
            f"{what}: too short to filter at {cutoff_hz:g} Hz: its longest stretch without a "
            f"gap of more than {1e3 * MAX_GAP_S:.0f} ms is {longest:.3f} s; valid is at "
            f"least {min_s:.2f} s")
    sos = butter(4, cutoff_hz, fs=rate, output="sos")
    done = [_piece(p, sos, rate, cutoff_hz, rate_hz, edge_s) for p in pieces]
    sizes = np.array([d[0].size for d in done])
    starts = np.r_[0, np.cumsum(sizes)[:-1]]
    fine_t = np.concatenate([d[0] for d in done])
    fine = {k: np.concatenate([d[1][k] for d in done]) for k in SIGNALS}
    pick = np.concatenate([d[2] + a for d, a in zip(done, starts, strict=True)])
    if pick.size < 2:
        raise InvalidInputError(f"{what}: {rec.duration:.3f} s of recording leaves no samples "
                                f"after trimming {edge_s:g} s at both ends of each piece")
    t_starts = np.r_[0, np.cumsum([d[2].size for d in done])[:-1]]
    return Signals(t=fine_t[pick], **{k: fine[k][pick] for k in SIGNALS}, rate=rate,
                   fine_t=fine_t, fine=fine, starts=starts, t_starts=t_starts,
                   spikes=sum(d[3] for d in done), dropped=len(every) - len(pieces))


def _piece(piece, sos, rate: float, cutoff_hz: float, rate_hz: float, edge_s: float):
    """``(fine_t, fine, pick, spikes)`` of one gap-free piece: steps 2-5."""
    from scipy.signal import sosfiltfilt

    t, *arrays = piece
    if np.max(np.abs(np.diff(t) * rate - 1.0)) > JITTER_TOL:
        grid = t[0] + np.arange(math.floor((t[-1] - t[0]) * rate) + 1) / rate
        arrays = [np.column_stack([np.interp(grid, t, a[:, j]) for j in range(N_JOINTS)])
                  for a in arrays]
        t = grid
    fine, spikes = {}, 0
    pad = min(t.shape[0] - 1, int(3.0 * rate / cutoff_hz))
    for name, a in zip(("q", "dq", "tau"), arrays, strict=True):
        a, found = despike(a)
        spikes += found
        fine[name] = sosfiltfilt(sos, a, axis=0, padlen=pad)
    fine["ddq"] = np.gradient(fine["dq"], t, axis=0)
    fine["dtau"] = np.gradient(fine["tau"], t, axis=0)
    step = max(1, round(rate / rate_hz))
    pick = np.flatnonzero((t >= t[0] + edge_s) & (t <= t[-1] - edge_s))[::step]
    return t, fine, pick, spikes


def piece_of(sig: Signals, times: np.ndarray) -> np.ndarray:
    """The piece of ``sig`` each of ``times`` (s) lies inside, or -1 (int, same shape)."""
    times = np.asarray(times, dtype=float)
    first = sig.fine_t[sig.starts]
    last = sig.fine_t[np.r_[sig.starts[1:], sig.fine_t.shape[0]] - 1]
    k = np.searchsorted(first, times, side="right") - 1
    return np.where((k >= 0) & (times <= last[np.maximum(k, 0)]), k, -1)


def covered(sig: Signals, times: np.ndarray) -> np.ndarray:
    """Which of ``times`` (s) lie inside a piece of ``sig`` (bool, same shape)."""
    return piece_of(sig, times) >= 0


def sample(sig: Signals, times: np.ndarray) -> dict:
    """The filtered ``q, dq, ddq, tau, dtau`` at ``times`` (s), each inside a piece
    (:func:`covered`): linear interpolation between the filtered samples."""
    return {name: np.column_stack([np.interp(times, sig.fine_t, sig.fine[name][:, j])
                                   for j in range(N_JOINTS)]) for name in SIGNALS}


def _dq_on_grid(sig: Signals, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """``(grid, dq)``: the filtered joint velocities on a uniform grid of step ``dt`` over the
    recording, less their mean, zero between its pieces."""
    grid = sig.fine_t[0] + dt * np.arange(math.floor((sig.fine_t[-1] - sig.fine_t[0]) / dt) + 1)
    inside = covered(sig, grid)
    dq = np.column_stack([np.interp(grid, sig.fine_t, sig.fine["dq"][:, j])
                          for j in range(N_JOINTS)])
    dq -= dq[inside].mean(axis=0)
    dq[~inside] = 0.0
    return grid, dq


def lag(loaded: Signals, bare: Signals) -> float:
    """Time to add to the bare recording's clock to put it on the loaded one's, s: the peak
    of the cross-correlation of the filtered joint velocities (both on a grid of the loaded
    recording's step, zero between pieces), parabolic for the sub-sample part."""
    dt = 1.0 / loaded.rate
    grid_a, a = _dq_on_grid(loaded, dt)
    grid_b, b = _dq_on_grid(bare, dt)
    size = 1 << math.ceil(math.log2(a.shape[0] + b.shape[0]))
    fa = np.fft.rfft(a, size, axis=0)
    fb = np.fft.rfft(b, size, axis=0)
    xc = np.fft.irfft((fa * np.conj(fb)).sum(axis=1), size)
    k = int(np.argmax(xc))
    y0, y1, y2 = xc[k - 1], xc[k], xc[(k + 1) % size]
    den = y0 - 2.0 * y1 + y2
    frac = 0.5 * (y0 - y2) / den if den < 0.0 else 0.0
    shift = (k if k <= size // 2 else k - size) + frac  # a[i] ~ b[i - shift]
    return grid_a[0] + shift * dt - grid_b[0]
