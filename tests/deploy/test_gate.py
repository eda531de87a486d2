"""The safety gate: every refusal reason, on hand-made estimates with an explicit clock."""

import logging
import math
from functools import partial

import numpy as np
import pytest

from deploy.gate import REASONS, Decision, GateConfig, SafetyGate
from deploy.gate_checks import com_2sigma
from iem.types import PayloadEstimate
from sim.family import test_payloads
from sim.payload import Payload

Config = partial(GateConfig, allow_without_uncertainty=True)
"""These tests are about the gate's own logic (checks of the load, stability, rate, acks,
refusals, the wire, the model's figures where given) and often give no raw estimate: they
allow that. The contract that fails closed without it is tests/deploy/test_gate_contract.py's."""

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
    gate = SafetyGate(Config())
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
    decision = SafetyGate(Config()).decide(1.0, bad)
    assert decision.reason == "not_finite" and not decision.send and decision.payload is None


def test_inconsistent_mass_inertia_and_triangle_inequality():
    gate = SafetyGate(Config())
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
    d = SafetyGate(Config()).decide(0.0, heavy)
    assert d.reason == "over_rated" and "3.500 kg > rated 3 kg" in d.detail
    assert SafetyGate(Config(rated_mass_kg=3.0)).decide(0.0, phi_of()).reason != "over_rated"


def test_com_too_far_from_the_flange():
    far = phi_of(dcom=(0.0, 0.0, 0.2 - P.com[2]))
    d = SafetyGate(Config()).decide(0.0, far)
    assert d.reason == "com_too_far" and "> 0.15 m" in d.detail
    d = SafetyGate(Config(max_com_radius_m=0.25)).decide(0.0, far)
    assert d.reason != "com_too_far"


def test_physical_refusals_come_before_the_stream_conditions():
    gate = SafetyGate(Config())
    gate.controller_silent(True)
    assert gate.decide(0.0, np.full(10, np.nan)).reason == "not_finite"
    assert gate.decide(0.1, phi_of()).reason == "controller_silent"


def test_non_finite_estimates_are_not_watched():
    gate = SafetyGate(Config())
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
    gate = SafetyGate(Config())
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
    gate = SafetyGate(Config())
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
    gate = SafetyGate(Config(max_rate_hz=rate))
    t_sent = first_send(gate)
    decisions = feed(gate, phi_of(dm=0.015), 0.61, 2.0)
    sends = [d for d in decisions if d.send]
    early = [d for d in decisions if d.t < t_sent + 1.0 / rate - 1e-9]
    assert set(reasons(early)) == {"rate_limited"}
    assert sends and sends[0].t >= t_sent + 1.0 / rate - 1e-9
    assert "rate_limited" not in reasons(decisions[decisions.index(sends[0]):])


# -- the controller: silence, acknowledgements -----------------------------------------------
def test_silent_controller_stops_sends_and_they_resume():
    gate = SafetyGate(Config())
    first_send(gate)
    gate.controller_silent(True)
    silent = feed(gate, phi_of(dm=0.05), 0.61, 2.5)
    assert set(reasons(silent)) == {"controller_silent"}
    assert "no joint state" in silent[0].detail
    gate.controller_silent(False)
    after = feed(gate, phi_of(dm=0.05), 2.51, 2.6)
    assert after[0].send  # stable, changed and more than 1 s after the last write


def test_unacknowledged_write_stops_sends_until_the_ack_arrives():
    gate = SafetyGate(Config())
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
    config = Config(ack_timeout_s=0.5, ack_retry_s=2.0)
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
    gate = SafetyGate(Config(ack_timeout_s=0.5, ack_retry_s=100.0))
    t_sent = first_send(gate)
    gate.sent_command(3, t_sent)
    assert set(reasons(feed(gate, phi_of(dm=0.015), 0.61, 2.0))) == {"ack_missing"}
    gate.acknowledged(3)
    assert gate.decide(2.05, phi_of(dm=0.015)).send


# -- bookkeeping -------------------------------------------------------------------------------
def test_due_follows_the_decision_period():
    gate = SafetyGate(Config(decision_period_s=0.05))
    assert gate.due(0.0)
    gate.decide(1.0, phi_of())
    assert not gate.due(1.04) and gate.due(1.05)


def test_counts_and_summary():
    gate = SafetyGate(Config())
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
    gate = SafetyGate(Config())
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


# -- the wire ------------------------------------------------------------------------------------
BAR = Payload("bar", 2.5, (0.0, 0.0, 0.05), (0.6, 0.0, 0.0, 0.001, 0.0, 0.6))
"""A 2.5 kg bar 1.7 m long: physically possible, within the rating and reach, but Ixx 0.6
kg·m² is beyond the CAN signal's range (±0.524 kg·m²)."""


