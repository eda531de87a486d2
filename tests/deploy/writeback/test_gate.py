"""The safety gate, fail-closed as a cell runs it: the load in force as its state, writes that
help, the empty load, lost commands, reports, refusals, rate, logging, the wire.

Every test here uses the default configuration (an estimate must report its std, nis and
ood) unless it is about a setting; the estimates are :class:`iem.types.PayloadEstimate` with
a band, as IEM+phys gives them."""

import logging
import math

import numpy as np
import pytest

from deploy.writeback.gate import REASONS, SafetyGate
from deploy.writeback.settings import GateConfig
from deploy.writeback.write_rule import RecentMotion, torque_errors
from firmware_bridge.messages import LoadReport
from iem.types import PayloadEstimate
from sim.family import test_payloads
from sim.payload import Payload

P = test_payloads()["test-3w"]  # 1.615 kg, CoM about 64 mm out, physically consistent
DT = 0.01  # s between block points
STD = np.r_[0.002, np.full(3, 2e-4), np.full(6, 1e-4)]  # a converged IEM+phys band


def phi_of(dm: float = 0.0, dcom=(0.0, 0.0, 0.0), base: Payload = P) -> np.ndarray:
    """``base`` with its mass and CoM moved (inertia about the CoM kept): consistent."""
    com = tuple(c + d for c, d in zip(base.com, dcom, strict=True))
    return Payload("x", base.mass + dm, com, base.inertia).to_phi()


def est(phi, t: float = 0.0, std=STD, nis: float = 1.0, **kw) -> PayloadEstimate:
    return PayloadEstimate(t=t, phi=np.asarray(phi, dtype=float), std=std, nis=nis, ood=False,
                           determined=("mass", "com", "inertia"), **kw)


class Controller:
    """Answers the gate's sends as a controller would: applies each, unless told to lose
    the next ``lose`` commands."""

    def __init__(self, gate: SafetyGate, lose: int = 0) -> None:
        self.gate, self.lose, self.seq, self.applied = gate, lose, 0, []

    def handle(self, decision) -> None:
        if not decision.send:
            return
        self.seq += 1
        self.gate.commands.sent_command(self.seq, decision.payload, decision.t)
        if self.lose:
            self.lose -= 1
            return
        self.applied.append((decision.t, decision.payload))
        self.gate.commands.acknowledged(self.seq, decision.t)


def feed(gate: SafetyGate, phi_at, t0: float, t1: float, controller=None, std=STD, **kw):
    """A block point every DT s in [t0, t1] (``phi_at``: a vector or ``t -> vector``), one
    gate step each; the controller answers sends."""
    decisions = []
    for k in range(round((t1 - t0) / DT) + 1):
        t = round(t0 + k * DT, 9)
        phi = phi_at(t) if callable(phi_at) else phi_at
        d = gate.step(t, phi, est(phi, t, std=std, **kw))
        if d is not None:
            decisions.append(d)
            if controller is not None:
                controller.handle(d)
    return decisions


def report(gate: SafetyGate, r: LoadReport, t: float) -> None:
    """The controller's own report of the load in force, as the load writer passes it on."""
    gate.commands.report(r.seq, r.load, r.has_values, t, r.t)


def reasons(decisions) -> list[str]:
    return [d.reason for d in decisions]


# -- a payload mounted, written once, kept -----------------------------------------------------
def test_a_stable_estimate_far_from_the_empty_load_is_written_once_and_kept():
    gate = SafetyGate()
    ctl = Controller(gate)
    decisions = feed(gate, phi_of(), 0.0, 5.0, ctl)
    before = [d for d in decisions if d.t < 0.45]
    assert before and set(reasons(before)) == {"unstable"}
    sends = [d for d in decisions if d.send]
    assert len(sends) == 1 and sends[0].t >= 0.45 * 0.999
    assert sends[0].payload.mass == pytest.approx(P.mass)
    assert gate.in_force.mass == pytest.approx(P.mass)
    after = reasons(decisions[decisions.index(sends[0]) + 1:])
    assert set(after) == {"no_change"}  # within its own band: holding is right
    s = gate.summary()
    assert (s["sent"], s["acked"], s["lost"], s["in_force"]) == (1, 1, 0, 1)


