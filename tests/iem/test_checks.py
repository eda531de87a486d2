"""Every estimator passes the shared check suite of :mod:`iem.checks`.

The data are synthetic (no sim, no Pinocchio): a smooth 7-joint path whose joints travel well
over 60° in all (so the default 30° / 0.2 m thresholds form several bags), a flange position
that is a fixed linear map of q, and at every point 77 samples ``[q, dq, A(q) phi_k]`` with a
smooth regressor ``A(q)`` and 77 payload-like parameter vectors ``phi_k``.
"""

from __future__ import annotations

import numpy as np
import pytest

from iem import checks
from iem.bem import BatchEnsemble
from iem.checks import CheckData, CheckFailed, check_estimator
from iem.ensemble import IncrementalEnsemble
from iem.errors import IemError, InvalidInputError
from iem.least_squares import RecursiveLeastSquares
from iem.old_iem import InPlaceEnsemble
from iem.physics import PhysicsInformedEnsemble

# One line per estimator under check; each lambda returns a fresh, seeded estimator.
ESTIMATORS = {
    "IEM": lambda: IncrementalEnsemble(seed=0, fit_epochs=2, warmup_iters=10, iters=2),
    "old_IEM": lambda: InPlaceEnsemble(seed=0, fit_epochs=2, warmup_iters=10, iters=2),
    "BEM": lambda: BatchEnsemble(seed=0, n_networks=2, n_trees=2, fit_epochs=2, max_depth=4),
    "LS": lambda: RecursiveLeastSquares(),
    "IEM+phys": lambda: PhysicsInformedEnsemble(
        ensemble={"seed": 0, "fit_epochs": 2, "warmup_iters": 10, "iters": 2}),
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
    checks._train(est, DATA)
    n_train = est.n_bags
    for i in DATA.further_points():
        checks._learn(est, DATA, i)
    assert n_train >= 2
    assert est.n_bags > n_train  # the further points reach new ground


@pytest.mark.parametrize("check", checks.CHECKS, ids=lambda c: c.__name__)
@pytest.mark.parametrize("name", sorted(ESTIMATORS))
def test_check(name, check):
    check(ESTIMATORS[name], DATA)


@pytest.mark.parametrize("name", sorted(ESTIMATORS))
def test_check_estimator_runs_all(name):
    check_estimator(ESTIMATORS[name], DATA)


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
