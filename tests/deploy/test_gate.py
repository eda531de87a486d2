"""The safety gate: every refusal reason, on hand-made estimates with an explicit clock."""

import logging

import numpy as np
import pytest

from deploy.gate import REASONS, GateConfig, SafetyGate
from sim.family import test_payloads
from sim.payload import Payload

P = test_payloads()["test-3w"]  # 1.615 kg, CoM about 64 mm out, physically consistent
DT = 0.01  # s between estimates in these sequences (the service: 1 ms)


def phi_of(dm: float = 0.0, dcom=(0.0, 0.0, 0.0), base: Payload = P) -> np.ndarray:
    """``base`` with its mass and CoM moved (inertia about the CoM kept): consistent."""
    com = tuple(c + d for c, d in zip(base.com, dcom, strict=True))
    return Payload("x", base.mass + dm, com, base.inertia).to_phi()


def feed(gate: SafetyGate, phi_at, t0: float, t1: float) -> list:
    """Observe an estimate every DT s in [t0, t1]; decide whenever the gate is due."""
    decisions = []
    for k in range(round((t1 - t0) / DT) + 1):
        t = round(t0 + k * DT, 9)
        phi = phi_at(t) if callable(phi_at) else phi_at
        gate.observe(t, phi)
        if gate.due(t):
            decisions.append(gate.decide(t, phi))
    return decisions


def reasons(decisions) -> list[str]:
    return [d.reason for d in decisions]


def first_send(gate: SafetyGate, phi=None) -> float:
    """Watch a constant estimate until the first send; return its time."""
    decisions = feed(gate, phi_of() if phi is None else phi, 0.0, 0.6)
    sends = [d for d in decisions if d.send]
    assert sends, reasons(decisions)
    return sends[0].t


# -- the estimate itself ----------------------------------------------------------------------
def test_a_stable_consistent_estimate_is_sent_after_one_stability_window():
    gate = SafetyGate()
    decisions = feed(gate, phi_of(), 0.0, 0.6)
    before = [d for d in decisions if d.t < 0.45]
    assert before and set(reasons(before)) == {"unstable"}
    assert "not yet watched" in before[0].detail
    sent = [d for d in decisions if d.send]
    assert sent[0].t >= 0.45 * 0.999
    assert sent[0].payload.mass == pytest.approx(P.mass)
    np.testing.assert_allclose(sent[0].payload.com, P.com, atol=1e-12)
    assert "mass 1.6150 kg" in sent[0].detail
    assert gate.last_sent is sent[0].payload


@pytest.mark.parametrize("bad", [
    np.full(10, np.nan), np.r_[phi_of()[:9], np.inf], phi_of()[:9]])
def test_not_finite_or_wrong_shape(bad):
    decision = SafetyGate().decide(1.0, bad)
    assert decision.reason == "not_finite" and not decision.send and decision.payload is None


def test_inconsistent_mass_inertia_and_triangle_inequality():
    gate = SafetyGate()
    zero = phi_of()
    zero[0] = 0.0
    assert gate.decide(0.0, zero).reason == "inconsistent"
    assert "mass 0 kg is not > 0" in gate.decide(0.1, zero).detail
    negative = Payload("x", 1.0, (0.0, 0.0, 0.05), (-1e-3, 0.0, 0.0, 1e-3, 0.0, 1e-3))
    d = gate.decide(0.2, negative.to_phi())
    assert d.reason == "inconsistent" and "positive definite" in d.detail
    # principal moments 1e-3, 1e-3, 3e-3: I1 + I2 < I3
    triangle = Payload("x", 1.0, (0.0, 0.0, 0.05), (1e-3, 0.0, 0.0, 1e-3, 0.0, 3e-3))
    d = gate.decide(0.3, triangle.to_phi())
    assert d.reason == "inconsistent" and "triangle inequality" in d.detail


def test_over_rated_mass():
    heavy = Payload("x", 3.5, P.com, P.inertia).to_phi()
    d = SafetyGate().decide(0.0, heavy)
    assert d.reason == "over_rated" and "3.500 kg > rated 3 kg" in d.detail
    assert SafetyGate(GateConfig(rated_mass_kg=3.0)).decide(0.0, phi_of()).reason != "over_rated"


def test_com_too_far_from_the_flange():
    far = phi_of(dcom=(0.0, 0.0, 0.2 - P.com[2]))
    d = SafetyGate().decide(0.0, far)
    assert d.reason == "com_too_far" and "> 0.15 m" in d.detail
    d = SafetyGate(GateConfig(max_com_radius_m=0.25)).decide(0.0, far)
    assert d.reason != "com_too_far"


