"""Every link kind of ``firmware_bridge.links.LINKS`` passes the shared link checks
(:mod:`firmware_bridge.checks`), with the other end real where this machine allows it:

- ``virtual`` (both wire profiles): the controller's port on python-can's virtual bus;
- ``slcan``: python-can's slcan interface on a pty, the emulated adapter at the other end;
- ``serial``: the serial link on a pty, the controller's serial port at the other end;
- ``socketcan``: vcan0, where the kernel has AF_CAN (skipped here otherwise);
- ``franka``: the pylibfranka fake (:mod:`tests.firmware_bridge.franka_fake`);
- ``program``: a program's robot in this process: each published state fed as the motion's
  callback would, the motion over after it (``apply`` then writes the kept command);
- ``ros2``: Cyclone DDS in this process on loopback (unicast peer 127.0.0.1, no multicast),
  a JointState writer and a SetLoad service at the other end (skipped without the ``ros2``
  extra);
- ``replay``: a CAN log written with python-can's logger; ``recording``: a joint-state CSV and
  a rosbag2 bag written with rosbags.

One test per (kind, check); a new kind without a harness here fails
``test_every_link_kind_is_checked``. The last tests break a good link in one way each and
see its check fail.
"""

from __future__ import annotations

import itertools
import time

import pytest

from firmware_bridge import checks
from firmware_bridge.checks import CheckFailed
from firmware_bridge.errors import BridgeConfigError, LinkError, LogFileError
from firmware_bridge.link_harness import (
    CAN_TOLERANCE,
    N_STATES,
    ControllerHarness,
    Harness,
    RecordingHarness,
)
from firmware_bridge.links import LINKS
from iem.errors import IemError, PayloadError
from iem.types import JointState
from tests.franky_state import RobotState

from .conftest import synthetic_states
from .hil import vcan_unavailable
from .test_recordings import arrays, write_bag, write_csv
from .test_stream_integrity import encoded, write_log

_channels = itertools.count()
NO_TTY = "/dev/iem-conformance-no-such-tty"
DOMAIN = 77
"""The DDS domain of the ros2 harnesses (the ros2 tests use others)."""
LOOPBACK = {"interface": "lo", "peers": ["127.0.0.1"]}


def _virtual(tmp_path, monkeypatch, profile="fd"):
    return lambda: ControllerHarness("virtual", "virtual", synthetic_states, profile=profile,
                                     channel=f"conformance-{next(_channels)}")


def _socketcan(tmp_path, monkeypatch):
    why = vcan_unavailable()
    if why:
        pytest.skip(why)
    return lambda: ControllerHarness("socketcan", "socketcan", synthetic_states,
                                     channel="vcan0", bad_channel=("iemnone0", LinkError))


def _slcan(tmp_path, monkeypatch):
    return lambda: ControllerHarness("slcan", "slcan-pty", synthetic_states,
                                     bad_channel=(NO_TTY, LinkError))


def _serial(tmp_path, monkeypatch):
    return lambda: ControllerHarness("serial", "serial-pty", synthetic_states,
                                     bad_channel=(NO_TTY, LinkError))


def _replay(tmp_path, monkeypatch):
    states = synthetic_states(N_STATES)
    log = tmp_path / "states.log"
    write_log(log, [m for cycle in encoded("fd", states) for m in cycle])
    return lambda: RecordingHarness("replay", log, states, tolerance=CAN_TOLERANCE,
                                    bad_channel=(str(tmp_path / "none.blf"), LogFileError))


def _recorded_states(n: int = N_STATES):
    t, q, dq, tau, ns = arrays(n)
    states = [JointState(t=float(t[k]), q=q[k], dq=dq[k], tau_J=tau[k], cycle=k)
              for k in range(n)]
    return (t, q, dq, tau, ns), states


def _recording_csv(tmp_path, monkeypatch):
    (t, q, dq, tau, _), states = _recorded_states()
    path = write_csv(tmp_path / "states.csv", t, q, dq, tau)
    return lambda: RecordingHarness("recording", path, states,
                                    bad_channel=(str(tmp_path / "none.csv"), LogFileError))


def _recording_rosbag2(tmp_path, monkeypatch):
    (_, q, dq, tau, ns), states = _recorded_states()
    path = write_bag(tmp_path / "bag", ns, q, dq, tau)
    return lambda: RecordingHarness("recording", path, states,
                                    bad_channel=(str(tmp_path / "no-bag"), LogFileError))


class FrankaHarness(Harness):
    """The franka link on the pylibfranka fake: a state per ``release``, ``set_load``
    applied at once and reported in the next state (what the robot sends is the plant's,
    so the values are not compared)."""

    kind, channel, tolerance = "franka", "172.16.0.2", None
    bad_channel = ("unreachable", LinkError)

    def __init__(self, robots: list) -> None:
        from firmware_bridge.links import open_link

        self.link = open_link("franka", self.channel)
        self.robot = robots[-1]

    def publish(self, n: int) -> None:
        self.robot.release(n)

    def serve(self) -> None:
        self.robot.release()  # the acknowledgement comes with a state

    def close(self) -> None:
        self.link.close()
        self.robot.release(10)  # the reader may wait in read_once: let it see the stop


