"""The paper's algorithms step by step on small hand-made inputs.

- Algorithm 1 (:class:`iem.ensemble.router.BagRouter`): bag membership, running means and counts
  by hand.
- Algorithm 2 (:class:`iem.ensemble.learner.WeakLearner`): one SGD step computed by hand.
- Eq. 1-2 and the online rules (:class:`iem.ensemble.IncrementalEnsemble`): new bags copy the
  nearest learner, the open bag trains, a closed bag's learner never changes, the estimate
  comes from the bag the point falls in or else the nearest one.
"""

from __future__ import annotations

import numpy as np
import pytest

from iem.ensemble import IncrementalEnsemble
from iem.ensemble.learner import SCALE_FLOOR, WeakLearner, output_range
from iem.ensemble.router import BagRouter
from tests.iem.router_views import q_means


def e(i: int, n: int = 7) -> np.ndarray:
    v = np.zeros(n)
    v[i] = 1.0
    return v


def q7(*head: float) -> np.ndarray:
    """A 7-D joint vector from its first entries (the rest zero)."""
    return np.array([*head, *([0.0] * (7 - len(head)))])


# =========================================================================================
# Algorithm 1: the bag router
# =========================================================================================
DELTA, RHO = 1.0, 0.5  # joint-space radius (rad) and Cartesian radius (m) of the example

# (q, flange, expected (bag, created, nearest)) and, after the point, the bag means and
# counts worked out by hand (running means of q and of the flange position)
STEPS = [
    # first point: a new bag, no bag to copy from
    (q7(), [0.0, 0.0, 0.0], (0, True, -1),
     [q7()], [[0.0, 0.0, 0.0]], [1]),
    # |dq|² = 0.25 < 1, |dx|² = 0.01 < 0.25: joins bag 0; means (0+0.5)/2, (0+0.1)/2
    (q7(0.5), [0.1, 0.0, 0.0], (0, False, 0),
     [q7(0.25)], [[0.05, 0.0, 0.0]], [2]),
    # |dq|² = 0.15² + 0.3² = 0.1125, |dx|² = 0.15² + 0.3² = 0.1125: joins; means /3
    (q7(0.1, 0.3), [0.2, 0.3, 0.0], (0, False, 0),
     [q7(0.2, 0.1)], [[0.1, 0.1, 0.0]], [3]),
    # within δ in joint space (|dq|² = 0.01) but beyond ρ in Cartesian (|dx|² = 0.36): new bag
    (q7(0.3, 0.1), [0.1, 0.1, 0.6], (1, True, 0),
     [q7(0.2, 0.1), q7(0.3, 0.1)], [[0.1, 0.1, 0.0], [0.1, 0.1, 0.6]], [3, 1]),
    # within ρ of bag 0 (|dx|² = 0) but beyond δ (|dq|² = 2.30 to bag 0, 2.35 to bag 1):
    # new bag; nearest in joint space is bag 0
    (q7(0.0, 0.0, 1.5), [0.1, 0.1, 0.0], (2, True, 0),
     [q7(0.2, 0.1), q7(0.3, 0.1), q7(0, 0, 1.5)],
     [[0.1, 0.1, 0.0], [0.1, 0.1, 0.6], [0.1, 0.1, 0.0]], [3, 1, 1]),
    # inside bags 0 (|dq|² = 0.0225, |dx|² = 0.09) and 1 (|dq|² = 0.0025, |dx|² = 0.09):
    # the nearer in joint space, bag 1, wins; its means become (0.3+0.35)/2, (0.6+0.3)/2
    (q7(0.35, 0.1), [0.1, 0.1, 0.3], (1, False, 1),
     [q7(0.2, 0.1), q7(0.325, 0.1), q7(0, 0, 1.5)],
     [[0.1, 0.1, 0.0], [0.1, 0.1, 0.45], [0.1, 0.1, 0.0]], [3, 2, 1]),
    # nearest in joint space is bag 1 (|dq|² = 0.005²) but beyond ρ of it (|dx|² = 0.65²);
    # it qualifies for bag 0 only (|dq|² = 0.13², |dx|² = 0.2²): joins bag 0, nearest is 1
    (q7(0.33, 0.1), [0.1, 0.1, -0.2], (0, False, 1),
     [q7(0.2325, 0.1), q7(0.325, 0.1), q7(0, 0, 1.5)],
     [[0.1, 0.1, -0.05], [0.1, 0.1, 0.45], [0.1, 0.1, 0.0]], [4, 2, 1]),
]


def _example_router() -> BagRouter:
    router = BagRouter(DELTA, RHO)
    for q, f, *_ in STEPS:
        router.add(q, f)
    return router