def test_a_small_drift_inside_the_band_is_not_written_a_large_one_is():
    gate = SafetyGate()
    ctl = Controller(gate)
    feed(gate, phi_of(), 0.0, 2.0, ctl)
    assert len(ctl.applied) == 1
    feed(gate, phi_of(dm=0.002), 2.0, 4.0, ctl)  # inside 2 sigma (0.004 kg)
    assert len(ctl.applied) == 1
    feed(gate, phi_of(dm=0.05), 4.0, 7.0, ctl)  # 0.05 kg: ~0.4 N·m at the reach
    assert len(ctl.applied) == 2 and ctl.applied[-1][1].mass == pytest.approx(P.mass + 0.05)


def test_the_bare_arm_with_the_controller_at_zero_is_never_written():
    gate = SafetyGate()
    ctl = Controller(gate)
    wide = np.r_[0.04, np.full(3, 0.004), np.full(6, 0.002)]  # a real arm's band
    bare = np.r_[0.01, 0.0002, -0.0001, 0.0003, np.zeros(6)]
    decisions = feed(gate, bare, 0.0, 10.0, ctl, std=wide)
    assert not ctl.applied and "send" not in reasons(decisions)
    assert gate.in_force is None


def test_a_wide_band_is_written_when_the_write_still_halves_the_error():
    """The real recording's case: 1.63 +- 0.08 kg against 0 kg in force."""
    wide = np.r_[0.04, np.full(3, 0.004), np.full(6, 0.002)]
    gate = SafetyGate()
    ctl = Controller(gate)
    feed(gate, phi_of(), 0.0, 3.0, ctl, std=wide)
    assert len(ctl.applied) == 1
    # a band as wide as the payload itself: not sure to help
    gate = SafetyGate()
    huge = np.r_[0.6, np.full(3, 0.05), np.full(6, 0.002)]
    decisions = feed(gate, phi_of(), 0.0, 3.0, Controller(gate), std=huge)
    assert "send" not in reasons(decisions) and decisions[-1].reason == "uncertain"
    assert "could err by" in decisions[-1].detail


def test_the_torque_bound_along_the_motion_matches_a_direct_computation():
    """Independent truth: the bound from Pinocchio's payload regressor at each pose,
    computed here joint by joint."""
    from sim.robot import ArmModel

    model = ArmModel()
    rng = np.random.default_rng(0)
    motion = RecentMotion(lambda q, dq: model.payload_regressor(q, dq, np.zeros(7)))
    poses = [(model.random_state(rng)[0], rng.normal(0, 0.3, 7)) for _ in range(5)]
    for k, (q, dq) in enumerate(poses):
        motion.observe(0.2 * k, q, dq)
    have, cand, phi = np.zeros(10), phi_of(), phi_of(dm=0.01)
    band = 2 * STD
    hold, write = torque_errors(motion, have, cand, phi, band, 0.855)
    want_hold = max(max(abs(Y @ (have - phi)) - abs(Y) @ band)
                    for Y in (model.payload_regressor(q, dq, np.zeros(7)) for q, dq in poses))
    want_write = max(max(abs(Y @ (cand - phi)) + abs(Y) @ band)
                     for Y in (model.payload_regressor(q, dq, np.zeros(7)) for q, dq in poses))
    assert hold == pytest.approx(want_hold) and write == pytest.approx(want_write)
    assert hold > 10 * write > 0


