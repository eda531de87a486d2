"""The CART regression tree against an independent brute-force search, plus its contract."""

from __future__ import annotations

from itertools import pairwise

import msgpack
import numpy as np
import pytest

from iem.baselines.tree import LEAF, RegressionTree
from iem.errors import InvalidInputError


def _sse(Y: np.ndarray) -> float:
    return float(((Y - Y.mean(axis=0)) ** 2).sum()) if len(Y) else 0.0


def brute_force_split(X, Y, min_leaf):
    """Every (feature, midpoint threshold) in turn, scored by the plain SSE of both sides.

    Returns ``(sse, feature, threshold)`` of the best split (first in feature, then
    threshold order on ties), or None if no split keeps ``min_leaf`` rows on each side.
    """
    best = None
    for f in range(X.shape[1]):
        values = np.unique(X[:, f])
        for lo, hi in pairwise(values):
            thr = 0.5 * (lo + hi)
            go = X[:, f] <= thr
            if go.sum() < min_leaf or (~go).sum() < min_leaf:
                continue
            sse = _sse(Y[go]) + _sse(Y[~go])
            if best is None or sse < best[0] - 1e-12 * max(1.0, best[0]):
                best = (sse, f, thr)
    return best


def brute_force_tree(X, Y, depth, min_leaf):
    """The greedy tree grown by :func:`brute_force_split`, as a function ``x -> prediction``."""
    split = brute_force_split(X, Y, min_leaf) if depth > 0 else None
    if split is None or split[0] >= _sse(Y) * (1 - 1e-12):
        mean = Y.mean(axis=0)
        return lambda x: mean
    _, f, thr = split
    go = X[:, f] <= thr
    left = brute_force_tree(X[go], Y[go], depth - 1, min_leaf)
    right = brute_force_tree(X[~go], Y[~go], depth - 1, min_leaf)
    return lambda x: left(x) if x[f] <= thr else right(x)


def _data(seed, n=60, d=4, m=3, integer=False):
    rng = np.random.default_rng(seed)
    X = rng.integers(0, 5, (n, d)).astype(float) if integer else rng.standard_normal((n, d))
    Y = np.column_stack([np.sin(2 * X[:, 0]) + X[:, 1] * X[:, 2 % d], X[:, -1] ** 2,
                         *[rng.standard_normal(n) for _ in range(m - 2)]])
    return X, Y + 0.1 * rng.standard_normal(Y.shape)


def _root_split_sse(tree, X, Y):
    go = X[:, tree.feature[0]] <= tree.threshold[0]
    return _sse(Y[go]) + _sse(Y[~go])


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("min_leaf", [1, 4])
def test_root_split_equals_brute_force(seed, min_leaf):
    X, Y = _data(seed)
    tree = RegressionTree(max_depth=1, min_samples_leaf=min_leaf).fit(X, Y)
    sse, f, thr = brute_force_split(X, Y, min_leaf)
    assert (tree.feature[0], tree.threshold[0]) == (f, pytest.approx(thr, abs=0))
    assert _root_split_sse(tree, X, Y) == pytest.approx(sse, rel=1e-12)


@pytest.mark.parametrize("seed", range(4))
def test_root_split_with_repeated_values_equals_brute_force(seed):
    """Integer features: many equal values, splits only between distinct ones; ties allowed."""
    X, Y = _data(seed, n=50, integer=True)
    tree = RegressionTree(max_depth=1, min_samples_leaf=3).fit(X, Y)
    sse, _, _ = brute_force_split(X, Y, 3)
    f, thr = tree.feature[0], tree.threshold[0]
    assert thr not in X[:, f] and np.any(X[:, f] < thr) and np.any(X[:, f] > thr)
    assert _root_split_sse(tree, X, Y) == pytest.approx(sse, rel=1e-12)