def test_algorithm1_step_by_step():
    router = BagRouter(DELTA, RHO)
    assert len(router) == 0 and router.route(q7(), [0, 0, 0]) == (-1, -1)
    for k, (q, f, result, q_expected, f_means, counts) in enumerate(STEPS):
        expected_route = (-1 if result[1] else result[0], result[2])
        assert router.route(q, f) == expected_route, f"route of step {k}"
        assert router.add(q, f) == result, f"step {k}"
        assert len(router) == len(counts)
        np.testing.assert_allclose(q_means(router), q_expected, rtol=0, atol=1e-15)
        np.testing.assert_allclose(router.flange_means, f_means, rtol=0, atol=1e-15)
        assert router.counts.tolist() == counts


def test_running_mean_is_the_mean_of_the_members():
    rng = np.random.default_rng(0)
    router = BagRouter(delta=10.0, rho=10.0)
    Q = rng.uniform(-0.5, 0.5, (50, 7))
    F = rng.uniform(-0.5, 0.5, (50, 3))
    for q, f in zip(Q, F, strict=True):
        assert router.add(q, f)[0] == 0
    np.testing.assert_allclose(q_means(router)[0], Q.mean(0), atol=1e-14)
    np.testing.assert_allclose(router.flange_means[0], F.mean(0), atol=1e-14)
    assert router.counts.tolist() == [50]


def test_thresholds_are_strict():
    router = BagRouter(delta=0.5, rho=0.25)  # exact binary fractions: no rounding
    router.add(q7(), [0, 0, 0])
    assert router.route(q7(0.5), [0, 0, 0]) == (-1, 0)  # |dq| = δ: outside
    assert router.route(q7(0.5 - 2**-20), [0, 0, 0]) == (0, 0)
    assert router.route(q7(), [0.25, 0, 0]) == (-1, 0)  # |dx| = ρ: outside
    assert router.route(q7(), [0.25 - 2**-20, 0, 0]) == (0, 0)


def test_route_changes_nothing():
    router = _example_router()
    before = (q_means(router), router.flange_means, router.counts, len(router))
    rng = np.random.default_rng(1)
    for _ in range(50):
        router.route(rng.normal(0, 0.5, 7), rng.normal(0, 0.3, 3))
    router.route_many(rng.normal(0, 0.5, (20, 7)), rng.normal(0, 0.3, (20, 3)))
    after = (q_means(router), router.flange_means, router.counts, len(router))
    for a, b in zip(before[:3], after[:3], strict=True):
        assert a.tobytes() == b.tobytes()
    assert before[3] == after[3]


def test_route_many_equals_route_row_by_row():
    router = _example_router()
    rng = np.random.default_rng(2)
    Q = np.vstack([q_means(router)[rng.integers(0, 3, 300)] + rng.normal(0, 0.4, (300, 7)),
                   [s[0] for s in STEPS]])
    F = np.vstack([router.flange_means[rng.integers(0, 3, 300)] + rng.normal(0, 0.25, (300, 3)),
                   [s[1] for s in STEPS]])
    bags = router.route_many(Q, F)
    expected = [router.route(q, f)[0] for q, f in zip(Q, F, strict=True)]
    assert bags.tolist() == expected
    assert {-1, 0, 1, 2} <= set(expected)  # every case is exercised
    assert BagRouter().route_many(Q, F).tolist() == [-1] * len(Q)


def test_router_state_round_trip():
    router = _example_router()
    state = router.to_state()
    again = BagRouter.from_state(state)
    assert (again.delta, again.rho) == (DELTA, RHO)
    assert q_means(again).tobytes() == q_means(router).tobytes()
    assert again.flange_means.tobytes() == router.flange_means.tobytes()
    assert again.counts.tolist() == router.counts.tolist()
    for q, f in [(q7(0.25, 0.1), [0.1, 0.1, 0.1]), (q7(3.0), [1.0, 0, 0]), (q7(0.3), [0, 0, 0.5])]:
        assert again.route(q, f) == router.route(q, f)
        assert again.add(q, f) == router.add(q, f)
    np.testing.assert_array_equal(q_means(again), q_means(router))
    assert BagRouter.from_state(BagRouter(0.3, 0.1).to_state()).route(q7(), [0, 0, 0]) == (-1, -1)


def test_growth_beyond_capacity_keeps_all_means():
    router = BagRouter(delta=0.1, rho=0.1, capacity=2)
    for i in range(9):  # 9 bags, 1 m / 1 rad apart: the arrays double twice and then some
        assert router.add(q7(float(i)), [float(i), 0, 0]) == (i, True, i - 1 if i else -1)
    assert router.add(q7(4.02), [4.0, 0.0, 0.0]) == (4, False, 4)
    expected_q = np.array([q7(float(i)) for i in range(9)])
    expected_q[4, 0] = 4.01
    np.testing.assert_allclose(q_means(router), expected_q, atol=1e-15)
    np.testing.assert_allclose(router.flange_means[:, 0], np.arange(9.0), atol=1e-15)
    assert router.counts.tolist() == [1, 1, 1, 1, 2, 1, 1, 1, 1]
    for i in range(9):
        assert router.route(q7(i + 0.05), [i, 0, 0]) == (i, i)


