"""The ensemble over long runs: learning off the cycle, the out-of-distribution flag, the bag
budget and the router's slot operations (synthetic data of :mod:`tests.iem.test_checks`)."""

from __future__ import annotations

import copy
import threading

import numpy as np
import pytest

from iem import checks
from iem.ensemble import IncrementalEnsemble
from iem.ensemble.ood_hold import OOD_THRESHOLD, VELOCITY_THRESHOLD
from iem.ensemble.router import BagRouter
from iem.ensemble.worker import LearningError, LearningWorker
from iem.errors import InvalidInputError
from iem.persistence import dumps, loads
from tests.iem.router_views import q_means

from .test_checks import DATA

PARAMS = {"seed": 3, "fit_epochs": 2, "warmup_iters": 10, "iters": 2}


def fitted(**kw) -> IncrementalEnsemble:
    model = IncrementalEnsemble(**PARAMS, **kw)
    idx = list(DATA.fit_points)
    model.fit(DATA.X[idx, :7], DATA.F[idx], lambda i: DATA.samples_at(idx[i]))
    return model


def learn(model, points) -> None:
    for i in points:
        model.learn_one(DATA.X[i], DATA.F[i], lambda i=i: DATA.samples_at(i))


def weights(model) -> list[tuple[np.ndarray, ...]]:
    return [(lr.a.copy(), lr.b.copy(), lr.center.copy(), lr.scale.copy())
            for lr in (model.learner(b) for b in range(model.n_bags))]


def same(a, b) -> bool:
    return all(all(np.array_equal(x, y) for x, y in zip(p, q, strict=True))
               for p, q in zip(a, b, strict=True))


class Gate:
    """A job that holds the worker until released (so no training can land meanwhile)."""

    def __init__(self) -> None:
        self.release = threading.Event()
        self.started = threading.Event()

    def __call__(self) -> None:
        self.started.set()
        assert self.release.wait(30)


# -- learning off the cycle ----------------------------------------------------------------
def test_background_learns_exactly_what_synchronous_learns():
    sync, back = fitted(), fitted(background=True)
    points = DATA.train_points() + DATA.further_points()
    learn(sync, points)
    learn(back, points)
    sync.close()
    back.close()
    back.drain()
    assert back.n_bags == sync.n_bags > 2
    assert same(weights(back), weights(sync))
    back.stop()


def test_the_samples_of_a_point_joining_the_open_bag_are_made_in_the_worker():
    """Making a point's tandem samples is learning: in the background, only a new bag's (its
    learner's centre needs them) are made in the caller's thread."""
    model = fitted(background=True)
    made_in: list[tuple[int, str]] = []

    def lazy(i):
        def samples():
            made_in.append((i, threading.current_thread().name))
            return DATA.samples_at(i)
        return samples

    bags_before = model.n_bags
    for i in DATA.train_points():
        model.learn_one(DATA.X[i], DATA.F[i], lazy(i))
    model.drain()
    assert model.n_bags > bags_before
    threads = {name for _, name in made_in}
    assert threads == {threading.current_thread().name, "iem-learning"}
    assert sum(name == threading.current_thread().name for _, name in made_in) == (
        model.n_bags - bags_before)  # one per new bag
    model.stop()


def test_each_learnt_point_reports_its_learners_errors_once_in_order():
    sync, back = fitted(), fitted(background=True)
    for m in (sync, back):
        m.report_errors = True
    reports = {}
    for name, m in (("sync", sync), ("back", back)):
        got = []
        for i in DATA.train_points():
            m.learn_one(DATA.X[i], DATA.F[i], lambda i=i: DATA.samples_at(i))
            if name == "sync":  # inline: a learnt point's errors are there at once
                errs = m.trained_errors()
                assert len(errs) == (m.open_bag >= 0)  # it started or joined the open bag
                for bag, gen, err, _ in errs:
                    X, Y0 = DATA.samples_at(i)
                    assert bag == m.open_bag and gen == m.slot_generation(bag)
                    np.testing.assert_array_equal(err, m.learner(bag).predict_many(X) - Y0)
                got += errs
            else:
                m.drain()
                got += m.trained_errors()
        reports[name] = got
    assert len(reports["sync"]) == len(reports["back"]) > 3
    for a, b in zip(reports["sync"], reports["back"], strict=True):
        assert a[:2] == b[:2]
        np.testing.assert_array_equal(a[2], b[2])
    assert back.trained_errors() == [] and not fitted().trained_errors()  # off by default
    back.stop()


