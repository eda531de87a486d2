"""The safety contract: the gate reads typed fields of the estimate and fails closed.

An estimator that omits, misnames or cannot give what the gate needs (its standard
deviations, its data's verdict, its out-of-distribution verdict) never gets a write through,
unless the cell allows it ([gate] allow_without_uncertainty)."""

import math
from dataclasses import replace

import numpy as np
import pytest

from deploy.writeback.checks import model_doubt
from deploy.writeback.gate import SafetyGate
from deploy.writeback.settings import GateConfig
from iem.types import PayloadEstimate
from sim.family import test_payloads

TRUTH = test_payloads()["test-3w"]
PHI = TRUTH.to_phi()
GOOD = PayloadEstimate(t=0.0, phi=PHI, std=np.full(10, 1e-4), nis=1.0, ood=False,
                       determined=("mass", "com", "inertia"))
LOOSE = GateConfig(stable_window_s=0.01, decision_period_s=0.01)


def writes(estimate, config=LOOSE, seconds: float = 1.0) -> int:
    gate = SafetyGate(config)
    sent = 0
    for k in range(round(seconds / 0.01)):
        t = k * 0.01
        decision = gate.step(t, PHI, estimate)
        if decision is not None and decision.send:
            sent += 1
            gate.commands.sent_command(sent, decision.payload, t)
            gate.commands.acknowledged(sent, t)
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
    from sim.arm import NOMINAL_DYNAMICS

    x = np.zeros(21)
    for model, reported in ((PhysicsInformedEnsemble(dynamics=NOMINAL_DYNAMICS), {"std"}),
                            (RecursiveLeastSquares(NOMINAL_DYNAMICS), {"std"}),
                            (IncrementalEnsemble(), set()), (BatchEnsemble(), set())):
        est = model.predict_one(x, np.zeros(3))
        assert isinstance(est, PayloadEstimate)
        assert {f for f in ("std", "nis", "ood") if getattr(est, f) is not None} >= reported


# -- the holes: each refused with its reason, never an exception --------------------------------
def _bypass(**fields) -> PayloadEstimate:
    """A PayloadEstimate whose fields were set past its own checks (as a buggy model, or a
    pickled one, might hand over)."""
    e = object.__new__(PayloadEstimate)
    for name, value in {**GOOD.__dict__, **fields}.items():
        object.__setattr__(e, name, value)
    return e


@pytest.mark.parametrize(("fields", "reason", "words"), [
    ({"std": np.r_[-0.01, np.full(9, 1e-4)]}, "malformed", "negative or NaN"),
    ({"std": np.r_[np.nan, np.full(9, 1e-4)]}, "malformed", "negative or NaN"),
    ({"nis": -1.0}, "malformed", "negative"),
    ({"std": np.full(7, 1e-4)}, "malformed", "shape"),
    ({"phi": PHI[:9]}, "malformed", "shape"),
    ({"ood": np.array([True, False])}, "malformed", "ood"),
    ({"std": np.r_[np.full(4, 1e-4), np.inf, np.full(5, 1e-4)]}, "uncertain", "inertia"),
    ({"std": np.r_[np.full(4, 1e-4), 0.1, np.full(5, 1e-4)]}, "uncertain", "inertia"),
    ({"std": np.r_[np.inf, np.full(9, 1e-4)]}, "uncertain", "no band"),
    ({"unverified": True, "nis": math.nan}, "unverified", "restored"),
])
def test_each_hole_in_the_contract_is_refused_with_its_reason(fields, reason, words):
    gate = SafetyGate(LOOSE)
    for k in range(50):  # the newest estimates are fresh: the gate knows their age
        gate.step(k * 0.01, PHI, replace(GOOD, t=k * 0.01))
    bad = _bypass(**fields)
    decision = gate.step(0.5, PHI, bad)
    assert decision.reason == reason and words in decision.detail, decision
    assert not decision.send


def test_the_estimate_checks_itself_where_it_is_made():
    from iem.errors import InvalidInputError

    for bad in ({"std": np.r_[-0.01, np.full(9, 1e-4)]}, {"nis": -1.0},
                {"phi": PHI[:9]}, {"std": np.full(7, 1.0)},
                {"phi": np.r_[np.inf, PHI[1:]]}):
        with pytest.raises(InvalidInputError, match="valid"):
            replace(GOOD, **bad)
    replace(GOOD, phi=np.full(10, np.nan))  # no estimate yet: allowed
    replace(GOOD, nis=math.nan, std=np.full(10, np.inf))  # no verdict, nothing known


def test_a_restored_payload_is_unverified_until_live_data_test_it():
    """IEM+phys after a run: its posterior, distrusted as at a restart, is the prior of an
    unverified estimate until the window holds enough live equations again."""
    from iem.physics import DETECT_AFTER, PhysicsInformedEnsemble
    from tests.iem.test_physics import _hand_made, linear_dynamics

    X = _hand_made(1500)
    model = PhysicsInformedEnsemble(dynamics=linear_dynamics(), rate_hz=1000.0,
                                    update_every=10, point_frames=1)
    for x in X[:1000]:
        model.observe_one(x, None)
    before = model.predict_one(X[999], None)
    assert not before.unverified and model_doubt(before, LOOSE) is None
    model.distrust()
    after = model.predict_one(X[999], None)
    assert after.unverified and model_doubt(after, GateConfig())[0] == "unverified"
    np.testing.assert_allclose(after.phi, before.phi, atol=1e-6)
    for x in X[1000:]:
        model.observe_one(x, None)
    assert model._window.m >= DETECT_AFTER and not model.predict_one(X[-1], None).unverified