# -- boundary consistency -------------------------------------------------------------------
def _boundary_points(router: BagRouter, n_bags: int, rng):
    """Pairs of points straddling bag ``b``'s joint-space boundary (adjacent floats apart),
    found by bisection on :meth:`BagRouter.route` along random directions."""
    for bag in range(n_bags):
        m = q_means(router)[bag]
        f = router.flange_means[bag]
        for _ in range(2):
            d = rng.normal(size=7)
            d /= np.linalg.norm(d)
            lo, hi = 0.5 * router.delta, 1.5 * router.delta
            for _ in range(80):
                mid = 0.5 * (lo + hi)
                if router.route(m + d * mid, f)[0] == bag:
                    lo = mid
                else:
                    hi = mid
            yield m + d * lo, f
            yield m + d * hi, f


def _crowded_router(n: int = 200) -> BagRouter:
    rng = np.random.default_rng(1)
    router = BagRouter(delta=0.5, rho=10.0)
    for _ in range(n):
        router.add(rng.normal(size=7) * 0.6 + 1.0, np.zeros(3))
    return router


@pytest.mark.parametrize("n_bags", [12, 200])
def test_route_many_equals_route_on_bag_boundaries(n_bags):
    router = _crowded_router(n_bags)
    rng = np.random.default_rng(3)
    for q, f in _boundary_points(router, min(20, len(router)), rng):
        assert router.route_many(q[None], f[None])[0] == router.route(q, f)[0]


def test_state_round_trip_routes_bag_boundaries_identically():
    # regression: the cached |mean|² once came from different roundings in add() and
    # from_state(), so reloaded routers decided boundary points differently
    router = _crowded_router()
    again = BagRouter.from_state(router.to_state())
    rng = np.random.default_rng(4)
    for q, f in _boundary_points(router, 20, rng):
        assert again.route(q, f) == router.route(q, f)


# =========================================================================================
# Algorithm 2: the weak learner, one SGD step by hand
# =========================================================================================
def _hand_learner() -> WeakLearner:
    """center 1, scale 2 for every input; outputs scaled by lo = 0, hi = 2 (t = phi / 2)."""
    learner = WeakLearner(lo=np.zeros(10), hi=np.full(10, 2.0), center=np.ones(21),
                          scale=np.full(21, 2.0), lr=0.7, input_noise=None)
    a = np.zeros((10, 21))
    a[0, 0], a[0, 1] = 0.5, 0.125
    a[1, 0] = -1.0
    b = np.full(10, 0.5)
    b[3] = -1.0  # output 3: pre-activation -1 < 0 for every sample, so no gradient
    learner.a, learner.b = a, b
    return learner


def _hand_batch():
    X = np.ones((2, 21))
    X[0, 0] = 3.0  # scaled: x_1 = (3 - 1) / 2 e_0 = e_0
    X[1, 1] = -3.0  # scaled: x_2 = (-3 - 1) / 2 e_1 = -2 e_1
    Y = np.ones((2, 10))  # scaled targets t = Y / 2 = 0.5 ...
    Y[1, 0] = 1.5  # ... except t_2[0] = 0.75
    Y[1, 1] = 0.0  # ... and t_2[1] = 0
    return X, Y