# -- the empty load ---------------------------------------------------------------------------
def test_a_removed_tool_is_cleared_with_the_empty_load():
    gate = SafetyGate()
    ctl = Controller(gate)
    feed(gate, phi_of(), 0.0, 2.0, ctl)
    assert gate.in_force is not None
    bare = np.r_[-0.004, 0.0001, 0.0, -0.0002, np.zeros(6)]  # inconsistent: negative mass
    decisions = feed(gate, bare, 2.0, 5.0, ctl)
    sends = [d for d in decisions if d.send]
    assert len(sends) == 1 and sends[0].payload is None and "empty load" in sends[0].detail
    assert sends[0].t - 2.0 < 1.5 and gate.in_force is None
    assert ctl.applied[-1][1] is None


def test_a_swap_to_another_tool_reaches_the_controller():
    other = test_payloads()["test-2w"]
    gate = SafetyGate()
    ctl = Controller(gate)
    feed(gate, phi_of(), 0.0, 2.0, ctl)
    feed(gate, other.to_phi(), 2.0, 4.0, ctl)
    assert gate.in_force.mass == pytest.approx(other.mass) and len(ctl.applied) == 2


def test_no_payload_needs_the_upper_bound_below_the_threshold_for_the_whole_window():
    gate = SafetyGate()
    ctl = Controller(gate)
    feed(gate, phi_of(), 0.0, 2.0, ctl)
    light = Payload("light", 0.2, (0.0, 0.0, 0.03), (1e-4, 0, 0, 1e-4, 0, 1e-4)).to_phi()
    decisions = feed(gate, light, 2.0, 4.0, ctl)  # 0.2 kg: a payload, not none
    assert gate.in_force.mass == pytest.approx(0.2)
    assert all(d.payload is not None for d in decisions if d.send)


WIDE = np.r_[0.11, np.full(3, 0.01), np.full(6, 0.002)]
"""The band of a model trained for an uncalibrated arm (noise "arm", no arm file)."""


def test_a_removed_tool_is_cleared_by_the_write_rule_whatever_the_band():
    """After the removal the estimate reads 0.015 +- 0.22 kg (2 sigma), its CoM 0.18 m out
    (a CoM no near-zero mass determines): the empty load is written within the stability
    window, where a fixed threshold of the upper bound (0.2 kg) never let it, and no CoM
    check refuses it."""
    gate = SafetyGate()
    ctl = Controller(gate)
    feed(gate, phi_of(), 0.0, 2.0, ctl, std=WIDE)
    assert gate.in_force.mass == pytest.approx(P.mass)
    removed = np.r_[0.015, 0.015 * np.array([0.05, 0.05, 0.17]), np.zeros(6)]
    decisions = feed(gate, removed, 2.0, 5.0, ctl, std=WIDE)
    sends = [d for d in decisions if d.send]
    assert len(sends) == 1 and sends[0].payload is None and gate.in_force is None
    assert sends[0].t - 2.0 <= GateConfig().stable_window_s + 0.1
    assert "com_too_far" not in reasons(decisions)
    assert set(reasons(decisions[decisions.index(sends[0]) + 1:])) == {"no_change"}


def test_the_empty_load_is_written_only_when_it_helps():
    """A 0.1 kg load in force and an estimate of 0.02 +- 0.22 kg: the empty load would not
    surely cut the joint-torque error; held with the write rule's reason."""
    gate = SafetyGate()
    ctl = Controller(gate)
    small = Payload("small", 0.1, (0.0, 0.0, 0.02), (1e-4, 0, 0, 1e-4, 0, 1e-4))
    gate.commands.sent_command(1, small, 0.0)
    gate.commands.acknowledged(1, 0.0)
    near = np.r_[0.02, 0.0, 0.0, 0.0004, np.zeros(6)]
    decisions = feed(gate, near, 0.0, 3.0, ctl, std=WIDE)
    assert not ctl.applied and gate.in_force.mass == pytest.approx(0.1)
    assert decisions[-1].reason in ("no_change", "uncertain")