def _franka(tmp_path, monkeypatch):
    pytest.importorskip("mujoco", reason="the pylibfranka fake runs the simulated Panda "
                                         "(the 'sim' extra)")
    from . import franka_fake

    robots: list = []
    module = franka_fake.module()

    def robot(address, config):
        if address == "unreachable":
            raise franka_fake.NetworkException("libfranka: Connection timeout")
        robots.append(franka_fake.Robot(address, config, udp_timeout=30.0))
        return robots[-1]

    module.Robot = robot
    franka_fake.install(monkeypatch, module)
    return lambda: FrankaHarness(robots)


class _ProgramRobot:
    """A program's robot: ``set_load`` holds the load its states then report."""

    def __init__(self) -> None:
        self.load = (0.0, [0.0] * 3, [0.0] * 9)
        self.last = None

    def set_load(self, mass, com, inertia) -> None:
        self.load = (float(mass), list(com), list(inertia))

    def state(self) -> RobotState:
        return RobotState(self.last, self.load)


class ProgramHarness(Harness):
    """The program link in this process: ``publish`` feeds states as a motion's callback
    does and ends the motion (``apply``: no command kept yet); ``serve`` is the program's
    ``apply`` between motions."""

    kind, channel = "program", "program"
    bad_channel = ("program", BridgeConfigError)  # iem run cannot open it

    def __init__(self) -> None:
        from firmware_bridge.program_link import ProgramLink

        self.robot = _ProgramRobot()
        self.link = ProgramLink(self.robot, lambda robot: robot.state())
        self._next = 0

    def publish(self, n: int) -> list[JointState]:
        out = synthetic_states(n, 1, self._next)
        for s in out:
            self.robot.last = s
            self.link.feed(RobotState(s, self.robot.load))
        self._next += n
        self.link.apply()  # the motion is over; nothing kept yet
        return out

    def serve(self) -> None:
        self.link.apply()


def _program(tmp_path, monkeypatch):
    return ProgramHarness


class Ros2Harness(Harness):
    """The ros2 link on loopback DDS: a reliable JointState writer, a SetLoad service
    (``firmware_bridge.ros2_peers``) and a FrankaRobotState writer reporting the load the
    service last set (as franka_ros2's broadcaster fills it) in this process, on topics of
    its own."""

    kind, tolerance = "ros2", (0.0, 0.0, 0.0)
    bad_channel = ("conformance/joint_states", BridgeConfigError)  # not fully qualified

    def __init__(self) -> None:
        from cyclonedds.pub import DataWriter
        from cyclonedds.topic import Topic

        from firmware_bridge.links import open_link
        from firmware_bridge.ros2_dds import cyclone_config, participant, qos
        from firmware_bridge.ros2_peers import SetLoadServer
        from firmware_bridge.ros2_types import FrankaRobotState, JointStateMsg, topic_name

        n = next(_channels)
        self.channel, service = f"/conformance{n}/joint_states", f"/conformance{n}/set_load"
        robot_state = f"/conformance{n}/robot_state"
        self.dp = dp = participant(DOMAIN, cyclone_config(**LOOPBACK))
        self.server = SetLoadServer(dp, service)
        self.writer = DataWriter(dp, Topic(dp, topic_name(self.channel), JointStateMsg),
                                 qos=qos(reliable=True, depth=100))
        self.state_writer = DataWriter(dp, Topic(dp, topic_name(robot_state), FrankaRobotState),
                                       qos=qos(reliable=True, depth=10))
        self.link = open_link("ros2", self.channel, domain_id=DOMAIN, set_load_service=service,
                              estimate_topic=f"/conformance{n}/payload",
                              robot_state_topic=robot_state, set_load_timeout_s=2.0,
                              **LOOPBACK)
        deadline = time.monotonic() + 20.0
        while not (self.writer.get_matched_subscriptions()
                   and self.state_writer.get_matched_subscriptions()
                   and not self.link.set_load.replier_problem()):
            if time.monotonic() > deadline:
                self.close()
                raise AssertionError("the ros2 link and its peers did not match in 20 s")
            time.sleep(0.01)
        self._t0, self._k = 1000.0 + n, 0

    def publish(self, n: int) -> list[JointState]:
        from firmware_bridge.ros2_peers import joint_state_messages

        msgs = joint_state_messages(n, self._t0 + self._k / 1000.0)
        self._k += n
        out = []
        for m in msgs:
            self.writer.write(m)
            t = m.header.stamp.sec + m.header.stamp.nanosec * 1e-9
            out.append(JointState(t=t, q=m.position, dq=m.velocity, tau_J=m.effort,
                                  cycle=round(t * 1000.0) % 2**32))
        return out

    def serve(self) -> None:
        """Report the load the service last set (none yet: the empty load)."""
        from firmware_bridge.ros2_types import (
            FrankaRobotState,
            Header,
            Inertia,
            InertiaStamped,
            JointStateMsg,
            Vector3,
        )

        mass, com, i9 = (self.server.requests[-1] if self.server.requests
                         else (0.0, [0.0] * 3, [0.0] * 9))
        inertia = Inertia(m=mass, com=Vector3(*com), ixx=i9[0], ixy=i9[1], ixz=i9[2],
                          iyy=i9[4], iyz=i9[5], izz=i9[8])  # column-major, symmetric
        names = [f"fr3_joint{i}" for i in range(1, 8)]
        self.state_writer.write(FrankaRobotState(
            measured_joint_state=JointStateMsg(name=names, position=[0.0] * 7,
                                               velocity=[0.0] * 7, effort=[0.0] * 7),
            inertia_load=InertiaStamped(header=Header(frame_id="fr3_link9"),
                                        inertia=inertia)))

    def close(self) -> None:
        try:
            self.link.close()
        finally:
            self.server.close()


