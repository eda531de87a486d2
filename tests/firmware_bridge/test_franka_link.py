"""The pylibfranka backend against a fake with pylibfranka 0.21's types and exceptions
(test_pylibfranka_binding.py checks the fake against the real binding)."""

import sys
import threading

import numpy as np
import pytest

from firmware_bridge.errors import AckTimeout, BridgeConfigError, ControllerSilent, LinkError
from firmware_bridge.franka_link import FrankaLink
from firmware_bridge.links import JointStateSource, PayloadSink, open_link
from sim.family import default_test_payload

from . import franka_fake
from .franka_fake import Robot


@pytest.fixture
def fake():
    return Robot(udp_timeout=0.5)


@pytest.fixture
def link(fake):
    out = FrankaLink(fake, franka_fake.module(), silence_timeout=0.2, load_timeout=0.3)
    yield out
    out.close()


def ack_of(link, fake, seq, states=200):
    """The ack of ``seq``: the robot sends states (one at a time) until it arrives."""
    for _ in range(states):
        fake.release()
        try:
            return link.wait_ack(seq, 0.05)
        except AckTimeout:
            continue
    raise AssertionError(f"no ack of {seq} after {states} states")


def test_states_come_from_read_once_and_skipped_cycles_are_lost(fake, link):
    assert isinstance(link, JointStateSource) and isinstance(link, PayloadSink)
    fake.release(2)
    a, b = link.read(), link.read()
    fake.skip_next = 2
    fake.release()
    c = link.read()
    assert (a.cycle, b.cycle, c.cycle) == (0, 1, 4)
    assert link.counters.lost == 2 and link.counters.delivered == 3
    np.testing.assert_allclose(b.t, 1e-3)
    assert link.rate_hz == 1000.0 and link.last_frame_time > 0


def test_read_honours_its_timeout(link):
    """No state from the robot: ControllerSilent after the timeout given, not libfranka's."""
    with pytest.raises(ControllerSilent, match="no robot state for 50 ms"):
        link.read(0.05)
    assert link.counters.silences == 1


def test_set_load_gets_column_major_inertia_and_the_ack_reads_it_back(fake, link):
    p = default_test_payload()
    seq = link.send(p)  # returns at once; the command thread calls set_load
    ack = ack_of(link, fake, seq)
    mass, com, inertia = fake.load
    assert mass == p.mass and com == list(p.com)
    np.testing.assert_allclose(np.reshape(inertia, (3, 3), order="F"), p.inertia_matrix)
    assert ack.applied and ack.error == "" and ack.load.mass == p.mass
    np.testing.assert_allclose(ack.load.inertia, p.inertia)
    assert link.read().cycle == 0  # the states read while waiting are not lost
    seq = link.send(None)
    assert ack_of(link, fake, seq).load is None and fake.load[0] == 0.0


@pytest.mark.parametrize("stale", [1, 3])
def test_the_ack_reports_the_load_of_a_state_read_after_the_command(fake, link, stale):
    """libfranka hands over the states queued on its socket in order: the first read after
    set_load returned may have left the robot before it applied the command. The ack waits
    for a state that reports the commanded load (``iem set-load`` printed the load before
    its own command from such a state)."""
    fake.stale = stale
    p = default_test_payload()
    ack = ack_of(link, fake, link.send(p))
    assert ack.applied and ack.load is not None and ack.load.mass == p.mass
    np.testing.assert_allclose(ack.load.com, p.com)
    ack = ack_of(link, fake, link.send(None))  # the clear reads back as the empty load
    assert ack.applied and ack.load is None


def test_an_ack_whose_load_never_shows_carries_what_the_robot_reports(fake, link):
    """The robot applied the command but its states go on reporting another load (another
    client set one): after SETTLE_STATES states the ack carries what the robot reports."""
    from firmware_bridge.franka_link import SETTLE_STATES

    fake.stale = 10 * SETTLE_STATES
    ack = ack_of(link, fake, link.send(default_test_payload()), states=4 * SETTLE_STATES)
    assert ack.applied and ack.load is None  # the empty load the states still report


def test_a_lost_connection_is_made_again(fake):
    """After libfranka's UDP receive timed out the Robot is unusable; a link that can connect
    drops it and connects anew; reads resume, and read's own timeout marks the silence."""
    robots = [fake]

    def connect():
        robots.append(Robot(udp_timeout=0.5))
        robots[-1].release(5)
        return robots[-1]

    link = FrankaLink(fake, franka_fake.module(), silence_timeout=0.2, connect=connect)
    try:
        fake.fail = "network"
        fake.release()
        with pytest.raises(ControllerSilent, match="no robot state for 100 ms"):
            link.read(0.1)
        state = link.read(2.0)
        assert link.reconnects == 1 and len(robots) == 2 and state.cycle == 0
    finally:
        link.close()