def test_algorithm2_one_step_by_hand():
    learner = _hand_learner()
    X, Y = _hand_batch()
    # scaled inputs
    x1, x2 = e(0, 21), -2.0 * e(1, 21)
    # forward pass z = a x + b:
    #   sample 1: z0 = 0.5 + 0.5 = 1.0, z1 = -1 + 0.5 = -0.5 (negative), z3 = -1, others 0.5
    #   sample 2: z0 = 0.125 * -2 + 0.5 = 0.25, z1 = 0.5, z3 = -1, others 0.5
    z1 = learner.a @ x1 + learner.b
    z2 = learner.a @ x2 + learner.b
    assert z1[[0, 1, 3, 5]].tolist() == [1.0, -0.5, -1.0, 0.5]
    assert z2[[0, 1, 3, 5]].tolist() == [0.25, 0.5, -1.0, 0.5]
    np.testing.assert_allclose(learner.predict_many(X) / 2.0,
                               np.maximum(np.vstack((z1, z2)), 0.0), atol=1e-15)
    # residuals y - t (ReLU(z) - t): sample 1: [0.5, -0.5 (masked), 0, -0.5 (masked), 0...]
    #                                  sample 2: [-0.5, 0.5, 0, -0.5 (masked), 0...]
    # MSE L = 1/2 (3 * 0.25 + 3 * 0.25) = 0.75 (the masked residuals count in the loss)
    # dL/da = 2/N sum_k r_k mask_k x_k^T: [0,0] = 0.5, [0,1] = -0.5 * -2 = 1, [1,1] = 0.5 * -2
    # dL/db = 2/N sum_k r_k mask_k: [0] = 0.5 - 0.5 = 0, [1] = 0.5
    ga, gb, loss = learner.gradient(np.vstack((x1, x2)), Y / 2.0)
    assert loss == pytest.approx(0.75, abs=1e-12)
    ga_hand = np.zeros((10, 21))
    ga_hand[0, 0], ga_hand[0, 1], ga_hand[1, 1] = 0.5, 1.0, -1.0
    gb_hand = np.zeros(10)
    gb_hand[1] = 0.5
    np.testing.assert_allclose(ga, ga_hand, rtol=0, atol=1e-12)
    np.testing.assert_allclose(gb, gb_hand, rtol=0, atol=1e-12)
    # normalised step: alpha = lr / (mean_k |x_k|² + 1) = 0.7 / ((1 + 4) / 2 + 1) = 0.2
    a0, b0 = learner.a.copy(), learner.b.copy()
    assert learner.learn(X, Y, iters=1) == pytest.approx(0.75, abs=1e-12)
    a_hand, b_hand = a0.copy(), b0.copy()
    a_hand[0, 0] = 0.5 - 0.2 * 0.5  # 0.4
    a_hand[0, 1] = 0.125 - 0.2 * 1.0  # -0.075
    a_hand[1, 1] = 0.0 + 0.2 * 1.0  # 0.2
    b_hand[1] = 0.5 - 0.2 * 0.5  # 0.4
    np.testing.assert_allclose(learner.a, a_hand, rtol=0, atol=1e-12)
    np.testing.assert_allclose(learner.b, b_hand, rtol=0, atol=1e-12)
    # the output with negative pre-activation, and the one whose two residuals cancel in b
    assert learner.a[3].tobytes() == a0[3].tobytes() and learner.b[3] == -1.0
    assert learner.a[1, 0] == -1.0 and learner.b[0] == 0.5


def _reference_step(a, b, center, scale, lo, hi, lr, X, Y):
    """One step of Algorithm 2 with explicit loops over samples, outputs and inputs."""
    n, n_in, n_out = len(X), len(center), len(lo)
    x = [[(X[k][j] - center[j]) / scale[j] for j in range(n_in)] for k in range(n)]
    t = [[(Y[k][o] - lo[o]) / (hi[o] - lo[o]) for o in range(n_out)] for k in range(n)]
    ga = [[0.0] * n_in for _ in range(n_out)]
    gb = [0.0] * n_out
    loss = 0.0
    for k in range(n):
        for o in range(n_out):
            z = sum(a[o][j] * x[k][j] for j in range(n_in)) + b[o]
            r = max(z, 0.0) - t[k][o]
            loss += r * r / n
            if z > 0.0:
                gb[o] += 2.0 / n * r
                for j in range(n_in):
                    ga[o][j] += 2.0 / n * r * x[k][j]
    alpha = lr / (sum(sum(v * v for v in row) for row in x) / n + 1.0)
    a_new = [[a[o][j] - alpha * ga[o][j] for j in range(n_in)] for o in range(n_out)]
    b_new = [b[o] - alpha * gb[o] for o in range(n_out)]
    return np.array(a_new), np.array(b_new), loss


def test_algorithm2_matches_an_explicit_loop_on_random_values():
    rng = np.random.default_rng(5)
    lo, hi = -rng.uniform(0.5, 1, 10), rng.uniform(0.5, 1, 10)
    center, scale = rng.normal(0, 1, 21), rng.uniform(0.5, 2, 21)
    learner = WeakLearner(lo, hi, center, scale, lr=0.3, input_noise=None)
    learner.a = rng.normal(0, 0.3, (10, 21))
    learner.b = rng.normal(0.3, 0.3, 10)
    learner.b[7] = -50.0  # one output always negative
    X = center + scale * rng.normal(0, 1, (6, 21))
    Y = rng.uniform(lo, hi, (6, 10))
    a_ref, b_ref, loss_ref = _reference_step(learner.a.tolist(), learner.b.tolist(), center,
                                             learner.scale, lo, hi, 0.3, X.tolist(), Y.tolist())
    a7 = learner.a[7].copy()
    loss = learner.learn(X, Y, iters=1)
    assert loss == pytest.approx(loss_ref, abs=1e-12)
    np.testing.assert_allclose(learner.a, a_ref, rtol=0, atol=1e-12)
    np.testing.assert_allclose(learner.b, b_ref, rtol=0, atol=1e-12)
    assert learner.a[7].tobytes() == a7.tobytes() and learner.b[7] == -50.0


