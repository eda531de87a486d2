"""The old IEM's in-place update (:mod:`iem.baselines.old_iem`): what it changes in the nearest
learner and what it leaves as trained (the synthetic path of ``test_checks``: no sim)."""

from __future__ import annotations

import numpy as np
import pytest

from iem.baselines.old_iem import UPDATES, InPlaceEnsemble, frozen_update
from iem.ensemble.learner import WeakLearner, output_range
from iem.errors import InvalidInputError

from .test_checks import DATA


def _fitted(update: str, **kw) -> InPlaceEnsemble:
    model = InPlaceEnsemble(seed=0, fit_epochs=2, update=update, **kw)
    idx = np.asarray(DATA.fit_points)
    model.fit(DATA.X[idx, :7], DATA.F[idx], lambda i: DATA.samples_at(int(idx[i])))
    return model


def _outside(model) -> tuple[int, int]:
    """A point of the path outside every bag, and its nearest bag."""
    for i in range(len(DATA.X) - 1, max(DATA.fit_points), -1):
        bag, nearest = model.router.route(DATA.X[i, :7], DATA.F[i])
        if bag < 0:
            return i, nearest
    pytest.fail("the synthetic path never leaves its bags")


def _snapshot(model) -> list[dict]:
    return [{k: getattr(model.learner(s), k).copy() for k in ("center", "scale", "a", "b")}
            for s in range(model.n_bags)]


@pytest.mark.parametrize("update", UPDATES)
def test_an_update_changes_the_nearest_learner_only(update):
    """Each update trains the nearest learner's weights in place; ``frozen`` and ``strict``
    leave its standardisation as trained, ``running_centre`` moves its centre by
    ``center_rate`` of the way to the point's mean input, never its scale."""
    model = _fitted(update, center_rate=0.05)
    i, nearest = _outside(model)
    before = _snapshot(model)
    X, Y = DATA.samples_at(i)
    model.learn_one(DATA.X[i], DATA.F[i], (X, Y))
    after = _snapshot(model)
    for s, (b, a) in enumerate(zip(before, after, strict=True)):
        if s != nearest:
            assert all(np.array_equal(b[k], a[k]) for k in b), f"bag {s} changed"
    b, a = before[nearest], after[nearest]
    assert not np.array_equal(b["a"], a["a"]) and not np.array_equal(b["b"], a["b"])
    assert np.array_equal(a["scale"], b["scale"])
    if update == "running_centre":
        assert np.array_equal(a["center"], b["center"] + 0.05 * (X.mean(axis=0) - b["center"]))
    else:
        assert np.array_equal(a["center"], b["center"])


def _learner_and_samples() -> tuple[WeakLearner, np.ndarray, np.ndarray]:
    Xs, Ys = zip(*(DATA.samples_at(i) for i in range(0, 40, 4)), strict=True)
    X, Y = np.concatenate(Xs), np.concatenate(Ys)
    learner = WeakLearner.fit(X, Y, *output_range(Y), input_noise=np.full(21, 0.01), seed=3,
                              epochs=3)
    return learner, *DATA.samples_at(20)


def test_frozen_update_is_algorithm_2_where_every_output_is_alive():
    learner, X, Y = _learner_and_samples()
    z = (X - learner.center) / learner.scale @ learner.a.T + learner.b
    assert (z > 0.0).any(axis=0).all()  # no output off on every sample
    ours, reference = learner.copy(), learner.copy()
    frozen_update(ours, X, Y, 5)
    reference.learn(X, Y, 5)  # the learner's own SGD (Algorithm 2), same noise draw
    np.testing.assert_allclose(ours.a, reference.a, rtol=1e-12, atol=0.0)
    np.testing.assert_allclose(ours.b, reference.b, rtol=1e-12, atol=0.0)
    assert not np.array_equal(ours.a, learner.a)


def test_frozen_update_revives_an_output_dead_on_every_sample():
    """Algorithm 2's gradient is zero through a ReLU that is off on every sample, so that
    output can never adapt; the frozen update moves it up towards its target, and every other
    output exactly as Algorithm 2 does."""
    learner, X, Y = _learner_and_samples()
    learner.b[0] = -50.0  # mass output off on every sample
    ours, reference = learner.copy(), learner.copy()
    frozen_update(ours, X, Y, 5)
    reference.learn(X, Y, 5)
    assert np.array_equal(reference.a[0], learner.a[0]) and reference.b[0] == -50.0
    assert ours.b[0] > -50.0
    np.testing.assert_allclose(ours.a[1:], reference.a[1:], rtol=1e-12, atol=0.0)
    np.testing.assert_allclose(ours.b[1:], reference.b[1:], rtol=1e-12, atol=0.0)
    assert np.array_equal(ours.center, learner.center)
    assert np.array_equal(ours.scale, learner.scale)


def test_the_update_is_a_hyper_parameter():
    model = InPlaceEnsemble(update="running_centre", center_rate=0.01)
    assert model.clone().params()["update"] == "running_centre"
    assert InPlaceEnsemble().update == "frozen"  # the paper's: weights only
    with pytest.raises(InvalidInputError, match="frozen, strict, running_centre"):
        InPlaceEnsemble(update="centre")
