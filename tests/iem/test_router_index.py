"""The router's spatial index (:mod:`iem.spatial`): routing through it decides exactly as the
scan does and as an independent brute-force float64 computation does (ties included), on maps
of several sizes whose means move as points join, with bags added and slots reused; the index
is derived state (never saved, rebuilt by a copy or a loaded router)."""

from __future__ import annotations

import copy

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from iem.ensemble import IncrementalEnsemble
from iem.persistence import dumps, loads
from iem.router import INDEX_ABOVE, BagRouter
from iem.spatial import CentreIndex

from .test_checks import DATA
from .test_ensemble_longrun import PARAMS, fitted, learn, same, weights

LO, HI = -2.0, 2.0  # rad: a box small enough that bags overlap at δ = 0.5
DELTA, RHO = 0.5, 0.3


def brute(means: np.ndarray, q, x, delta: float, rho: float) -> tuple[int, int]:
    """Algorithm 1's decision by brute force in float64, written apart from the router
    (einsum, every bag): the nearest bag in joint space (lowest index of equals), and the
    nearest of those whose two spheres (strict) hold the point, or -1."""
    if len(means) == 0:
        return -1, -1
    dq = means[:, :7] - np.asarray(q, dtype=np.float64)
    dx = means[:, 7:] - np.asarray(x, dtype=np.float64)
    eq = np.einsum("ij,ij->i", dq, dq)
    ex = np.einsum("ij,ij->i", dx, dx)
    nearest = int(np.flatnonzero(eq == eq.min())[0])
    inside = (eq < delta ** 2) & (ex < rho ** 2)
    if not inside.any():
        return -1, nearest
    eq_in = np.where(inside, eq, np.inf)
    return int(np.flatnonzero(eq_in == eq_in.min())[0]), nearest


def means_of(router: BagRouter) -> np.ndarray:
    return np.hstack((router.q_means, router.flange_means))


def probes(rng, router: BagRouter, k: int):
    """Points near bag means (most inside a bag), at bag means exactly (ties when two bags
    share a mean), and uniform in the box (most outside every bag)."""
    n = len(router)
    pick = rng.integers(0, n, k)
    Q = np.vstack((router.q_means[pick] + rng.normal(0, 0.15, (k, 7)),
                   router.q_means[pick[: k // 4]],
                   rng.uniform(LO, HI, (k, 7))))
    F = np.vstack((router.flange_means[pick] + rng.normal(0, 0.1, (k, 3)),
                   router.flange_means[pick[: k // 4]],
                   rng.uniform(LO / 4, HI / 4, (k, 3))))
    return Q, F


def twins(n: int, seed: int, loose_max: int = 8):
    """The same map of ``n`` bags routed by the scan and by the index (forced at any size,
    with a small ``loose_max`` so that the tree is rebuilt often)."""
    rng = np.random.default_rng(seed)
    Q = rng.uniform(LO, HI, (n, 7))
    F = rng.uniform(LO / 4, HI / 4, (n, 3))
    scan = BagRouter.from_means(Q, F, DELTA, RHO)
    scan.index_above = None
    indexed = BagRouter.from_means(Q, F, DELTA, RHO)
    indexed.index_above = 0
    indexed.route(Q[0], F[0])
    indexed._index.loose_max = loose_max
    return rng, scan, indexed


def assert_same(rng, scan: BagRouter, indexed: BagRouter, k: int = 40) -> None:
    means = means_of(scan)
    np.testing.assert_array_equal(means, means_of(indexed))
    for q, x in zip(*probes(rng, scan, k), strict=True):
        truth = brute(means, q, x, DELTA, RHO)
        assert scan.route(q, x) == truth
        assert indexed.route(q, x) == truth


@pytest.mark.parametrize("n", [3, 65, 400, 3000])
def test_index_routes_as_the_scan_and_brute_force_while_means_move(n):
    rng, scan, indexed = twins(n, n)
    assert_same(rng, scan, indexed)
    for step in range(6):
        # Algorithm 1 on points near the bags: they join (means move) or start bags
        Q, F = probes(rng, scan, 30)
        for q, x in zip(Q, F, strict=True):
            assert indexed.add(q, x) == scan.add(q, x)
        # a budget reuses slots: some at a far point, some exactly onto another bag's mean
        # (two bags with one mean: ties, which the lowest index wins)
        for _ in range(5):
            i, j = (int(v) for v in rng.integers(0, len(scan), 2))
            if step % 2:
                q, x = scan.q_means[j], scan.flange_means[j]
            else:
                q, x = rng.uniform(LO, HI, 7), rng.uniform(LO / 4, HI / 4, 3)
            scan.replace(i, q, x)
            indexed.replace(i, q, x)
        assert_same(rng, scan, indexed)
    assert indexed._index.builds > 1  # the tree was rebuilt from moved means on the way


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 120),
       ops=st.lists(st.sampled_from(["add", "join", "replace", "dup"]), max_size=40))
def test_any_sequence_of_slot_operations_routes_as_brute_force(seed, n, ops):
    rng, scan, indexed = twins(n, seed, loose_max=4)
    for op in ops:
        i, j = (int(v) for v in rng.integers(0, len(scan), 2))
        q = rng.uniform(LO, HI, 7)
        x = rng.uniform(LO / 4, HI / 4, 3)
        if op == "dup":  # bag i takes bag j's joint-space mean: ties
            q = scan.q_means[j]
        for r in (scan, indexed):
            if op == "add":
                r.add(q, x)
            elif op == "join":  # a far point joins: a large move of the mean
                r.join(i, q, x)
            else:
                r.replace(i, q, x)
    assert_same(rng, scan, indexed, k=12)


def test_a_stale_index_would_be_caught():
    """The comparison can fail: an index that ignored moved means routes wrongly."""
    rng, scan, indexed = twins(200, 7)

    class Stale(CentreIndex):
        def moved(self, bag, mean_q):
            pass

    indexed._index = Stale(indexed.q_means)
    far = rng.uniform(LO, HI, 7), rng.uniform(LO / 4, HI / 4, 3)
    for r in (scan, indexed):
        r.replace(5, *far)
    assert scan.route(*far) == brute(means_of(scan), *far, DELTA, RHO) == (5, 5)
    assert indexed.route(*far) != (5, 5)


def test_bags_moved_away_from_a_query_do_not_hide_the_nearest():
    """Ten bags at one spot, then all reused far away: the tree still holds them at the spot
    (more than the nearest it asks for), and the nearest is another bag."""
    rng = np.random.default_rng(4)
    spot = np.zeros(7)
    Q = np.vstack((spot + rng.normal(0, 1e-3, (10, 7)), rng.uniform(1.0, HI, (50, 7))))
    F = rng.uniform(LO / 4, HI / 4, (60, 3))
    scan, indexed = (BagRouter.from_means(Q, F, DELTA, RHO) for _ in range(2))
    scan.index_above, indexed.index_above = None, 0
    indexed.route(spot, F[0])
    for r in (scan, indexed):
        for i in range(10):
            r.replace(i, np.full(7, 50.0 + i), F[i])
    assert indexed._index.loose(60) == 10
    truth = brute(means_of(scan), spot, F[0], DELTA, RHO)
    assert truth[1] >= 10 and scan.route(spot, F[0]) == truth == indexed.route(spot, F[0])


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 60),
       moves=st.lists(st.floats(0.0, 0.1), max_size=30), r=st.floats(0.01, 1.5))