def test_physical_refusals_come_before_the_stream_conditions():
    gate = SafetyGate()
    gate.controller_silent(True)
    assert gate.decide(0.0, np.full(10, np.nan)).reason == "not_finite"
    assert gate.decide(0.1, phi_of()).reason == "controller_silent"


def test_non_finite_estimates_are_not_watched():
    gate = SafetyGate()
    feed(gate, lambda t: phi_of() if t < 0.3 else np.full(10, np.nan), 0.0, 0.6)
    # the window holds only the finite ones (0 .. 0.29 s): not watched long enough
    assert "not yet watched" in gate.decide(0.6, phi_of()).detail


# -- stability and hysteresis -------------------------------------------------------------------
def wobble(amplitude: float, what: str):
    """Every other estimate moved by ``amplitude`` (kg for mass, m for the CoM's x)."""
    def at(t: float) -> np.ndarray:
        a = amplitude if round(t / DT) % 2 else 0.0
        return phi_of(dm=a) if what == "mass" else phi_of(dcom=(a, 0.0, 0.0))
    return at


@pytest.mark.parametrize(("what", "band"), [("mass", 0.02), ("com", 0.004)])
def test_stability_has_hysteresis(what, band):
    gate = SafetyGate()
    assert "unstable" not in reasons(feed(gate, phi_of(), 0.0, 0.6)[-3:])
    # stable: a spread of 1.5 bands keeps it stable (below twice the band)
    assert "unstable" not in reasons(feed(gate, wobble(1.5 * band, what), 0.61, 1.6))
    # above twice the band it becomes unstable at once
    assert set(reasons(feed(gate, wobble(2.5 * band, what), 1.61, 2.2))) == {"unstable"}
    # unstable: 1.5 bands is not good enough to become stable again
    assert set(reasons(feed(gate, wobble(1.5 * band, what), 2.21, 3.2))) == {"unstable"}
    # below the band (steady) for a whole window: stable again
    late = feed(gate, phi_of(), 3.21, 4.0)
    assert reasons(late)[0] == "unstable" and late[-1].reason != "unstable"
    spread = [d.detail for d in late if d.reason == "unstable"]
    assert spread and spread[0].startswith("spread over 0.5 s: mass")


# -- no change, rate limit ------------------------------------------------------------------
def test_min_change_against_the_last_written_load():
    gate = SafetyGate()
    first_send(gate)
    # 5 g and 1 mm moves (below 10 g / 2 mm) are not worth a write, even after a long time
    assert set(reasons(feed(gate, phi_of(dm=0.005), 0.61, 2.0))) == {"no_change"}
    assert set(reasons(feed(gate, phi_of(dcom=(0.001, 0, 0)), 2.01, 3.0))) == {"no_change"}
    # 15 g is (within the stability band, so still stable): sent at once
    d = feed(gate, phi_of(dm=0.015), 3.01, 3.2)
    assert d[0].send and d[0].payload.mass == pytest.approx(P.mass + 0.015)
    # a 3 mm CoM move as well, once the rate limit allows
    d = [x for x in feed(gate, phi_of(dm=0.015, dcom=(0.003, 0, 0)), 3.21, 4.5) if x.send]
    assert len(d) == 1 and d[0].payload.com[0] == pytest.approx(P.com[0] + 0.003)


@pytest.mark.parametrize("rate", [1.0, 2.0])
def test_rate_limit(rate):
    gate = SafetyGate(GateConfig(max_rate_hz=rate))
    t_sent = first_send(gate)
    decisions = feed(gate, phi_of(dm=0.015), 0.61, 2.0)
    sends = [d for d in decisions if d.send]
    early = [d for d in decisions if d.t < t_sent + 1.0 / rate - 1e-9]
    assert set(reasons(early)) == {"rate_limited"}
    assert sends and sends[0].t >= t_sent + 1.0 / rate - 1e-9
    assert "rate_limited" not in reasons(decisions[decisions.index(sends[0]):])


# -- the controller: silence, acknowledgements -----------------------------------------------
def test_silent_controller_stops_sends_and_they_resume():
    gate = SafetyGate()
    first_send(gate)
    gate.controller_silent(True)
    silent = feed(gate, phi_of(dm=0.05), 0.61, 2.5)
    assert set(reasons(silent)) == {"controller_silent"}
    assert "no joint state" in silent[0].detail
    gate.controller_silent(False)
    after = feed(gate, phi_of(dm=0.05), 2.51, 2.6)
    assert after[0].send  # stable, changed and more than 1 s after the last write