def wire_gate(profile: str = "fd", **config) -> SafetyGate:

    from firmware_bridge.protocol import payload_wire_error

    return SafetyGate(Config(**config), wire_check=partial(payload_wire_error,
                                                                profile=profile))


@pytest.mark.parametrize("profile", ["fd", "classic"])
def test_a_load_the_wire_cannot_carry_is_refused_counted_and_logged(profile, caplog):
    assert BAR.is_consistent()
    gate = wire_gate(profile)
    with caplog.at_level(logging.INFO, logger="iem.gate"):
        decisions = feed(gate, BAR.to_phi(), 0.0, 1.0)
    assert set(reasons(decisions)) == {"out_of_wire_range"}
    d = decisions[0]
    assert "Ixx" in d.detail and "0.6" in d.detail and "0.524287" in d.detail
    assert gate.counts["out_of_wire_range"] == len(decisions)
    assert gate.summary()["rejected"] == len(decisions) and gate.last_sent is None
    logged = [r for r in caplog.records if getattr(r, "reason", "") == "out_of_wire_range"]
    assert len(logged) == 1 and logged[0].levelno == logging.INFO  # once, when it began
    # the same bar without a wire check (a link without ranges) would be written
    assert any(d.send for d in feed(SafetyGate(Config()), BAR.to_phi(), 0.0, 1.0))
    # and a load the wire carries passes the check
    assert first_send(wire_gate(profile)) > 0


def test_the_wire_check_agrees_with_cantools_own_encoder():
    """Independent truth: cantools encodes the DBC's LoadCommandFD with its range checks on
    exactly when payload_wire_error finds nothing to say."""
    from cantools.database.errors import EncodeError as CantoolsEncodeError

    from firmware_bridge.protocol import PAYLOAD_FIELDS, database, payload_wire_error

    message = database().get_message_by_name("LoadCommandFD")
    rng = np.random.default_rng(3)
    for _ in range(300):
        mass = float(rng.uniform(0.0, 15.0))
        com = rng.uniform(-1.5, 1.5, 3)
        inertia = rng.uniform(-0.7, 0.7, 6)
        load = Payload("x", mass, tuple(com), tuple(inertia))
        values = dict(zip(PAYLOAD_FIELDS, (mass, *com, *inertia), strict=True))
        signals = {**values, "Seq": 1, "E2E_CRC": 0, "E2E_Counter": 0}
        signals = {s.name: signals.get(s.name, 0) for s in message.signals}
        try:
            message.encode(signals, strict=True)
            fits = True
        except (CantoolsEncodeError, ValueError):
            fits = False
        error = payload_wire_error(load, "fd")
        if round(mass / 1e-4) == 0:  # 0 on the wire means "no load": refused, valid in DBC
            assert error is not None and "rounds to 0" in error
            continue
        assert (error is None) == fits, (values, error)


# -- the model's own figures: uncertainty and agreement ------------------------------------------
def estimate(std_mass: float | None = None, nis: float | None = None):
    from iem.types import PayloadEstimate

    std = None if std_mass is None else np.r_[std_mass, np.full(9, 1e-4)]
    return PayloadEstimate(t=0.0, phi=phi_of(), std=std, nis=math.nan if nis is None else nis,
                           ood=False)


def feed_with(gate: SafetyGate, est, t0: float, t1: float) -> list:
    decisions = []
    for k in range(round((t1 - t0) / DT) + 1):
        t = round(t0 + k * DT, 9)
        gate.observe(t, phi_of(), est)
        if gate.due(t):
            decisions.append(gate.decide(t, phi_of()))
    return decisions


def test_a_wide_two_sigma_band_on_the_mass_holds_writes_back():
    gate = SafetyGate(Config())
    wide = feed_with(gate, estimate(std_mass=0.011), 0.0, 1.0)  # 2 sigma = 0.022 kg > 0.02
    assert set(reasons(wide)) == {"uncertain"}
    assert "2-sigma band on the mass 0.022 kg > 0.02 kg" in wide[0].detail
    narrow = feed_with(gate, estimate(std_mass=0.009), 1.01, 1.2)  # 0.018 kg: written
    assert narrow[0].send
    # the limit is the configured one; a NaN std is no band at all
    loose = SafetyGate(Config(max_mass_2sigma_kg=0.05))
    assert any(d.send for d in feed_with(loose, estimate(std_mass=0.011), 0.0, 1.0))
    assert set(reasons(feed_with(SafetyGate(Config()), estimate(std_mass=math.nan), 0.0, 1.0))) == {
        "uncertain"}


