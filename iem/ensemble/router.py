"""The bag router: the paper's Algorithm 1 with the two thresholds of its section 4.1.

A bag is a sphere around a running mean, in joint space and in Cartesian space at once. A new
point joins a bag only if its joint-space distance to the bag's mean is below ``delta`` AND
its flange-position distance is below ``rho`` (Eqs. 7-8). Among the bags that qualify the
point joins the nearest one in joint space (Algorithm 1 takes the first that qualifies; the
nearest is the same when bags do not overlap and is well defined when they do), and that
bag's means move to include it. A point that fits no bag starts a new bag with itself as mean.
The router also reports the nearest bag in joint space, qualifying or not: a new bag's learner
is a copy of that bag's.

One method decides (:meth:`BagRouter._decide`): from exact float64 distances to a set of
candidate bags it names the nearest bag in joint space and the nearest that qualifies, ties
to the lowest bag index. Every way of routing only proposes the candidates:

- up to 64 bags, every bag;
- beyond, a float32 scan of the joint-space means, mirrored one coordinate per row with
  their squared norms cached: one small matrix-vector product (``|m - q|² = |m|² - 2 m·q +
  |q|²``) names the bags within δ in joint space and those within rounding of the nearest,
  with a margin far above float32's rounding, so the scan never changes a decision;
- :meth:`BagRouter.route_many`, for many points at once, the bags within both thresholds
  (with the same margin) of each point, by one expanded-form product per threshold.

The scan is linear in the bags: about 22 µs a route at 10,000 bags and 29 µs at 20,000 on
the project's 2-core machine. A k-d tree over the means is faster than that only on points
inside a bag (about 15 µs), slower on points outside every bag (41-48 µs), and costs 30 MB of
scipy and a rebuild of milliseconds on the routing thread; at the 2,000-bag budget and 100
block points a second it does not pay (docs/decisions.md).
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import InvalidInputError

DEFAULT_DELTA = math.radians(30.0)
"""Joint-space threshold δ of the paper, rad (30°)."""
DEFAULT_RHO = 0.2
"""Cartesian threshold ρ of the paper, m."""

_SMALL = 64
"""Up to this many bags every bag is a candidate (exact distances to all of them)."""

_SCAN_MARGIN = 1e-4
"""Slack on the squared thresholds (rad², m²) of the scans' candidates; float64 decides."""
_MARGIN32 = np.float32(_SCAN_MARGIN)