def test_unacknowledged_write_stops_sends_until_the_ack_arrives():
    gate = SafetyGate()
    t_sent = first_send(gate)
    gate.sent_command(7, t_sent)
    waiting = feed(gate, phi_of(dm=0.015), 0.61, 0.9)
    assert set(reasons(waiting)) == {"ack_missing"}
    assert "waiting for the ack of command 7" in waiting[0].detail
    gate.acknowledged(6)  # not the one awaited
    assert gate.decide(0.95, phi_of(dm=0.015)).reason == "ack_missing"
    gate.acknowledged(7)
    after = feed(gate, phi_of(dm=0.015), 0.96, 2.0)
    assert "ack_missing" not in reasons(after) and any(d.send for d in after)
    assert (gate.sent, gate.acked) == (1, 1)


def test_missing_ack_stops_sends_until_the_retry_time():
    config = GateConfig(ack_timeout_s=0.5, ack_retry_s=2.0)
    gate = SafetyGate(config)
    t_sent = first_send(gate)
    gate.sent_command(1, t_sent)
    decisions = feed(gate, phi_of(dm=0.015), 0.61, 4.0)
    timed_out = [d for d in decisions if "not acknowledged within 0.5 s" in d.detail]
    assert len(timed_out) == 1 and timed_out[0].t > t_sent + 0.5
    t_fail = timed_out[0].t
    waiting = [d for d in decisions if d.t < t_fail + 2.0 - 1e-9]
    assert set(reasons(waiting)) == {"ack_missing"}
    assert any("acknowledgements stopped; retry in" in d.detail for d in waiting)
    retry = [d for d in decisions if d.send]
    assert len(retry) == 1 and retry[0].t >= t_fail + 2.0 - 1e-9  # one retry
    assert gate.acked == 0


def test_a_late_ack_ends_the_retry_wait():
    gate = SafetyGate(GateConfig(ack_timeout_s=0.5, ack_retry_s=100.0))
    t_sent = first_send(gate)
    gate.sent_command(3, t_sent)
    assert set(reasons(feed(gate, phi_of(dm=0.015), 0.61, 2.0))) == {"ack_missing"}
    gate.acknowledged(3)
    assert gate.decide(2.05, phi_of(dm=0.015)).send


# -- bookkeeping -------------------------------------------------------------------------------
def test_due_follows_the_decision_period():
    gate = SafetyGate(GateConfig(decision_period_s=0.05))
    assert gate.due(0.0)
    gate.decide(1.0, phi_of())
    assert not gate.due(1.04) and gate.due(1.05)


def test_counts_and_summary():
    gate = SafetyGate()
    decisions = feed(gate, phi_of(), 0.0, 0.6)
    gate.sent_command(1, next(d for d in decisions if d.send).t)
    gate.acknowledged(1)
    gate.decide(1.0, np.full(10, np.nan))
    gate.decide(1.1, Payload("x", 3.5, P.com, P.inertia).to_phi())
    gate.decide(1.2, phi_of(dcom=(0.0, 0.0, 0.2)))
    s = gate.summary()
    assert set(s) == {"decisions", "sent", "acked", "rejected"}
    assert set(s["decisions"]) <= set(REASONS)
    assert s["decisions"]["send"] == 1 and s["decisions"]["unstable"] >= 1
    assert (s["sent"], s["acked"], s["rejected"]) == (1, 1, 3)
    assert sum(s["decisions"].values()) == sum(gate.counts.values())
    assert sum(s["decisions"].values()) == len(decisions) + 3


def test_a_decision_is_logged_when_its_reason_changes(caplog):
    gate = SafetyGate()
    nan = np.full(10, np.nan)
    with caplog.at_level(logging.DEBUG, logger="iem.gate"):
        for t in (0.0, 0.1, 0.2):
            gate.decide(t, nan)
        gate.decide(0.3, Payload("x", 3.5, P.com, P.inertia).to_phi())
        gate.decide(0.4, nan)
        feed(gate, phi_of(), 1.0, 1.3)  # unstable (not watched long enough), at DEBUG
    records = [r for r in caplog.records if r.name == "iem.gate"]
    assert [r.reason for r in records] == ["not_finite", "over_rated", "not_finite", "unstable"]
    assert all(r.event == "gate" for r in records)
    assert records[0].levelno == logging.INFO and records[-1].levelno == logging.DEBUG
    assert "rated 3 kg" in records[1].getMessage() and records[1].detail
