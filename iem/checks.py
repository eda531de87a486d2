"""One check suite that every estimator passes (river's ``check_estimator``).

:func:`check_estimator` runs every ``check_*`` function of this module and of
:mod:`iem.capability_checks` (what an estimator declares beyond the seam: ``resume``,
``gap``, ``learn_predict_one``, ``observe_one``, ``go_live``, ``close``...) on an estimator
factory and a small data set; the functions are also listed in :data:`CHECKS` so a test can
parametrise over (estimator, check) pairs. A check that fails raises :class:`CheckFailed`
(an :class:`AssertionError`, so pytest reports it as a failed assertion) saying what was
expected and what was found.

The estimator under check is made by ``make()``, which must return a fresh, seeded
estimator with the :class:`iem.base.Estimator` methods (an :class:`iem.base.BaseEstimator`
has the defaults) plus ``params()`` and ``clone()`` (and ``fit(Q, F, samples_at)`` if the
data name ``fit_points``). The data are a :class:`iem.check_data.CheckData`: a short path of
points with their tandem samples.

Memory bound (:func:`check_memory_bounded`): an estimator's ``nbytes()`` must stay within
``BYTES_PER_BAG * max(1, n_bags) + BYTES_FIXED`` = 8 KiB per bag + 2 MiB. One IEM bag costs
about 2.2 KB (the router's 13 floats and a learner's 10x21 weights, 10 biases and 2x21 input
scalings), so 8 KiB leaves room for richer learners; 2 MiB covers what an estimator keeps
independently of the bags (the sample of the open bag, a least-squares normal matrix, a
batch model's fixed learners).
"""

from __future__ import annotations

import copy
import tempfile
from collections.abc import Callable
from pathlib import Path

import numpy as np

from .capability_checks import CAPABILITY_CHECKS
from .check_data import (
    CheckData,
    CheckFailed,
    fail,
    fit,
    identical,
    learn,
    learn_together,
    predictions,
    predictions_one,
    same_params,
    samples,
    train,
)

BYTES_PER_BAG = 8 * 1024
"""Memory budget of one bag, bytes (see the module docstring)."""
BYTES_FIXED = 2 * 1024 * 1024
"""Memory budget independent of the bags, bytes: the IEM's open bag keeps a fixed-size
sample of its points' tandem inputs (100 points x 77 samples x 21 values, 1.3 MB)."""
REPEAT_PASSES = 5
"""How many times :func:`check_memory_bounded` relearns the same points."""


# -- the checks --------------------------------------------------------------------------
def check_predict_before_learn(make, data: CheckData) -> None:
    """A fresh estimator predicts without raising: phi of shape (10,) / (N, 10), NaN allowed."""
    name = "predict before learn"
    est = make()
    for i in (0, data.n - 1):
        phi = np.asarray(est.predict_one(data.X[i].copy(), data.F[i].copy()).phi)
        if phi.shape != (10,):
            raise fail(name, f"predict_one gave phi of shape {phi.shape}, expected (10,)")
    out = np.asarray(est.predict_many(data.X.copy(), data.F.copy()))
    if out.shape != (data.n, 10):
        raise fail(name, f"predict_many gave shape {out.shape}, expected ({data.n}, 10)")


def check_inputs_not_mutated(make, data: CheckData) -> None:
    """fit/learn_one/predict_one/predict_many leave inputs alone and accept read-only ones."""
    name = "inputs not mutated"
    X0 = data.X.copy()
    F0 = data.F.copy()

    # writable inputs: compare with copies after every call
    est = make()
    fit(est, data)
    X = data.X.copy()
    F = data.F.copy()
    for i in range(data.n):
        x, f = X[i].copy(), F[i].copy()
        Xs, Ys = samples(data, i)
        Xs0, Ys0 = Xs.copy(), Ys.copy()
        lazy = i % 2 == 1  # every other point gives its samples lazily
        est.learn_one(x, f, (lambda s=(Xs, Ys): s) if lazy else (Xs, Ys))
        for label, arr, ref in (("x", x, X0[i]), ("flange", f, F0[i]),
                                ("samples X", Xs, Xs0), ("samples Y", Ys, Ys0)):
            if not identical(arr, ref):
                raise fail(name, f"learn_one changed its input {label} at point {i}")
        est.predict_one(x, f)
        if not (identical(x, X0[i]) and identical(f, F0[i])):
            raise fail(name, f"predict_one changed its input x or flange at point {i}")
    est.predict_many(X, F)
    if not (identical(X, X0) and identical(F, F0)):
        raise fail(name, "predict_many changed its input X or F")

    # read-only inputs: must not raise
    est = make()
    try:
        fit(est, data, readonly=True)
        X.flags.writeable = False
        F.flags.writeable = False
        for i in range(data.n):
            Xs, Ys = samples(data, i, readonly=True)
            est.learn_one(X[i], F[i], (Xs, Ys))
            est.predict_one(X[i], F[i])
        est.predict_many(X, F)
    except ValueError as exc:
        if "read-only" not in str(exc):
            raise
        raise fail(name, f"the estimator writes into a read-only input: {exc}") from exc
    if not (identical(data.X, X0) and identical(data.F, F0)):
        raise fail(name, "the estimator changed the CheckData's arrays")


