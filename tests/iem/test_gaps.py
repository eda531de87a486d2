"""The one gap rule (iem.signals.gaps) and the filters that apply it: lost, duplicated and late
samples never make a derivative span several cycles as if they were one."""

from __future__ import annotations

import numpy as np
import pytest

from iem.base import BaseEstimator
from iem.factories import register_factory
from iem.online import OnlineIdentifier
from iem.physics.regression import PayloadRegression
from iem.signals.filters import LowPass2, StateFilter
from iem.signals.gaps import RESTART, SKIP, GapRule
from iem.signals.smoothing import ExponentialSmoother
from iem.types import JointState, PayloadEstimate


def test_gap_rule_verdicts_from_time_stamps():
    rule = GapRule(rate_hz=1000.0, max_bridge_s=0.02)
    times = [5.0, 5.001, 5.002, 5.005, 5.005, 5.004, 5.0061, 5.030, 5.031, 4.0, 4.001]
    verdicts = [rule(t) for t in times]
    # first; normal; normal; 2 lost; duplicate; late (older); jittered +1; 24 ms silence;
    # normal; a jump back (controller restart); normal
    assert verdicts == [RESTART, 1, 1, 3, SKIP, SKIP, 1, RESTART, 1, RESTART, 1]
    assert rule.bridged == 2 and rule.skipped == 2 and rule.restarts == 3


def test_gap_rule_tolerates_a_drifting_controller_clock():
    """A controller clock 0.6 % fast still gives one cycle per sample."""
    rule = GapRule(1000.0)
    verdicts = {rule(k * 1.006e-3) for k in range(5000)}
    assert verdicts == {RESTART, 1}


def test_bridged_low_pass_equals_the_filter_run_on_the_interpolated_samples():
    rng = np.random.default_rng(0)
    x = rng.normal(size=(60, 3)).cumsum(axis=0)
    drop = {10, 11, 12, 30, 45}
    full = np.array(x)
    kept = [k for k in range(len(x)) if k not in drop]
    for k in drop:  # what the bridge feeds: linear interpolation between the kept neighbours
        lo = max(j for j in kept if j < k)
        hi = min(j for j in kept if j > k)
        full[k] = x[lo] + (x[hi] - x[lo]) * (k - lo) / (hi - lo)
    ref = LowPass2(20.0, 1000.0, channels=3)
    want = [ref(v) for v in full]
    lp = LowPass2(20.0, 1000.0, channels=3)
    last = None
    for k in kept:
        y = lp(x[k], 1 if last is None else k - last)
        np.testing.assert_allclose(y, want[k], rtol=0, atol=1e-12)
        if last is not None:
            np.testing.assert_allclose(lp.previous, want[k - 1], rtol=0, atol=1e-12)
        last = k


def _sine_state(t):
    w = 2.0 * np.pi * 0.5
    return np.sin(w * t) * np.ones(7), w * np.cos(w * t) * np.ones(7), -w * w * np.sin(w * t)


def test_state_filter_ddq_is_right_across_lost_cycles():
    """5 % of cycles lost: ddq stays what the unbroken stream gives (not doubled)."""
    rng = np.random.default_rng(1)
    t = np.arange(3000) * 1e-3
    keep = rng.random(t.size) > 0.05
    keep[:10] = True
    whole, broken = StateFilter(50.0, 1000.0), StateFilter(50.0, 1000.0)  # per frame
    ddq_whole = {}
    for k, tk in enumerate(t):
        q, dq, _ = _sine_state(tk)
        ddq_whole[k] = whole(q, dq, tk)[2]
    worst = 0.0
    for k in np.flatnonzero(keep):
        q, dq, _ = _sine_state(t[k])
        ddq = broken(q, dq, t[k])[2]
        if k > 100:
            worst = max(worst, float(np.abs(ddq - ddq_whole[k]).max()))
    # the true ddq amplitude is ~10 rad/s²; an unbridged lost cycle gives ~100 % errors
    assert worst < 0.05


def test_state_filter_skips_a_sample_that_is_not_newer():
    f = StateFilter()  # at the 100 Hz of block points
    first = f(np.zeros(7), np.ones(7), 0.0)
    second = f(np.zeros(7), 2 * np.ones(7), 0.01)
    again = f(np.full(7, 9.0), np.full(7, 99.0), 0.005)  # late: older than the last used
    assert f.steps == SKIP
    for a, b in zip(again, second, strict=True):
        np.testing.assert_array_equal(a, b)
    assert not np.array_equal(first[1], second[1])


def _fake_dynamics():
    """A linear toy arm: tau_robot = 2 ddq + dq, Y = [ddq, dq, q] padded."""
    def f(q, dq, ddq):
        Y = np.zeros((7, 10))
        Y[:, 0], Y[:, 1], Y[:, 2] = ddq, dq, q
        return 2 * ddq + dq, Y, np.eye(7)
    return f


FAKE = "tests.iem.test_gaps:_fake_dynamics"
register_factory(FAKE)  # a model may name it (iem.factories)


