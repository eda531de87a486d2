"""The long run's task motion: random rest-to-rest quintic segments within the arm's limits,
and the same motion driven backwards.

Each segment (:func:`sim.paths.linear_path`) goes between random waypoints drawn uniformly
within the joint limits less a margin of :data:`MARGIN` of each joint's range; its duration
is the shortest that keeps every joint's velocity and acceleration within
:data:`LIMIT_FRACTION` (90 %) of its limit (a quintic's peaks are ``1.875 |dq| / T`` and
``5.7735 |dq| / T²``).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["LIMIT_FRACTION", "MARGIN", "MIN_SEGMENT_S", "random_segments", "reversed_path",
           "segment_duration"]

MARGIN = 0.1
"""Margin of the waypoints from the joint limits, as a fraction of each joint's range."""
LIMIT_FRACTION = 0.9
"""Largest fraction of the velocity and acceleration limits a segment uses."""
MIN_SEGMENT_S = 0.5
_QUINTIC_DS = 1.875
_QUINTIC_DDS = 10.0 / math.sqrt(3.0)


def segment_duration(q_a, q_b, dq_max, ddq_max, fraction: float = LIMIT_FRACTION) -> float:
    """Shortest quintic duration (s, whole ms) from ``q_a`` to ``q_b`` within ``fraction``
    of the velocity and acceleration limits."""
    d = np.abs(np.asarray(q_b, float) - np.asarray(q_a, float))
    t_v = float(np.max(_QUINTIC_DS * d / (fraction * dq_max)))
    t_a = float(np.max(np.sqrt(_QUINTIC_DDS * d / (fraction * ddq_max))))
    return max(MIN_SEGMENT_S, math.ceil(max(t_v, t_a) * 1000.0 + 1.0) / 1000.0)


def random_segments(seconds: float, seed: int, kin):
    """Random rest-to-rest quintic segments (:class:`sim.paths.Path`) totalling at least
    ``seconds``; yields them one at a time."""
    from sim.paths import linear_path

    rng = np.random.default_rng([seed, 15])
    span = kin.q_max - kin.q_min
    lo, hi = kin.q_min + MARGIN * span, kin.q_max - MARGIN * span
    q = rng.uniform(lo, hi)
    total, k = 0.0, 0
    while total < seconds:
        nxt = rng.uniform(lo, hi)
        T = segment_duration(q, nxt, kin.dq_max, kin.ddq_max)
        seg = linear_path(q, nxt, T, name=f"segment-{k}", model=kin)
        total += seg.duration
        k += 1
        q = nxt
        yield seg


def reversed_path(segments):
    """The segments driven backwards: the last first, each from its end to its start, with
    every velocity reversed (q(T - t), -dq(T - t), ddq(T - t))."""
    from sim.paths import Path

    path = None
    for seg in reversed(segments):
        back = Path(name=f"{seg.name}-back", t=seg.t, q=seg.q[::-1], dq=-seg.dq[::-1],
                    ddq=seg.ddq[::-1])
        path = back if path is None else path.then(back)
    return path