def test_a_wide_two_sigma_radius_of_the_com_holds_writes_back():
    """A load whose CoM the model itself cannot place within max_com_2sigma_m is not written
    (the mass's band alone let through a load 5 mm off on a faulty stream)."""
    from iem.types import PayloadEstimate

    phi = phi_of()

    def est(std_mr: float) -> PayloadEstimate:  # std of each m·r_i, kg·m; mass std small
        return PayloadEstimate(t=0.0, phi=phi, std=np.r_[0.001, np.full(3, std_mr),
                                                         np.full(6, 1e-4)])

    # radius 2 * sqrt(3 * std_mr² + |r|² std_m²) / m: about 6.9 mm for 0.0032 kg·m
    gate = SafetyGate(Config())
    wide = feed_with(gate, est(0.0032), 0.0, 1.0)
    assert set(reasons(wide)) == {"uncertain"}
    assert "2-sigma radius of the CoM" in wide[0].detail and "> 5 mm" in wide[0].detail
    narrow = feed_with(gate, est(0.001), 1.01, 1.2)  # about 2.2 mm: written
    assert narrow[0].send
    assert any(d.send for d in feed_with(SafetyGate(Config(max_com_2sigma_m=0.01)),
                                         est(0.0032), 0.0, 1.0))
    # the radius is the docstring's formula, from the payload's own mass and CoM
    r2 = float(np.dot(P.com, P.com))
    expected = 2.0 * math.sqrt(3 * 0.0032**2 + r2 * 0.001**2) / P.mass
    assert com_2sigma(phi, est(0.0032).std) == pytest.approx(expected, rel=1e-9)
    assert 0.0064 < expected < 0.0074  # the 6.9 mm the limits above rest on


def test_the_com_two_sigma_radius_matches_sampling():
    """First-order propagation through r = (m r) / m against 200,000 draws of phi."""
    rng = np.random.default_rng(5)
    phi = phi_of()
    std = np.r_[0.02, 0.004, 0.003, 0.006, np.full(6, 1e-4)]
    draws = phi + rng.standard_normal((200_000, 10)) * std
    com = draws[:, 1:4] / draws[:, :1]
    sampled = 2.0 * float(np.sqrt(np.sum(com.var(axis=0))))
    assert com_2sigma(phi, std) == pytest.approx(sampled, rel=0.02)
    assert math.isnan(com_2sigma(np.r_[0.0, phi[1:]], std))  # no mass: no CoM


def test_data_disagreeing_with_the_model_holds_writes_back():
    gate = SafetyGate(Config())
    bad = feed_with(gate, estimate(std_mass=0.001, nis=4.5), 0.0, 1.0)
    assert set(reasons(bad)) == {"data_disagree"}
    assert "normalised innovation squared 4.5" in bad[0].detail and "> 3" in bad[0].detail
    good = feed_with(gate, estimate(std_mass=0.001, nis=1.1), 1.01, 1.2)
    assert good[0].send
    assert any(d.send for d in feed_with(SafetyGate(Config(max_nis=5.0)),
                                         estimate(nis=4.5), 0.0, 1.0))
    # no verdict yet (NaN) does not hold a write back
    assert any(d.send for d in feed_with(SafetyGate(Config()), estimate(nis=math.nan), 0.0, 1.0))


def test_a_model_without_std_or_nis_is_held_back_unless_allowed():
    iem = PayloadEstimate(t=0.0, phi=phi_of(), std=None, nis=None, ood=False)
    assert any(d.send for d in feed_with(SafetyGate(Config()), iem, 0.0, 1.0))
    held = reasons(feed_with(SafetyGate(GateConfig()), iem, 0.0, 1.0))
    assert set(held) == {"unreported"}
    assert first_send(SafetyGate(Config())) > 0  # no raw estimate given at all, allowed


def test_decide_takes_the_raw_estimate_or_the_last_observed_one():
    gate = SafetyGate(Config())
    feed(gate, phi_of(), 0.0, 0.6)  # stable (and written once)
    gate.observe(0.7, phi_of(), estimate(std_mass=0.05))
    assert gate.decide(0.7, phi_of(dm=0.015)).reason == "uncertain"  # the observed one
    assert gate.decide(0.8, phi_of(dm=0.015), estimate(std_mass=0.001)).reason != "uncertain"


# -- refusals by the controller --------------------------------------------------------------------
def until_send(gate: SafetyGate, phi, t0: float, t1: float) -> tuple[list, Decision]:
    """Like :func:`feed`, but stop at the first send; the decisions before it and the send."""
    decisions = []
    for k in range(round((t1 - t0) / DT) + 1):
        t = round(t0 + k * DT, 9)
        gate.observe(t, phi)
        if gate.due(t):
            d = gate.decide(t, phi)
            if d.send:
                return decisions, d
            decisions.append(d)
    raise AssertionError(f"no send in [{t0}, {t1}]: {reasons(decisions)}")


