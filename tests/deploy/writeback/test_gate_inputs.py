"""No input fools the gate: a controller's restart and a clock that jumps, a covariance that
lies, an absurd inertia, an estimate of any shape, a controller that disagrees forever, and
answers to commands it never got.

Every test drives the gate through its one step (:meth:`deploy.writeback.gate.SafetyGate.step`) and
the load in force as the load writer tells it."""

from __future__ import annotations

import logging
import math

import numpy as np
import pytest

from deploy.writeback import checks as gate_checks
from deploy.writeback.gate import GateConfig, SafetyGate
from firmware_bridge.messages import LoadReport
from iem.types import PayloadEstimate
from sim.family import test_payloads
from sim.payload import Payload

P = test_payloads()["test-3w"]  # 1.615 kg, CoM about 64 mm out
B = Payload("tool-b", 2.0, (0.0, 0.01, 0.05), (0.004, 0.0, 0.0, 0.004, 0.0, 0.003))
DT = 0.01
STD = np.r_[0.002, np.full(3, 2e-4), np.full(6, 1e-4)]
WINDOW = GateConfig().stable_window_s


def est(phi, t, std=STD, **kw) -> PayloadEstimate:
    fields = {"nis": 1.0, "ood": False, "determined": ("mass", "com", "inertia"), **kw}
    return PayloadEstimate(t=t, phi=np.asarray(phi, dtype=float), std=std, **fields)


class Controller:
    """Applies and acknowledges every load the gate sends, as the load writer tells it."""

    def __init__(self, gate: SafetyGate) -> None:
        self.gate, self.seq, self.applied = gate, 0, []

    def handle(self, d) -> None:
        if d is None or not d.send:
            return
        self.seq += 1
        self.gate.commands.sent_command(self.seq, d.payload, d.t)
        self.gate.commands.acknowledged(self.seq, d.t)  # at once: the time is not read
        self.applied.append((d.t, d.payload))


def run(gate, ctl, points):
    """``points``: ``(gate time, phi, estimate)``; one step each; the decisions."""
    out = []
    for t, phi, e in points:
        d = gate.step(t, phi, e)
        if d is not None:
            out.append(d)
            ctl.handle(d)
    return out


def stream(payload, t0, t1, clock=lambda te: te, **kw):
    """A point every DT s of controller time in [t0, t1): ``(clock(te), phi, estimate)``."""
    phi = payload.to_phi()
    for k in range(round((t1 - t0) / DT)):
        te = t0 + k * DT
        yield clock(te), phi, est(phi, te, **kw)


def first_send(decisions, after: float = -math.inf):
    return next((d for d in decisions if d.send and d.t >= after), None)


# -- one clock, restarts and jumps ----------------------------------------------------------
def test_a_controller_restart_stops_writes_no_longer_than_the_stability_window():
    """A live gate (this PC's clock) on a controller that ran 2 h, then restarts at t = 0
    with another tool: the new tool is written within the stability window."""
    gate = SafetyGate()
    ctl = Controller(gate)
    run(gate, ctl, stream(P, 7200.0, 7202.0, clock=lambda te: te - 7200.0))
    assert ctl.applied and ctl.applied[-1][1].mass == pytest.approx(P.mass)
    restart = 2.3  # the gate's clock when the controller is back (0.3 s of silence)
    after = run(gate, ctl, stream(B, 0.0, 3.0, clock=lambda te: te + restart))
    sent = first_send(after)
    assert sent is not None and sent.payload.mass == pytest.approx(B.mass)
    assert sent.t - restart <= WINDOW + 2 * GateConfig().decision_period_s
    assert "stale" not in {d.reason for d in after}


def test_one_estimate_stamped_far_ahead_stops_no_write():
    gate = SafetyGate()
    ctl = Controller(gate)
    phi = P.to_phi()
    points = [(te, phi, est(phi, 1e9 if k == 150 else te))
              for k, te in enumerate(np.arange(0.0, 2.0, DT))]
    run(gate, ctl, points)
    after = run(gate, ctl, stream(B, 2.0, 4.0))
    sent = first_send(after)
    assert sent is not None and sent.payload.mass == pytest.approx(B.mass)
    assert sent.t - 2.0 <= WINDOW + 0.1 and "stale" not in {d.reason for d in after}


