"""The benchmarks' timing: bag routing among many bags, IEM+phys's cycle as the plug-in runs
it on a live link (back to back, and paced as a 1 kHz cell's blocks come), and the machine's
own speed (:func:`machine_speed`), which a timing is read beside.
"""

from __future__ import annotations

import time
from collections.abc import Iterable

import numpy as np

from iem.ensemble.router import BagRouter
from iem.online import OnlineIdentifier
from iem.types import NOMINAL_POINT_RATE_HZ

from .harness import Bench, rollout_blocks

__all__ = ["MACHINE_LOOP", "PACED_RATE_HZ", "ROUTE_SIZES", "cycle_timing", "machine_speed",
           "route_timing", "step_timing"]

ROUTE_SIZES = (1, 10, 100, 1000, 10000)
PACED_RATE_HZ = NOMINAL_POINT_RATE_HZ
"""The rate at which :func:`cycle_timing`'s paced run feeds block points: a Panda's 1 kHz in
blocks of 10 frames."""


def cycle_timing(bench: Bench, model, rollout, rate_hz: float | None = None,
                 points: int | None = None) -> dict:
    """µs per :meth:`iem.online.OnlineIdentifier.step_block` of ``model`` along ``rollout``'s
    block points (a new task, learning on) with its ensemble's training in the learning
    worker, as the plug-in runs it on a live link (:meth:`iem.base.Estimator.go_live`):
    ``{"median", "p99", "cpu_mean", "points"}`` (``cpu_mean``: the step thread's CPU). The
    worker's own time is not counted (it competes for the interpreter, so it shows in the
    step's time as it would there).

    ``rate_hz``: one step per period of that rate, the thread idle between them, as on a live
    link; None: back to back. Paced, the same steps cost more: each is a short burst of
    interpreter and NumPy code that starts with cold caches and predictors. The paced figure
    is the one a cell meets; the back-to-back one is the code's own cost.

    ``points``: only the rollout's first that many block points (None: all of them). A paced
    run takes the rollout's own duration of wall time, whatever the machine."""
    model.reset()
    model.go_live()  # the live link's set-up, as deploy.service.loop makes it
    online = OnlineIdentifier(model, bench.kin.flange_position, bench.tandem.samples,
                              learn=True)
    blocks = rollout_blocks(rollout)
    n = len(blocks) if points is None else min(int(points), len(blocks))
    try:
        return step_timing(online, (blocks.state(k) for k in range(n)), rate_hz)
    finally:
        model.stop()


def step_timing(online: OnlineIdentifier, states: Iterable, rate_hz: float | None = None
                ) -> dict:
    """µs per ``online.step_block`` over ``states`` (block points), back to back (``rate_hz``
    None) or one per period of ``rate_hz`` with the thread idle between them: ``{"median",
    "p99"}`` of the wall time, ``"cpu_mean"`` of this thread's CPU and ``"points"``."""
    times, cpu = [], []
    period = None if rate_hz is None else 1.0 / float(rate_hz)
    due = time.perf_counter()
    for state in states:
        if period is not None:  # the next block comes one period after the last
            due += period
            wait = due - time.perf_counter()
            if wait > 0.0:
                time.sleep(wait)
        c0, t0 = time.thread_time(), time.perf_counter()
        online.step_block(state)
        times.append(time.perf_counter() - t0)
        cpu.append(time.thread_time() - c0)
    if not times:
        raise ValueError("step_timing needs at least one block point")
    times_us = np.asarray(times) * 1e6
    return {"median": float(np.median(times_us)), "p99": float(np.percentile(times_us, 99)),
            "cpu_mean": float(np.mean(cpu) * 1e6), "points": len(times)}


def route_timing(kin, sizes=ROUTE_SIZES, queries: int = 2000, seed: int = 0) -> dict:
    """Median µs of one :meth:`BagRouter.route` among ``n`` bags spread over the workspace."""
    rng = np.random.default_rng(seed)
    out = {}
    for n in sizes:
        qs = rng.uniform(kin.q_min, kin.q_max, size=(n, 7))
        router = BagRouter.from_means(qs, kin.flange_positions(qs))
        probe_q = rng.uniform(kin.q_min, kin.q_max, size=(queries, 7))
        probe_f = kin.flange_positions(probe_q)
        times = np.empty(queries)
        for i in range(queries):
            t0 = time.perf_counter()
            router.route(probe_q[i], probe_f[i])
            times[i] = time.perf_counter() - t0
        out[str(n)] = float(np.median(times) * 1e6)
    return out


MACHINE_LOOP = (2000, 5)
"""The fixed work :func:`machine_speed` times: ``(rounds, repeats)``. A round is what an
estimate is made of: a few dozen small NumPy calls (products, a solve, a Cholesky factor, on
7 to 22 values) and the Python arithmetic between them."""


def _machine_round(a: np.ndarray, b: np.ndarray, v: np.ndarray) -> float:
    """One round of :data:`MACHINE_LOOP`'s fixed work; its result (so nothing is skipped)."""
    m = a @ a.T
    m += b @ b.T
    m += np.eye(22)
    c = np.linalg.cholesky(m)
    x = np.linalg.solve(m, v)
    y = np.maximum(a[:10] @ x, 0.0)
    acc = 0.0
    for k in range(40):  # the interpreter's share: scalar arithmetic and branches
        acc += (k * 0.5 + float(y[k % 10])) / (1.0 + k)
    return acc + float(c[-1, -1]) + float(np.abs(x).max())


def machine_speed(rounds: int | None = None, repeats: int | None = None) -> dict:
    """The machine's own speed now: :data:`MACHINE_LOOP`'s fixed work (the same numbers every
    time), ``repeats`` times, each timed by this thread's CPU clock and by the wall clock:
    ``{"cpu_us", "wall_us"}``, the medians, µs per round. On the same machine and build a
    change of it is the host (its load, its clock, another process on the core's sibling),
    not the code: a share read beside it tells the two apart."""
    rounds = MACHINE_LOOP[0] if rounds is None else int(rounds)
    repeats = MACHINE_LOOP[1] if repeats is None else int(repeats)
    if rounds < 1 or repeats < 1:
        raise ValueError(f"machine_speed needs rounds and repeats >= 1, got {rounds}, "
                         f"{repeats}")
    rng = np.random.default_rng(0)
    a, b, v = rng.standard_normal((22, 22)), rng.standard_normal((22, 22)), rng.standard_normal(22)
    cpu, wall = [], []
    for _ in range(repeats):
        c0, t0 = time.thread_time(), time.perf_counter()
        for _ in range(rounds):
            _machine_round(a, b, v)
        cpu.append(time.thread_time() - c0)
        wall.append(time.perf_counter() - t0)
    return {"cpu_us": float(np.median(cpu)) / rounds * 1e6,
            "wall_us": float(np.median(wall)) / rounds * 1e6}
