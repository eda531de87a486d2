"""The ``expected`` learner (:mod:`iem.ensemble.expected`): Algorithm 2 in expectation over its
input noise, computed exactly, and the ensemble that trains with it."""

from __future__ import annotations

import copy
import pickle

import numpy as np
import pytest

from iem import checks
from iem.check_data import train
from iem.ensemble import IncrementalEnsemble
from iem.ensemble.expected import BagStatistics, ExpectedLearner, refit
from iem.ensemble.learner import SENSOR_NOISE, WeakLearner, output_range
from iem.ensemble.learners import FAST_LEARNER, LEARNERS, learner_class
from iem.errors import InvalidInputError
from iem.persistence import dumps, loads
from iem.physics import PhysicsInformedEnsemble
from sim.arm import NOMINAL_DYNAMICS
from tests.iem.test_checks import DATA

RNG = np.random.default_rng(49)
K = 40


def _point(rng, q=None, dq=None):
    """One state's samples: 7 joint values and velocities shared, K torques and targets."""
    q = rng.uniform(-1.0, 1.0, 7) if q is None else q
    dq = rng.uniform(-0.5, 0.5, 7) if dq is None else dq
    phi = np.column_stack((rng.uniform(0.8, 2.2, K), rng.normal(0.0, 0.05, (K, 9))))
    A = rng.normal(0.0, 3.0, (10, 7))
    X = np.column_stack((np.tile(q, (K, 1)), np.tile(dq, (K, 1)), phi @ A))
    return X, phi


X0, Y0 = _point(RNG)
LO, HI = output_range(Y0)


def _learner(cls=ExpectedLearner, noise=SENSOR_NOISE):
    rng = np.random.default_rng(3)
    scale = np.sqrt(X0.var(axis=0) + SENSOR_NOISE ** 2)
    learner = cls(LO, HI, X0.mean(axis=0), scale, input_noise=noise, seed=1)
    learner.a = rng.normal(0.0, 0.01, (10, 21))  # every ReLU on: Algorithm 2 is linear
    learner.b = rng.uniform(0.3, 0.7, 10)
    return learner


def test_one_step_is_the_mean_of_algorithm_2s_noisy_steps():
    """One step of Algorithm 2 is linear in its noise's first two moments, so its mean over
    many draws is the expected learner's step (an independent computation: the SGD's own
    noisy arithmetic), within four standard errors."""
    expected = _learner()
    expected.learn(X0, Y0, iters=1)
    runs = 3000
    a = np.empty((runs, 10, 21))
    for s in range(runs):
        sgd = _learner(WeakLearner)
        sgd._rng = np.random.default_rng([7, s])
        sgd.learn(X0, Y0, iters=1)
        a[s] = sgd.a
    assert (np.asarray(_learner().a) @ ((X0 - X0.mean(axis=0)).T)).min() > -0.15
    err = a.std(axis=0) / np.sqrt(runs)
    assert np.all(np.abs(a.mean(axis=0) - expected.a) <= 4.0 * err + 1e-12)


