"""One routing decision (:meth:`iem.ensemble.router.BagRouter._decide`), whatever proposes its
candidates: every bag (up to 64 bags, and :meth:`BagRouter.route_exact`), the float32 scan
(beyond), :meth:`BagRouter.route_many`'s candidates and :meth:`BagRouter.route_join` decide
as an independent brute-force float64 computation does, ties included, on maps of several
sizes whose means move as points join, with bags added and slots reused."""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from iem.ensemble.router import BagRouter
from iem.errors import InvalidInputError
from tests.iem.router_views import q_means

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
    return np.hstack((q_means(router), router.flange_means))


def probes(rng, router: BagRouter, k: int):
    """Points near bag means (most inside a bag), at bag means exactly (ties when two bags
    share a mean), and uniform in the box (most outside every bag)."""
    n = len(router)
    pick = rng.integers(0, n, k)
    Q = np.vstack((q_means(router)[pick] + rng.normal(0, 0.15, (k, 7)),
                   q_means(router)[pick[: k // 4]],
                   rng.uniform(LO, HI, (k, 7))))
    F = np.vstack((router.flange_means[pick] + rng.normal(0, 0.1, (k, 3)),
                   router.flange_means[pick[: k // 4]],
                   rng.uniform(LO / 4, HI / 4, (k, 3))))
    return Q, F


def random_router(n: int, seed: int) -> tuple[np.random.Generator, BagRouter]:
    rng = np.random.default_rng(seed)
    return rng, BagRouter.from_means(rng.uniform(LO, HI, (n, 7)),
                                     rng.uniform(LO / 4, HI / 4, (n, 3)), DELTA, RHO)


def assert_every_path_decides_as_brute_force(rng, router: BagRouter, k: int = 40) -> None:
    means = means_of(router)
    Q, F = probes(rng, router, k)
    by_many = router.route_many(Q, F)
    for q, x, bag in zip(Q, F, by_many, strict=True):
        truth = brute(means, q, x, DELTA, RHO)
        assert router.route(q, x) == truth  # the scan above 64 bags, every bag below
        assert router.route_exact(q, x) == truth
        assert bag == truth[0]
        joined = copy.deepcopy(router)
        assert joined.route_join(q, x) == truth


@pytest.mark.parametrize("n", [3, 50, 65, 3000, 12000])
def test_every_path_decides_as_brute_force_while_means_move(n):
    rng, router = random_router(n, n)
    assert_every_path_decides_as_brute_force(rng, router, k=40 if n < 5000 else 12)
    for step in range(4):
        # Algorithm 1 on points near the bags: they join (means move) or start bags
        Q, F = probes(rng, router, 30)
        for q, x in zip(Q, F, strict=True):
            router.add(q, x)
        # a budget reuses slots: some at a far point, some exactly onto another bag's mean
        # (two bags with one mean: ties, which the lowest index wins)
        for _ in range(5):
            i, j = (int(v) for v in rng.integers(0, len(router), 2))
            if step % 2:
                q, x = q_means(router)[j], router.flange_means[j]
            else:
                q, x = rng.uniform(LO, HI, 7), rng.uniform(LO / 4, HI / 4, 3)
            router.replace(i, q, x)
        assert_every_path_decides_as_brute_force(rng, router, k=20 if n < 5000 else 8)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 120),
       ops=st.lists(st.sampled_from(["add", "join", "replace", "dup"]), max_size=40))
def test_any_sequence_of_slot_operations_routes_as_brute_force(seed, n, ops):
    rng, router = random_router(n, seed)
    for op in ops:
        i, j = (int(v) for v in rng.integers(0, len(router), 2))
        q = rng.uniform(LO, HI, 7)
        x = rng.uniform(LO / 4, HI / 4, 3)
        if op == "dup":  # bag i takes bag j's joint-space mean: ties
            q = q_means(router)[j]
        if op == "add":
            router.add(q, x)
        elif op == "join":  # a far point joins: a large move of the mean
            router.join(i, q, x)
        else:
            router.replace(i, q, x)
    assert_every_path_decides_as_brute_force(rng, router, k=12)


@pytest.mark.parametrize("n_bags", [12, 60, 200])
def test_route_join_is_route_then_join_on_bag_boundaries(n_bags):
    """The algorithms test's boundary points (adjacent floats on either side of a bag's
    sphere): route_join joins where route says, and the means move as join moves them, to
    the bit; the scan (200 bags) decides them as every bag does."""
    from tests.iem.test_algorithms import _boundary_points, _crowded_router

    fused = _crowded_router(n_bags)
    split = copy.deepcopy(fused)
    rng = np.random.default_rng(4)
    points = list(_boundary_points(split, 10, rng))
    points += [(q_means(split)[i % len(split)] + rng.normal(0, 0.2, 7), np.zeros(3))
               for i in range(200)]
    outcomes = set()
    for q, f in points:
        want = split.route(q, f)
        assert split.route_exact(q, f) == want
        if want[0] >= 0:
            split.join(want[0], q, f)
        assert fused.route_join(q, f) == want
        outcomes.add(want[0] >= 0)
    assert outcomes == {True, False}
    assert means_of(fused).tobytes() == means_of(split).tobytes()
    assert fused.counts.tolist() == split.counts.tolist()


@pytest.mark.parametrize("others", [0, 100])
def test_route_join_when_the_nearest_bag_is_out_of_reach_in_cartesian_space(others):
    """The nearest bag in joint space fails the flange sphere; a farther one holds the
    point: that one is joined, the nearest is still reported (Algorithm 1's two spheres).
    With 100 bags more, far away, the scan proposes the candidates."""
    router = BagRouter()
    q = np.zeros(7)
    router.new_bag(q + 0.01, np.array([0.5, 0.0, 0.0]))  # nearest, its flange 0.5 m away
    router.new_bag(q + 0.1, np.zeros(3))  # within both spheres
    router.new_bag(q + 0.2, np.zeros(3))  # within both, farther
    for i in range(others):
        router.new_bag(np.full(7, 3.0 + 0.01 * i), np.zeros(3))
    split = copy.deepcopy(router)
    bag, nearest = split.route(q, np.zeros(3))
    split.join(bag, q, np.zeros(3))
    assert (bag, nearest) == (1, 0)
    assert router.route_join(q, np.zeros(3)) == (1, 0)
    assert q_means(router).tobytes() == q_means(split).tobytes()
    assert router.counts.tolist()[:3] == [1, 2, 1]
    # nothing holds it: no bag moves, the nearest is reported
    far = np.full(7, 2.0)
    assert router.route_join(far, np.zeros(3)) == (-1, 2 if others == 0 else 3)
    assert router.counts.tolist()[:3] == [1, 2, 1]
    for bad in ((np.zeros(6), np.zeros(3)), (np.zeros(7), np.zeros(2))):
        with pytest.raises(InvalidInputError, match=r"q \(7\) and flange \(3\)"):
            router.route_join(*bad)
        with pytest.raises(InvalidInputError, match=r"q \(7\) and flange \(3\)"):
            router.route(*bad)


def test_near_ties_in_float32_are_decided_in_float64():
    """Bags whose distances to the point differ by less than float32 resolves (means
    1e-7 rad apart, 1 rad from the point): the scan keeps them all as candidates and the
    float64 distances name the nearest, as brute force does."""
    rng = np.random.default_rng(8)
    for _ in range(50):
        centre = rng.uniform(LO, HI, 7)
        Q = np.vstack((centre + rng.normal(0, 1e-7, (20, 7)), rng.uniform(LO, HI, (80, 7))))
        F = np.zeros((100, 3))
        router = BagRouter.from_means(Q, F, DELTA, RHO)
        d = rng.normal(size=7)
        for r in (0.3, 1.0):  # inside the bags, and outside every bag
            q = centre + d / np.linalg.norm(d) * r
            assert router.route(q, F[0]) == brute(means_of(router), q, F[0], DELTA, RHO)


@pytest.mark.filterwarnings("ignore:invalid value encountered:RuntimeWarning")
@pytest.mark.parametrize("n", [3, 100])
def test_a_point_that_is_not_finite_joins_nothing(n):
    """A NaN point (never from a link, whose decoders refuse it) joins nothing and names
    the first bag nearest, as NumPy's argmin of NaN distances, by every path; no bag
    moves."""
    _, router = random_router(n, 5)
    q = np.full(7, 0.1)
    q[2] = math.nan
    before = means_of(router).tobytes()
    for r in (router, copy.deepcopy(router)):
        assert r.route(q, np.zeros(3)) == r.route_exact(q, np.zeros(3)) == (-1, 0)
        assert r.route_join(q, np.zeros(3)) == (-1, 0)
    assert router.route_many(q[None], np.zeros((1, 3))).tolist() == [-1]
    assert means_of(router).tobytes() == before
    q[2] = math.inf  # every distance infinite: the first bag, as argmin
    assert router.route(q, np.zeros(3)) == router.route_exact(q, np.zeros(3)) == (-1, 0)


def test_a_copy_and_a_loaded_router_decide_the_same():
    rng, router = random_router(300, 3)
    state = router.to_state()
    assert set(state) == {"delta", "rho", "means", "counts"}
    loaded = BagRouter.from_state(state)
    copied = copy.deepcopy(router)
    for q, x in zip(*probes(rng, router, 30), strict=True):
        assert loaded.route(q, x) == copied.route(q, x) == router.route(q, x)
