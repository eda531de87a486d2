"""The shared checks of what an estimator declares beyond ``learn_one``/``predict_one``.

:class:`iem.base.Estimator` declares the capabilities the online loop, the plug-in service
and the benchmarks call (with defaults in :class:`iem.base.BaseEstimator`); these checks
hold every estimator to what the declaration promises, whatever it overrides:

- the declaration is there and plain: the flags are bools, ``busy`` is False off a live
  link, ``learning_cpu_s`` is a time;
- ``resume()`` and ``gap(k)`` restart and bridge signal filters only: the estimates stay;
- ``learn_predict_one`` is ``learn_one`` then ``predict_one``, estimate for estimate;
- ``observe_one`` trains nothing: after ``reset()`` the model predicts as one that never
  observed;
- ``go_live()`` twice is ``go_live()`` once, live learning lands the same either way, and
  ``go_live(False)`` after it leaves what ``go_live(False)`` alone does (no live residue);
- ``close()``, ``drain()`` and ``stop()`` may be called twice, and learning goes on after.

They run in :func:`iem.checks.check_estimator` with the others (:data:`CAPABILITY_CHECKS`).
"""

from __future__ import annotations

import math
from collections.abc import Callable

from .base import Estimator
from .check_data import (
    CheckData,
    fail,
    identical,
    learn,
    predictions,
    predictions_one,
    same_params,
    samples,
    train,
)

LIVE_POINTS = 5
"""Further points :func:`check_go_live_idempotent` learns on a live estimator."""


def _same_estimate(a, b) -> bool:
    """Two :class:`iem.types.PayloadEstimate` alike field for field (arrays bit for bit)."""
    if (a.std is None) != (b.std is None):
        return False
    return (identical(a.phi, b.phi) and (a.std is None or identical(a.std, b.std))
            and a.t == b.t and a.bag == b.bag and a.learning == b.learning
            and same_params(a.nis, b.nis) and a.ood == b.ood
            and a.unverified == b.unverified and a.determined == b.determined
            and same_params(a.extra, b.extra))


def _same_predictions(a, b, data: CheckData) -> bool:
    return (identical(predictions(a, data), predictions(b, data))
            and identical(predictions_one(a, data), predictions_one(b, data)))


def check_capabilities_declared(make, data: CheckData) -> None:
    """It is an :class:`iem.base.Estimator`; its flags are bools; ``busy`` is False off a
    live link; ``learning_cpu_s`` is a finite time >= 0."""
    name = "capabilities declared"
    est = make()
    if not isinstance(est, Estimator):
        declared = {*Estimator.__annotations__, *(m for m in vars(Estimator)
                                                  if not m.startswith("_"))}
        missing = sorted(declared - set(dir(est)))
        raise fail(name, f"{type(est).__name__} lacks {', '.join(missing)}: inherit "
                          "iem.base.BaseEstimator for the defaults")
    train(est, data)
    flags = {"detects_changes": est.detects_changes, "tracks_payload": est.tracks_payload,
             "background_learning": est.background_learning}
    for flag, value in flags.items():
        if not isinstance(value, bool):
            raise fail(name, f"{flag} is {value!r}, expected a bool")
    if est.busy is not False:
        raise fail(name, f"busy is {est.busy!r} off a live link, expected False")
    cpu = est.learning_cpu_s
    if not (isinstance(cpu, float) and math.isfinite(cpu) and cpu >= 0.0):
        raise fail(name, f"learning_cpu_s is {cpu!r}, expected a finite float >= 0")


def _twins(make, data: CheckData, n: int) -> list:
    """``n`` estimators trained alike (fresh from ``make()``, not copies: a copy of an
    estimator that learns in a worker holds only its published state)."""
    twins = [train(make(), data) for _ in range(n)]
    for est in twins:
        est.drain()
    return twins


def check_resume_and_gap_keep_the_estimate(make, data: CheckData) -> None:
    """``resume()`` and ``gap(k)`` change no estimate: a silence or lost cycles are not a
    new payload."""
    name = "resume and gap keep the estimate"
    est, twin = _twins(make, data, 2)
    for label, call in (("resume()", est.resume), ("gap(3)", lambda: est.gap(3))):
        call()
        if not _same_predictions(est, twin, data):
            raise fail(name, f"{label} changed the estimates")


