"""The safety contract: the gate reads typed fields of the estimate and fails closed.

An estimator that omits, misnames or cannot give what the gate needs (its standard
deviations, its data's verdict, its out-of-distribution verdict) never gets a write through,
unless the cell allows it ([gate] allow_without_uncertainty)."""

import math
from dataclasses import replace

import numpy as np
import pytest

from deploy.gate import GateConfig, SafetyGate
from deploy.gate_checks import model_doubt
from iem.types import PayloadEstimate
from sim.family import test_payloads

TRUTH = test_payloads()["test-3w"]
PHI = TRUTH.to_phi()
GOOD = PayloadEstimate(t=0.0, phi=PHI, std=np.full(10, 1e-4), nis=1.0, ood=False,
                       determined=("mass", "com", "inertia"))
LOOSE = GateConfig(stable_window_s=0.0, decision_period_s=0.01)


def writes(estimate, config=LOOSE, seconds: float = 1.0) -> int:
    gate = SafetyGate(config)
    sent = 0
    for k in range(round(seconds / 0.01)):
        t = k * 0.01
        gate.observe(t, PHI, estimate)
        if gate.due(t):
            decision = gate.decide(t, PHI)
            if decision.send:
                sent += 1
                gate.sent_command(sent, t)
                gate.acknowledged(sent)
    return sent


def test_a_complete_estimate_is_written():
    assert model_doubt(GOOD, LOOSE) is None
    assert writes(GOOD) >= 1


@pytest.mark.parametrize("field", ["std", "nis", "ood"])
def test_an_estimate_that_omits_a_field_is_never_written(field):
    est = replace(GOOD, **{field: None})
    assert model_doubt(est, LOOSE)[0] == "unreported"
    assert field in model_doubt(est, LOOSE)[1]
    assert writes(est) == 0


@pytest.mark.parametrize("field", ["std", "nis", "ood"])
def test_a_field_put_in_the_diagnostics_is_not_read(field):
    """The old untyped contract: the same figures in ``extra`` count for nothing."""
    value = {"std": GOOD.std, "nis": 1.0, "ood": False}[field]
    est = replace(GOOD, **{field: None}, extra={field: value})
    assert writes(est) == 0


@pytest.mark.parametrize("name", ["nls", "sigma", "out_of_distribution", "undetermined"])
def test_a_misnamed_field_is_an_error_where_the_estimate_is_made(name):
    with pytest.raises(TypeError):
        PayloadEstimate(t=0.0, phi=PHI, **{name: 1.0})


def test_something_that_is_not_an_estimate_is_never_written():
    class Lookalike:  # every figure, but not the typed estimate
        t, phi, std, nis, ood, unverified, extra = 0.0, PHI, np.full(10, 1e-4), 1.0, False, \
            False, {}

    assert model_doubt(Lookalike(), LOOSE)[0] == "unreported"
    assert writes(Lookalike()) == 0
    assert writes(Lookalike(), replace(LOOSE, allow_without_uncertainty=True)) == 0


def test_allowing_it_writes_the_papers_iem_but_still_checks_what_it_reports():
    allow = replace(LOOSE, allow_without_uncertainty=True)
    iem = PayloadEstimate(t=0.0, phi=PHI, std=None, nis=None, ood=False)
    assert writes(iem) == 0 and writes(iem, allow) >= 1
    assert model_doubt(replace(iem, ood=True), allow)[0] == "out_of_distribution"
    assert model_doubt(replace(iem, std=np.full(10, 0.1)), allow)[0] == "uncertain"
    assert model_doubt(replace(iem, nis=9.0), allow)[0] == "data_disagree"
    assert model_doubt(replace(iem, unverified=True), allow)[0] == "unverified"


def test_no_verdict_yet_is_reported_and_does_not_hold_back():
    assert model_doubt(replace(GOOD, nis=math.nan), LOOSE) is None


def test_the_estimators_report_what_they_can_say():
    from iem.baselines.bem import BatchEnsemble
    from iem.baselines.least_squares import RecursiveLeastSquares
    from iem.ensemble import IncrementalEnsemble
    from iem.physics import PhysicsInformedEnsemble
    from sim.robot import PANDA_DYNAMICS

    x = np.zeros(21)
    for model, reported in ((PhysicsInformedEnsemble(dynamics=PANDA_DYNAMICS), {"std"}),
                            (RecursiveLeastSquares(PANDA_DYNAMICS), {"std"}),
                            (IncrementalEnsemble(), set()), (BatchEnsemble(), set())):
        est = model.predict_one(x, np.zeros(3))
        assert isinstance(est, PayloadEstimate)
        assert {f for f in ("std", "nis", "ood") if getattr(est, f) is not None} >= reported