def _ros2(tmp_path, monkeypatch):
    pytest.importorskip("cyclonedds", reason="the ros2 link needs the 'ros2' extra")
    return Ros2Harness


HARNESSES = {
    "virtual": _virtual,
    "virtual-classic": lambda tmp_path, mp: _virtual(tmp_path, mp, profile="classic"),
    "socketcan": _socketcan,
    "slcan": _slcan,
    "serial": _serial,
    "franka": _franka,
    "program": _program,
    "ros2": _ros2,
    "replay": _replay,
    "recording-csv": _recording_csv,
    "recording-rosbag2": _recording_rosbag2,
}
"""Variant -> ``(tmp_path, monkeypatch) -> factory of harnesses``; the kind is the variant's
name up to its first '-'."""


def test_every_link_kind_is_checked():
    assert {v.partition("-")[0] for v in HARNESSES} == set(LINKS)


@pytest.mark.parametrize("check", checks.CHECKS, ids=lambda c: c.__name__)
@pytest.mark.parametrize("variant", list(HARNESSES))
def test_link(variant, check, tmp_path, monkeypatch):
    if check in checks.SINK_CHECKS and not LINKS[variant.partition("-")[0]].sink:
        pytest.skip(f"{variant} is not a payload sink")
    check(HARNESSES[variant](tmp_path, monkeypatch))


# -- the checks can fail -------------------------------------------------------------------
class Proxy:
    """A link with one behaviour changed: ``replace`` maps an attribute to its stand-in
    (given the real link)."""

    def __init__(self, link, replace: dict) -> None:
        self._link = link
        self._replace = {k: f(link) for k, f in replace.items()}

    def __getattr__(self, name):
        return self._replace[name] if name in self._replace else getattr(self._link, name)


def _close_once(link):
    closed = []

    def close():
        if closed:
            raise LinkError("already closed")
        closed.append(True)
        link.close()
    return close


def _never_silent(link):
    last = []

    def read(timeout=None):
        try:
            last[:] = [link.read(timeout)]
        except TimeoutError:
            if not last:
                raise
        return last[0]
    return read


def _stutters(link):
    again = []

    def read(timeout=None):
        if again:
            return again.pop()
        again.append(link.read(timeout))
        return again[0]
    return read


def _numbers_refusals(link):
    def send(payload):
        if payload is not None and not payload.is_consistent():
            link.send(None)  # something goes out, and takes a number, before the refusal
            raise PayloadError(f"payload {payload.name!r} is not physically consistent")
        return link.send(payload)
    return send


def _reports_nothing(link):
    return None


BROKEN = [
    ({"close": _close_once}, checks.check_close_idempotent, "a second close raised"),
    ({"load_report": _reports_nothing}, checks.check_load_report,
     "load_report is None; it carries seq"),
    ({"read": _never_silent}, checks.check_silence_or_end, "nothing was sent, yet read"),
    ({"read": _stutters}, checks.check_reads_joint_states, "is followed by cycle 0 .*not "
                                                           "forward"),
    ({"send": _numbers_refusals}, checks.check_refuses_impossible_payload,
     "the refused one took a number"),
]


@pytest.mark.parametrize(("replace", "check", "message"), BROKEN,
                         ids=[c.__name__ for _, c, _ in BROKEN])
def test_a_broken_link_fails_its_check(replace, check, message):
    make_good = _virtual(None, None)

    def make():
        h = make_good()
        h.link = Proxy(h.link, replace)
        return h

    with pytest.raises(CheckFailed, match=message) as info:
        check(make)
    assert isinstance(info.value, AssertionError) and isinstance(info.value, IemError)