def check_learn_predict_one(make, data: CheckData) -> None:
    """``learn_predict_one`` gives the estimate ``learn_one`` then ``predict_one`` give on
    a twin, point after point, and leaves the model as they do."""
    name = "learn_predict_one"
    est, twin = _twins(make, data, 2)
    for i in data.further_points():
        t = i * 1e-3
        x, f, s = data.X[i].copy(), data.F[i].copy(), samples(data, i)
        a = est.learn_predict_one(x, f, s, t=t)
        twin.learn_one(x, f, s)
        b = twin.predict_one(x, f, t=t)
        if not _same_estimate(a, b):
            raise fail(name, f"at point {i} learn_predict_one gave {a}, learn_one then "
                              f"predict_one {b}")
    if est.n_bags != twin.n_bags or not _same_predictions(est, twin, data):
        raise fail(name, "the model after learn_predict_one differs from the one after "
                          "learn_one and predict_one")


def check_observe_one_trains_nothing(make, data: CheckData) -> None:
    """``observe_one`` may follow the payload, never train: once ``reset()`` forgets the
    payload, the model predicts as a twin that observed nothing."""
    name = "observe_one trains nothing"
    est, twin = _twins(make, data, 2)
    for i in data.further_points():
        est.observe_one(data.X[i].copy(), data.F[i].copy())
    est.drain()
    est.reset()
    twin.reset()
    if est.n_bags != twin.n_bags:
        raise fail(name, f"observe_one changed the bags: {twin.n_bags} -> {est.n_bags}")
    if not _same_predictions(est, twin, data):
        raise fail(name, "after reset() the model that observed predicts differently from "
                          "one that did not: observe_one trained it")


def check_go_live_idempotent(make, data: CheckData) -> None:
    """``go_live()`` twice is ``go_live()`` once (hyper-parameters, estimates, and what live
    learning lands, drained point by point); ``go_live(False)`` then gives the
    hyper-parameters ``go_live(False)`` gives a twin that never went live."""
    name = "go_live idempotent"
    offline, once, twice = _twins(make, data, 3)
    try:
        offline.go_live(False)
        once.go_live()
        twice.go_live()
        twice.go_live()
        if not same_params(once.params(), twice.params()):
            raise fail(name, f"params() after go_live() once {once.params()}, twice "
                              f"{twice.params()}")
        if not _same_predictions(once, twice, data):
            raise fail(name, "estimates after go_live() twice differ from once")
        for i in data.further_points()[:LIVE_POINTS]:
            for est in (once, twice):
                learn(est, data, i)
                est.drain()
        if not _same_predictions(once, twice, data):
            raise fail(name, "live learning landed differently after go_live() twice")
        for est in (once, twice):
            est.go_live(False)
            if not same_params(est.params(), offline.params()):
                raise fail(name, f"params() after go_live() and go_live(False) {est.params()}, "
                                  f"after go_live(False) alone {offline.params()}")
    finally:
        for est in (offline, once, twice):
            est.stop()


def check_close_drain_stop_twice(make, data: CheckData) -> None:
    """``close()``, ``drain()`` and ``stop()`` twice are fine: the second changes nothing,
    and the model learns on afterwards."""
    name = "close, drain and stop twice"
    est, twin = _twins(make, data, 2)
    further = data.further_points()
    for model in (est, twin):
        for i in further[:-1]:
            learn(model, data, i)
        model.close()
        model.drain()
    for call in (est.close, est.drain, est.stop) * 2:
        call()
    if not _same_predictions(est, twin, data):
        raise fail(name, "close(), drain() or stop() after close() changed the estimates")
    for model in (est, twin):
        learn(model, data, further[-1])
        model.stop()
    if not _same_predictions(est, twin, data):
        raise fail(name, "learning after close(), drain() and stop() twice differs from "
                          "learning after close() once")


CAPABILITY_CHECKS: tuple[Callable[..., None], ...] = (
    check_capabilities_declared,
    check_resume_and_gap_keep_the_estimate,
    check_learn_predict_one,
    check_observe_one_trains_nothing,
    check_go_live_idempotent,
    check_close_drain_stop_twice,
)
"""The capability checks, in the order :func:`iem.checks.check_estimator` runs them."""