def test_a_mass_below_zero_is_judged_as_the_empty_load():
    """A bare arm through a wrong end effector reads -0.7 +- 0.004 kg: no possible body; the
    empty load, the possible load nearest to it, is the candidate: written while 1.615 kg
    is in force (it surely cuts the error), then held (it is in force)."""
    gate = SafetyGate()
    ctl = Controller(gate)
    feed(gate, phi_of(), 0.0, 2.0, ctl)
    wrong = np.r_[-0.7, 0.0, 0.0, -0.01, np.zeros(6)]
    decisions = feed(gate, wrong, 2.0, 5.0, ctl)
    assert [p for _, p in ctl.applied][1:] == [None] and gate.in_force is None
    assert set(reasons(decisions)) <= {"inconsistent", "send", "no_change"}
    assert decisions[-1].reason == "no_change"


def test_a_fixed_empty_mass_threshold_is_no_setting_any_more():
    from deploy.config import ConfigError, config_from_dict

    with pytest.raises(ConfigError, match=r"empty_mass_kg: not a setting of this gate: the "
                                          r"empty load is judged as every write is"):
        config_from_dict({"gate": {"empty_mass_kg": 0.2}}, where="cell.toml")


def test_a_mass_is_told_from_zero_by_its_band():
    from deploy.writeback import excludes_zero

    assert excludes_zero(1.615, 0.11) and not excludes_zero(0.015, 0.11)
    assert not excludes_zero(-0.7, 0.002)  # below zero: no body either
    assert excludes_zero(0.3, None) and not excludes_zero(0.0, None)  # no band: the mass
    assert not excludes_zero(1.0, math.inf) and not excludes_zero(1.0, math.nan)


def test_a_silence_is_the_hold_reason_for_as_long_as_it_lasts():
    gate = SafetyGate()
    ctl = Controller(gate)
    feed(gate, phi_of(), 0.0, 1.0, ctl)
    gate.controller_silent(True)
    silent = [gate.step(1.0 + 0.1 * k) for k in range(1, 31)]  # 3 s of silence ticks
    assert {d.reason for d in silent if d is not None} == {"controller_silent"}
    assert sum(d is not None for d in silent) == 30


# -- commands lost, refused, reported -------------------------------------------------------------
def test_a_lost_command_is_retried_with_an_unchanged_estimate():
    gate = SafetyGate()
    ctl = Controller(gate, lose=1)
    decisions = feed(gate, phi_of(), 0.0, 4.0, ctl)
    assert "lost" in reasons(decisions)
    sends = [d for d in decisions if d.send]
    assert len(sends) == 2 and gate.in_force.mass == pytest.approx(P.mass)
    s = gate.summary()
    assert (s["sent"], s["acked"], s["lost"], s["in_force"]) == (2, 1, 1, 1)


def test_three_lost_commands_back_off_and_still_land_within_ten_seconds():
    gate = SafetyGate()
    ctl = Controller(gate, lose=3)
    decisions = feed(gate, phi_of(), 0.0, 10.0, ctl)
    sends = [d.t for d in decisions if d.send]
    assert len(sends) == 4 and gate.summary()["lost"] == 3
    gaps = np.diff(sends)
    assert (np.diff(gaps) > 0).all()  # the waits grow
    assert gate.in_force is not None and sends[-1] < 10.0


def test_an_ack_lost_but_the_command_reported_in_force_settles_it():
    gate = SafetyGate()
    ctl = Controller(gate, lose=1)
    feed(gate, phi_of(), 0.0, 0.6, ctl)
    assert gate.commands.pending is not None
    report(gate, LoadReport(t=0.0, seq=ctl.seq, load=None, has_values=False), 0.62)
    assert gate.commands.pending is None and gate.in_force.mass == pytest.approx(P.mass)
    assert gate.summary()["lost"] == 0