def test_the_service_distrusts_a_model_it_restarts_from(phys_model_file, monkeypatch):
    from deploy.config import config_from_dict
    from deploy.model.setup import checked_model
    from iem.physics import PhysicsInformedEnsemble

    calls = []
    monkeypatch.setattr(PhysicsInformedEnsemble, "distrust", lambda self: calls.append(1))
    config = config_from_dict({"model": {"path": str(phys_model_file), "kind": "IEM+phys",
                                         "train_if_missing": False}})
    checked_model(config)
    assert calls == [1]
    checked_model(config, model=PhysicsInformedEnsemble(dynamics="sim.arm:arm_dynamics"))
    assert calls == [1]  # a model handed over (just trained) is not a restart


# -- a property: nothing an estimate holds makes the gate raise ---------------------------------
from hypothesis import given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402
from hypothesis.extra.numpy import array_shapes, arrays  # noqa: E402

_floats = st.floats(allow_nan=True, allow_infinity=True, width=64)
_vectors = st.one_of(
    arrays(np.float64, st.sampled_from([(10,), (9,), (11,), (), (2, 5)]), elements=_floats),
    arrays(np.float64, array_shapes(max_dims=2, max_side=12), elements=_floats),
    st.lists(_floats, max_size=12), st.none(), st.text(max_size=3), st.integers())
_anything = st.one_of(st.none(), st.booleans(), _floats, st.text(max_size=3),
                      st.integers(), arrays(np.float64, (2,), elements=_floats))


_matrices = st.one_of(
    st.none(), arrays(np.float64, (10, 10), elements=_floats),
    arrays(np.float64, (10, 10), elements=st.floats(-1e-3, 1e-3)),
    st.builds(lambda a: a @ a.T, arrays(np.float64, (10, 10), elements=st.floats(-0.1, 0.1))),
    _vectors, _anything)
_extras = st.one_of(
    st.none(), st.just({"ood_score": "x"}), _anything,
    st.fixed_dictionaries({"ood_score": _anything, "velocity_score": _anything}),
    st.dictionaries(st.text(max_size=3), _anything))
_states = st.one_of(st.none(), st.builds(
    lambda q, dq: type("State", (), {"q": q, "dq": dq})(), _vectors, _vectors))


@settings(max_examples=1000, deadline=None)
@given(phi=_vectors, std=_vectors, nis=_anything, t=_anything, ood=_anything,
       unverified=_anything, determined=st.one_of(st.none(), st.tuples(st.text(max_size=4)),
                                                  st.tuples(st.sampled_from(["mass", "com",
                                                                             "inertia"])),
                                                  st.integers(), st.text(max_size=3)),
       smoothed=_vectors, extra=_extras, cov=_matrices, prior=_vectors, bag=_anything,
       learning=_anything, state=_states, gate_t=_anything)
def test_no_estimate_however_malformed_makes_the_step_raise(phi, std, nis, t, ood, unverified,
                                                            determined, smoothed, extra, cov,
                                                            prior, bag, learning, state,
                                                            gate_t):
    """Every field of the estimate, its extras, its covariance and its prior, the smoothed
    estimate, the point's pose and the step's own time: whatever they hold, a step decides
    (and never sends a load that is not finite)."""
    bad = _bypass(phi=phi, std=std, nis=nis, t=t, ood=ood, unverified=unverified,
                  determined=determined, extra=extra, cov=cov, prior=prior, bag=bag,
                  learning=learning)
    regressor = _regressor()
    for config in (GateConfig(), GateConfig(allow_without_uncertainty=True)):
        gate = SafetyGate(config, regressor=regressor)
        for k in range(3):
            gate.step(k * 0.3, PHI, GOOD)
        decision = gate.step(1.0, smoothed, bad, state)
        if smoothed is None:  # no estimate: a silence's step, and the controller is not
            assert decision is None
            continue
        assert decision.reason and not (decision.send and decision.payload is not None
                                        and not np.isfinite(decision.payload.to_phi()).all())
        gate.step(gate_t, smoothed, bad, state)
        gate.step(1.2)
        gate.verdict()
        gate.summary()


def _regressor():
    """A payload regressor of the shape the arm model's has (7 joints)."""
    Y = np.linspace(-1.0, 1.0, 70).reshape(7, 10)
    return lambda q, dq: Y * (1.0 + float(np.sum(q) + np.sum(dq)) * 0.0)


def test_a_covariance_is_checked_by_value_each_time_it_changes():
    """Estimates between two refreshes share one covariance, checked once; a covariance of
    other values (a new array, or the same array changed in place) is checked again, and
    a bad one is refused whatever was read before it."""
    from deploy.writeback.checks import read

    std = np.full(10, 1e-3)
    cov = np.diag(std ** 2)
    good = replace(GOOD, std=std, cov=cov)
    for _ in range(2):
        reading, broken = read(good)
        assert broken is None and np.array_equal(reading.sigma, std)
    skew = cov.copy()
    skew[0, 1] = 1e-7  # not symmetric
    assert read(replace(good, cov=skew))[1][0] == "malformed"
    assert read(good)[1] is None
    cov[0, 1] = 1e-7  # the same array, changed in place
    reading, broken = read(good)
    assert reading is None and "not symmetric" in broken[1]
