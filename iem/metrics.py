"""Accuracy figures of the paper: MAE per parameter and per group, and convergence time.

- ``mae``: mean absolute error of each of the 10 parameters over the estimates a model output
  along a path (after the causal smoothing, the same for every model).
- ``mae_groups``: ``mass`` = MAE of m; ``com`` = mean MAE of m·rx, m·ry, m·rz; ``inertia`` =
  mean MAE of the six inertia terms.
- ``convergence_s``: for each group, the first time from which the 100 ms moving average of
  the estimate stays within the group's threshold until the end of the path (the group's
  error at an instant is the mean absolute error of its parameters), or None if it never does.
  The thresholds are twice the paper's new-path MAE (Table 4): 0.014 kg, 0.016 kg·m,
  0.0014 kg·m².
- ``coverage``: for models that report a standard deviation per parameter, the share of
  samples whose absolute error is within two of them (0.95 for honest Gaussian errors).
"""

from __future__ import annotations

import numpy as np

from .types import GROUPS, NOMINAL_RATE_HZ, PARAMS

PAPER_NEW_PATH_MAE = {"mass": 0.007, "com": 0.008, "inertia": 0.0007}
CONVERGENCE_THRESHOLDS = {g: 2.0 * v for g, v in PAPER_NEW_PATH_MAE.items()}


def abs_errors(estimates, truth) -> np.ndarray:
    return np.abs(np.asarray(estimates, dtype=float) - np.asarray(truth, dtype=float))


def mae(estimates, truth) -> dict[str, float]:
    """MAE of each parameter, keyed by the names in :data:`iem.types.PARAMS`."""
    err = abs_errors(estimates, truth).mean(axis=0)
    return {name: float(v) for name, v in zip(PARAMS, err, strict=True)}


def groups_of(per_param: dict[str, float]) -> dict[str, float]:
    values = np.array([per_param[p] for p in PARAMS])
    return {g: float(values[list(idx)].mean()) for g, idx in GROUPS.items()}


def mae_groups(estimates, truth) -> dict[str, float]:
    return groups_of(mae(estimates, truth))


def moving_average(x: np.ndarray, window: int) -> np.ndarray:
    """Trailing moving average over up to ``window`` samples (causal), row-wise."""
    x = np.asarray(x, dtype=float)
    c = np.cumsum(np.vstack((np.zeros((1, *x.shape[1:])), x)), axis=0)
    n = np.arange(1, x.shape[0] + 1)
    lo = np.maximum(n - window, 0)
    counts = (n - lo).reshape((-1,) + (1,) * (x.ndim - 1))
    return (c[n] - c[lo]) / counts


def convergence_s(t, estimates, truth, thresholds=None, window_s: float = 0.1,
                  dt: float = 1.0 / NOMINAL_RATE_HZ) -> dict[str, float | None]:
    """Per group, the first time after which the moving-average error stays in bounds."""
    thresholds = CONVERGENCE_THRESHOLDS if thresholds is None else thresholds
    t = np.asarray(t, dtype=float)
    smooth = moving_average(estimates, max(1, round(window_s / dt)))
    err = abs_errors(smooth, truth)
    out: dict[str, float | None] = {}
    for g, idx in GROUPS.items():
        e = err[:, list(idx)].mean(axis=1)
        bad = np.flatnonzero(~(e <= thresholds[g]))
        if bad.size == 0:
            out[g] = float(t[0] - t[0])
        elif bad[-1] == len(e) - 1:
            out[g] = None
        else:
            out[g] = float(t[bad[-1] + 1] - t[0])
    return out


def coverage(estimates, std, truth, k: float = 2.0) -> dict[str, float] | None:
    """Share of (sample, parameter) pairs whose absolute error is within ``k`` reported
    standard deviations: ``"all"`` over the ten parameters and one entry per group; None if
    the estimates carry no standard deviation (``std`` None or NaN)."""
    if std is None:
        return None
    std = np.asarray(std, dtype=float)
    if std.size == 0 or not np.all(np.isfinite(std)):
        return None
    inside = abs_errors(estimates, truth) <= k * std
    out = {"all": float(inside.mean())}
    out.update({g: float(inside[:, list(idx)].mean()) for g, idx in GROUPS.items()})
    return out