def test_a_report_that_disagrees_is_logged_and_written_again(caplog):
    gate = SafetyGate()
    ctl = Controller(gate)
    feed(gate, phi_of(), 0.0, 2.0, ctl)
    with caplog.at_level(logging.WARNING, logger="iem.gate"):  # someone else set 0 kg
        report(gate, LoadReport(t=0.0, seq=None, load=None, has_values=True), 2.0)
    assert gate.in_force is None and "believed" in caplog.text
    feed(gate, phi_of(), 2.0, 4.0, ctl)
    assert len(ctl.applied) == 2 and gate.summary()["mismatches"] == 1


def test_a_refused_load_keeps_the_old_one_and_is_retried_with_back_off():
    gate = SafetyGate()
    seq = 0
    times = []
    for k in range(600):
        t = round(k * DT, 9)
        d = gate.step(t, phi_of(), est(phi_of(), t))
        if d is not None and d.send:
            seq += 1
            times.append(t)
            gate.commands.sent_command(seq, d.payload, t)
            if seq < 3:
                gate.commands.refused_command(seq, t + 0.01,
                                              "command not possible in the current mode")
            else:
                gate.commands.acknowledged(seq, t + 0.01)
    assert len(times) == 3 and gate.commands.refused == 2 and gate.in_force is not None
    assert times[2] - times[1] > times[1] - times[0] - 0.06  # doubled wait


@pytest.mark.parametrize("answer", ["refused", "lost"])
def test_a_refused_write_is_retried_at_its_back_off_not_the_rate_limit(answer):
    """A refused write changed nothing: its retry waits the refusal's back-off (0.25 s),
    not the rate limit (1 write a second). A lost one may have been applied: the rate limit
    still counts it (and its own back-off, 0.5 s, is shorter)."""
    gate = SafetyGate(GateConfig(refusal_retry_s=0.25, refusal_retry_max_s=0.25,
                                 ack_timeout_s=0.05, ack_retry_s=0.5, max_rate_hz=1.0))
    seq, times = 0, []
    for k in range(round(2.0 / DT)):
        t = round(k * DT, 9)
        gate.commands.tick(t)
        d = gate.step(t, phi_of(), est(phi_of(), t))
        if d is not None and d.send:
            seq += 1
            times.append(t)
            gate.commands.sent_command(seq, d.payload, t)
            if answer == "refused":
                gate.commands.refused_command(seq, t + 0.01, "the arm moves")
    gaps = np.diff(times)
    assert len(gaps) >= 1
    if answer == "refused":
        assert len(times) >= 4 and np.all(gaps < 0.5), times  # every back-off, 0.25 s
    else:
        assert np.all(gaps >= 1.0), times  # the rate limit, not the 0.5 s back-off


@pytest.mark.parametrize("error", ["EncodeError: Ixx does not fit", "LinkError: bus-off"])
def test_a_send_error_is_survived_and_retried(error):
    gate = SafetyGate()
    decisions = []
    for k in range(300):
        t = round(k * DT, 9)
        d = gate.step(t, phi_of(), est(phi_of(), t))
        if d is not None:
            decisions.append(d)
            if d.send:
                gate.commands.send_failed(t, error)
    assert gate.commands.send_errors >= 2 and gate.in_force is None
    assert "lost" in reasons(decisions)


def test_silence_stops_writes():
    gate = SafetyGate()
    gate.controller_silent(True)
    decisions = feed(gate, phi_of(), 0.0, 2.0)
    assert set(reasons(decisions)) == {"controller_silent"}


# -- stability, rate, settings ------------------------------------------------------------------
def test_stability_has_hysteresis():
    """Stable once the spread is within the band; unstable again only beyond twice it. A
    wobble of 1.5 bands keeps a stable estimate stable and a fresh one unstable; 2.5 bands
    is unstable."""
    band = 0.02

    def wobble(bands: float):
        return lambda t: phi_of(dm=bands * band / 2 * math.sin(40 * t))  # spread: bands x band

    gate = SafetyGate(GateConfig(stable_mass_kg=band))
    ctl = Controller(gate)
    steady = reasons(feed(gate, phi_of(), 0.0, 1.0, ctl))
    assert steady[0] == "unstable" and "send" in steady and steady[-1] == "no_change"
    within = reasons(feed(gate, wobble(1.5), 1.0, 3.0, ctl))
    assert within and "unstable" not in within
    beyond = reasons(feed(gate, wobble(2.5), 3.0, 5.0, ctl))
    assert "unstable" in beyond and beyond[-1] == "unstable"
    fresh = SafetyGate(GateConfig(stable_mass_kg=band))
    assert set(reasons(feed(fresh, wobble(1.5), 0.0, 2.0, Controller(fresh)))) == {"unstable"}