class BagRouter:
    """Bags of path points (Algorithm 1).

    Args:
        delta: joint-space radius of a bag, rad (paper: 30° = 0.524 rad).
        rho: flange-position radius of a bag, m (paper: 0.2 m).
        capacity: initial number of bag slots (grows by doubling).
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
        self._allocate(max(1, int(capacity)))

    def _allocate(self, cap: int) -> None:
        n = self._n
        means = np.zeros((cap, 10))  # [q mean (7), flange mean (3)], the truth
        counts = np.zeros(cap, dtype=np.int64)
        if n:
            means[:n] = self._means[:n]
            counts[:n] = self._counts[:n]
        self._means, self._counts = means, counts
        # the scan's mirror: -2 q, one row per coordinate (exactly -2 times the float32
        # means: a power of two), and |q|²
        self._qTm2 = np.zeros((7, cap), dtype=np.float32)
        self._sqq = np.zeros(cap, dtype=np.float32)
        for i in range(n):
            self._mirror(i)

    def _mirror(self, i: int) -> None:
        if self._n <= _SMALL and i < _SMALL:
            return  # a small map is routed from the float64 means; mirrored when it grows
        row = self._means[i]
        self._qTm2[:, i] = -2.0 * row[:7]
        self._sqq[i] = row[:7] @ row[:7]

    # -- views ---------------------------------------------------------------------------
    def __len__(self) -> int:
        return self._n

    @property
    def flange_means(self) -> np.ndarray:
        """Flange-position mean of every bag, ``(n, 3)`` m (a copy)."""
        return self._means[: self._n, 7:].copy()

    @property
    def counts(self) -> np.ndarray:
        """Number of points that joined each bag (a copy)."""
        return self._counts[: self._n].copy()

    # -- the decision --------------------------------------------------------------------
    def _decide(self, cand: np.ndarray | None, q: np.ndarray, x: np.ndarray
                ) -> tuple[int, int]:
        """Algorithm 1's decision among the bags ``cand`` (ascending bag indices, or None:
        every bag), by exact float64 distances of ``q``/``x`` to their means.

        Returns ``(bag, nearest)``: the nearest candidate in joint space whose spheres both
        hold the point (strictly), or -1, and the nearest candidate in joint space; ties go
        to the lowest index (and a NaN distance is the nearest, as NumPy's argmin). ``bag``
        is Algorithm 1's if ``cand`` holds every bag that qualifies, ``nearest`` if it holds
        the nearest bag and its equals.
        """
        m = self._means[: self._n] if cand is None else self._means[cand]
        d = m - np.concatenate((q, x))
        d *= d
        eq = d[:, :7].sum(axis=1)
        ex = d[:, 7:].sum(axis=1)
        near = int(eq.argmin())
        if eq[near] < self._delta2 and ex[near] < self._rho2:
            bag = near  # the usual case: the nearest qualifies, so it is the nearest that does
        elif eq.shape[0] == 1:
            bag = -1  # the other usual case: the one candidate does not
        else:
            inside = (eq < self._delta2) & (ex < self._rho2)
            bag = int(np.where(inside, eq, np.inf).argmin()) if inside.any() else -1
        if cand is None:
            return bag, near
        return (int(cand[bag]) if bag >= 0 else -1), int(cand[near])

    def _scan(self, q: np.ndarray) -> np.ndarray | None:
        """Candidates by the float32 scan (more than :data:`_SMALL` bags): the bags within δ
        of ``q`` in joint space and those within rounding of the nearest, ascending (None,
        every bag, where it rules out none: a point that is not finite)."""
        n = self._n
        # |m|² - 2 m·q, the squared distance less the constant |q|²
        d2q = self._sqq[:n] + q.astype(np.float32) @ self._qTm2[:, :n]
        near = d2q[d2q.argmin()] + _MARGIN32  # (argmin: the first NaN, if any)
        reach = np.float32(self._delta2 + _SCAN_MARGIN - float(q @ q))
        cand = np.flatnonzero(d2q < reach) if reach > near else np.flatnonzero(d2q <= near)
        return cand if cand.size else None

    # -- queries -------------------------------------------------------------------------
    def route(self, q, flange) -> tuple[int, int]:
        """Where a point belongs, without changing anything.

        Returns ``(bag, nearest)``: ``bag`` is the nearest bag (joint space) whose spheres
        both contain the point, or -1 if none does; ``nearest`` is the nearest bag in joint
        space whatever the thresholds, or -1 if there are no bags.
        """
        if self._n == 0:
            return -1, -1
        q, x = _point(q, flange)
        return self._decide(self._scan(q) if self._n > _SMALL else None, q, x)

    def route_exact(self, q, flange) -> tuple[int, int]:
        """:meth:`route` with every bag a candidate (what :meth:`route` does up to 64 bags):
        the reference the scan is held to, at any size."""
        if self._n == 0:
            return -1, -1
        q, x = _point(q, flange)
        return self._decide(None, q, x)

    def route_join(self, q, flange) -> tuple[int, int]:
        """:meth:`route`, then, if the point is inside a bag, :meth:`join` it: Algorithm 1
        without the new bag (the caller decides what a point outside every bag starts).
        Returns :meth:`route`'s ``(bag, nearest)``."""
        bag, nearest = self.route(q, flange)
        if bag >= 0:
            self.join(bag, q, flange)
        return bag, nearest

    def route_many(self, Q, F) -> np.ndarray:
        """:meth:`route`'s bag for many points at once, ``(N,)`` (-1: outside every bag).

        The candidates of every point at once, by one expanded-form product per threshold
        with a margin: the bags within both; :meth:`_decide` decides for each point that has
        any.
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
        starts = np.flatnonzero(np.diff(rows, prepend=-1)).tolist()  # each row's first pair
        for a, b in zip(starts, [*starts[1:], rows.size], strict=True):
            r = rows[a]
            out[r] = self._decide(cols[a:b], Q[r], F[r])[0]
        return out

    def nbytes(self) -> int:
        """Bytes held for the bags (the preallocated slots included)."""
        return sum(a.nbytes for a in (self._means, self._counts, self._qTm2, self._sqq))

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
        row += (np.concatenate(_point(q, flange)) - row) / k
        self._counts[bag] = k
        self._mirror(bag)

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
        return router


def _point(q, flange) -> tuple[np.ndarray, np.ndarray]:
    """A point's ``q`` (7) and flange position (3) as float64 arrays (themselves if they
    are already: the cycle's case)."""
    q, x = _floats(q), _floats(flange)
    if q.shape != (7,) or x.shape != (3,):
        raise InvalidInputError(f"a point is q (7) and flange (3), got {q.shape} and "
                                f"{x.shape}")
    return q, x


def _floats(v) -> np.ndarray:
    """``v`` as a float64 array (itself if it is one already)."""
    return v if type(v) is np.ndarray and v.dtype == np.float64 else np.asarray(v, dtype=float)
