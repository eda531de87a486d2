"""The bag router: the paper's Algorithm 1 with the two thresholds of its section 4.1.

A bag is a sphere around a running mean, in joint space and in Cartesian space at once. A new
point joins a bag only if its joint-space distance to the bag's mean is below ``delta`` AND
its flange-position distance is below ``rho`` (Eqs. 7-8). Among the bags that qualify the
point joins the nearest one in joint space (Algorithm 1 takes the first that qualifies; the
nearest is the same when bags do not overlap and is well defined when they do), and that
bag's means move to include it. A point that fits no bag starts a new bag with itself as mean.
The router also reports the nearest bag in joint space, qualifying or not: a new bag's learner
is a copy of that bag's.

Routing is vectorised over the bags, not a Python loop. The bag means live in preallocated
float64 arrays (the truth, updated as points join). Up to 64 bags a query computes the exact
distances to all of them; beyond, the joint-space means are mirrored in a float32 array laid
out one coordinate per row, with their squared norms cached, and a query scans it with one
small matrix-vector product (``|m - q|² = |m|² - 2 m·q + |q|²``): only the few bags within δ
in joint space can qualify, and float64 distances to those decide both spheres, so float32
rounding never changes a decision. Above :data:`INDEX_ABOVE` bags a spatial index over the
joint-space means (:class:`iem.spatial.CentreIndex`, a k-d tree) names the few bags that can
be within δ of the point, or within the distance of a bag near it, and the same exact float64
distances decide among them: the scan's decision (ties go to the lowest bag index), at a cost
that grows with the log of the bags rather than with the bags. The index is derived state:
never saved; a router loaded above the threshold builds it at load, one that grows past it at
its next route (importing scipy.spatial then), and it is rebuilt, on the thread that routes,
when more than 128 bags moved or were added since (5-14 ms at 20,000 bags here).
"""

from __future__ import annotations

import math

import numpy as np

from . import kernels
from .errors import InvalidInputError
from .spatial import CentreIndex

DEFAULT_DELTA = math.radians(30.0)
"""Joint-space threshold δ of the paper, rad (30°)."""
DEFAULT_RHO = 0.2
"""Cartesian threshold ρ of the paper, m."""

_SMALL = 64
"""Up to this many bags a query computes the exact distances to all of them directly."""

_SCAN_MARGIN = 1e-4
"""Slack on the squared thresholds (rad², m²) of the float32 scan; float64 decides."""

INDEX_ABOVE = 5_000
"""Above this many bags the spatial index routes instead of the scan: where it became the
faster on points inside a bag (what the cycle routes almost always), measured with
``iem bench longrun --routing-only`` on the project's 2-core machine (README)."""