@pytest.mark.parametrize("seed", range(3))
def test_deep_tree_equals_brute_force_tree(seed):
    X, Y = _data(seed, n=80)
    tree = RegressionTree(max_depth=3, min_samples_leaf=5).fit(X, Y)
    probe = np.vstack([X, np.random.default_rng(seed + 100).standard_normal((40, 4))])
    reference = brute_force_tree(X, Y, 3, 5)
    expected = np.array([reference(x) for x in probe])
    np.testing.assert_allclose(tree.predict_many(probe), expected, rtol=1e-12, atol=1e-12)


def test_depth_one_recovers_a_step_exactly():
    rng = np.random.default_rng(1)
    X = np.column_stack([rng.uniform(0, 1, 200), rng.standard_normal(200)])
    low, high = np.arange(10.0), -np.arange(10.0) - 3.0
    Y = np.where((X[:, 0] > 0.37)[:, None], high, low)
    tree = RegressionTree(max_depth=1, min_samples_leaf=1).fit(X, Y)
    below, above = X[X[:, 0] <= 0.37, 0].max(), X[X[:, 0] > 0.37, 0].min()
    assert tree.feature[0] == 0 and tree.threshold[0] == 0.5 * (below + above)
    assert len(tree.feature) == 3
    np.testing.assert_array_equal(tree.predict_many(X), Y)
    np.testing.assert_array_equal(tree.predict_one([0.1, 5.0]), low)
    np.testing.assert_array_equal(tree.predict_one([0.9, -5.0]), high)


def test_constant_targets_give_a_single_leaf():
    X = np.random.default_rng(0).standard_normal((50, 3))
    tree = RegressionTree(min_samples_leaf=1).fit(X, np.ones((50, 10)))
    assert len(tree.feature) == 1 and tree.depth == 0


@pytest.mark.parametrize("min_leaf", [1, 7, 30])
def test_leaves_respect_min_samples_leaf(min_leaf):
    X, Y = _data(3, n=300, d=5, m=10)
    tree = RegressionTree(max_depth=8, min_samples_leaf=min_leaf).fit(X, Y)
    leaves, counts = np.unique(tree.apply(X), return_counts=True)
    assert set(leaves) == set(tree.leaves())
    assert counts.min() >= min_leaf
    np.testing.assert_array_equal(counts, tree.n_samples[leaves])
    assert tree.depth <= 8


def test_predictions_are_the_leaf_means():
    X, Y = _data(4, n=400, d=5, m=10)
    tree = RegressionTree(max_depth=4, min_samples_leaf=10).fit(X, Y)
    leaf = tree.apply(X)
    pred = tree.predict_many(X)
    for node in np.unique(leaf):
        np.testing.assert_allclose(pred[leaf == node], np.broadcast_to(
            Y[leaf == node].mean(axis=0), pred[leaf == node].shape), rtol=1e-12, atol=1e-15)


def test_predict_one_equals_predict_many():
    X, Y = _data(5, n=300, d=5, m=10)
    tree = RegressionTree(max_depth=5, min_samples_leaf=5).fit(X, Y)
    probe = np.random.default_rng(9).standard_normal((100, 5)) * 2
    many = tree.predict_many(probe)
    for x, row in zip(probe, many, strict=True):
        np.testing.assert_array_equal(tree.predict_one(x), row)


def test_seeded_determinism():
    X, Y = _data(6, n=300, d=8, m=10)
    a = RegressionTree(max_depth=5, min_samples_leaf=5, max_features=2, seed=3).fit(X, Y)
    b = RegressionTree(max_depth=5, min_samples_leaf=5, max_features=2, seed=3).fit(X, Y)
    c = RegressionTree(max_depth=5, min_samples_leaf=5, max_features=2, seed=4).fit(X, Y)
    assert a.to_state() == b.to_state()
    assert a.to_state() != c.to_state()
    full = RegressionTree(max_depth=5, min_samples_leaf=5).fit(X, Y)
    assert full.to_state()["feature"] != a.to_state()["feature"]


