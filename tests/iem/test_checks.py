"""Every estimator passes the shared check suite of :mod:`iem.checks`.

The data are synthetic (no sim, no Pinocchio): a smooth 7-joint path whose joints travel well
over 60° in all (so the default 30° / 0.2 m thresholds form several bags), a flange position
that is a fixed linear map of q, and at every point 77 samples ``[q, dq, A(q) phi_k]`` with a
smooth regressor ``A(q)`` and 77 payload-like parameter vectors ``phi_k``.
"""

from __future__ import annotations

import numpy as np
import pytest

from iem import capability_checks, checks
from iem.baselines.bem import BatchEnsemble
from iem.baselines.least_squares import RecursiveLeastSquares
from iem.baselines.old_iem import InPlaceEnsemble
from iem.checks import CheckData, CheckFailed, check_estimator
from iem.ensemble import IncrementalEnsemble
from iem.errors import IemError, InvalidInputError
from iem.model_kinds import MODELS
from iem.physics import PhysicsInformedEnsemble
from iem.types import PayloadEstimate
from sim.arm import NOMINAL_DYNAMICS

# One line per estimator kind of iem.model_kinds.MODELS; each lambda returns a fresh, seeded
# estimator.
ESTIMATORS = {
    "IEM": lambda: IncrementalEnsemble(seed=0, fit_epochs=2, warmup_iters=10, iters=2),
    "old_IEM": lambda: InPlaceEnsemble(seed=0, fit_epochs=2, warmup_iters=10, iters=2),
    "BEM": lambda: BatchEnsemble(seed=0, n_networks=2, n_trees=2, fit_epochs=2, max_depth=4),
    "LS": lambda: RecursiveLeastSquares(NOMINAL_DYNAMICS),
    "IEM+phys": lambda: PhysicsInformedEnsemble(
        ensemble={"seed": 0, "fit_epochs": 2, "warmup_iters": 10, "iters": 2},
        dynamics=NOMINAL_DYNAMICS),
}

N_POINTS = 300
N_PAYLOADS = 77
DT = 0.01


def synthetic_family(rng: np.random.Generator, k: int = N_PAYLOADS) -> np.ndarray:
    """``(k, 10)`` payload-like phi: mass 0.79-2.2 kg, small CoM moments, positive inertia."""
    m = rng.uniform(0.79, 2.2, k)
    r = rng.uniform(-0.03, 0.03, (k, 3)) + np.array([0.0, 0.0, 0.05])
    inertia = rng.uniform(0.001, 0.01, (k, 6)) * np.array([1.0, 0.1, 0.1, 1.0, 0.1, 1.0])
    return np.column_stack((m, m[:, None] * r, inertia))


def synthetic_data(n: int = N_POINTS, seed: int = 7) -> CheckData:
    rng = np.random.default_rng(seed)
    s = np.linspace(0.0, 1.0, n)[:, None]
    q0 = rng.uniform(-0.5, 0.5, 7)
    travel = rng.uniform(-1.0, 1.0, 7)
    travel *= 2.0 / np.linalg.norm(travel)  # 2 rad (115°) in joint space
    wiggle = 0.1 * np.sin(2 * np.pi * (rng.uniform(0.5, 1.5, 7) * s + rng.uniform(0, 1, 7)))
    Q = q0 + s * travel + wiggle
    dQ = np.gradient(Q, DT, axis=0)
    M = rng.normal(0.0, 0.15, (7, 3))
    F = Q @ M + np.array([0.3, 0.0, 0.5])
    c0 = rng.normal(0.0, 2.0, (7, 10))
    c1 = rng.normal(0.0, 1.0, (7, 7, 10))
    c2 = rng.normal(0.0, 1.0, (7, 7, 10))
    phi = synthetic_family(rng)
    A = c0 + np.einsum("nj,jrc->nrc", np.sin(Q), c1) + np.einsum("nj,jrc->nrc", np.cos(Q), c2)
    tau = np.einsum("nrc,kc->nkr", A, phi)  # (n, K, 7)
    K = phi.shape[0]
    Xs_all = np.concatenate((np.repeat(Q[:, None], K, 1), np.repeat(dQ[:, None], K, 1), tau),
                            axis=2)
    tau_meas = tau[:, 0]  # the "real" payload is the first of the family
    X = np.column_stack((Q, dQ, tau_meas))

    def samples_at(i: int):
        return Xs_all[i].copy(), phi.copy()

    return CheckData(X=X, F=F, samples_at=samples_at, fit_points=list(range(100)))


DATA = synthetic_data()


def test_synthetic_path_forms_several_bags():
    Q = DATA.X[:, :7]
    spread = np.linalg.norm(Q.max(0) - Q.min(0))
    assert np.degrees(spread) > 60
    est = ESTIMATORS["IEM"]()
    checks.train(est, DATA)
    n_train = est.n_bags
    for i in DATA.further_points():
        checks.learn(est, DATA, i)
    assert n_train >= 2
    assert est.n_bags > n_train  # the further points reach new ground


def test_every_kind_is_checked():
    """Every kind a model file may hold has a factory here, making an estimator of its class."""
    assert sorted(ESTIMATORS) == sorted(MODELS)
    for kind, make in ESTIMATORS.items():
        est = make()
        assert est.name == kind
        assert f"{type(est).__module__}:{type(est).__name__}" == MODELS[kind]


@pytest.mark.parametrize("check", checks.CHECKS, ids=lambda c: c.__name__)
@pytest.mark.parametrize("name", sorted(MODELS))
def test_check(name, check):
    check(ESTIMATORS[name], DATA)