def test_regression_equations_across_lost_cycles_match_the_whole_stream():
    t = np.arange(2000) * 1e-3
    rng = np.random.default_rng(2)
    keep = rng.random(t.size) > 0.05
    keep[:5] = True

    def x_at(tk):
        q, dq, ddq = _sine_state(tk)
        return np.concatenate((q, dq, 2 * ddq + dq + 0.3 * q))  # phi[2] = 0.3

    whole = PayloadRegression(FAKE, cutoff_hz=4.0, every=10, settle=-1)
    ref = {}
    for k, tk in enumerate(t):
        eq = whole(x_at(tk))
        if eq is not None:
            ref[k] = eq
    broken = PayloadRegression(FAKE, cutoff_hz=4.0, every=10, settle=-1)
    last, got = None, 0
    for k in np.flatnonzero(keep):
        eq = broken(x_at(t[k]), steps=RESTART if last is None else k - last)
        last = k
        if eq is None:
            continue
        Y, r, _ = eq
        if k in ref:  # the same equation as the unbroken stream's (ddq ~ 10 rad/s²)
            got += 1
            np.testing.assert_allclose(Y, ref[k][0], atol=2e-3)
            np.testing.assert_allclose(r, ref[k][1], atol=2e-3)
    assert got > 0.7 * len(ref)


def test_smoother_decays_by_the_time_of_lost_cycles():
    a, b = ExponentialSmoother(tau_s=0.2), ExponentialSmoother(tau_s=0.2)
    for _ in range(500):
        a(np.zeros(2))
        b(np.zeros(2))
    a(np.ones(2), steps=5)
    for _ in range(5):
        out = b(np.ones(2))
    np.testing.assert_allclose(a.value, out, rtol=1e-12)


class _Recorder(BaseEstimator):
    name = "recorder"

    def __init__(self):
        self.events = []

    def resume(self):
        self.events.append("resume")

    def gap(self, k):
        self.events.append(k)

    def learn_one(self, x, flange, samples):
        self.events.append("learn")

    def predict_one(self, x, flange, t=0.0):
        return PayloadEstimate(t=t, phi=np.full(10, t))


def test_online_loop_bridges_skips_and_restarts_by_one_rule():
    toy = _Recorder()
    online = OnlineIdentifier(toy, lambda q: np.zeros(3), None)
    outs = []
    for t in (0.0, 0.01, 0.03, 0.03, 0.02, 0.04, 0.5):  # block points, 100 per second
        raw, _ = online.step_block(JointState(t=t, q=np.zeros(7), dq=np.zeros(7),
                                              tau_J=np.zeros(7)))
        outs.append(raw.t)
    assert toy.events == ["resume", "learn", "learn", 2, "learn", "learn", "resume", "learn"]
    assert outs == [0.0, 0.01, 0.03, 0.03, 0.03, 0.04, 0.5]  # skipped: the last again
    assert online.skipped == 2


@pytest.fixture(scope="module")
def excitation_run(trained_phys_model_file):
    """A light IEM+phys trained on the excitation path (the session's, tests/conftest.py),
    and the plant's run along its first 8 s with test-3w (noise seed 7)."""
    from deploy.model.training import tandem_for
    from iem.persistence import load_model
    from sim.family import test_payloads
    from sim.paths import excitation_path
    from sim.plant import ArmPlant
    from sim.robot import ArmModel

    model = load_model(trained_phys_model_file)
    payload = test_payloads()["test-3w"]
    path = excitation_path()
    n = 8000
    from sim.paths import Path

    part = Path(path.name, path.t[:n], path.q[:n], path.dq[:n], path.ddq[:n])
    rollout = ArmPlant(payload=payload, seed=7, controller_load=payload).follow(part)
    return model, rollout, payload.to_phi(), ArmModel(), tandem_for("paper")


def _mae(excitation_run, order):
    import copy

    model, ro, truth, kin, tandem = excitation_run
    model = copy.deepcopy(model)
    online = OnlineIdentifier(model, kin.flange_position, tandem.samples)
    err = []
    for k in order:  # frames: the online loop forms them into block points
        out = online.step(JointState(t=ro.t[k], q=ro.q[k], dq=ro.dq[k], tau_J=ro.tau[k]))
        if out is None:
            continue  # before the first block point
        smoothed = out[1]
        if ro.t[k] > 1.0:
            err.append(abs(smoothed[0] - truth[0]))
    return float(np.mean(err)), model.changes


def test_faulty_stream_estimates_as_well_as_the_clean_one(excitation_run):
    """5 % of cycles dropped, 2 % duplicated and 2 % late: IEM+phys stays within 1.5x of
    the clean stream's mass error (floor 1 g) and sees no payload change."""
    n = len(excitation_run[1].t)
    clean, clean_changes = _mae(excitation_run, range(n))
    rng = np.random.default_rng(11)
    order = []
    for k in range(n):
        if rng.random() < 0.05:
            continue
        order.append(k)
        if rng.random() < 0.02:
            order.append(k)
        if rng.random() < 0.02 and k > 5:
            order.append(k - 3)
    faulty, changes = _mae(excitation_run, order)
    assert clean_changes == 0 and changes == 0
    assert faulty <= max(1.5 * clean, clean + 0.001)