def test_a_due_decision_waits_up_to_three_busy_steps():
    """While the model does heavy work the decision waits, at most three steps."""
    gate = SafetyGate()
    phi = phi_of()
    assert gate.step(0.0, phi, est(phi, 0.0), busy=True) is None
    assert gate.step(0.01, phi, est(phi, 0.01), busy=True) is None
    assert gate.step(0.02, phi, est(phi, 0.02), busy=True) is None
    assert gate.step(0.03, phi, est(phi, 0.03), busy=True) is not None
    assert gate.step(0.04, phi, est(phi, 0.04)) is None  # not due: 10 ms since
    assert gate.step(0.08, phi, est(phi, 0.08)) is not None


def test_rate_limit_between_writes():
    gate = SafetyGate(GateConfig(max_rate_hz=0.5))
    ctl = Controller(gate)
    feed(gate, phi_of(), 0.0, 1.0, ctl)
    decisions = feed(gate, phi_of(dm=0.2), 1.0, 2.4, ctl)
    assert "rate_limited" in reasons(decisions)


@pytest.mark.parametrize("bad", [{"stable_window_s": 0.0}, {"max_rate_hz": 0.0},
                                 {"write_margin": 2.0}, {"ack_retry_max_s": 0.1},
                                 {"allow_without_uncertainty": 1}])
def test_a_gate_config_built_in_code_checks_itself(bad):
    from iem.errors import InvalidInputError

    with pytest.raises(InvalidInputError, match="valid"):
        GateConfig(**bad)


def test_the_rating_counts_the_end_effector():
    gate = SafetyGate(GateConfig(end_effector_mass_kg=0.76))
    d = gate.step(0.0, Payload("x", 2.5, P.com, P.inertia).to_phi(), est(phi_of()))
    assert d.reason == "over_rated" and "end effector 0.760 kg" in d.detail
    assert SafetyGate().step(0.0, Payload("x", 2.5, P.com, P.inertia).to_phi(),
                             est(phi_of())).reason != "over_rated"


# -- what a user sees ----------------------------------------------------------------------------
def test_holding_is_logged_at_info_at_most_once_per_ten_seconds(caplog):
    gate = SafetyGate()
    huge = np.r_[0.6, np.full(3, 0.05), np.full(6, 0.002)]
    with caplog.at_level(logging.INFO, logger="iem.gate"):
        feed(gate, phi_of(), 0.0, 25.0, std=huge)
    infos = [r for r in caplog.records if r.levelno == logging.INFO]
    assert 2 <= len(infos) <= 3
    assert any("holding: uncertain" in r.getMessage() and "2-sigma mass 1.200 kg"
               in r.getMessage() for r in infos)


def test_verdict_and_summary_say_the_load_in_force():
    gate = SafetyGate()
    ctl = Controller(gate)
    feed(gate, phi_of(), 0.0, 2.0, ctl)
    v = gate.verdict()
    assert v["reason"] == "no_change" and v["load_in_force"]["mass"] == pytest.approx(P.mass)
    assert (v["sent"], v["acked"], v["lost"], v["in_force"]) == (1, 1, 0, 1)
    assert set(gate.summary()["decisions"]) <= set(REASONS)


# -- the wire ------------------------------------------------------------------------------------
BAR = Payload("bar", 2.0, (0.0, 0.0, 0.05), (0.6, 0.0, 0.0, 0.001, 0.0, 0.6))
"""A 2 kg bar 1.9 m long: physically possible, within the rating and reach, but Ixx 0.6
kg·m² is beyond the CAN signal's range (±0.524 kg·m²)."""


