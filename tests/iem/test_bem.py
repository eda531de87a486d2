"""The BEM baseline: bagging of its members, bootstrap resamples, never updated, plain state."""

from __future__ import annotations

import msgpack
import numpy as np
import pytest

from iem.base import Estimator
from iem.baselines.bem import BatchEnsemble
from iem.baselines.tree import RegressionTree
from iem.ensemble.learner import WeakLearner, output_range
from iem.errors import InvalidInputError

N_POINTS, K = 30, 77


@pytest.fixture(scope="module")
def problem():
    """30 path points, 77 samples each, ``Y = X W + c`` plus noise."""
    rng = np.random.default_rng(42)
    centers = rng.standard_normal((N_POINTS, 21))
    X = centers[:, None, :] + 0.3 * rng.standard_normal((N_POINTS, K, 21))
    W = 0.05 * rng.standard_normal((21, 10))
    Y = X @ W + np.linspace(0.5, 2.0, 10) + 0.01 * rng.standard_normal((N_POINTS, K, 10))
    Q = centers[:, :7]
    F = rng.standard_normal((N_POINTS, 3))
    return Q, F, X, Y


def _samples_at(problem, calls=None):
    _, _, X, Y = problem

    def samples_at(i):
        if calls is not None:
            calls.append(i)
        return X[i], Y[i]
    return samples_at


def _fit(problem, **kw):
    Q, F, _, _ = problem
    kw = {"n_networks": 3, "n_trees": 3, "fit_stride": 2, "fit_epochs": 3, **kw}
    return BatchEnsemble(**kw).fit(Q, F, _samples_at(problem))


def _probe(problem, n=50):
    _, F, X, _ = problem
    rows = np.random.default_rng(7).integers(0, N_POINTS * K, n)
    return X.reshape(-1, 21)[rows], F[rows // K]


def test_is_an_estimator_with_no_bags(problem):
    bem = _fit(problem)
    assert isinstance(bem, Estimator) and bem.name == "BEM"
    assert bem.n_bags == 0
    assert len(bem.learners) == 3 and len(bem.trees) == 3
    assert bem.nbytes() == (sum(lr.nbytes() for lr in bem.learners)
                            + sum(t.nbytes() for t in bem.trees)) > 0


def test_prediction_is_the_mean_of_the_members(problem):
    bem = _fit(problem)
    X, F = _probe(problem)
    members = [lr.predict_many(X) for lr in bem.learners] + [t.predict_many(X)
                                                             for t in bem.trees]
    np.testing.assert_allclose(bem.predict_many(X, F), np.mean(members, axis=0), rtol=1e-12)
    # and it has learnt something: far better than the mean target
    _, F, Xs, Ys = problem
    Xa, Ya = Xs.reshape(-1, 21), Ys.reshape(-1, 10)
    err = np.abs(bem.predict_many(Xa, np.repeat(F, K, axis=0)) - Ya).mean()
    assert err < 0.5 * np.abs(Ya - Ya.mean(axis=0)).mean()


def test_fit_takes_every_stride_th_point(problem):
    Q, F, _, _ = problem
    calls = []
    BatchEnsemble(n_networks=1, n_trees=1, fit_stride=4, fit_epochs=1).fit(
        Q, F, _samples_at(problem, calls))
    assert calls == list(range(0, N_POINTS, 4))


def test_each_member_trains_on_its_own_bootstrap_resample(problem):
    """Without input noise, every member equals its learner trained on ``resample(i)``."""
    _, _, X, Y = problem
    bem = _fit(problem, input_noise=None, seed=5)
    idx = range(0, N_POINTS, 2)
    Xp = np.vstack([X[i] for i in idx])
    Yp = np.vstack([Y[i] for i in idx])
    n = len(Yp)
    resamples = [bem.resample(i, n) for i in range(6)]
    for i, rows in enumerate(resamples):
        assert rows.shape == (n,) and rows.min() >= 0 and rows.max() < n
        assert len(np.unique(rows)) < n  # drawn with replacement
        for other in resamples[i + 1:]:
            assert not np.array_equal(rows, other)
    probe, _ = _probe(problem)
    for i, member in enumerate(bem.learners):
        rows = resamples[i]
        ref = WeakLearner.fit(Xp[rows], Yp[rows], *output_range(Yp), input_noise=None,
                              seed=[5, i], epochs=3, batch=K, fit_lr=0.1)
        np.testing.assert_array_equal(member.predict_many(probe), ref.predict_many(probe))
    for j, member in enumerate(bem.trees):
        rows = resamples[3 + j]
        ref = RegressionTree(6, 20, seed=[5, 3 + j]).fit(Xp[rows], Yp[rows])
        np.testing.assert_array_equal(member.predict_many(probe), ref.predict_many(probe))
    trees = [t.predict_many(probe) for t in bem.trees]
    assert not np.array_equal(trees[0], trees[1])


def test_learn_one_changes_nothing_and_never_asks_for_samples(problem):
    bem = _fit(problem)
    X, F = _probe(problem)
    before, state = bem.predict_many(X, F), bem.to_state()

    def samples():
        raise AssertionError("BEM must never ask for tandem samples")
    for x, f in zip(X, F, strict=True):
        bem.learn_one(x, f, samples)
    np.testing.assert_array_equal(bem.predict_many(X, F), before)
    assert bem.to_state() == state


def test_predict_before_fit_is_nan(problem):
    bem = BatchEnsemble()
    X, F = _probe(problem, 4)
    bem.learn_one(X[0], F[0], lambda: pytest.fail("samples resolved"))
    est = bem.predict_one(X[0], F[0], t=1.5)
    assert est.t == 1.5 and est.bag == -1 and np.isnan(est.phi).all() and est.phi.shape == (10,)
    out = bem.predict_many(X, F)
    assert out.shape == (4, 10) and np.isnan(out).all()
    assert bem.nbytes() == 0


def test_seeded_determinism(problem):
    X, F = _probe(problem)
    a = _fit(problem, seed=1).predict_many(X, F)
    b = _fit(problem, seed=1).predict_many(X, F)
    c = _fit(problem, seed=2).predict_many(X, F)
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a, c)


