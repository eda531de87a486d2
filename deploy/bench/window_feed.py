"""One model fed through the online loop frame by frame, with its figures per window of the
long run (``iem bench longrun``): bags, memory, route, estimate and learning times, the MAE of
the smoothed estimate, the changes it reported and its share of out-of-distribution
estimates.
"""

from __future__ import annotations

import math
import os
import time

import numpy as np

from iem.metrics import groups_of, mae
from iem.online import OnlineIdentifier
from iem.types import JointState

__all__ = ["ROUTE_EVERY", "WindowFeed", "percentiles", "rss_mb"]

ROUTE_EVERY = 10
"""Every how many samples the route time is measured."""


def rss_mb() -> float:
    """Resident set size of this process, MB (from /proc/self/statm)."""
    try:
        with open("/proc/self/statm") as f:
            pages = int(f.read().split()[1])
        return pages * os.sysconf("SC_PAGE_SIZE") / 1e6
    except (OSError, ValueError, IndexError):
        return math.nan


class WindowFeed:
    """One model fed through an :class:`OnlineIdentifier`, with per-window figures."""

    def __init__(self, name, model, kin, tandem, learn: bool = True) -> None:
        self.name = name
        self.model = model
        self.kin = kin
        self.online = OnlineIdentifier(model, kin.flange_position, tandem.samples,
                                       learn=learn, timed=True)
        self._new_window()
        self.changes_total = 0

    def _new_window(self) -> None:
        self.smoothed: list[np.ndarray] = []
        self.route_s: list[float] = []
        self.route_cpu_s: list[float] = []
        self.changes = 0
        self.ood = 0
        self.online.learn_times.clear()
        self.online.predict_times.clear()
        self.online.learnt.clear()

    @property
    def ensemble(self):
        """The model's ensemble (IEM+phys's own, or the IEM itself)."""
        return getattr(self.model, "ensemble_model", self.model)

    @property
    def router(self):
        return self.ensemble.router

    def step(self, state: JointState, k: int) -> None:
        """One 1 kHz frame: formed into block points by the online loop (an estimate only
        when a block closes; the frames between hold it, as the plug-in's output does)."""
        out = self.online.step(state)
        if out is None:
            return  # before the first block point
        est, smoothed = out
        self.smoothed.append(smoothed)
        if est.extra.get("change"):
            self.changes += 1
        self.ood += bool(est.ood)
        if k % ROUTE_EVERY == 0:
            flange = self.kin.flange_position(state.q)
            router = self.router
            c0, t0 = time.thread_time(), time.perf_counter()
            router.route(state.q, flange)
            self.route_s.append(time.perf_counter() - t0)
            self.route_cpu_s.append(time.thread_time() - c0)

    def window(self, phi) -> dict:
        o = self.online
        learnt = np.array(o.learnt, dtype=bool)
        learn_ms = np.array(o.learn_times)[learnt] * 1e3 if learnt.any() else np.array([])
        est_us = np.array(o.predict_times) * 1e6
        route_us = np.array(self.route_s) * 1e6
        budget = self.ensemble.budget
        out = {
            "bags": int(self.model.n_bags), "nbytes": int(self.model.nbytes()),
            "retired": 0 if budget is None else budget.retired,
            "promoted": 0 if budget is None else budget.promoted,
            "rss_mb": rss_mb(),
            "route_us": percentiles(route_us),
            "route_cpu_us": percentiles(np.array(self.route_cpu_s) * 1e6),
            "estimate_us": percentiles(est_us),
            "learn_ms": {"median": float(np.median(learn_ms)) if learn_ms.size else None,
                         "max": float(learn_ms.max()) if learn_ms.size else None,
                         "total": float(learn_ms.sum()), "points": int(learn_ms.size)},
            "mae": groups_of(mae(np.array(self.smoothed), phi)),
            "changes": self.changes,
            "ood_share": self.ood / max(1, len(self.smoothed)),
        }
        self.changes_total += self.changes
        self._new_window()
        return out


def percentiles(values: np.ndarray) -> dict:
    """``{"p50", "p99"}`` of ``values`` (None each if there are none)."""
    if values.size == 0:
        return {"p50": None, "p99": None}
    return {"p50": float(np.percentile(values, 50)), "p99": float(np.percentile(values, 99))}