def test_check_estimator_runs_every_check_in_order_and_stops_at_the_first_failure(
        monkeypatch):
    """Every ``check_*`` of the two modules is in CHECKS, once; check_estimator runs them in
    that order on the factory and data it is given (test_check ran each above), and the first
    failure ends it."""
    import inspect

    defined = {f for module in (checks, capability_checks)
               for name, f in inspect.getmembers(module, inspect.isfunction)
               if name.startswith("check_") and f is not check_estimator
               and f.__module__ == module.__name__}
    assert len(checks.CHECKS) == len(set(checks.CHECKS)) and set(checks.CHECKS) == defined
    ran = []

    def check(k: int, fails: bool = False):
        def run(make, data):
            ran.append((k, make, data))
            if fails:
                raise CheckFailed(f"check {k}")
        return run

    make = ESTIMATORS["LS"]
    monkeypatch.setattr(checks, "CHECKS", (check(0), check(1), check(2)))
    check_estimator(make, DATA)
    assert ran == [(0, make, DATA), (1, make, DATA), (2, make, DATA)]
    ran.clear()
    monkeypatch.setattr(checks, "CHECKS", (check(0), check(1, fails=True), check(2)))
    with pytest.raises(CheckFailed, match="check 1"):
        check_estimator(make, DATA)
    assert [k for k, *_ in ran] == [0, 1]


# -- the checks catch what they are meant to catch -------------------------------------
class _Broken(IncrementalEnsemble):
    """An IEM with one fault switched on, to show each check fails for it."""

    fault = ""

    def learn_one(self, x, flange, samples):
        if self.fault == "mutate":
            x[0] += 1.0
        if self.fault == "grow":
            self._junk = [*getattr(self, "_junk", []), np.zeros(1)]
        super().learn_one(x, flange, samples)

    def nbytes(self):
        extra = sum(a.nbytes for a in getattr(self, "_junk", []))
        return super().nbytes() + extra + (10**7 if self.fault == "huge" else 0)

    def _nudge(self):
        """Move bag 0's learner: every estimate of that bag changes."""
        learner = self._learners[0]
        learner.b = learner.b + 0.1

    def resume(self):
        if self.fault == "resume":
            self._nudge()

    def observe_one(self, x, flange):
        if self.fault == "observe":
            self._nudge()

    def learn_predict_one(self, x, flange, samples, t=0.0):
        if self.fault != "combined":
            return super().learn_predict_one(x, flange, samples, t)
        est = self.predict_one(x, flange, t)  # the estimate before learning the point
        self.learn_one(x, flange, samples)
        return est

    def _go_live(self, on):
        if self.fault == "go_live":
            self.lr += 1.0  # each call moves it again

    def close(self):
        super().close()
        if self.fault == "close":
            self._nudge()


def _broken(fault: str, **kw):
    def make():
        est = _Broken(seed=0, fit_epochs=2, warmup_iters=10, iters=2, **kw)
        est.fault = fault
        return est
    return make


def test_mutating_estimator_fails_its_check():
    with pytest.raises(CheckFailed, match="inputs not mutated"):
        checks.check_inputs_not_mutated(_broken("mutate"), DATA)


def test_unbounded_memory_fails_its_check():
    with pytest.raises(CheckFailed, match="grew nbytes"):
        checks.check_memory_bounded(_broken("grow"), DATA)
    with pytest.raises(CheckFailed, match="exceeds"):
        checks.check_memory_bounded(_broken("huge"), DATA)


@pytest.mark.parametrize(("fault", "check", "match"), [
    ("resume", capability_checks.check_resume_and_gap_keep_the_estimate, "resume.. changed"),
    ("combined", capability_checks.check_learn_predict_one, "learn_predict_one gave"),
    ("observe", capability_checks.check_observe_one_trains_nothing, "observe_one trained it"),
    ("go_live", capability_checks.check_go_live_idempotent, "twice"),
    ("close", capability_checks.check_close_drain_stop_twice, "changed the estimates"),
])
def test_broken_capability_fails_its_check(fault, check, match):
    with pytest.raises(CheckFailed, match=match):
        check(_broken(fault), DATA)


class _Undeclared:
    """The seam alone, none of the declared capabilities: a caller would have to probe."""

    name = "undeclared"
    n_bags = 0

    def learn_one(self, x, flange, samples):
        pass

    def predict_one(self, x, flange, t=0.0):
        return PayloadEstimate(t=t, phi=np.zeros(10))

    def predict_many(self, X, F):
        return np.zeros((len(X), 10))

    def to_state(self):
        return {}

    def nbytes(self):
        return 0


def test_undeclared_capabilities_fail_their_check():
    with pytest.raises(CheckFailed, match=r"lacks .*go_live.*BaseEstimator"):
        capability_checks.check_capabilities_declared(_Undeclared, DATA)


def test_unseeded_estimator_fails_determinism():
    seeds = iter(range(100))

    def make():
        return IncrementalEnsemble(seed=next(seeds), fit_epochs=2, warmup_iters=10, iters=2)
    with pytest.raises(CheckFailed, match="seeded determinism"):
        checks.check_seeded_determinism(make, DATA)


def test_check_failed_is_an_assertion_and_a_project_error():
    assert issubclass(CheckFailed, AssertionError)
    assert issubclass(CheckFailed, IemError)


def test_check_data_rejects_bad_shapes():
    with pytest.raises(InvalidInputError, match=r"X \(N, 21\)"):
        CheckData(X=np.zeros((5, 20)), F=np.zeros((5, 3)), samples_at=DATA.samples_at)
    with pytest.raises(InvalidInputError, match="split"):
        CheckData(X=np.zeros((5, 21)), F=np.zeros((5, 3)), samples_at=DATA.samples_at,
                  split=5)