def test_copy_is_independent():
    learner = _hand_learner()
    twin = learner.copy()
    for name in ("a", "b", "center", "scale", "lo", "hi"):
        assert getattr(twin, name).tobytes() == getattr(learner, name).tobytes()
        assert not np.shares_memory(getattr(twin, name), getattr(learner, name))
    X, Y = _hand_batch()
    a0, b0 = learner.a.copy(), learner.b.copy()
    twin.learn(X, Y, iters=3)
    assert learner.a.tobytes() == a0.tobytes() and learner.b.tobytes() == b0.tobytes()
    learner.learn(X, Y, iters=3)  # the same steps on the original: the same weights
    assert learner.a.tobytes() == twin.a.tobytes()


def test_copy_shares_the_noise_stream_unless_reseeded():
    learner = WeakLearner(np.zeros(10), np.ones(10), np.zeros(21), np.ones(21),
                          input_noise=np.full(21, 0.1), seed=4)
    X, Y = np.random.default_rng(0).normal(0, 1, (5, 21)), np.full((5, 10), 0.8)
    learner.learn(X, Y, 2)
    same, other = learner.copy(), learner.copy(seed=99)
    learner.learn(X, Y, 2)
    same.learn(X, Y, 2)
    other.learn(X, Y, 2)
    assert same.a.tobytes() == learner.a.tobytes()
    assert other.a.tobytes() != learner.a.tobytes()


def test_copy_for_keeps_weights_and_scale_and_takes_the_new_center():
    learner = _hand_learner()
    center = np.linspace(-1, 1, 21)
    other = learner.copy_for(center)
    assert other.a.tobytes() == learner.a.tobytes() and other.b.tobytes() == learner.b.tobytes()
    assert other.scale.tobytes() == learner.scale.tobytes()
    assert other.lo.tobytes() == learner.lo.tobytes() and other.hi.tobytes() == learner.hi.tobytes()
    assert other.center.tolist() == center.tolist()
    assert learner.center.tolist() == [1.0] * 21
    center[0] = 99.0  # the caller's array is not kept
    assert other.center[0] == -1.0


def test_predict_one_equals_predict_many():
    rng = np.random.default_rng(6)
    learner = WeakLearner(-np.ones(10), np.ones(10), rng.normal(0, 1, 21),
                          rng.uniform(0.5, 2, 21), input_noise=None)
    learner.a = rng.normal(0, 0.5, (10, 21))
    learner.b = rng.normal(0, 0.5, 10)
    X = rng.normal(0, 2, (40, 21))
    many = learner.predict_many(X)
    for x, row in zip(X, many, strict=True):
        np.testing.assert_allclose(learner.predict_one(x), row, rtol=1e-14, atol=1e-14)
    assert (many == learner.lo).any()  # some outputs are floored by the ReLU