@pytest.mark.parametrize("profile", ["fd", "classic"])
def test_a_load_the_wire_cannot_carry_is_refused(profile):
    from firmware_bridge.load_range import of_profile

    assert BAR.is_consistent()
    gate = SafetyGate(wire_check=of_profile(profile).error)
    decisions = feed(gate, BAR.to_phi(), 0.0, 1.0)
    assert set(reasons(decisions)) == {"out_of_wire_range"}
    assert "Ixx" in decisions[0].detail and "0.524287" in decisions[0].detail
    assert gate.summary()["rejected"] == len(decisions)


def test_the_wire_check_agrees_with_cantools_own_encoder():
    """Independent truth: cantools encodes the DBC's LoadCommandFD with its range checks on
    exactly when the profile's wire range finds nothing to say."""
    from cantools.database.errors import EncodeError as CantoolsEncodeError

    from firmware_bridge.load_range import of_profile
    from firmware_bridge.protocol import PAYLOAD_FIELDS, database

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
        error = of_profile("fd").error(load)
        if round(mass / 1e-4) == 0:  # 0 on the wire means "no load": refused, valid in DBC
            assert error is not None and "rounds to 0" in error
            continue
        assert (error is None) == fits, (values, error)


# -- the estimate's covariance, the prior, an old report ---------------------------------------
def test_with_a_covariance_the_band_is_the_torques_own_two_sigma():
    """Independent truth: the torque's 2-sigma from sampling the estimate's covariance."""
    from sim.robot import ArmModel

    model = ArmModel()
    rng = np.random.default_rng(1)
    motion = RecentMotion(lambda q, dq: model.payload_regressor(q, dq, np.zeros(7)))
    q = model.random_state(rng)[0]
    motion.observe(0.0, q, np.zeros(7))
    A = rng.normal(size=(10, 10)) * 1e-3
    cov = A @ A.T
    phi = phi_of()
    _, write = torque_errors(motion, np.zeros(10), phi, phi, 2 * np.sqrt(np.diag(cov)), 0.855,
                             cov)
    Y = model.payload_regressor(q, np.zeros(7), np.zeros(7))
    samples = rng.multivariate_normal(np.zeros(10), cov, 200_000) @ Y.T
    assert write == pytest.approx(2 * samples.std(axis=0).max(), rel=0.01)
    _, worst = torque_errors(motion, np.zeros(10), phi, phi, 2 * np.sqrt(np.diag(cov)), 0.855)
    assert worst >= write  # without correlations: the worst case


def test_an_estimate_the_data_do_not_determine_is_not_written():
    gate = SafetyGate()
    decisions = []
    for k in range(200):
        t = round(k * DT, 9)
        e = PayloadEstimate(t=t, phi=phi_of(), std=STD, nis=1.0, ood=False,
                            determined=("inertia",))
        d = gate.step(t, phi_of(), e)
        if d is not None:
            decisions.append(d)
    assert "send" not in reasons(decisions)
    assert "the prior's guess" in decisions[-1].detail


def test_a_report_taken_before_the_ack_is_passed_over():
    """A heartbeat on its way when the controller acknowledged names the old command."""
    gate = SafetyGate()
    feed(gate, phi_of(), 0.0, 0.6)
    gate.commands.sent_command(1, gate.sent_loads[-1][1], 0.6)
    gate.commands.acknowledged(1, 0.62, received=10.0)
    report(gate, LoadReport(t=9.9, seq=0, load=None, has_values=False), 0.63)
    assert gate.in_force.mass == pytest.approx(P.mass) and gate.summary()["mismatches"] == 0
    report(gate, LoadReport(t=10.1, seq=0, load=None, has_values=False), 0.7)
    assert gate.summary()["mismatches"] == 1  # newer than the ack: the controller says so
