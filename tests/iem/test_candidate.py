"""IEM+phys after an alarm: a change of the size of the arm's slow drift is detected, a false
alarm costs nothing (the posterior before it comes back within a second, chosen by the
data's likelihood), a true change stands (iem.physics.candidate, iem.physics.tracking)."""

import copy

import numpy as np
import pytest

from iem.physics import PhysicsInformedEnsemble
from iem.physics.candidate import DECIDE_S, Candidate, log_likelihood
from iem.physics.torque_noise import TorqueNoise
from sim.arm import NOMINAL_DYNAMICS
from sim.family import test_payloads

P3, P2 = test_payloads()["test-3w"], test_payloads()["test-2w"]
NOISE = TorqueNoise(std=(0.15, 0.36, 0.18, 0.24, 0.05, 0.10, 0.03),
                    weight=(33.0, 44.0, 32.0, 42.0, 29.0, 41.0, 20.0),
                    offset_std=(0.07, 0.30, 0.12, 0.19, 0.03, 0.08, 0.01),
                    source="a realistic arm's, as iem calibrate measured it (bench seed 1)")
"""What a calibrated realistic arm leaves in the equations, its slow drift included: a
0.275 kg swap is about 1 N·m on the shoulder, three times its slow part."""


def _points(rollout):
    from iem.signals.blocks import BlockFormer

    b = BlockFormer().push_many(rollout.t, rollout.features)
    return b.X, b.t


def _run(rollout, **kw):
    """The physics alone (no bags: the rated-payload prior) with the arm's noise along a
    rollout: ``(t, estimates)``."""
    model = PhysicsInformedEnsemble(dynamics=NOMINAL_DYNAMICS, torque_noise=NOISE.to_dict(),
                                    **kw)
    X, t = _points(rollout)
    out = []
    for x in X:
        model.observe_one(x, None)
        out.append(model.predict_one(x, None))
    return t, out, model


@pytest.fixture(scope="module")
def rollouts():
    """The excitation path: test-3w throughout; swapped for test-2w at 10 s; and test-3w
    with the shoulder's torque sensor kicked by 3 N·m for 80 ms at 10 s (a bump the detector
    must take for a change, the payload staying)."""
    from sim.paths import excitation_path
    from sim.plant import ArmPlant

    path = excitation_path()
    plain = ArmPlant(payload=P3, seed=8, controller_load=P3).follow(path)
    swapped = ArmPlant(payload=P3, seed=8, controller_load=P3).follow(path, mount={10000: P2})
    kicked = copy.deepcopy(plain)  # the same plant, seed and path: the same rollout
    kicked.tau[10000:10080, 1] += 3.0
    return plain, swapped, kicked


def test_a_swap_the_size_of_the_arms_slow_drift_is_detected(rollouts):
    """The test judges an equation net of the window's offsets against the error without
    their slow part: counting the drift twice hid this 0.275 kg swap (chi² 15-27 an
    equation, under the detector's drift)."""
    plain, swapped, _ = rollouts
    t, est, _ = _run(swapped)
    fired = [k for k, e in enumerate(est) if e.extra.get("change")]
    assert fired and 10.0 <= t[fired[0]] <= 10.5, [t[k] for k in fired]
    assert not any(e.extra.get("reverted") for e in est[fired[0]:])  # the change stands
    assert abs(est[-1].phi[0] - P2.mass) < 0.02
    _, est, _ = _run(plain)
    assert not any(e.extra.get("change") for e in est)


def test_a_false_alarm_returns_to_the_posterior_before_it_within_a_second(rollouts):
    _, _, kicked = rollouts
    t, est, model = _run(kicked)
    fired = [k for k, e in enumerate(est) if e.extra.get("change")]
    assert len(fired) == 1 and 10.0 <= t[fired[0]] <= 10.3, [t[k] for k in fired]
    back = [k for k, e in enumerate(est) if e.extra.get("reverted")]
    assert len(back) == 1 and 0.0 < t[back[0]] - t[fired[0]] <= 1.0
    assert est[back[0]].extra.get("reset")  # the output smoothing restarts at it
    assert model.reverts == 1 and model.changes == 1
    # the window is the one from before the alarm, with the equations since: not restarted
    assert model._window.m > 0.9 * 100 * t[-1]
    assert abs(est[back[0]].phi[0] - P3.mass) < 0.01
    assert abs(est[-1].phi[0] - P3.mass) < 0.01


def test_the_evidence_is_the_likelihood_ratio_per_independent_equation():
    """An equation the old payload predicts better counts for it, one it predicts worse
    against it, by its log-likelihood ratio over the equations that count as one."""
    rng = np.random.default_rng(1)
    S = np.diag(rng.uniform(0.01, 0.1, 7))
    nu = rng.normal(size=7) * 0.1
    want = -0.5 * (nu @ np.linalg.solve(S, nu) + np.log(np.linalg.det(S)))
    assert log_likelihood(nu, S) == pytest.approx(want, rel=1e-12)
    cand = Candidate(window=None, post=None, summary=None, initial=None, decide_n=90,
                     weight=4.0)
    assert cand.judge(-1.0, -3.0) is None and cand.evidence == pytest.approx(0.5)
    assert cand.judge(-100.0, -1.0) == "drop"
    late = Candidate(window=None, post=None, summary=None, initial=None, decide_n=3,
                     weight=1.0)
    late.judge(-1.0, -1.5)
    assert [late.due() for _ in range(3)] == [None, None, "revert"]
    assert DECIDE_S < 1.0  # a false alarm's estimate is back within a second


def test_a_model_saved_while_it_holds_a_candidate_resumes_with_it(rollouts):
    """A model file written between an alarm and the data's choice holds the candidate: the
    model loaded from it reverts the false alarm as the one that went on, to the bit."""
    from iem.persistence import dumps, loads

    _, _, kicked = rollouts
    X, t = _points(kicked)
    model = PhysicsInformedEnsemble(dynamics=NOMINAL_DYNAMICS, torque_noise=NOISE.to_dict())
    k = 0
    while model._candidate is None:
        model.observe_one(X[k], None)
        k += 1
    assert 10.0 <= t[k - 1] <= 10.3
    model.observe_one(X[k], None)  # a sample into its decision
    twin = loads(dumps(model))
    assert twin._candidate is not None and twin._candidate.samples == model._candidate.samples
    for x in X[k + 1:]:
        model.observe_one(x, None)
        twin.observe_one(x, None)
        np.testing.assert_array_equal(twin.predict_one(x, None).phi,
                                      model.predict_one(x, None).phi)
    assert model.reverts == twin.reverts == 1