def test_new_bag_estimates_with_its_copied_learner_until_its_training_lands():
    model = fitted(background=True)
    before = model.n_bags
    gate = Gate()
    model._schedule.submit(gate)
    assert gate.started.wait(30)
    i = next(j for j in DATA.further_points()
             if model.router.route(DATA.X[j, :7], DATA.F[j])[0] < 0)
    nearest = model.router.route(DATA.X[i, :7], DATA.F[i])[1]
    source = model.learner(nearest)
    model.learn_one(DATA.X[i], DATA.F[i], lambda: DATA.samples_at(i))
    bag = model.n_bags - 1
    assert bag == before and model.open_bag == bag and model.pending >= 1
    copied = model.learner(bag)
    assert np.array_equal(copied.a, source.a) and np.array_equal(copied.b, source.b)
    est = model.predict_one(DATA.X[i], DATA.F[i])
    assert est.bag == bag and est.learning
    assert np.array_equal(est.phi, copied.predict_one(DATA.X[i]))
    gate.release.set()
    model.drain()
    trained = model.learner(bag)
    assert trained is not copied and not np.array_equal(trained.a, copied.a)
    # the copy it estimated with was swapped out, never trained in place
    assert np.array_equal(copied.a, source.a)
    model.stop()


def test_published_learners_never_change_and_closed_bags_are_never_retrained():
    model = fitted(background=True)
    learn(model, DATA.train_points())
    model.close()
    model.drain()
    closed = weights(model)
    held = [model.learner(b) for b in range(model.n_bags)]
    learn(model, DATA.further_points())
    model.close()
    model.drain()
    assert same(weights(model)[: len(closed)], closed)
    assert same([(lr.a, lr.b, lr.center, lr.scale) for lr in held], closed)
    model.stop()


def test_saving_and_copying_finish_pending_work():
    model = fitted(background=True)
    gate = Gate()
    model._schedule.submit(gate)
    learn(model, DATA.further_points()[:40])
    assert model.pending > 0
    threading.Timer(0.05, gate.release.set).start()
    state = model.to_state()  # waits for the gate, then for the training behind it
    assert model.pending == 0
    sync = fitted()
    learn(sync, DATA.further_points()[:40])
    loaded = loads(dumps(model))
    assert same(weights(loaded), weights(sync))
    assert state["open"] == sync.open_bag
    model.stop()


def test_a_copy_of_a_background_ensemble_does_not_wait_and_holds_the_published_state():
    model = fitted(background=True)
    learn(model, DATA.further_points()[:20])
    model.close()
    model.drain()
    closed = model.n_bags  # every bag so far is closed and trained
    gate = Gate()
    model._schedule.submit(gate)
    assert gate.started.wait(30)
    learn(model, DATA.further_points()[20:60])
    assert model.pending > 0
    published = weights(model)
    twin = copy.deepcopy(model)  # the gate still holds the worker: a wait would hang here
    assert same(weights(twin), published) and twin.open_bag == -1 and twin.pending == 0
    gate.release.set()
    model.drain()
    learn(twin, DATA.further_points()[60:])
    twin.drain()
    assert same(weights(model)[:closed], published[:closed])  # closed bags: untouched
    model.stop()
    twin.stop()