def test_does_not_mutate_inputs():
    X, Y = _data(7, n=100)
    X0, Y0 = X.copy(), Y.copy()
    tree = RegressionTree(max_depth=3, min_samples_leaf=2).fit(X, Y)
    tree.predict_many(X)
    np.testing.assert_array_equal(X, X0)
    np.testing.assert_array_equal(Y, Y0)


def test_state_round_trip_through_msgpack():
    X, Y = _data(8, n=300, d=5, m=10)
    tree = RegressionTree(max_depth=5, min_samples_leaf=5, max_features=3, seed=[1, 2]).fit(X, Y)
    state = msgpack.unpackb(msgpack.packb(tree.to_state()))
    back = RegressionTree.from_state(state)
    assert back.params() == tree.params()
    probe = np.random.default_rng(0).standard_normal((200, 5))
    np.testing.assert_array_equal(back.predict_many(probe), tree.predict_many(probe))
    assert back.nbytes() == tree.nbytes() > 0
    unfitted = RegressionTree.from_state(msgpack.unpackb(msgpack.packb(
        RegressionTree().to_state())))
    assert not unfitted.fitted


def test_state_with_a_bad_child_index_is_rejected():
    X, Y = _data(8, n=100)
    state = RegressionTree(max_depth=2, min_samples_leaf=2).fit(X, Y).to_state()
    state["left"][0] = 0  # the root its own child: a cycle
    with pytest.raises(InvalidInputError, match="child index"):
        RegressionTree.from_state(state)


@pytest.mark.parametrize(("X", "Y", "match"), [
    (np.zeros(10), np.zeros((10, 2)), "X must be a 2-D"),
    (np.zeros((10, 3)), np.zeros(10), "Y must be a 2-D"),
    (np.zeros((10, 3)), np.zeros((9, 2)), "same N"),
    (np.zeros((0, 3)), np.zeros((0, 2)), "same N"),
    (np.full((10, 3), np.nan), np.zeros((10, 2)), "X must be finite"),
    (np.zeros((10, 3)), np.full((10, 2), np.inf), "Y must be finite"),
])
def test_fit_rejects_invalid_inputs(X, Y, match):
    with pytest.raises(InvalidInputError, match=match):
        RegressionTree().fit(X, Y)


def test_invalid_hyper_parameters_and_predictions_raise():
    with pytest.raises(InvalidInputError, match="min_samples_leaf >= 1"):
        RegressionTree(min_samples_leaf=0)
    with pytest.raises(InvalidInputError, match="max_depth >= 0"):
        RegressionTree(max_depth=-1)
    with pytest.raises(InvalidInputError, match="max_features"):
        RegressionTree(max_features=0)
    X, Y = _data(9, n=50)
    with pytest.raises(InvalidInputError, match="at most the 4 features"):
        RegressionTree(max_features=5).fit(X, Y)
    with pytest.raises(InvalidInputError, match="not fitted"):
        RegressionTree().predict_one(X[0])
    tree = RegressionTree(max_depth=2, min_samples_leaf=2).fit(X, Y)
    with pytest.raises(InvalidInputError, match="4 features per row"):
        tree.predict_many(np.zeros((3, 5)))
    with pytest.raises(InvalidInputError, match="4 values"):
        tree.predict_one(np.zeros(3))
    with pytest.raises(InvalidInputError, match="finite"):
        tree.predict_one([0.0, np.nan, 0.0, 0.0])
    with pytest.raises(InvalidInputError, match="finite"):
        tree.predict_many(np.full((2, 4), np.nan))


def test_leaf_marker_and_depth_zero():
    X, Y = _data(10, n=50)
    tree = RegressionTree(max_depth=0).fit(X, Y)
    assert len(tree.feature) == 1 and tree.feature[0] == LEAF
    np.testing.assert_allclose(tree.predict_one(X[0]), Y.mean(axis=0))