def test_a_refused_load_is_not_the_written_one_and_is_retried_until_acknowledged(caplog):
    gate = SafetyGate(Config(refusal_retry_s=0.5, refusal_retry_max_s=1.0))
    target = phi_of(dm=0.015)
    t1 = first_send(gate)  # the first write, acknowledged: the robot has P
    gate.sent_command(1, t1)
    gate.acknowledged(1)
    written = gate.last_sent
    _, send = until_send(gate, target, 0.61, 2.0)
    gate.sent_command(2, send.t)
    with caplog.at_level(logging.INFO, logger="iem.gate"):
        gate.refused(2, send.t, "command not possible in the current mode")
    assert gate.last_sent is written  # the refused load was not written
    assert gate.refusals == 1
    record = next(r for r in caplog.records if getattr(r, "event", "") == "load_refused")
    assert record.levelno == logging.WARNING and record.seq == 2
    assert "command not possible in the current mode" in record.getMessage()
    assert "retry in 0.5 s" in record.getMessage()
    # it waits refusal_retry_s, then tries the same load again
    wait, retry = until_send(gate, target, send.t + DT, send.t + 2.0)
    assert wait and set(reasons(wait)) == {"refused"}
    assert "refused command 2 (command not possible in the current mode); retry in" in \
        wait[0].detail
    assert retry.t >= send.t + 0.5 - 1e-9 and wait[-1].t < send.t + 0.5
    assert retry.payload.mass == pytest.approx(P.mass + 0.015)
    # refused again: the wait doubles (0.5 -> 1.0 s, the cap)
    gate.sent_command(3, retry.t)
    gate.refused(3, retry.t)
    wait, again = until_send(gate, target, retry.t + DT, retry.t + 3.0)
    assert set(reasons(wait)) == {"refused"}
    assert again.t >= retry.t + 1.0 - 1e-9 and wait[-1].t < retry.t + 1.0
    gate.sent_command(4, again.t)
    gate.refused(4, again.t)  # a third time: still 1.0 s (capped)
    wait, last = until_send(gate, target, again.t + DT, again.t + 3.0)
    assert 1.0 - 1e-9 <= last.t - again.t < 1.0 + 0.05  # 1.0 s, on the decision grid
    # accepted: that load is the written one and the retries stop
    gate.sent_command(5, last.t)
    gate.acknowledged(5)
    assert gate.last_sent is last.payload
    after = feed(gate, target, last.t + DT, last.t + 5.0)
    assert set(reasons(after)) == {"no_change"}
    assert (gate.sent, gate.acked, gate.refusals) == (5, 2, 3)
    # a new refusal streak starts at refusal_retry_s again
    _, nxt = until_send(gate, phi_of(dm=0.04), last.t + 5.0 + DT, last.t + 7.0)
    gate.sent_command(6, nxt.t)
    gate.refused(6, nxt.t)
    assert "retry in 0.5 s" in gate.decide(nxt.t + 0.0001, phi_of(dm=0.04)).detail


def test_the_first_load_refused_leaves_nothing_written_and_is_retried():
    gate = SafetyGate(Config(refusal_retry_s=0.2))
    t = first_send(gate)
    gate.sent_command(9, t)
    gate.refused(9, t)
    assert gate.last_sent is None
    d = feed(gate, phi_of(), t + 0.01, t + 0.5)
    assert reasons(d)[0] == "refused" and any(x.send for x in d)


def test_a_refusal_of_an_older_command_is_counted_but_does_not_undo_the_newer(caplog):
    gate = SafetyGate(Config())
    t = first_send(gate)
    gate.sent_command(1, t)
    with caplog.at_level(logging.WARNING, logger="iem.gate"):
        gate.refused(7, t + 0.01, "stale")
    assert gate.refusals == 1 and gate.last_sent is not None
    assert "retry" not in caplog.records[-1].getMessage()


def test_a_load_the_link_could_not_send_is_not_the_written_one(caplog):
    gate = SafetyGate(Config())
    t = first_send(gate)
    assert gate.last_sent is not None
    with caplog.at_level(logging.ERROR, logger="iem.gate"):
        gate.send_failed("Ixx does not fit")
    assert gate.last_sent is None and gate.send_errors == 1
    assert caplog.records[-1].event == "load_send_failed"
    # no hammering: the next try waits for the rate limit
    assert gate.decide(t + 0.5, phi_of()).reason == "rate_limited"


def test_the_out_of_distribution_reason_names_the_velocity_score():
    from deploy.gate_checks import model_doubt

    est = PayloadEstimate(t=0.0, phi=phi_of(), ood=True,
                          extra={"ood_score": 2.2, "velocity_score": 84.5})
    reason, why = model_doubt(est, Config())
    assert reason == "out_of_distribution" and "84.5" in why and "velocities" in why