@pytest.mark.parametrize("jump", [-7200.0, 1e9])
def test_the_controllers_clock_as_the_gates_jumps_and_decisions_go_on(jump):
    """A replay decides on the controller's clock: its time going back (a restart) or far
    forward never stops the decisions, and the new tool is written within the window."""
    gate = SafetyGate()
    ctl = Controller(gate)
    run(gate, ctl, stream(P, 7200.0, 7202.0))
    after = run(gate, ctl, stream(B, 7202.0 + jump, 7205.0 + jump))
    assert len(after) >= 50  # a decision every 50 ms of the 3 s
    sent = first_send(after)
    assert sent is not None and sent.payload.mass == pytest.approx(B.mass)
    assert sent.t - (7202.0 + jump) <= WINDOW + 0.1


def test_a_clock_jump_is_counted_and_logged_once(caplog):
    gate = SafetyGate()
    ctl = Controller(gate)
    with caplog.at_level(logging.WARNING, logger="iem.gate"):
        run(gate, ctl, stream(P, 7200.0, 7201.0, clock=lambda te: te - 7200.0))
        run(gate, ctl, stream(P, 0.0, 1.0, clock=lambda te: te + 1.0))
    jumps = [r for r in caplog.records if getattr(r, "event", "") == "clock_jump"]
    assert len(jumps) == 1 and "back by 7200.99 s" in jumps[0].getMessage()
    assert gate.summary()["clock_jumps"] == 1


def test_an_estimate_that_stops_advancing_is_stale():
    gate = SafetyGate()
    ctl = Controller(gate)
    phi = P.to_phi()
    stuck = est(phi, 5.0)
    decisions = run(gate, ctl, [(k * DT, phi, stuck) for k in range(200)])
    assert decisions[-1].reason == "stale" and "not advanced" in decisions[-1].detail
    assert all(d.reason != "stale" for d in decisions if d.t < 1.0)


def _gate_over_link_times(times):
    """A live gate stepped once per block of 10 joint states whose controller times the
    link delivered: the test tool P before the time goes back, B after it. The gate's
    clock: 10 ms a block, and the silence the restart took."""
    gate = SafetyGate()
    ctl = Controller(gate)
    times = np.asarray(times)
    back = int(np.flatnonzero(np.diff(times) < 0)[0]) + 1
    decisions, clock, restart = [], 0.0, None
    for k in range(0, len(times) - 9, 10):
        block = times[k:k + 10]
        if k >= back and restart is None:
            clock += 0.3  # the silence
            restart = clock
        if k < back <= k + 9:
            continue  # the block the restart cut
        payload = P if k + 9 < back else B
        phi = payload.to_phi()
        decisions += run(gate, ctl, [(clock, phi, est(phi, float(block.mean())))])
        clock += 0.01
    return decisions, restart


def test_a_can_links_time_going_back_at_a_controller_restart():
    """A controller restarted behind a CAN link (virtual bus, fd profile): the link delivers
    its time from 0 again after the silence; the gate writes the new tool."""
    import threading
    import time

    from firmware_bridge.controller_port import open_port
    from firmware_bridge.errors import ControllerSilent
    from firmware_bridge.links import open_link
    from iem.types import JointState

    channel = f"gate-clock-{id(object())}"
    link = open_link("virtual", channel, profile="fd", silence_timeout=0.1)
    times, done = [], threading.Event()

    def read() -> None:
        while True:
            try:
                times.append(link.read(0.2).t)
            except ControllerSilent:
                if done.is_set():
                    return

    def controller(t0: float, n: int) -> None:
        port, _ = open_port("virtual", channel, "fd")
        zeros = np.zeros(7)
        for k in range(n):
            t = t0 + k * 1e-3
            port.publish(JointState(t=t, q=zeros, dq=zeros, tau_J=zeros,
                                    cycle=round(t * 1000)))
            if k % 50 == 49:
                time.sleep(0.01)
        port.close()

    reader = threading.Thread(target=read)
    reader.start()
    try:
        controller(7200.0, 1500)
        time.sleep(0.4)  # the controller restarts: a silence
        controller(0.0, 3000)
        done.set()
        reader.join(20.0)
    finally:
        link.close()
    assert link.counters.resyncs == 1 and min(times) < 1.0 < 7200.0 < max(times)
    decisions, restart = _gate_over_link_times(times)
    sent = first_send(decisions, restart)
    assert sent is not None and sent.payload.mass == pytest.approx(B.mass)
    assert sent.t - restart <= WINDOW + 0.1