def test_a_failed_job_is_reported_not_lost():
    worker = LearningWorker()

    def boom():
        raise ValueError("bad batch")

    worker.submit(boom)
    with pytest.raises(LearningError, match="bad batch"):
        worker.drain()
    ran = []
    worker.submit(lambda: ran.append(1))
    worker.close()
    assert ran == [1]


@pytest.mark.parametrize("synchronous", [False, True])
def test_the_worker_counts_the_cpu_time_of_its_jobs(synchronous):
    """What learning costs beside the cycle is counted: a job that computes for 30 ms of
    CPU adds about that to ``cpu_s`` (threaded or inline); an idle worker adds nothing."""
    import time

    worker = LearningWorker(synchronous=synchronous)
    assert worker.cpu_s == 0.0

    def burn():
        end = time.thread_time() + 0.03
        while time.thread_time() < end:
            pass

    worker.submit(burn)
    worker.drain()
    assert 0.03 <= worker.cpu_s < 0.5
    before = worker.cpu_s
    time.sleep(0.05)
    assert worker.cpu_s == before
    worker.close()


# -- out of distribution -------------------------------------------------------------------
def test_training_inputs_are_in_distribution_and_reversed_velocities_are_not():
    model = fitted()  # its bags' learners were trained on the fit points' samples
    inside, reversed_ = [], []
    for i in DATA.fit_points:
        bag = model.router.route(DATA.X[i, :7], DATA.F[i])[0]
        X, _ = DATA.samples_at(i)
        inside += [model.ood_score(x, bag) for x in X]
        x = DATA.X[i].copy()
        x[7:14] *= -3.0  # the same pose driven the other way, faster
        est = model.predict_one(x, DATA.F[i])
        assert est.extra["ood_score"] == pytest.approx(model.ood_score(x, est.bag))
        reversed_.append(est.ood)
    assert np.max(inside) < OOD_THRESHOLD
    assert np.mean(reversed_) > 0.9
    est = model.predict_one(DATA.X[50], DATA.F[50])
    assert est.ood is False


