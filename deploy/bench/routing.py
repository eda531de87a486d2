"""Routing among many bags: the float32 scan against the spatial index, on the same maps.

For each size a map of that many bags (means drawn uniformly within the joint limits, one bag
per mean, :meth:`BagRouter.from_means`) routes two sets of queries, each query timed once
with the scan and once with the index, one after the other (so the machine's other work
falls on both alike):

- ``random``: poses drawn uniformly within the limits; among a few thousand bags nearly all
  fall outside every bag (the slow case of the index: it also looks for the nearest bag);
- ``inside``: a bag's mean moved by N(0, 0.05 rad) per joint, nearly all inside a bag (what
  the cycle routes almost always: a point outside every bag starts a bag and its learning).

Per size: ``bags``, ``build_ms`` (the index's first build and one route through it),
``same`` (the two gave the same ``(bag, nearest)`` for every query) and, per query set,
``scan`` and ``index`` route µs (p50/p99, wall clock; ``scan_cpu`` and ``index_cpu`` the
same in this thread's CPU time, which leaves out the time the machine ran other work) and
``inside_share`` (the share of queries inside a bag).
"""

from __future__ import annotations

import time

import numpy as np


def scan_vs_index(kin, sizes, seed: int = 0, queries: int = 2000) -> list[dict]:
    """The scan and the index on maps of ``sizes`` bags; see the module docstring."""
    import scipy.spatial  # noqa: F401  (imported once here: ``build_ms`` is the build alone)

    from iem.router import BagRouter

    out = []
    for n in sizes:
        rng = np.random.default_rng([seed, 2001, int(n)])
        Q = rng.uniform(kin.q_min, kin.q_max, size=(int(n), 7))
        router = BagRouter.from_means(Q, kin.flange_positions(Q))
        probes = {"random": rng.uniform(kin.q_min, kin.q_max, size=(queries, 7)),
                  "inside": Q[rng.integers(0, n, queries)] + rng.normal(0, 0.05, (queries, 7))}
        router.index_above = 0
        t0 = time.perf_counter()
        router.route(probes["random"][0], kin.flange_position(probes["random"][0]))
        row = {"bags": int(n), "build_ms": (time.perf_counter() - t0) * 1e3, "same": True}
        for name, P in probes.items():
            F = kin.flange_positions(P)
            times = {way: np.empty(queries) for way in ("scan", "index", "scan_cpu", "index_cpu")}
            inside = 0
            for i in range(queries):
                router.index_above = None
                c0, t0 = time.thread_time(), time.perf_counter()
                by_scan = router.route(P[i], F[i])
                times["scan"][i] = time.perf_counter() - t0
                times["scan_cpu"][i] = time.thread_time() - c0
                router.index_above = 0
                c0, t0 = time.thread_time(), time.perf_counter()
                by_index = router.route(P[i], F[i])
                times["index"][i] = time.perf_counter() - t0
                times["index_cpu"][i] = time.thread_time() - c0
                row["same"] &= by_scan == by_index
                inside += by_scan[0] >= 0
            row[name] = {way: _pct(t * 1e6) for way, t in times.items()}
            row[name]["inside_share"] = inside / queries
        out.append(row)
    return out


def _pct(values: np.ndarray) -> dict:
    return {"p50": float(np.percentile(values, 50)), "p99": float(np.percentile(values, 99))}


def format_rows(rows: list[dict]) -> str:
    """One line per size and query set: route µs p50/p99, scan vs index, wall and CPU."""
    lines = []
    for r in rows:
        for name in ("random", "inside"):
            f = {k: f"{v['p50']:.1f}/{v['p99']:.1f}" for k, v in r[name].items()
                 if isinstance(v, dict)}
            lines.append(f"{r['bags']:>7,} bags {name:6s}: scan {f['scan']} (cpu "
                         f"{f['scan_cpu']}) µs, index {f['index']} (cpu {f['index_cpu']}) µs, "
                         f"{r[name]['inside_share']:.0%} inside a bag")
        lines.append(f"{r['bags']:>7,} bags: index build {r['build_ms']:.1f} ms, "
                     f"same decisions {r['same']}")
    return "\n".join(lines)
