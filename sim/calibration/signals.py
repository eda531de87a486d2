"""Step 1 of the calibration: the signals, zero-phase filtered, differentiated and decimated
(on a uniform grid), and traffic split at its gaps into segments filtered apart."""

from __future__ import annotations

import numpy as np
from scipy.signal import butter, sosfiltfilt

from .prior import DEFAULT_SETTINGS, CalibrationError, CalibrationSettings

JITTER_TOL = 0.01
"""Time steps that depart from their median by more than this fraction make
:func:`prepare` resample the traffic onto a uniform grid before it filters."""


def prepare(t, q, dq, tau, s: CalibrationSettings = DEFAULT_SETTINGS):
    """Zero-phase filtered, differentiated and decimated ``(t, q, dq, ddq, tau)``.

    The filter runs on a uniform grid: traffic whose time steps jitter (a logger's: by more
    than :data:`JITTER_TOL` of the median step) is first interpolated linearly onto the grid
    of its median step, so that the filter and the derivative see the time stamps, not the
    sample count (a real Panda log, filtered sample by sample, had ``ddq`` 12 % off and twice
    the residual on joints 1-3)."""
    t = np.asarray(t, dtype=float)
    q, dq, tau = (np.asarray(a, dtype=float) for a in (q, dq, tau))
    n = t.shape[0]
    if n < 10 or q.shape != (n, 7) or dq.shape != (n, 7) or tau.shape != (n, 7):
        raise CalibrationError(f"calibration needs (N, 7) q, dq, tau with N >= 10 samples, "
                               f"got t {t.shape}, q {q.shape}, dq {dq.shape}, tau {tau.shape}")
    dt = np.diff(t)
    if np.any(dt <= 0.0):
        raise CalibrationError("calibration needs strictly increasing time stamps")
    rate = 1.0 / float(np.median(dt))
    duration = float(t[-1] - t[0])
    if duration < 4.0 * s.trim_s + 2.0:
        raise CalibrationError(f"{duration:.2f} s of traffic is too short to calibrate; "
                               f"record at least {4.0 * s.trim_s + 2.0:.0f} s of the "
                               f"calibration motion (30 s: sim.paths.calibration_path)")
    if np.max(np.abs(dt * rate - 1.0)) > JITTER_TOL:
        grid = t[0] + np.arange(int(np.floor(duration * rate)) + 1) / rate
        q, dq, tau = (np.column_stack([np.interp(grid, t, a[:, j]) for j in range(7)])
                      for a in (q, dq, tau))
        t = grid
    sos = butter(4, min(s.cutoff_hz, 0.45 * rate), fs=rate, output="sos")
    qf, dqf, tauf = (sosfiltfilt(sos, a, axis=0) for a in (q, dq, tau))
    ddqf = np.gradient(dqf, t, axis=0)
    step = max(1, round(rate / s.rate_hz))
    keep = np.flatnonzero((t >= t[0] + s.trim_s) & (t <= t[-1] - s.trim_s))[::step]
    return t[keep], qf[keep], dqf[keep], ddqf[keep], tauf[keep]


MAX_GAP_S = 0.05
"""A longer gap between two time stamps splits the traffic into segments filtered apart."""


def segments(t, q, dq, tau, min_s: float = 3.0) -> list[tuple]:
    """``(t, q, dq, tau)`` split where the time stamps jump by more than :data:`MAX_GAP_S`
    (lost cycles, a restart); segments shorter than ``min_s`` are dropped."""
    t = np.asarray(t, dtype=float)
    cuts = np.flatnonzero(np.diff(t) > MAX_GAP_S) + 1
    out = []
    for a, b in zip(np.r_[0, cuts], np.r_[cuts, t.shape[0]], strict=True):
        if b - a >= 10 and t[b - 1] - t[a] >= min_s:
            out.append((t[a:b], *(np.asarray(x)[a:b] for x in (q, dq, tau))))
    return out