def test_state_round_trip_through_msgpack(problem):
    bem = _fit(problem, max_features=5, seed=3)
    back = BatchEnsemble.from_state(msgpack.unpackb(msgpack.packb(bem.to_state())))
    assert back.params() == bem.params()
    X, F = _probe(problem)
    np.testing.assert_array_equal(back.predict_many(X, F), bem.predict_many(X, F))
    assert back.nbytes() == bem.nbytes()
    empty = BatchEnsemble.from_state(msgpack.unpackb(msgpack.packb(
        BatchEnsemble().to_state())))
    assert not empty.fitted


def test_state_with_the_wrong_member_count_is_rejected(problem):
    state = _fit(problem).to_state()
    state["trees"] = state["trees"][:1]
    with pytest.raises(InvalidInputError, match="3 networks and 1 trees"):
        BatchEnsemble.from_state(state)


def test_clone_is_fresh_with_the_same_params(problem):
    bem = _fit(problem, seed=9, max_depth=4)
    twin = bem.clone()
    assert twin.params() == bem.params() and not twin.fitted
    X, F = _probe(problem)
    before = bem.predict_many(X, F)
    twin.fit(*problem[:2], _samples_at(problem))
    np.testing.assert_array_equal(bem.predict_many(X, F), before)
    np.testing.assert_array_equal(twin.predict_many(X, F), before)


def test_predict_one_equals_predict_many_rows(problem):
    bem = _fit(problem)
    X, F = _probe(problem)
    many = bem.predict_many(X, F)
    for k, (x, f) in enumerate(zip(X, F, strict=True)):
        est = bem.predict_one(x, f, t=0.1 * k)
        assert est.t == 0.1 * k and est.bag == -1
        np.testing.assert_allclose(est.phi, many[k], rtol=1e-12, atol=1e-15)


def test_does_not_mutate_inputs(problem):
    X, F = _probe(problem)
    X0 = X.copy()
    bem = _fit(problem)
    bem.predict_many(X, F)
    bem.predict_one(X[0], F[0])
    np.testing.assert_array_equal(X, X0)
    assert np.array_equal(problem[2][0], _samples_at(problem)(0)[0])


def test_invalid_inputs_raise(problem):
    Q, F, _, _ = problem
    with pytest.raises(InvalidInputError, match="at least one member"):
        BatchEnsemble(n_networks=0, n_trees=0)
    with pytest.raises(InvalidInputError, match="fit_stride"):
        BatchEnsemble(fit_stride=0)
    with pytest.raises(InvalidInputError, match=r"Q \(N, 7\)"):
        BatchEnsemble().fit(Q[:, :6], F, _samples_at(problem))
    with pytest.raises(InvalidInputError, match="samples_at must give"):
        BatchEnsemble().fit(Q, F, lambda i: (np.zeros((K, 20)), np.zeros((K, 10))))
    bem = BatchEnsemble()
    with pytest.raises(InvalidInputError, match="21 values"):
        bem.predict_one(np.zeros(20), F[0])
    with pytest.raises(InvalidInputError, match=r"\(N, 21\)"):
        bem.predict_many(np.zeros((3, 20)), F[:3])