@pytest.mark.hil
def test_a_ros2_links_time_going_back_at_a_clock_resync():
    """JointStates over loopback DDS whose stamps go back by 2 h (a ROS clock restarted):
    the ros2 link delivers them (a resync), and the gate writes the new tool."""
    pytest.importorskip("cyclonedds", reason="the ros2 link needs the 'ros2' extra")
    import time

    from cyclonedds.pub import DataWriter
    from cyclonedds.topic import Topic

    from firmware_bridge.errors import ControllerSilent
    from firmware_bridge.ros2_dds import cyclone_config, participant, qos
    from firmware_bridge.ros2_link import open_ros2_link
    from firmware_bridge.ros2_peers import joint_state_messages
    from firmware_bridge.ros2_types import JointStateMsg, topic_name

    domain, topic = 93, "/gate_clock/joint_states"
    loop = {"interface": "lo", "peers": ["127.0.0.1"]}
    link = open_ros2_link("ros2", topic, domain_id=domain, set_load_service="",
                          estimate_topic="/gate_clock/payload", **loop)
    try:
        dp = participant(domain, cyclone_config("lo", ("127.0.0.1",)))
        writer = DataWriter(dp, Topic(dp, topic_name(topic), JointStateMsg),
                            qos=qos(reliable=True, depth=5000))
        deadline = time.monotonic() + 10.0
        while not writer.get_matched_subscriptions() and time.monotonic() < deadline:
            time.sleep(0.05)
        messages = [*joint_state_messages(1500, 7200.0, arm="panda"),
                    *joint_state_messages(3000, 0.0, arm="panda")]
        times = []
        for k, m in enumerate(messages):
            writer.write(m)
            if k % 100 == 99:
                time.sleep(0.01)
                times += _drain(link, ControllerSilent)
        time.sleep(0.5)
        times += _drain(link, ControllerSilent)
    finally:
        link.close()
    assert min(times) < 1.0 < 7200.0 < max(times) and len(times) == len(messages)
    decisions, restart = _gate_over_link_times(times)
    sent = first_send(decisions, restart)
    assert sent is not None and sent.payload.mass == pytest.approx(B.mass)
    assert sent.t - restart <= WINDOW + 0.1


def _drain(link, silent) -> list[float]:
    out = []
    while True:
        try:
            out.append(link.read(0.05).t)
        except silent:
            return out


# -- one uncertainty, checked -------------------------------------------------------------
def _regressor():
    from sim.robot import ArmModel

    model = ArmModel()
    return lambda q, dq: model.payload_regressor(q, dq, np.zeros(7))


def _poses(n: int = 25):
    """Feed the gate's recent motion some poses of the arm (its torque bound then reads
    them)."""
    from sim.robot import ArmModel

    rng = np.random.default_rng(0)
    model = ArmModel()
    return [model.random_state(rng)[0] for _ in range(n)]


def _bypass(**fields) -> PayloadEstimate:
    """A PayloadEstimate whose fields skip its own checks (as a hostile model could make)."""
    e = est(P.to_phi(), 0.0)
    for name, value in fields.items():
        object.__setattr__(e, name, value)
    return e


WIDE_MASS = np.r_[1.0, STD[1:]]
LIES = {
    "zeros": np.zeros((10, 10)),
    "asymmetric": np.diag(STD ** 2) + np.triu(np.full((10, 10), 1e-6), 1),
    "not positive semidefinite": np.diag(np.r_[-1e-4, STD[1:] ** 2]),
    "NaN": np.full((10, 10), math.nan),
    "another diagonal": np.diag((2 * STD) ** 2),
}


