"""Routing among many bags: the router's float32 scan against exact distances to every bag.

For each size a map of that many bags (means drawn uniformly within the joint limits, one bag
per mean, :meth:`BagRouter.from_means`) routes two sets of queries, each set timed once with
:meth:`BagRouter.route` (the scan above 64 bags) and then once with
:meth:`BagRouter.route_exact` (float64 distances to every bag; one loop each, so the exact
distances' large arrays do not evict the scan's from the caches between its queries):

- ``random``: poses drawn uniformly within the limits; among a few thousand bags nearly all
  fall outside every bag;
- ``inside``: a bag's mean moved by N(0, 0.05 rad) per joint, nearly all inside a bag (what
  the cycle routes almost always: a point outside every bag starts a bag and its learning).

Per size: ``bags``, ``same`` (the two gave the same ``(bag, nearest)`` for every query) and,
per query set, ``scan`` and ``exact`` route µs (p50/p99, wall clock; ``scan_cpu`` and
``exact_cpu`` the same in this thread's CPU time, which leaves out the time the machine ran
other work) and ``inside_share`` (the share of queries inside a bag).
"""

from __future__ import annotations

import time

import numpy as np


def scan_vs_exact(kin, sizes, seed: int = 0, queries: int = 2000) -> list[dict]:
    """The scan and exact distances on maps of ``sizes`` bags; see the module docstring."""
    from iem.ensemble.router import BagRouter

    out = []
    for n in sizes:
        rng = np.random.default_rng([seed, 2001, int(n)])
        Q = rng.uniform(kin.q_min, kin.q_max, size=(int(n), 7))
        router = BagRouter.from_means(Q, kin.flange_positions(Q))
        probes = {"random": rng.uniform(kin.q_min, kin.q_max, size=(queries, 7)),
                  "inside": Q[rng.integers(0, n, queries)] + rng.normal(0, 0.05, (queries, 7))}
        row = {"bags": int(n), "same": True}
        for name, P in probes.items():
            F = kin.flange_positions(P)
            times, got = {}, {}
            for way, route in (("scan", router.route), ("exact", router.route_exact)):
                wall, cpu = np.empty(queries), np.empty(queries)
                got[way] = []
                for i in range(queries):
                    c0, t0 = time.thread_time(), time.perf_counter()
                    got[way].append(route(P[i], F[i]))
                    wall[i] = time.perf_counter() - t0
                    cpu[i] = time.thread_time() - c0
                times[way], times[f"{way}_cpu"] = wall, cpu
            row["same"] &= got["scan"] == got["exact"]
            row[name] = {way: _pct(t * 1e6) for way, t in times.items()}
            row[name]["inside_share"] = sum(bag >= 0 for bag, _ in got["scan"]) / queries
        out.append(row)
    return out


def _pct(values: np.ndarray) -> dict:
    return {"p50": float(np.percentile(values, 50)), "p99": float(np.percentile(values, 99))}


def format_rows(rows: list[dict]) -> str:
    """One line per size and query set: route µs p50/p99, scan vs exact, wall and CPU."""
    lines = []
    for r in rows:
        for name in ("random", "inside"):
            f = {k: f"{v['p50']:.1f}/{v['p99']:.1f}" for k, v in r[name].items()
                 if isinstance(v, dict)}
            lines.append(f"{r['bags']:>7,} bags {name:6s}: scan {f['scan']} (cpu "
                         f"{f['scan_cpu']}) µs, exact {f['exact']} (cpu {f['exact_cpu']}) µs, "
                         f"{r[name]['inside_share']:.0%} inside a bag")
        lines.append(f"{r['bags']:>7,} bags: same decisions {r['same']}")
    return "\n".join(lines)