def test_the_velocity_score_is_a_mahalanobis_distance_to_the_training_velocities():
    """Against an independent computation (the covariance of the bag's training velocities
    plus the noise's variance, inverted by solve): training inputs score about 1; a visit of
    the same pose with the velocities in another combination, each within its range, scores
    above the threshold and is flagged."""
    model = fitted()
    i = DATA.fit_points[len(DATA.fit_points) // 2]
    bag = model.router.route(DATA.X[i, :7], DATA.F[i])[0]
    learner = model.learner(bag)
    assert learner.dq_precision is not None
    train = [DATA.samples_at(j)[0] for j in DATA.fit_points
             if model.router.route(DATA.X[j, :7], DATA.F[j])[0] == bag][:: model.fit_stride]
    V = np.vstack(train)[:, 7:14]
    sig = np.maximum(model.input_noise[7:14], 1e-3)
    cov = np.cov(V.T, bias=True) + np.diag(sig ** 2)
    x = DATA.X[i].copy()
    d = x[7:14] - V.mean(axis=0)
    assert learner.velocity_score(x) == pytest.approx(np.sqrt(d @ np.linalg.solve(cov, d) / 7),
                                                      rel=1e-6)
    # over the training inputs the mean square is tr((S + N)^-1 S) / 7 <= 1 (N the noise)
    assert np.mean([learner.velocity_score(v) ** 2 for v in np.vstack(train)]) <= 1.0 + 1e-9
    # each velocity within its training range, the combination never seen: one joint's
    # velocity swapped for another's
    other = x.copy()
    lo, hi = V.min(axis=0), V.max(axis=0)
    other[7:14] = np.where(np.arange(7) % 2 == 0, lo, hi)
    est = model.predict_one(other, DATA.F[i])
    assert est.bag == bag and not est.learning
    assert est.extra["velocity_score"] == pytest.approx(learner.velocity_score(other))
    assert est.extra["ood_score"] <= OOD_THRESHOLD  # every input within its scale, yet
    assert est.extra["velocity_score"] > VELOCITY_THRESHOLD and est.ood
    assert model.predict_one(DATA.X[i], DATA.F[i]).ood is False
    # off: no score, and the same input is flagged only by the per-input score
    plain = fitted(velocity_threshold=None)
    est = plain.predict_one(other, DATA.F[i])
    assert "velocity_score" not in est.extra
    assert est.ood == (est.extra["ood_score"] > OOD_THRESHOLD)
    assert plain.clone().velocity_threshold is None
    assert loads(dumps(fitted(velocity_threshold=2.5))).velocity_threshold == 2.5
    with pytest.raises(InvalidInputError, match="velocity_threshold"):
        IncrementalEnsemble(velocity_threshold=0.0)
    # IEM+phys does not use the flag (its physics governs through the per-input score)
    from iem.physics import PhysicsInformedEnsemble
    from sim.arm import NOMINAL_DYNAMICS

    assert PhysicsInformedEnsemble(
        dynamics=NOMINAL_DYNAMICS).ensemble_model.velocity_threshold is None
    assert PhysicsInformedEnsemble(ensemble={"velocity_threshold": 3.0},
                                   dynamics=NOMINAL_DYNAMICS).ensemble_model.params()[
        "velocity_threshold"] == 3.0


def test_learners_keep_their_velocities_through_copies_and_files_not_for_another_bag():
    model = fitted()
    learner = model.learner(0)
    again = type(learner).from_state(learner.to_state())
    np.testing.assert_array_equal(again.dq_precision, learner.dq_precision)
    assert learner.copy().dq_precision is learner.dq_precision
    assert learner.copy_for(learner.center + 0.1).dq_precision is None
    old = learner.to_state()
    old.pop("dq_precision")  # a file made before the score: no score, no flag from it
    assert type(learner).from_state(old).velocity_score(DATA.X[0] * 5) == 0.0


def test_ood_threshold_is_a_hyper_parameter_and_the_open_bag_is_never_flagged():
    model = fitted(ood_threshold=1e-9)
    assert model.predict_one(DATA.X[0], DATA.F[0]).ood
    i = next(j for j in DATA.further_points()
             if model.router.route(DATA.X[j, :7], DATA.F[j])[0] < 0)
    model.learn_one(DATA.X[i], DATA.F[i], lambda: DATA.samples_at(i))
    est = model.predict_one(DATA.X[i] + 1.0, DATA.F[i])
    assert est.learning and est.extra["ood_score"] > 1e-9 and est.ood is False
    with pytest.raises(InvalidInputError, match="ood_threshold"):
        IncrementalEnsemble(ood_threshold=0.0)


def test_an_estimate_out_of_distribution_holds_the_last_one_in_it_for_ood_hold_s():
    model = fitted(ood_hold_s=0.5)
    raw_model = copy.deepcopy(model)
    i = 50
    x, f = DATA.X[i], DATA.F[i]
    far = x.copy()
    far[7:14] *= -3.0  # the pose driven the other way, faster: flagged
    good = model.predict_one(x, f, t=0.0)
    assert not good.ood and "held" not in good.extra
    # flagged: the last estimate in distribution, flagged, for 0.5 s of estimate time
    for t in (0.001, 0.2, 0.45):
        est = model.predict_one(far, f, t=t)
        raw = raw_model.predict_raw(far, f, t=t)
        assert est.ood and est.extra["held"] and est.bag == raw.bag
        assert est.extra["ood_score"] == raw.extra["ood_score"]
        assert np.array_equal(est.phi, good.phi) and not np.array_equal(raw.phi, good.phi)
    late = model.predict_one(far, f, t=0.55)  # the run of flags outlasted the hold
    assert late.ood and "held" not in late.extra
    assert np.array_equal(late.phi, raw_model.predict_raw(far, f).phi)
    # back in distribution: its own estimate, and a new run of flags is held again
    assert np.array_equal(model.predict_one(x, f, t=0.6).phi, good.phi)
    assert model.predict_one(far, f, t=0.7).extra["held"]
    # learn_predict_one holds as predict_one does; the raw twins never hold
    j = next(j for j in DATA.further_points()
             if model.router.route(DATA.X[j, :7], DATA.F[j])[0] < 0)
    est = model.learn_predict_one(DATA.X[j], DATA.F[j], lambda: DATA.samples_at(j), t=0.8)
    assert est.learning and not est.ood  # the open bag's: trusted now
    assert np.array_equal(model.predict_one(far, f, t=0.9).phi, est.phi)
    assert not model.predict_raw(far, f, t=0.9).extra.get("held")
    # a new task forgets what was held; nothing to hold: the learner's own, flagged
    model.reset()
    est = model.predict_one(far, f, t=1.0)
    assert est.ood and "held" not in est.extra


def test_no_hold_with_ood_hold_s_zero_or_before_any_estimate_in_distribution():
    model = fitted(ood_hold_s=0.0)
    x, f = DATA.X[50], DATA.F[50]
    far = x.copy()
    far[7:14] *= -3.0
    model.predict_one(x, f, t=0.0)
    assert np.array_equal(model.predict_one(far, f, t=0.1).phi,
                          model.predict_raw(far, f, t=0.1).phi)
    fresh = fitted()
    est = fresh.predict_one(far, f, t=0.0)
    assert est.ood and "held" not in est.extra
    assert IncrementalEnsemble(ood_hold_s=2.0).clone().ood_hold_s == 2.0
    assert loads(dumps(fitted(ood_hold_s=0.25))).ood_hold_s == 0.25
    with pytest.raises(InvalidInputError, match="ood_hold_s"):
        IncrementalEnsemble(ood_hold_s=-1.0)


# -- the bag budget ------------------------------------------------------------------------
def test_budget_bounds_the_bags_and_retires_the_least_used_without_probation():
    small = {"delta": 0.15, "rho": 0.08}  # many small bags
    free = fitted(**small)
    learn(free, DATA.train_points() + DATA.further_points())
    budget = free.n_bags - 5
    model = fitted(budget_bags=budget, probation_bags=0, **small)
    retired_counts = []
    orig = model.budget.victim

    def spy(counts, open_bag):
        victim = orig(counts, open_bag)
        counts = model.router.counts.astype(float)
        counts[model.open_bag] = np.inf
        assert counts[victim] == counts.min()
        retired_counts.append(int(model.router.counts[victim]))
        return victim

    model.budget.victim = spy
    for i in DATA.train_points() + DATA.further_points():
        model.learn_one(DATA.X[i], DATA.F[i], lambda i=i: DATA.samples_at(i))
        assert model.n_bags <= budget
    assert model.retired == len(retired_counts) >= 3
    assert sum(model.slot_generation(b) for b in range(model.n_bags)) == model.retired
    loaded = loads(dumps(model))
    assert loaded.retired == model.retired and loaded.params()["budget_bags"] == budget
    assert loaded.budget.probation == 0
    np.testing.assert_array_equal(loaded.predict_many(DATA.X, DATA.F),
                                  model.predict_many(DATA.X, DATA.F))
    with pytest.raises(InvalidInputError, match="budget_bags"):
        IncrementalEnsemble(budget_bags=1)


def test_old_model_state_without_the_new_fields_loads():
    model = fitted()
    state = model.to_state()
    for key in ("gen", "retired"):
        state.pop(key)
    for key in ("background", "budget_bags", "ood_threshold"):
        state["params"].pop(key)
    old = IncrementalEnsemble.from_state(state)
    assert old.n_bags == model.n_bags and old.budget_bags is None and not old.background
    np.testing.assert_array_equal(old.predict_many(DATA.X, DATA.F),
                                  model.predict_many(DATA.X, DATA.F))


# -- router slot operations ----------------------------------------------------------------
@pytest.mark.parametrize("n", [10, 300])
def test_router_after_replacements_routes_as_a_fresh_router_of_its_means(n):
    rng = np.random.default_rng(n)
    Q = rng.uniform(-2.5, 2.5, (n, 7))
    F = rng.uniform(-0.8, 0.8, (n, 3))
    router = BagRouter.from_means(Q, F)
    for _ in range(n // 2):
        i = int(rng.integers(n))
        q, f = rng.uniform(-2.5, 2.5, 7), rng.uniform(-0.8, 0.8, 3)
        router.replace(i, q, f)
        router.join(i, q + 0.01, f)
    fresh = BagRouter.from_means(q_means(router), router.flange_means)
    probes_q = np.vstack((q_means(router) + rng.normal(0, 0.1, (n, 7)),
                          rng.uniform(-2.5, 2.5, (200, 7))))
    probes_f = np.vstack((router.flange_means + rng.normal(0, 0.05, (n, 3)),
                          rng.uniform(-0.8, 0.8, (200, 3))))
    for q, f in zip(probes_q, probes_f, strict=True):
        assert router.route(q, f) == fresh.route(q, f)
    np.testing.assert_array_equal(router.route_many(probes_q, probes_f),
                                  fresh.route_many(probes_q, probes_f))
    with pytest.raises(InvalidInputError, match="does not exist"):
        router.replace(n, Q[0], F[0])


class Drained(IncrementalEnsemble):
    """A background ensemble that waits for its training after every point (so the shared
    checks, which compare predictions point by point, see a deterministic model)."""

    def learn_one(self, x, flange, samples) -> None:
        super().learn_one(x, flange, samples)
        self.drain()

    def learn_predict_one(self, x, flange, samples, t: float = 0.0):
        self.learn_one(x, flange, samples)  # the estimate after the training landed
        return self.predict_one(x, flange, t)


@pytest.mark.parametrize("check", [c for c in checks.CHECKS if c is not checks.check_save_load],
                         ids=lambda c: c.__name__)
def test_background_ensemble_passes_the_shared_checks(check):
    check(lambda: Drained(seed=0, fit_epochs=2, warmup_iters=10, iters=2, background=True),
          DATA)


def test_a_dropped_background_ensemble_ends_its_thread():
    import gc

    model = fitted(background=True)
    learn(model, DATA.further_points()[:5])
    model.drain()
    thread = model._schedule.worker._thread
    assert thread.is_alive()
    del model
    gc.collect()
    thread.join(10)
    assert not thread.is_alive()


def test_a_worker_far_behind_skips_open_bag_points_and_counts_them(monkeypatch):
    import iem.ensemble.scheduler as scheduler

    monkeypatch.setattr(scheduler, "MAX_PENDING", 5)
    model = fitted(background=True)
    gate = Gate()
    model._schedule.submit(gate)
    assert gate.started.wait(30)
    learn(model, DATA.further_points())
    assert model.skipped_points > 0
    assert model.pending <= 5 + 1 + model.n_bags  # new bags and closes always go
    gate.release.set()
    model.drain()
    model.stop()


# -- the fit's memory ----------------------------------------------------------------------
def test_fit_stacks_a_bags_samples_as_vstack_does_and_refuses_uneven_points():
    from iem.ensemble.training import _stacked

    idx = np.array(DATA.fit_points[:5])
    X, Y = _stacked(DATA.samples_at, idx)
    pairs = [DATA.samples_at(int(i)) for i in idx]
    np.testing.assert_array_equal(X, np.vstack([p[0] for p in pairs]))
    np.testing.assert_array_equal(Y, np.vstack([p[1] for p in pairs]))

    def uneven(i):
        Xi, Yi = DATA.samples_at(i)
        return (Xi[:-1], Yi[:-1]) if i == idx[2] else (Xi, Yi)

    with pytest.raises(InvalidInputError, match="every point must give as many"):
        _stacked(uneven, idx)