def test_a_refusal_comes_back_as_an_ack_with_the_error_text(fake, link):
    fake.refuse = "libfranka: Set Load command rejected: command not possible in the current mode"
    seq = link.send(default_test_payload())
    ack = ack_of(link, fake, seq)
    assert not ack.applied and ack.load is None
    assert "command not possible in the current mode" in ack.error
    assert link.last_ack is ack
    fake.refuse = None
    seq = link.send(default_test_payload())  # accepted once the robot takes commands again
    assert ack_of(link, fake, seq).applied


def test_set_load_runs_off_the_cycle_with_a_bounded_timeout(fake, link):
    """A set_load that hangs (libfranka waits 60 s) does not stop reading; after
    load_timeout it is acknowledged as refused, and its late outcome replaces that."""
    fake.hold = threading.Event()
    seq = link.send(default_test_payload())
    fake.release(5)
    cycles = [link.read().cycle for _ in range(5)]
    assert cycles == [0, 1, 2, 3, 4]  # read goes on while set_load hangs
    for _ in range(50):  # nothing from the robot meanwhile: reads time out, the ack comes
        with pytest.raises(ControllerSilent):
            link.read(0.1)
        if link.last_ack is not None:
            break
    ack = link.last_ack
    assert ack.seq == seq and not ack.applied and "did not return within 0.3 s" in ack.error
    fake.hold.set()
    for _ in range(200):
        fake.release()
        link.read()
        if link.last_ack is not ack:
            break
    assert link.last_ack.seq == seq and link.last_ack.applied


def test_network_and_exclusive_failures_are_matched_by_class(fake, link):
    fake.fail = "network"
    fake.release()
    with pytest.raises(ControllerSilent, match="NetworkException"):
        link.read()
    fake.fail = "exclusive"
    fake.release()
    with pytest.raises(LinkError, match="one client control at a time"):
        link.read(1.0)
    with pytest.raises(AckTimeout, match="no acknowledgement of payload command 99"):
        link.wait_ack(99, 0.05)


def test_an_exception_with_the_right_name_but_another_class_is_not_a_network_error(link):
    """Matched by class: a foreign RuntimeError named NetworkException is a plain LinkError."""
    other = type("NetworkException", (RuntimeError,), {})
    error = __import__("firmware_bridge.franka_link", fromlist=["_franka_error"])._franka_error(
        franka_fake.module(), other("x"), "robot", "read_once")
    assert type(error) is LinkError


def test_without_pylibfranka_the_extra_is_named(monkeypatch):
    monkeypatch.setitem(sys.modules, "pylibfranka", None)
    with pytest.raises(BridgeConfigError, match=r"pip install 'iem-payload\[franka\]'"):
        open_link("franka", "172.16.0.2")


def test_open_link_connects_through_a_robot_process_without_realtime(monkeypatch):
    """``open_link("franka", address)`` makes the robot a
    :class:`~firmware_bridge.franka_process.RobotProcess` for that address (pylibfranka in a
    child process), with ``realtime=False`` (``RealtimeConfig.kIgnore``), and reads from
    it. The process itself is tested against franky-sim; here a fake robot stands in for it,
    so nothing is sent to the address."""
    import firmware_bridge.franka_link as franka_link

    made = []

    def process(address, api, *, realtime):
        made.append((address, api, realtime))
        robot = Robot(address, "kIgnore")
        made.append(robot)
        return robot

    monkeypatch.setattr(franka_link, "RobotProcess", process)
    monkeypatch.setitem(sys.modules, "pylibfranka", franka_fake.module())
    link = open_link("franka", "172.16.0.2", profile="fd", silence_timeout=0.3)
    try:
        address, api, realtime = made[0]
        assert (address, realtime) == ("172.16.0.2", False) and api is sys.modules["pylibfranka"]
        made[1].release()
        assert link.read().cycle == 0 and link.silence_timeout == 0.3
    finally:
        link.close()


def test_the_load_report_is_the_robot_states_own_load(fake, link):
    """``load_report`` carries the values the robot reports in each state (``m_load``,
    ``F_x_Cload``, ``I_load`` column-major about the CoM), no sequence number; mass 0 is
    the empty load."""
    from firmware_bridge.messages import LoadReport

    assert link.load_report is None  # no state yet
    fake.release()
    link.read()
    first = link.load_report
    assert isinstance(first, LoadReport)
    assert (first.seq, first.load, first.has_values) == (None, None, True)
    p = default_test_payload()
    ack_of(link, fake, link.send(p))
    fake.release()
    link.read()
    report = link.load_report
    assert report.has_values and report.seq is None and report.t > first.t
    mass, com, inertia = fake.load  # what the robot holds, column-major
    assert report.load.mass == mass and list(report.load.com) == com
    np.testing.assert_allclose(report.load.inertia_matrix,
                               np.reshape(inertia, (3, 3), order="F"))
    np.testing.assert_allclose(report.load.inertia_matrix, p.inertia_matrix)
    ack_of(link, fake, link.send(None))
    fake.release()
    link.read()
    assert link.load_report.load is None and link.load_report.has_values
