"""A spatial index over the bag centres: which bags may lie within a radius of a point.

:class:`CentreIndex` is a k-d tree (``scipy.spatial.cKDTree``) over a snapshot of the bags'
joint-space means, plus the bags it cannot vouch for ("loose"): those added since the
snapshot and those whose mean moved from its snapshot by more than ``slack`` (a point joins a
bag and its running mean moves; a budget reuses a slot and its mean jumps). Every other bag's
mean is within ``drift`` (the largest such move so far, at most ``slack``) of its snapshot,
so a bag truly within ``r`` of a point is within ``r + drift`` of it in the tree:
:meth:`CentreIndex.within` asks the tree for that widened ball and adds every loose bag, a
superset of the bags truly within ``r``; :meth:`CentreIndex.nearest` likewise says how far
its candidates are complete. The caller decides among them with exact float64 distances to
the current means, so the index changes how many bags are looked at, never which bag wins.
The tree is rebuilt from the current means when more than ``loose_max`` bags are loose (a
rebuild runs on the thread that routes: 5-14 ms at 20,000 bags here).

The index is derived state: it is never saved, and a copy or a loaded model builds its own
when it first routes.
"""

from __future__ import annotations

import math

import numpy as np

DEFAULT_SLACK = 0.05
"""How far, rad, a bag's mean may move from its snapshot before the bag is loose."""
DEFAULT_LOOSE_MAX = 128
"""Loose bags beyond which the tree is rebuilt (each is checked on every query)."""
NEAREST_K = 8
"""How many nearest bags of the snapshot :meth:`CentreIndex.nearest` asks the tree for."""
_ROUND = 1e-9
"""Widening of every tree radius, rad, for the tree's own float64 rounding."""


class CentreIndex:
    """A k-d tree over a snapshot of the bags' joint-space means, plus the loose bags.

    Args:
        means_q: the bags' joint-space means now, ``(n, 7)`` rad (copied).
        slack: largest move of a mean from its snapshot, rad, before the bag is loose.
        loose_max: rebuild when more bags than this are loose.
    """

    def __init__(self, means_q, slack: float = DEFAULT_SLACK,
                 loose_max: int = DEFAULT_LOOSE_MAX) -> None:
        self.slack = float(slack)
        self.loose_max = int(loose_max)
        self._slack2 = self.slack ** 2
        self.builds = 0
        self.rebuild(means_q)

    def rebuild(self, means_q) -> None:
        """A new snapshot of the current means; no bag is loose."""
        from scipy.spatial import cKDTree  # here: importing scipy.spatial adds ~30 MB RSS

        self._snap = np.array(means_q, dtype=float).reshape(-1, 7)  # the tree keeps this
        self._tree = cKDTree(self._snap)
        self._moved: list[int] = []
        self._is_moved = np.zeros(len(self._snap), dtype=bool)
        self._moved_arr = np.empty(0, dtype=np.intp)
        self.drift = 0.0  # largest move of a bag that is not loose from its snapshot, rad
        self._drift2 = 0.0
        self.builds += 1

    @property
    def size(self) -> int:
        """Bags in the snapshot."""
        return len(self._snap)

    def loose(self, n: int) -> int:
        """How many of ``n`` bags are loose (moved, or added since the snapshot)."""
        return len(self._moved) + max(0, n - len(self._snap))

    def moved(self, bag: int, mean_q) -> None:
        """Bag ``bag``'s joint-space mean is now ``mean_q`` (it joined a point or was reused)."""
        if bag >= len(self._snap) or self._is_moved[bag]:
            return  # already loose
        d = np.asarray(mean_q, dtype=float) - self._snap[bag]
        d2 = float(d @ d)
        if d2 > self._slack2:
            self._is_moved[bag] = True
            self._moved.append(bag)
            self._moved_arr = np.array(self._moved, dtype=np.intp)
        elif d2 > self._drift2:
            self._drift2 = d2
            self.drift = math.sqrt(d2)

    def within(self, q, r: float, n: int) -> np.ndarray:
        """Bags (indices below ``n``, possibly repeated) among which every bag whose current
        mean is within ``r`` of ``q`` (rad, closed ball) is found."""
        ball = self._tree.query_ball_point(q, r + self.drift + _ROUND)
        parts = [np.array(ball, dtype=np.intp)]
        if self._moved:
            parts.append(self._moved_arr)
        if n > len(self._snap):
            parts.append(np.arange(len(self._snap), n))
        return parts[0] if len(parts) == 1 else np.concatenate(parts)

    def nearest(self, q, n: int) -> tuple[np.ndarray, float]:
        """Bags (indices below ``n``, possibly repeated) near ``q``: the snapshot's
        :data:`NEAREST_K` nearest and the loose bags; and a distance, rad, such that every
        bag whose current mean is closer to ``q`` than it is among them."""
        k = min(NEAREST_K, len(self._snap))
        d, i = self._tree.query(q, k=k)
        d, i = np.atleast_1d(d), np.atleast_1d(i)
        covered = math.inf if k == len(self._snap) else float(d[-1]) - self.drift - _ROUND
        parts = [i.astype(np.intp, copy=False)]
        if self._moved:
            parts.append(self._moved_arr)
        if n > len(self._snap):
            parts.append(np.arange(len(self._snap), n))
        return (parts[0] if len(parts) == 1 else np.concatenate(parts)), covered

    def nbytes(self) -> int:
        """Bytes of the snapshot and the tree's index array (its nodes are not counted)."""
        return self._snap.nbytes + self._tree.indices.nbytes + self._is_moved.nbytes