def check_copies_independent(make, data: CheckData) -> None:
    """A deep copy learns on its own; ``clone()`` is untrained with equal ``params()``."""
    name = "copies independent"
    est = train(make(), data)
    before = predictions(est, data)
    twin = copy.deepcopy(est)
    for i in data.further_points():
        learn(twin, data, i)
    if not identical(predictions(est, data), before):
        raise fail(name, "learning on a deep copy changed the original's predictions")
    twin_before = predictions(twin, data)
    for i in data.further_points():
        learn(est, data, i)
    if not identical(predictions(twin, data), twin_before):
        raise fail(name, "learning on the original changed a deep copy's predictions")
    fresh = est.clone()
    if type(fresh) is not type(est):
        raise fail(name, f"clone() gave a {type(fresh).__name__}, expected {type(est).__name__}")
    if not same_params(fresh.params(), est.params()):
        raise fail(name, f"clone().params() = {fresh.params()} differs from "
                          f"params() = {est.params()}")
    untrained = make()
    if fresh.n_bags != untrained.n_bags:
        raise fail(name, f"clone() has {fresh.n_bags} bags, a fresh estimator "
                          f"{untrained.n_bags}: the clone is not untrained")
    if not identical(predictions(fresh, data), predictions(untrained, data)):
        raise fail(name, "clone() predicts differently from a fresh estimator: "
                          "it is not untrained")


def check_save_load(make, data: CheckData) -> None:
    """Save and load (``iem.persistence``): identical predictions, now and after learning."""
    from .persistence import load_model, save_model

    name = "save/load round trip"
    est = train(make(), data)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "model.iem"
        save_model(est, path)
        loaded = load_model(path)
    if type(loaded) is not type(est):
        raise fail(name, f"loaded a {type(loaded).__name__}, saved a {type(est).__name__}")
    if loaded.n_bags != est.n_bags:
        raise fail(name, f"loaded model has {loaded.n_bags} bags, saved {est.n_bags}")
    if not identical(predictions(loaded, data), predictions(est, data)):
        raise fail(name, "predict_many differs after the round trip")
    if not identical(predictions_one(loaded, data), predictions_one(est, data)):
        raise fail(name, "predict_one differs after the round trip")
    differ = learn_together(est, loaded, data, data.further_points())
    if differ is not None:
        i, a, b = differ
        raise fail(name, f"after learning point {i} the loaded model predicts "
                          f"{np.asarray(b).tolist()}, the original {np.asarray(a).tolist()}")
    if not identical(predictions(loaded, data), predictions(est, data)):
        raise fail(name, "predictions differ after both learnt the same further points")


def check_seeded_determinism(make, data: CheckData) -> None:
    """Two estimators from ``make()`` fed the same data predict bit for bit the same."""
    name = "seeded determinism"
    one, two = make(), make()
    fit(one, data)
    fit(two, data)
    differ = learn_together(one, two, data, data.train_points() + data.further_points())
    if differ is not None:
        i, a, b = differ
        raise fail(name, f"after point {i}: {np.asarray(a).tolist()} vs "
                          f"{np.asarray(b).tolist()}")
    if not identical(predictions(one, data), predictions(two, data)):
        raise fail(name, "predict_many differs between two estimators with the same seed")


def check_memory_bounded(make, data: CheckData) -> None:
    """``nbytes()`` stays within the bag budget, and relearning the same points adds nothing."""
    name = "memory bounded"
    est = train(make(), data)
    for i in data.further_points():
        learn(est, data, i)

    def within(when: str) -> int:
        nbytes = int(est.nbytes())
        bound = BYTES_PER_BAG * max(1, est.n_bags) + BYTES_FIXED
        if nbytes > bound:
            raise fail(name, f"{when}: nbytes() = {nbytes} exceeds {bound} "
                              f"({BYTES_PER_BAG} per bag x {est.n_bags} bags + {BYTES_FIXED})")
        return nbytes

    nbytes = within("after learning the data")
    bags = est.n_bags
    for p in range(REPEAT_PASSES):
        for i in range(data.n):
            learn(est, data, i)
        now = within(f"after relearning pass {p + 1}")
        if est.n_bags == bags and now > nbytes:
            raise fail(name, f"relearning pass {p + 1} grew nbytes() from {nbytes} to {now} "
                              f"with the number of bags unchanged ({bags})")
        nbytes, bags = now, est.n_bags


CHECKS: tuple[Callable[..., None], ...] = (
    check_predict_before_learn,
    check_inputs_not_mutated,
    check_copies_independent,
    check_save_load,
    check_seeded_determinism,
    check_memory_bounded,
    *CAPABILITY_CHECKS,
)
"""Every check, in the order :func:`check_estimator` runs them: the seam's, then the declared
capabilities' (:mod:`iem.capability_checks`)."""

__all__ = ["BYTES_FIXED", "BYTES_PER_BAG", "CHECKS", "REPEAT_PASSES", "CheckData", "CheckFailed",
           "check_estimator", *(check.__name__ for check in CHECKS)]


def check_estimator(make: Callable[[], object], data: CheckData) -> None:
    """Run every check of :data:`CHECKS` on ``make`` (a factory of fresh, seeded estimators).

    Raises:
        CheckFailed: the first check that fails, with what was expected and found.
    """
    for check in CHECKS:
        check(make, data)