@pytest.mark.parametrize("lie", LIES)
def test_a_covariance_that_lies_is_malformed(lie):
    std = WIDE_MASS if lie == "zeros" else STD
    phi = P.to_phi()
    gate = SafetyGate()
    decisions = run(gate, Controller(gate), [(k * DT, phi, _bypass(t=k * DT, std=std,
                                                                   cov=LIES[lie]))
                                             for k in range(100)])
    assert {d.reason for d in decisions} == {"malformed"} and "cov" in decisions[0].detail


def test_a_zero_covariance_beside_a_wide_std_gets_no_write():
    """1 kg of mass sigma, a covariance of zeros: refused, where it was written."""
    gate = SafetyGate(regressor=_regressor())
    ctl = Controller(gate)
    qs = _poses()
    phi = P.to_phi()
    decisions = []
    for k in range(300):
        t = k * DT
        e = _bypass(t=t, std=WIDE_MASS, cov=np.zeros((10, 10)))
        d = gate.step(t, phi, e, _State(qs[k % len(qs)]))
        if d is not None:
            decisions.append(d)
            ctl.handle(d)
    assert not ctl.applied and {d.reason for d in decisions} == {"malformed"}


class _State:
    def __init__(self, q) -> None:
        self.q, self.dq = q, np.zeros(7)


def test_the_rules_use_the_larger_of_cov_and_std():
    cov = np.diag(STD ** 2)
    cov[0, 0] *= (1 + 1e-7) ** 2  # within the agreement: the larger is the covariance's
    reading, _ = gate_checks.read(_bypass(cov=cov))
    assert reading.sigma[0] == pytest.approx(STD[0] * (1 + 1e-7), rel=1e-12)
    assert reading.sigma[0] > STD[0] and reading.cov[0, 0] == pytest.approx(
        reading.sigma[0] ** 2, rel=1e-12)
    inf = np.r_[STD[:4], np.full(6, np.inf)]  # nothing known of the inertia: no covariance
    reading, broken = gate_checks.read(_bypass(std=inf, cov=np.diag(np.r_[STD[:4], STD[4:]] ** 2)))
    assert broken is None and reading.cov is None and np.isinf(reading.sigma[4:]).all()


def test_the_rating_is_judged_at_the_bands_worst_the_com_at_the_value_written():
    """2.9 kg +- 0.4 kg (2 sigma) against a 3 kg rating: over_rated. A CoM 0.16 m out:
    com_too_far, with its band in the detail. A light tool (0.6 kg, CoM 0.062 m out) whose
    first moment is known to 0.042 kg·m (1 sigma; its CoM's 2-sigma band 0.14 m, reaching
    past 0.15 m) is written: the CoM's radius is judged at the value written, and what its
    band can cost is the write rule's to judge, by the joint torque."""
    near = Payload("2.9", 2.9, (0.0, 0.0, 0.05), (0.004, 0, 0, 0.004, 0, 0.003)).to_phi()
    std = np.r_[0.2, STD[1:]]
    gate = SafetyGate()
    decisions = run(gate, Controller(gate), [(k * DT, near, est(near, k * DT, std=std))
                                             for k in range(100)])
    assert {d.reason for d in decisions} == {"over_rated"}
    assert "+0.400 at 2 sigma" in decisions[0].detail
    far = Payload("far", 1.0, (0.0, 0.0, 0.16), (0.004, 0, 0, 0.004, 0, 0.003)).to_phi()
    std = np.r_[0.002, 0.01, 0.01, 0.01, STD[4:]]
    gate = SafetyGate()
    decisions = run(gate, Controller(gate), [(k * DT, far, est(far, k * DT, std=std))
                                             for k in range(100)])
    assert {d.reason for d in decisions} == {"com_too_far"}
    assert "0.160 (+0.020 at 2 sigma) m from the flange > 0.15 m" in decisions[0].detail
    light = Payload("light-tool", 0.6, (0.03, -0.02, 0.05),
                    (0.00068, 0, 0, 0.00082, 0, 0.0005)).to_phi()
    std = np.r_[0.068, 0.02, 0.02, 0.042, STD[4:]]
    assert gate_checks._com_band(light, 2.0 * std) > 0.14
    gate = SafetyGate()
    ctl = Controller(gate)
    decisions = run(gate, ctl, [(k * DT, light, est(light, k * DT, std=std))
                                for k in range(100)])
    assert "com_too_far" not in {d.reason for d in decisions}
    assert len(ctl.applied) == 1 and ctl.applied[0][1].mass == pytest.approx(0.6)