def test_fit_converges_on_a_noise_free_linear_problem():
    rng = np.random.default_rng(7)
    n = 770
    Z = rng.normal(0, 1, (n, 6))
    mix = rng.normal(0, 1, (6, 21))
    # strongly correlated inputs of very different scales (rad, rad/s, N·m)
    X = Z @ mix * np.repeat([0.3, 1.0, 20.0], 7) + np.repeat([0.5, 0.0, 5.0], 7)
    W = rng.normal(0, 1, (6, 10))
    phi = 1.0 + 0.2 * Z @ W  # phi depends linearly on the inputs
    lo, hi = output_range(phi)
    learner = WeakLearner.fit(X, phi, lo, hi, input_noise=None, epochs=30, batch=77, seed=0)
    # the whitened SGD converged: tiny MSE on the scaled outputs
    t = (phi - lo) / (hi - lo)
    x = (X - learner.center) / learner.scale
    _, _, loss = learner.gradient(x, t)
    assert loss < 1e-8
    # the weights were mapped back: the stored form a, b on the plainly scaled inputs
    # reproduces the fitted predictions, computed here directly
    direct = lo + np.maximum(x @ learner.a.T + learner.b, 0.0) * (hi - lo)
    np.testing.assert_allclose(learner.predict_many(X), direct, rtol=0, atol=1e-12)
    np.testing.assert_allclose(direct, phi, atol=1e-3 * np.abs(phi).max())
    # plain (unwhitened) SGD from the same start is far from converged after as many steps
    plain = WeakLearner(lo, hi, learner.center, learner.scale, lr=0.5, input_noise=None)
    for _ in range(30 * n // 77):
        plain.learn(X[:77], phi[:77], 1)
    assert plain.gradient(x, t)[2] > 100 * loss


def test_fit_scale_is_the_input_std_with_the_noise():
    rng = np.random.default_rng(8)
    X = rng.normal(0, 1, (40, 21)) * 3.0
    X[:, 0] = 2.0  # a constant feature: its scale is floored
    noise = np.full(21, 0.5)
    learner = WeakLearner.fit(X, np.full((40, 10), 0.5), np.zeros(10), np.ones(10),
                              input_noise=noise, epochs=1)
    expected = np.maximum(np.sqrt(X.var(0) + 0.25), SCALE_FLOOR)
    np.testing.assert_allclose(learner.scale, expected, rtol=1e-14)
    np.testing.assert_allclose(learner.center, X.mean(0), rtol=1e-14)


# =========================================================================================
# The ensemble: Eq. 1-2 and the online rules
# =========================================================================================
E_DELTA, E_RHO = 1.0, 0.5
K_SAMPLES = 6
_RNG = np.random.default_rng(9)
_A = _RNG.normal(0, 1, (7, 10))
_PHI = np.column_stack((_RNG.uniform(0.8, 2.2, K_SAMPLES), _RNG.uniform(-0.05, 0.05, (6, 3)),
                        _RNG.uniform(0.001, 0.01, (6, 6))))


def _x(q) -> np.ndarray:
    q = np.asarray(q, float)
    return np.concatenate((q, 0.1 * q, _A @ _PHI[0] * (1 + 0.1 * np.sin(q))))


def _samples(q):
    q = np.asarray(q, float)
    tau = (_PHI @ _A.T) * (1 + 0.1 * np.sin(q))
    X = np.column_stack((np.tile(q, (K_SAMPLES, 1)), np.tile(0.1 * q, (K_SAMPLES, 1)), tau))
    return X, _PHI.copy()


def _flange(q) -> np.ndarray:
    return 0.25 * np.asarray(q, float)[:3]


def _weights(learner: WeakLearner) -> bytes:
    return b"".join(getattr(learner, n).tobytes() for n in ("a", "b", "center", "scale"))


def _never(*_):
    raise AssertionError("samples were asked for a point that cannot train any learner")


def _ensemble(**kw) -> IncrementalEnsemble:
    params = {"delta": E_DELTA, "rho": E_RHO, "input_noise": None, "warmup_iters": 3,
              "iters": 2, "fit_epochs": 2, "seed": 0} | kw
    model = IncrementalEnsemble(**params)
    Q0 = np.array([q7(), q7(0.1), q7(0.0, 0.1)])
    model.fit(Q0, np.array([_flange(q) for q in Q0]), lambda i: _samples(Q0[i]))
    return model


def _learn(model, q, samples=None):
    model.learn_one(_x(q), _flange(q), _samples(q) if samples is None else samples)


def test_fit_forms_closed_initial_bags():
    model = _ensemble()
    assert model.n_bags == 1 and model.open_bag == -1
    assert model.router.counts.tolist() == [3]


def test_new_bag_copies_the_nearest_learner_before_training():
    model = _ensemble(warmup_iters=0)
    far = q7(2.0)
    _learn(model, far)  # outside every bag: new bag 1, copied from bag 0, no training
    assert model.n_bags == 2 and model.open_bag == 1
    new, old = model.learner(1), model.learner(0)
    assert new.a.tobytes() == old.a.tobytes() and new.b.tobytes() == old.b.tobytes()
    assert new.scale.tobytes() == old.scale.tobytes()
    assert new.center.tolist() == _samples(far)[0].mean(0).tolist()
    assert new is not old and not np.shares_memory(new.a, old.a)


def test_new_bag_copies_the_nearest_of_several():
    model = _ensemble(warmup_iters=0)
    _learn(model, q7(2.0))  # bag 1
    _learn(model, q7(-2.0))  # bag 2: nearest is bag 0 (2 rad) not bag 1 (4 rad)
    _learn(model, q7(3.5))  # bag 3: nearest is bag 1 (1.5 rad)
    assert model.n_bags == 4
    assert model.learner(2).a.tobytes() == model.learner(0).a.tobytes()
    assert model.learner(3).a.tobytes() == model.learner(1).a.tobytes()


def test_first_bag_of_an_untrained_model_starts_fresh():
    model = IncrementalEnsemble(delta=E_DELTA, rho=E_RHO, input_noise=None, warmup_iters=0)
    X, Y = _samples(q7(0.3))
    _learn(model, q7(0.3))
    learner = model.learner(0)
    assert learner.a.tolist() == np.zeros((10, 21)).tolist() and learner.b.tolist() == [0.5] * 10
    np.testing.assert_array_equal(learner.center, X.mean(0))
    np.testing.assert_array_equal(learner.scale, np.maximum(X.std(0), SCALE_FLOOR))
    lo, hi = output_range(Y)
    assert learner.lo.tolist() == lo.tolist() and learner.hi.tolist() == hi.tolist()


def test_online_rules_step_by_step():
    model = _ensemble()
    w0 = _weights(model.learner(0))

    # A: outside every bag -> bag 1, a copy of bag 0's learner trained at once (warmup)
    qa = q7(2.0)
    XA, YA = _samples(qa)
    expected = model.learner(0).copy_for(XA.mean(0))
    expected.learn(XA, YA, 3)
    _learn(model, qa)
    assert model.n_bags == 2 and model.open_bag == 1
    assert model.learner(1).a.tobytes() == expected.a.tobytes()
    assert model.learner(1).b.tobytes() == expected.b.tobytes()
    assert model.learner(1).a.tobytes() != model.learner(0).a.tobytes()

    # B: joins the open bag -> trains it (iters steps on B's samples)
    qb = q7(2.0, 0.1)
    XB, YB = _samples(qb)
    expected.learn(XB, YB, 2)
    _learn(model, qb)
    assert model.router.counts.tolist() == [3, 2] and model.open_bag == 1
    assert model.learner(1).a.tobytes() == expected.a.tobytes()
    assert model.learner(1).b.tobytes() == expected.b.tobytes()
    assert _weights(model.learner(0)) == w0  # a closed bag is never trained

    # C: goes to bag 0 -> bag 1 closes: its learner is trained once more on the points it
    # kept (A and B; no new samples are asked for) and is final from then on
    before = _weights(model.learner(1))
    model.learn_one(_x(q7(0.05)), _flange(q7(0.05)), _never)
    assert model.open_bag == -1 and model.router.counts.tolist() == [4, 2]
    w1 = _weights(model.learner(1))
    assert w1 != before
    refit = WeakLearner.fit(np.vstack((XA, XB)), np.vstack((YA, YB)), *model._out,
                            lr=model.lr, input_noise=model.input_noise, seed=[0, 1, 3],
                            epochs=model.fit_epochs, batch=XA.shape[0], fit_lr=model.fit_lr)
    assert w1 == _weights(refit)

    # more points in and out of bag 1, and a new bag 2 that forms and closes in turn
    for q in (q7(2.0, -0.1), q7(1.9), q7(2.1, 0.05)):  # into closed bag 1
        model.learn_one(_x(q), _flange(q), _never)
    _learn(model, q7(0.0, 0.0, 2.0))  # bag 2, open
    assert model.n_bags == 3 and model.open_bag == 2
    _learn(model, q7(0.0, 0.1, 2.0))  # trains bag 2
    model.learn_one(_x(q7(2.0)), _flange(q7(2.0)), _never)  # bag 1: closes bag 2
    assert model.open_bag == -1
    w2 = _weights(model.learner(2))
    for q in (q7(0.0, 0.0, 2.1), q7(2.0, 0.05), q7(0.02), q7(0.0, -0.1, 2.0)):
        model.learn_one(_x(q), _flange(q), _never)
    assert model.router.counts.tolist() == [5, 7, 4]
    assert _weights(model.learner(0)) == w0
    assert _weights(model.learner(1)) == w1
    assert _weights(model.learner(2)) == w2


def test_without_a_reservoir_closing_leaves_the_learner_as_it_was():
    """``reservoir = 0``: the paper's rule alone, the learner is final as the bag closes."""
    model = _ensemble(reservoir=0)
    _learn(model, q7(2.0))
    _learn(model, q7(2.0, 0.1))
    before = _weights(model.learner(1))
    model.learn_one(_x(q7(0.05)), _flange(q7(0.05)), _never)
    assert model.open_bag == -1 and _weights(model.learner(1)) == before


def test_lazy_samples_are_asked_for_only_when_a_learner_trains():
    model = _ensemble()
    calls = []

    def lazy(q):
        return lambda: calls.append(1) or _samples(q)

    for q, trains in ((q7(0.05), False), (q7(2.0), True), (q7(2.0, 0.1), True),
                      (q7(0.0), False), (q7(2.0), False)):
        n = len(calls)
        model.learn_one(_x(q), _flange(q), lazy(q))
        assert len(calls) == n + trains


def test_close_closes_the_open_bag():
    model = _ensemble()
    _learn(model, q7(2.0))
    assert model.open_bag == 1
    w1 = _weights(model.learner(1))
    model.close()
    assert model.open_bag == -1
    model.learn_one(_x(q7(2.0, 0.1)), _flange(q7(2.0, 0.1)), _never)
    assert _weights(model.learner(1)) == w1
    assert model.router.counts.tolist() == [3, 2]
    model.close()  # closing twice is harmless
    assert model.open_bag == -1


def test_estimate_uses_the_bag_the_point_falls_in_or_the_nearest():
    model = _ensemble()
    _learn(model, q7(2.0))  # bag 1 (open)
    _learn(model, q7(0.0, 0.0, 2.0))  # bag 2 (open; bag 1 closed)
    # (q, flange, bag that answers, inside that bag?, is it the open bag?)
    cases = [
        (q7(0.05), _flange(q7(0.05)), 0, True, False),
        (q7(2.0, 0.1), _flange(q7(2.0, 0.1)), 1, True, False),
        (q7(0.0, 0.0, 1.9), _flange(q7(0.0, 0.0, 1.9)), 2, True, True),  # the open bag
        # outside all bags (1.1 rad from bag 1, 3.1 from bag 0): the nearest, bag 1, answers
        (q7(3.1), _flange(q7(3.1)), 1, False, False),
        (q7(5.0, 5.0), _flange(q7(5.0, 5.0)), 1, False, False),
        (q7(0.0, 0.0, -3.0), _flange(q7(0.0, 0.0, -3.0)), 0, False, False),
        # near bag 0 in joint space but beyond ρ of it in Cartesian space: outside all bags,
        # so the nearest in joint space (bag 0) answers
        (q7(0.05), _flange(q7(0.05)) + np.array([0.0, 0.0, 0.6]), 0, False, False),
    ]
    X = [_x(q) for q, *_ in cases]
    F = [f for _, f, *_ in cases]
    bags = [bag for _, _, bag, _, _ in cases]
    for (q, f, bag, inside, learning), x in zip(cases, X, strict=True):
        assert model.router.route(q, f) == (bag if inside else -1, bag)
        est = model.predict_raw(x, f, t=1.5)  # the learner's own (predict_one may hold)
        assert est.bag == bag and est.learning == learning and est.t == 1.5
        assert est.phi.tobytes() == model.learner(bag).predict_one(x).tobytes()
    many = model.predict_many(np.array(X), np.array(F))
    np.testing.assert_allclose(many, [model.learner(b).predict_one(x) for x, b in
                                      zip(X, bags, strict=True)], rtol=1e-14, atol=1e-14)


def test_estimate_before_any_bag_is_nan():
    model = IncrementalEnsemble()
    est = model.predict_one(_x(q7()), _flange(q7()))
    assert est.bag == -1 and np.isnan(est.phi).all() and est.phi.shape == (10,)
    assert np.isnan(model.predict_many(np.array([_x(q7())] * 3), np.zeros((3, 3)))).all()


def test_predicting_changes_nothing():
    model = _ensemble()
    _learn(model, q7(2.0))
    state = model.to_state()
    for q in (q7(), q7(2.0), q7(9.0)):
        model.predict_one(_x(q), _flange(q))
    model.predict_many(np.array([_x(q7(2.0))] * 4), np.array([_flange(q7(2.0))] * 4))
    assert model.to_state() == state


def test_learn_predict_one_equals_learn_then_predict():
    """The combined online step routes once and gives exactly learn_one + predict_one."""
    import copy

    from tests.iem.test_checks import DATA

    one = IncrementalEnsemble(seed=0, fit_epochs=2, warmup_iters=10, iters=2)
    two = copy.deepcopy(one)
    for i in range(DATA.n):
        a = one.learn_predict_one(DATA.X[i], DATA.F[i], lambda i=i: DATA.samples_at(i), t=0.1)
        two.learn_one(DATA.X[i], DATA.F[i], lambda i=i: DATA.samples_at(i))
        b = two.predict_one(DATA.X[i], DATA.F[i], t=0.1)
        assert a.bag == b.bag and a.learning == b.learning
        np.testing.assert_array_equal(a.phi, b.phi)
    assert one.n_bags == two.n_bags >= 2


@pytest.mark.parametrize("n_bags", [12, 200])
def test_route_join_is_route_then_join(n_bags):
    """The cycle's one-pass route_join decides as route and moves the means as join, to the
    bit, on bag boundaries and inside, on a small map (one pass) and a large one (the scan)."""
    import copy

    fused = _crowded_router(n_bags)
    split = copy.deepcopy(fused)
    rng = np.random.default_rng(4)
    points = list(_boundary_points(split, min(10, len(split)), rng))
    points += [(q_means(split)[i % len(split)] + rng.normal(0, 0.2, 7), np.zeros(3))
               for i in range(200)]
    outcomes = set()
    for q, f in points:
        bag, nearest = split.route(q, f)
        if bag >= 0:
            split.join(bag, q, f)
        assert fused.route_join(q, f) == (bag, nearest)
        outcomes.add(bag >= 0)
    assert outcomes == {True, False}  # both cases are exercised
    assert q_means(fused).tobytes() == q_means(split).tobytes()
    assert fused.flange_means.tobytes() == split.flange_means.tobytes()
    assert fused.counts.tolist() == split.counts.tolist()