class BagRouter:
    """Bags of path points (Algorithm 1).

    Args:
        delta: joint-space radius of a bag, rad (paper: 30° = 0.524 rad).
        rho: flange-position radius of a bag, m (paper: 0.2 m).
        capacity: initial number of bag slots (grows by doubling).

    ``index_above`` (attribute): above this many bags :class:`~iem.spatial.CentreIndex`
    routes (None: the scan always); the decisions are the same either way.
    """

    def __init__(self, delta: float = DEFAULT_DELTA, rho: float = DEFAULT_RHO,
                 capacity: int = 16) -> None:
        if not (delta > 0 and rho > 0):
            raise InvalidInputError(f"delta and rho must be > 0, got delta={delta}, rho={rho}")
        self.delta = float(delta)
        self.rho = float(rho)
        self._delta2 = self.delta ** 2
        self._rho2 = self.rho ** 2
        self._n = 0
        self.index_above: int | None = INDEX_ABOVE
        self._index: CentreIndex | None = None  # derived: built when first needed
        self._allocate(max(1, int(capacity)))

    def __getstate__(self) -> dict:
        state = self.__dict__.copy()
        state["_index"] = None  # derived state: a copy builds its own
        return state

    def _allocate(self, cap: int) -> None:
        n = self._n
        means = np.zeros((cap, 10))  # [q mean (7), flange mean (3)], the truth
        counts = np.zeros(cap, dtype=np.int64)
        if n:
            means[:n] = self._means[:n]
            counts[:n] = self._counts[:n]
        self._means, self._counts = means, counts
        self._qT = np.zeros((7, cap), dtype=np.float32)  # scan mirror, one row per coordinate
        self._sqq = np.zeros(cap, dtype=np.float32)
        for i in range(n):
            self._mirror(i)

    def _mirror(self, i: int) -> None:
        if self._n <= _SMALL and i < _SMALL:
            return  # a small map is routed from the float64 means; mirrored when it grows
        row = self._means[i]
        self._qT[:, i] = row[:7]
        self._sqq[i] = row[:7] @ row[:7]

    # -- views ---------------------------------------------------------------------------
    def __len__(self) -> int:
        return self._n

    @property
    def q_means(self) -> np.ndarray:
        """Joint-space mean of every bag, ``(n, 7)`` rad (a copy)."""
        return self._means[: self._n, :7].copy()

    @property
    def flange_means(self) -> np.ndarray:
        """Flange-position mean of every bag, ``(n, 3)`` m (a copy)."""
        return self._means[: self._n, 7:].copy()

    @property
    def counts(self) -> np.ndarray:
        """Number of points that joined each bag (a copy)."""
        return self._counts[: self._n].copy()

    # -- queries -------------------------------------------------------------------------
    def _exact2(self, i, q: np.ndarray, x: np.ndarray):
        """Exact squared distances (float64) of ``q``/``x`` to bag(s) ``i``."""
        m = self._means[i]
        dq = m[..., :7] - q
        dx = m[..., 7:] - x
        return (dq * dq).sum(axis=-1), (dx * dx).sum(axis=-1)

    def _exact_q2(self, i: np.ndarray, q: np.ndarray) -> np.ndarray:
        """:meth:`_exact2`'s joint-space half alone (the same arithmetic)."""
        dq = self._means[i, :7] - q
        return (dq * dq).sum(axis=-1)

    def route(self, q, flange) -> tuple[int, int]:
        """Where a point belongs, without changing anything.

        Returns ``(bag, nearest)``: ``bag`` is the nearest bag (joint space) whose spheres
        both contain the point, or -1 if none does; ``nearest`` is the nearest bag in joint
        space whatever the thresholds, or -1 if there are no bags.
        """
        n = self._n
        if n == 0:
            return -1, -1
        q = np.asarray(q, dtype=float)
        x = np.asarray(flange, dtype=float)
        if self.index_above is not None and n > self.index_above:
            return self._route_indexed(q, x)
        if n <= _SMALL:
            return self._route_small(q, x)
        q32 = q.astype(np.float32)
        # |m|² - 2 m·q, i.e. the squared distance minus the constant |q|²
        d2q = self._sqq[:n] - 2.0 * (q32 @ self._qT[:, :n])
        nearest = int(d2q.argmin())
        near = np.flatnonzero(d2q <= d2q[nearest] + _SCAN_MARGIN)
        if near.size > 1:  # a near tie in float32: the exact distances order them
            nearest = int(near[np.argmin(self._exact2(near, q, x)[0])])
        qq = float(q @ q)
        eq, ex = self._exact2(nearest, q, x)
        if eq < self._delta2 and ex < self._rho2:
            return nearest, nearest  # the nearest bag qualifies, so it is the nearest that does
        # only bags within delta in joint space can qualify: they are few, and the exact
        # float64 check decides both spheres for them
        cand = np.flatnonzero(d2q < self._delta2 + _SCAN_MARGIN - qq)
        if cand.size == 0:
            return -1, nearest
        eq, ex = self._exact2(cand, q, x)
        ok = (eq < self._delta2) & (ex < self._rho2)
        if not ok.any():
            return -1, nearest
        return int(cand[np.flatnonzero(ok)[np.argmin(eq[ok])]]), nearest

    def route_join(self, q, flange) -> tuple[int, int]:
        """:meth:`route`, then, if the point is inside a bag, :meth:`join` it: Algorithm 1
        without the new bag (the caller decides what a point outside every bag starts).
        Returns :meth:`route`'s ``(bag, nearest)``. One pass over the bags for both on a
        small map (the online cycle's case)."""
        n = self._n
        if n > _SMALL or n == 0:
            bag, nearest = self.route(q, flange)
            if bag >= 0:
                self.join(bag, q, flange)
            return bag, nearest
        q, flange = _floats(q), _floats(flange)
        if q.shape != (7,) or flange.shape != (3,):  # (the kernel reads 7 and 3 unchecked)
            raise InvalidInputError(f"a point is q (7) and flange (3), got {q.shape} and "
                                    f"{flange.shape}")
        if kernels.active:  # compiled (iem.kernels): the same decision and means
            bag, nearest = kernels.route_join_small(self._means, self._counts, n, q, flange,
                                                    self._delta2, self._rho2)
            return bag, nearest  # (a small map is never mirrored)
        p = np.concatenate((q, flange))
        d = self._means[:n] - p
        d *= d
        d2q = d[:, :7].sum(axis=1)  # the same arithmetic as _route_small
        nearest = int(d2q.argmin())
        if d2q[nearest] < self._delta2 and d[nearest, 7:].sum() < self._rho2:
            bag = nearest  # the usual case: the nearest bag qualifies
        else:
            inside = (d2q < self._delta2) & (d[:, 7:].sum(axis=1) < self._rho2)
            if not inside.any():
                return -1, nearest
            bag = int(np.where(inside, d2q, np.inf).argmin())
        k = self._counts[bag] + 1
        row = self._means[bag]
        row += (p - row) / k  # as join: both means move toward the point
        self._counts[bag] = k
        return bag, nearest

    def _route_small(self, q: np.ndarray, x: np.ndarray) -> tuple[int, int]:
        """:meth:`route` for a few bags: exact float64 distances to every bag directly."""
        m = self._means[: self._n]
        dq = m[:, :7] - q
        dx = m[:, 7:] - x
        d2q = (dq * dq).sum(axis=1)  # the same arithmetic as _exact2 and route_many
        d2x = (dx * dx).sum(axis=1)
        nearest = int(d2q.argmin())
        inside = (d2q < self._delta2) & (d2x < self._rho2)
        if inside[nearest]:
            return nearest, nearest
        if not inside.any():
            return -1, nearest
        return int(np.where(inside, d2q, np.inf).argmin()), nearest

    def _route_indexed(self, q: np.ndarray, x: np.ndarray) -> tuple[int, int]:
        """:meth:`route` through the spatial index: the same exact decision among the few
        bags the index cannot rule out."""
        n = self._n
        index = self._index
        if index is None:
            index = self._index = CentreIndex(self._means[:n, :7])
        elif index.loose(n) > index.loose_max:
            index.rebuild(self._means[:n, :7])
        cand = index.within(q, self.delta, n)  # every bag within δ is among them
        if cand.size:
            eq, ex = self._exact2(cand, q, x)
            if cand.size == 1:
                if eq[0] < self._delta2:
                    bag = int(cand[0])
                    return (bag if ex[0] < self._rho2 else -1), bag
            else:
                best = eq.min()
                if best < self._delta2:  # so the nearest bag is among them too
                    nearest = _lowest(cand, eq, best)
                    ok = (eq < self._delta2) & (ex < self._rho2)
                    if not ok.any():
                        return -1, nearest
                    eq_ok = eq[ok]
                    return _lowest(cand[ok], eq_ok, eq_ok.min()), nearest
        # no bag within δ, so none qualifies; the nearest is among the snapshot's nearest and
        # the loose bags if it is closer than what they cover, else in the ball of its distance
        cand, covered = index.nearest(q, n)
        eq = self._exact_q2(cand, q)
        best = eq.min()
        if not math.sqrt(best) < covered:
            cand = index.within(q, math.sqrt(best), n)
            eq = self._exact_q2(cand, q)
            best = eq.min()
        return -1, _lowest(cand, eq, best)

    def route_many(self, Q, F) -> np.ndarray:
        """:meth:`route`'s bag for many points at once, ``(N,)`` (-1: outside every bag).

        The same decision as :meth:`route` row by row: an expanded-form scan with a margin
        picks the candidates, exact float64 distances decide.
        """
        Q = np.asarray(Q, dtype=float).reshape(-1, 7)
        F = np.asarray(F, dtype=float).reshape(-1, 3)
        out = np.full(Q.shape[0], -1, dtype=np.int64)
        if self._n == 0 or Q.shape[0] == 0:
            return out
        m = self._means[: self._n]
        sq_q, sq_x = (m[:, :7] ** 2).sum(1), (m[:, 7:] ** 2).sum(1)
        d2q = sq_q[None, :] - 2.0 * Q @ m[:, :7].T + (Q * Q).sum(1)[:, None]
        d2x = sq_x[None, :] - 2.0 * F @ m[:, 7:].T + (F * F).sum(1)[:, None]
        rows, cols = np.nonzero((d2q < self._delta2 + _SCAN_MARGIN)
                                & (d2x < self._rho2 + _SCAN_MARGIN))
        if rows.size == 0:
            return out
        eq = ((m[cols, :7] - Q[rows]) ** 2).sum(1)
        ex = ((m[cols, 7:] - F[rows]) ** 2).sum(1)
        ok = (eq < self._delta2) & (ex < self._rho2)
        rows, cols, eq = rows[ok], cols[ok], eq[ok]
        order = np.lexsort((cols, eq, rows))  # per row: smallest distance first
        rows, cols = rows[order], cols[order]
        first = np.ones(rows.size, dtype=bool)
        first[1:] = rows[1:] != rows[:-1]
        out[rows[first]] = cols[first]
        return out

    def nbytes(self) -> int:
        """Bytes held for the bags (the preallocated slots included)."""
        index = 0 if self._index is None else self._index.nbytes()
        return sum(a.nbytes for a in (self._means, self._counts, self._qT, self._sqq)) + index

    # -- Algorithm 1 ---------------------------------------------------------------------
    def add(self, q, flange) -> tuple[int, bool, int]:
        """Algorithm 1 for one point: join a bag (its means move) or start a new one.

        Returns ``(bag, created, nearest)``: the bag the point is now in, whether that bag
        was created for it, and the nearest existing bag before the point was added (-1 if
        there was none), which is the bag to copy a learner from.
        """
        q = np.asarray(q, dtype=float)
        x = np.asarray(flange, dtype=float)
        bag, nearest = self.route(q, x)
        if bag >= 0:
            self.join(bag, q, x)
            return bag, False, nearest
        return self._new_bag(q, x), True, nearest

    def join(self, bag: int, q, flange) -> None:
        """The point joins ``bag``: its means move to include it (Algorithm 1)."""
        k = self._counts[bag] + 1
        row = self._means[bag]
        row[:7] += (np.asarray(q, dtype=float) - row[:7]) / k
        row[7:] += (np.asarray(flange, dtype=float) - row[7:]) / k
        self._counts[bag] = k
        self._mirror(bag)
        if self._index is not None:
            self._index.moved(bag, row[:7])

    def new_bag(self, q, flange) -> int:
        """A new bag with the point as its mean; returns its index."""
        return self._new_bag(np.asarray(q, dtype=float), np.asarray(flange, dtype=float))

    def replace(self, bag: int, q, flange) -> None:
        """Bag ``bag`` is retired and its slot starts a new bag at the point (count 1)."""
        if not 0 <= bag < self._n:
            raise InvalidInputError(f"bag {bag} does not exist (there are {self._n})")
        self._means[bag, :7] = np.asarray(q, dtype=float)
        self._means[bag, 7:] = np.asarray(flange, dtype=float)
        self._counts[bag] = 1
        self._mirror(bag)
        if self._index is not None:
            self._index.moved(bag, self._means[bag, :7])

    def _new_bag(self, q: np.ndarray, x: np.ndarray) -> int:
        if self._n == self._means.shape[0]:
            self._allocate(2 * self._means.shape[0])
        i = self._n
        self._means[i, :7] = q
        self._means[i, 7:] = x
        self._counts[i] = 1
        self._n += 1
        if self._n == _SMALL + 1:
            for j in range(self._n):  # the map outgrew direct routing: mirror it all
                self._mirror(j)
        else:
            self._mirror(i)
        return i

    @classmethod
    def from_means(cls, Q, F, delta: float = DEFAULT_DELTA, rho: float = DEFAULT_RHO) -> BagRouter:
        """A router with one bag per given mean (no merging), e.g. to time a large map."""
        Q = np.asarray(Q, dtype=float).reshape(-1, 7)
        F = np.asarray(F, dtype=float).reshape(-1, 3)
        router = cls(delta=delta, rho=rho, capacity=max(16, len(Q)))
        for q, x in zip(Q, F, strict=True):
            router._new_bag(q, x)
        return router

    # -- persistence ---------------------------------------------------------------------
    def to_state(self) -> dict:
        n = self._n
        return {"delta": self.delta, "rho": self.rho,
                "means": self._means[:n].tolist(), "counts": self._counts[:n].tolist()}

    @classmethod
    def from_state(cls, state: dict) -> BagRouter:
        router = cls(delta=state["delta"], rho=state["rho"],
                     capacity=max(16, len(state["counts"])))
        means = np.asarray(state["means"], dtype=float).reshape(-1, 10)
        if not np.all(np.isfinite(means)):  # a None reads as NaN: a bag nothing routes to
            raise InvalidInputError("router state: means holds values that are not finite "
                                    "numbers (None, NaN or inf)")
        counts = np.asarray(state["counts"], dtype=np.int64).reshape(-1)
        if means.shape[0] != counts.shape[0]:
            raise InvalidInputError("router state: means and counts differ in length")
        n = counts.shape[0]
        router._means[:n] = means
        router._counts[:n] = counts
        router._n = n
        for i in range(n):
            router._mirror(i)
        if router.index_above is not None and n > router.index_above:
            router._index = CentreIndex(means[:, :7])  # at load, not at the first route
        return router


def _floats(v) -> np.ndarray:
    """``v`` as a float64 array (itself if it is one already: the cycle's case)."""
    return v if type(v) is np.ndarray and v.dtype == np.float64 else np.asarray(v, dtype=float)


def _lowest(bags: np.ndarray, d2: np.ndarray, best) -> int:
    """The lowest bag index among ``bags`` whose distance ``d2`` equals ``best``."""
    return int(bags[d2 == best].min())