# -- physical limits on every link ------------------------------------------------------------
@pytest.mark.parametrize("kind", ["virtual", "serial", "franka", "ros2"])
@pytest.mark.parametrize("inertia", [1e4, 1e300])
def test_an_absurd_inertia_is_refused_on_every_link(kind, inertia):
    from firmware_bridge.links import link_kind

    heavy = np.r_[1.0, 0.0, 0.0, 0.05, inertia, 0.0, 0.0, inertia, 0.0, inertia]
    gate = SafetyGate(wire_check=link_kind(kind).wire_range().error, regressor=_regressor())
    decisions = run(gate, Controller(gate), [(k * DT, heavy, est(heavy, k * DT))
                                             for k in range(100)])
    assert {d.reason for d in decisions} == {"inconsistent"}
    assert "beyond what" in decisions[0].detail


def test_every_link_that_writes_declares_its_wire_range_checked_by_one_code():
    from firmware_bridge.links import LINKS
    from firmware_bridge.load_range import FLOAT64, LoadRange, of_profile

    for kind, spec in LINKS.items():
        if spec.sink:
            assert isinstance(spec.wire_range(), LoadRange), kind
    nan = Payload("nan", 1.0, (0.0, 0.0, 0.05), (0.004, 0, 0, 0.004, 0, 0.003))
    object.__setattr__(nan, "mass", math.inf)
    assert "Mass" in FLOAT64.error(nan)
    assert "Mass" in LINKS["virtual"].wire_range().error(nan) == of_profile("fd").error(nan)


def test_an_inertia_the_data_do_not_determine_is_written_as_the_priors():
    absurd = Payload("x", P.mass, P.com, (0.05, 0.0, 0.0, 0.05, 0.0, 0.0999)).to_phi()
    prior = Payload("prior", 1.5, (0.0, 0.0, 0.06), (2e-3, 0.0, 0.0, 3e-3, 0.0, 4e-3))
    std = np.r_[STD[:4], np.full(6, np.inf)]
    gate = SafetyGate()
    ctl = Controller(gate)
    run(gate, ctl, [(k * DT, absurd, est(absurd, k * DT, std=std, determined=("mass", "com"),
                                         prior=prior.to_phi())) for k in range(200)])
    written = ctl.applied[0][1]
    assert written.mass == pytest.approx(P.mass) and written.com == pytest.approx(P.com)
    assert written.inertia == pytest.approx(prior.inertia, abs=1e-12)
    gate = SafetyGate()
    decisions = run(gate, Controller(gate), [(k * DT, absurd, est(
        absurd, k * DT, std=std, determined=("mass", "com"))) for k in range(200)])
    assert "send" not in {d.reason for d in decisions}
    assert "no prior" in decisions[-1].detail