def test_without_noise_the_steps_are_algorithm_2s_own():
    """No input noise: nothing to take the expectation of; the steps are the SGD's to
    rounding."""
    expected, sgd = _learner(noise=None), _learner(WeakLearner, noise=None)
    loss_e = expected.learn(X0, Y0, iters=5)
    loss_s = sgd.learn(X0, Y0, iters=5)
    np.testing.assert_allclose(expected.a, sgd.a, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(expected.b, sgd.b, rtol=1e-9, atol=1e-12)
    assert loss_e == pytest.approx(loss_s, rel=1e-9)  # both: before the last step


def test_steps_without_the_loss_and_on_read_only_targets_are_the_same_steps():
    """The estimator's path: the family's targets read-only (scaled once, kept) and no loss
    asked (NaN). The weights and the bag's statistics are those of the plain call, to the
    bit, and a writeable array of other targets is scaled afresh."""
    frozen = Y0.copy()
    frozen.flags.writeable = False
    plain, fast = _learner(), _learner()
    kept_plain, kept_fast = BagStatistics(plain), BagStatistics(fast)
    for _ in range(3):
        assert np.isfinite(plain.learn(X0, Y0, iters=4, keep=kept_plain))
        assert np.isnan(fast.learn(X0, frozen, iters=4, keep=kept_fast, loss=False))
    np.testing.assert_array_equal(fast.a, plain.a)
    np.testing.assert_array_equal(fast.b, plain.b)
    np.testing.assert_array_equal(kept_fast.cross, kept_plain.cross)
    other = Y0 * 1.01
    twin = copy.deepcopy(fast)
    fast.learn(X0, other, iters=2)
    twin.learn(X0, other.copy(), iters=2)
    np.testing.assert_array_equal(fast.a, twin.a)
    wider = [ExpectedLearner(LO - 0.1, HI + 0.1, X0.mean(axis=0), plain.scale,
                             input_noise=SENSOR_NOISE, seed=1) for _ in range(2)]
    wider[0].learn(X0, frozen, iters=2)  # the kept targets are another scaling's
    wider[1].learn(X0, Y0, iters=2)
    np.testing.assert_array_equal(wider[0].a, wider[1].a)


def _stats_of(points, start):
    stats = BagStatistics(start)
    for X, Y in points:
        stats.add(X, Y)
        stats.points += 1
    return stats


def test_the_refit_minimises_the_expected_loss_over_every_point():
    """The refit is where the gradient of the expected loss (least squares on all the bag's
    samples, plus n tr(a N aᵀ), plus the start's weight) vanishes: the gradient formed on the
    stacked samples in the original input units."""
    rng = np.random.default_rng(5)
    q = rng.uniform(-1.0, 1.0, 7)
    points = [_point(rng, q + 0.05 * k, rng.uniform(-0.5, 0.5, 7)) for k in range(6)]
    start = _learner()
    learner = refit(_stats_of(points, start), start)
    X = np.vstack([p[0] for p in points])
    T = (np.vstack([p[1] for p in points]) - LO) / (HI - LO)
    # the gradient in the start's coordinates, where the prior was set
    x = (X - start.center) / start.scale
    a_x = learner.a * (start.scale / learner.scale)  # the same function there
    b_x = learner.b + (learner.a / learner.scale) @ (start.center - learner.center)
    r = x @ a_x.T + b_x - T
    nvar = (SENSOR_NOISE / start.scale) ** 2
    grad_a = r.T @ x + len(X) * a_x * nvar + (a_x - start.a)
    grad_b = r.sum(axis=0) + (b_x - start.b)
    scale = np.abs(r.T @ x).max()
    assert np.abs(grad_a).max() <= 1e-8 * scale
    assert np.abs(grad_b).max() <= 1e-8 * scale


def test_the_refit_scaling_is_its_samples_and_keeps_the_function():
    rng = np.random.default_rng(6)
    points = [_point(rng) for _ in range(4)]
    start = _learner()
    stats = _stats_of(points, start)
    learner = refit(stats, start)
    X = np.vstack([p[0] for p in points])
    np.testing.assert_allclose(learner.center, X.mean(axis=0), rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(learner.scale, np.sqrt(X.var(axis=0) + SENSOR_NOISE ** 2),
                               rtol=1e-6)
    w = stats.solve()  # the solution in the start's coordinates
    x = (X - start.center) / start.scale
    phi = LO + np.maximum(x @ w[:, :21].T + w[:, 21], 0.0) * (HI - LO)
    np.testing.assert_allclose(learner.predict_many(X), phi, rtol=1e-9, atol=1e-9)
    assert learner.dq_precision.shape == (7, 7)


def test_the_statistics_point_by_point_are_those_of_the_stacked_samples():
    rng = np.random.default_rng(8)
    points = [_point(rng) for _ in range(5)]
    start = _learner()
    one = _stats_of(points, start)
    whole = BagStatistics(start)
    whole.add(np.vstack([p[0] for p in points]), np.vstack([p[1] for p in points]))
    np.testing.assert_allclose(one.gram, whole.gram, rtol=1e-12)
    np.testing.assert_allclose(one.cross, whole.cross, rtol=1e-12)
    assert one.n == 5 * K


def test_fit_is_the_refit_from_a_fresh_learner():
    rng = np.random.default_rng(9)
    X = np.vstack([_point(rng)[0] for _ in range(3)])
    Y = np.vstack([Y0] * 3)
    fitted = ExpectedLearner.fit(X, Y, LO, HI, input_noise=SENSOR_NOISE, seed=2)
    fresh = ExpectedLearner(LO, HI, X.mean(axis=0), np.sqrt(X.var(axis=0) + SENSOR_NOISE ** 2),
                            input_noise=SENSOR_NOISE, seed=2)
    stats = BagStatistics(fresh)
    stats.add(X, Y)
    again = refit(stats, fresh)
    np.testing.assert_array_equal(fitted.a, again.a)
    np.testing.assert_array_equal(fitted.b, again.b)
    assert type(fitted) is ExpectedLearner


def test_learners_by_name():
    assert learner_class("sgd") is WeakLearner
    assert learner_class(FAST_LEARNER) is ExpectedLearner
    for bad in ("SGD", "", None, 3):
        with pytest.raises(InvalidInputError, match="valid learners are sgd, expected"):
            learner_class(bad)
    with pytest.raises(InvalidInputError, match="valid learners are"):
        IncrementalEnsemble(learner="adam")
    assert set(LEARNERS) == {"sgd", "expected"}


def test_physics_ensemble_learns_by_the_fast_learner_unless_told():
    phys = PhysicsInformedEnsemble(dynamics=NOMINAL_DYNAMICS)
    assert phys._ens.learner_kind == FAST_LEARNER
    assert "learner" not in phys.params()["ensemble"]  # the params as given
    told = PhysicsInformedEnsemble(ensemble={"learner": "sgd"}, dynamics=NOMINAL_DYNAMICS)
    assert told._ens.learner_kind == "sgd"


def _ensemble(**kw):
    return IncrementalEnsemble(seed=0, fit_epochs=2, warmup_iters=10, iters=2,
                               learner="expected", **kw)


def _run(model, points):
    out = []
    for i in points:
        est = model.learn_predict_one(DATA.X[i], DATA.F[i], DATA.samples_at(i))
        out.append(est.phi)
    model.drain()
    return np.array(out)


@pytest.fixture(scope="module")
def trained():
    model = _ensemble()
    train(model, DATA)
    return model


def test_estimates_are_the_same_to_the_bit_run_after_run_and_in_another_process(trained):
    """Nothing is drawn: a copy, and a copy pickled as a replay's job gets it (``iem replay
    --jobs``), estimate to the bit as the model does."""
    further = list(DATA.further_points())
    first = _run(copy.deepcopy(trained), further)
    np.testing.assert_array_equal(_run(copy.deepcopy(trained), further), first)
    np.testing.assert_array_equal(_run(pickle.loads(pickle.dumps(trained)), further), first)
    assert np.isfinite(first).all()


def test_a_saved_open_bag_goes_on_as_if_never_saved(trained):
    further = list(DATA.further_points())
    half = len(further) // 2
    model = copy.deepcopy(trained)
    _run(model, further[:half])
    assert model.open_bag >= 0 and isinstance(model._kept, BagStatistics)
    loaded = loads(dumps(model))
    assert loaded.learner_kind == "expected"
    np.testing.assert_array_equal(_run(loaded, further[half:]), _run(model, further[half:]))


def test_a_closed_bag_is_refitted_on_every_point(trained):
    model = copy.deepcopy(trained)
    before = model.n_bags
    _run(model, list(DATA.further_points()))
    model.close()
    assert model.n_bags > before
    for bag in range(before, model.n_bags):
        learner = model.learner(bag)
        assert type(learner) is ExpectedLearner
        assert model._kept is None


@pytest.mark.parametrize("check", checks.CHECKS, ids=lambda c: c.__name__)
def test_the_ensemble_with_the_expected_learner_passes_every_check(check):
    check(_ensemble, DATA)