def test_the_index_holds_every_bag_within_a_radius_after_small_and_large_moves(
        seed, n, moves, r):
    """:meth:`CentreIndex.within` and :meth:`CentreIndex.nearest` against the current means:
    means moved by less than the slack (widened radii) and by more (loose bags)."""
    rng = np.random.default_rng(seed)
    means = rng.uniform(-1.0, 1.0, (n, 7))
    index = CentreIndex(means, slack=0.05)
    for size in moves:
        b = int(rng.integers(n))
        step = rng.normal(size=7)
        means[b] += size * step / np.linalg.norm(step)
        index.moved(b, means[b])
    added = rng.uniform(-1.0, 1.0, (int(rng.integers(0, 3)), 7))
    means = np.vstack((means, added))
    snap = index._snap
    for b in range(len(means)):
        # a query r from bag b's mean, on the side away from its snapshot (the worst case)
        away = means[b] - (snap[b] if b < n else 0.0) + 1e-12
        q = means[b] + away / np.linalg.norm(away) * r * (1 - 1e-9)
        true = np.sqrt(((means - q) ** 2).sum(1))
        assert set(np.flatnonzero(true <= r)) <= set(index.within(q, r, len(means)).tolist())
        cand, covered = index.nearest(q, len(means))
        assert set(np.flatnonzero(true < covered)) <= set(cand.tolist())


def test_above_the_threshold_the_router_uses_the_index_by_itself():
    n = INDEX_ABOVE + 50
    rng = np.random.default_rng(1)
    router = BagRouter.from_means(rng.uniform(LO, HI, (n, 7)),
                                  rng.uniform(LO / 4, HI / 4, (n, 3)), DELTA, RHO)
    assert router.index_above == INDEX_ABOVE and router._index is None
    before = router.nbytes()
    means = means_of(router)
    for q, x in zip(*probes(rng, router, 10), strict=True):
        assert router.route(q, x) == brute(means, q, x, DELTA, RHO)
    assert router._index is not None and router._index.size == n
    assert router.nbytes() == before + router._index.nbytes()
    loaded = BagRouter.from_state(router.to_state())
    assert loaded._index is not None and loaded._index.size == n  # built at load
    for q, x in zip(*probes(rng, router, 10), strict=True):
        assert loaded.route(q, x) == brute(means, q, x, DELTA, RHO)


def test_the_index_is_derived_state_never_saved():
    rng, scan, indexed = twins(300, 3)
    state = indexed.to_state()
    assert set(state) == {"delta", "rho", "means", "counts"}
    loaded = BagRouter.from_state(state)
    copied = copy.deepcopy(indexed)
    assert loaded._index is None and copied._index is None  # built again when first needed
    loaded.index_above = 0
    Q, F = probes(rng, indexed, 30)
    for q, x in zip(Q, F, strict=True):
        expected = indexed.route(q, x)
        assert loaded.route(q, x) == expected == copied.route(q, x) == scan.route(q, x)
    assert loaded._index is not None


def test_an_ensemble_at_its_budget_learns_the_same_through_the_index():
    small = {"delta": 0.15, "rho": 0.08}  # many small bags
    points = DATA.train_points() + DATA.further_points()
    by_scan = fitted(budget_bags=5, **small)
    model = IncrementalEnsemble(**PARAMS, budget_bags=5, **small)
    model.router.index_above = 0
    idx = list(DATA.fit_points)
    model.fit(DATA.X[idx, :7], DATA.F[idx], lambda i: DATA.samples_at(idx[i]))
    learn(by_scan, points)
    learn(model, points)
    assert model.retired == by_scan.retired > 0 and model.router._index is not None
    assert same(weights(model), weights(by_scan))
    np.testing.assert_array_equal(model.router.counts, by_scan.router.counts)
    np.testing.assert_array_equal(model.predict_many(DATA.X, DATA.F),
                                  by_scan.predict_many(DATA.X, DATA.F))
    assert loads(dumps(model)).router._index is None