def test_a_prior_that_is_no_body_gives_the_nearest_bodys_inertia():
    """A learnt prior whose inertia about its CoM breaks the triangle inequality (as an
    ensemble's can: its outputs are not constrained): the write takes the inertia of the
    nearest possible body, and goes out; the prior's own inertia would be `inconsistent`
    for ever."""
    light = Payload("light-tool", 0.6, (0.03, -0.02, 0.05), (6.8e-4, 0, 0, 8.2e-4, 0, 5e-4))
    prior = light.to_phi()
    prior[4:] = Payload("p", 0.6, (0.03, -0.02, 0.05), (1e-3, 0, 0, 1e-3, 0, 5e-4)).to_phi()[4:]
    prior[9] += 2.2e-3  # Izz about the CoM 2.7e-3 > Ixx + Iyy
    assert not Payload.from_phi(prior).is_consistent()
    std = np.r_[STD[:4], np.full(6, np.inf)]
    phi = light.to_phi()
    gate = SafetyGate()
    ctl = Controller(gate)
    decisions = run(gate, ctl, [(k * DT, phi, est(phi, k * DT, std=std, determined=(
        "mass", "com"), prior=prior)) for k in range(200)])
    assert "inconsistent" not in {d.reason for d in decisions}
    written = ctl.applied[0][1]
    assert written.is_consistent() and written.mass == pytest.approx(0.6)
    assert written.com == pytest.approx(light.com)
    eig = np.linalg.eigvalsh(written.inertia_matrix)
    assert eig[0] + eig[1] >= eig[2] and eig[2] == pytest.approx(2.7e-3, rel=0.05)  # kept


def test_a_mass_whose_band_reaches_zero_is_uncertain_until_the_empty_load_is_written():
    """A bare arm at start (the empty load in force): 0.02 +- 0.1 kg (2 sigma) is not
    told from the empty load. Before the stability window has passed it is held
    `uncertain` (a warning that passes), not `inconsistent` (an error: an inertia judged at
    a lightest mass of 0 kg) nor `com_too_far` (the CoM of a mass that may be none: its
    first moment over 0.02 kg, 0.3 m out), and nothing is written."""
    bare = Payload("bare", 0.02, (0.0, 0.0, 0.3), (1e-4, 0, 0, 1e-4, 0, 1e-4)).to_phi()
    std = np.r_[0.05, np.full(3, 0.005), np.full(6, 1e-3)]
    gate = SafetyGate()
    gate.commands.report(None, None, True, 0.0)
    ctl = Controller(gate)
    decisions = run(gate, ctl, [(k * DT, bare, est(bare, k * DT, std=std))
                                for k in range(100)])
    early = {d.reason for d in decisions if d.t < 0.9 * WINDOW}
    assert early == {"uncertain"}, early
    assert "not told from the empty load" in decisions[0].detail
    assert not ctl.applied and not {"inconsistent", "com_too_far"} & {d.reason for d in decisions}


# -- the rating from the arm model ----------------------------------------------------------
def test_a_rating_lifted_in_the_file_is_refused_naming_both():
    from deploy.config import ConfigError, config_from_dict

    with pytest.raises(ConfigError, match=r"rated_mass_kg = 50.*'panda', 3 kg"):
        config_from_dict({"gate": {"rated_mass_kg": 50.0}}, where="cell.toml")
    with pytest.raises(ConfigError, match=r"rated_mass_kg = 3.5.*'fr3', 3 kg"):
        config_from_dict({"arm": {"model": "fr3"}, "gate": {"rated_mass_kg": 3.5}},
                         where="cell.toml")
    assert config_from_dict({"gate": {"rated_mass_kg": 2.5}}).gate.rated_mass_kg == 2.5


def test_writing_without_uncertainty_warns_at_start_and_in_every_verdict(caplog):
    with caplog.at_level(logging.WARNING, logger="iem.gate"):
        gate = SafetyGate(GateConfig(allow_without_uncertainty=True))
    assert any("allow_without_uncertainty" in r.getMessage() for r in caplog.records)
    assert "allow_without_uncertainty" in gate.verdict()["warning"]
    gate.step(0.0, P.to_phi(), est(P.to_phi(), 0.0))
    assert "allow_without_uncertainty" in gate.verdict()["warning"]
    assert "warning" not in SafetyGate().verdict()


# -- a disagreeing controller ---------------------------------------------------------------
def test_a_report_that_disagrees_backs_off_and_gives_up():
    """The controller reports the empty load after every write: the writes back off, and
    after five the gate gives up, saying so in its verdict and on /diagnostics."""
    from firmware_bridge.ros2_diagnostics import ERROR, level_of

    gate = SafetyGate(GateConfig(max_rate_hz=100.0))
    ctl = Controller(gate)
    phi = P.to_phi()
    for k in range(12_000):  # 120 s
        t = k * DT
        ctl.handle(gate.step(t, phi, est(phi, t)))
        r = LoadReport(t=t, seq=None, load=None, has_values=True)
        gate.commands.report(r.seq, r.load, r.has_values, t, r.t)
    assert len(ctl.applied) == 5
    gaps = np.diff([t for t, _ in ctl.applied])
    assert (gaps[1:] > gaps[:-1]).all()  # the waits grow
    v = gate.verdict()
    assert v["reason"] == "controller_disagrees" and "gave up after 5" in v["detail"]
    assert level_of(v["reason"]) == ERROR and gate.summary()["gave_up"]
    # the controller takes another load (someone else's): the gate tries again
    other = Payload("other", 0.5, (0.0, 0.0, 0.02), (1e-3, 0, 0, 1e-3, 0, 1e-3))
    gate.commands.report(None, other, True, 121.0, 121.0)
    assert first_send(run(gate, ctl, stream(P, 121.0, 124.0))) is not None


# -- answers by sequence only ---------------------------------------------------------------
def test_an_ack_for_a_command_never_sent_is_ignored():
    gate = SafetyGate()
    ctl = Controller(gate)
    run(gate, ctl, stream(P, 0.0, 2.0))
    assert gate.in_force.mass == pytest.approx(P.mass)
    gate.commands.acknowledged(99, 2.0)  # no load: would read as the empty load
    assert gate.in_force.mass == pytest.approx(P.mass)
    assert gate.summary()["ignored_answers"] == 1 and gate.summary()["acked"] == 1


def test_a_late_ack_of_an_older_command_is_ignored_and_duplicates_count_once():
    gate = SafetyGate()
    c = gate.commands
    c.sent_command(1, P, 0.0)
    c.tick(1.0)  # lost
    c.sent_command(2, B, 2.0)
    c.acknowledged(2, 2.1)
    c.acknowledged(1, 2.2)  # the late ack of the lost, older command
    c.acknowledged(2, 2.3)  # a duplicate
    assert c.load is B and c.acked == 1 and c.ignored_answers == 2
    c.refused_command(7, 2.4, "not ours")
    assert c.refused == 0 and c.ignored_answers == 3 and c.load is B


def test_a_late_ack_of_the_newest_lost_command_still_settles():
    gate = SafetyGate()
    c = gate.commands
    c.sent_command(1, P, 0.0)
    c.tick(1.0)  # lost: no newer command since
    c.acknowledged(1, 1.5)
    assert c.load is P and c.acked == 1 and c.lost == 1


class _Sink:
    """A payload sink that takes every command and answers none."""

    last_ack = None
    load_report = None

    def __init__(self) -> None:
        self.sent = 0

    def send(self, load) -> int:
        self.sent += 1
        return self.sent

    def wait_ack(self, seq, timeout):
        return None

    def close(self) -> None:
        pass


def test_the_load_writer_keeps_the_gates_own_time_across_a_jump():
    """A replay-like clock that went back 2 h before a send: the command is lost after
    ``ack_timeout_s`` of the gate's time, not at once."""
    from deploy.writeback.writer import LoadWriter

    gate = SafetyGate()
    writer = LoadWriter(gate, _Sink(), write=True)
    phi = P.to_phi()
    for k in range(100):  # 7200 s .. 7201 s: P written (no answer), then lost
        writer.step(7200.0 + k * DT, phi, est(phi, 7200.0 + k * DT))
    lost_before = gate.commands.lost
    decisions = [writer.step(k * DT, phi, est(phi, k * DT)) for k in range(300)]  # 0 s ..
    sends = [d for d in decisions if d is not None and d.send]
    assert sends, [d.reason for d in decisions if d is not None]
    after_send = [d for d in decisions if d is not None and d.t > sends[0].t]
    reasons = [d.reason for d in after_send if d.t < sends[0].t + 0.45]
    assert reasons and set(reasons) == {"ack_missing"}  # waits its ack_timeout_s
    assert gate.commands.lost > lost_before
