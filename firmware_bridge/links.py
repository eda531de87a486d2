"""The seams between the bridge and the rest of the plug-in, and the table of link kinds.

Two small protocols, both implemented by every link (a CAN bus, the serial link, the
pylibfranka robot, a replayed log):

- :class:`JointStateSource`: ``read(timeout) -> JointState``, one complete controller cycle
  per call, in cycle order; ``counters`` tells what was dropped and why. ``read`` raises
  :class:`~firmware_bridge.errors.ControllerSilent` when no complete cycle arrived within
  ``timeout`` s; the source stays usable, so the caller can act (stop the estimator, alert)
  and call ``read`` again.
- :class:`PayloadSink`: ``send(payload) -> seq`` writes a load with libfranka ``setLoad``
  semantics (None clears it); the controller's acknowledgement arrives as ``last_ack``
  (processed while ``read`` runs) or is awaited with ``wait_ack(seq, timeout)``; the load in
  force, as the controller reports it, is ``load_report``.

A source that ends, a recording read back (a CAN log, a rosbag2 bag, a joint-state CSV),
inherits :class:`RecordedSource`: iteration until its end, ``close`` and ``with``, written
once over its ``read``, as python-can's ``BusABC`` writes them over ``recv``.

Three more declare what some links do beyond that, so that a caller asks ``isinstance``
rather than probing for a method: :class:`DiagnosticsSink` and :class:`EstimatePublisher`
(the ``ros2`` link's status and estimate topics) and :class:`WireProfiled` (a link whose
loads travel in DBC signals with ranges).

:data:`LINKS` is the one table of link kinds (:class:`LinkKind`): the configuration, the
service, the simulated controller and the recorder take their kinds from it. Every kind is
opened by :func:`open_link` through one opener signature, ``opener(kind, channel, *, profile,
silence_timeout, **kind_options)``; modules are imported only when a link of that kind is
opened (python-can's style), so the serial link never imports python-can and the CAN link
never imports pylibfranka. A new kind (a reader thread, ROS 2) is one entry and one opener.
"""

from __future__ import annotations

import importlib
import inspect
from dataclasses import dataclass, fields
from typing import TYPE_CHECKING, Protocol, runtime_checkable

from iem.types import NOMINAL_RATE_HZ, JointState

from .errors import BridgeConfigError, EndOfStream

if TYPE_CHECKING:
    from .protocol import WireProfile

DROP_KINDS = ("crc", "malformed", "duplicate", "out_of_order", "stale", "implausible",
              "orphaned")
"""The kinds of dropped frames, in the order they are reported."""


@dataclass
class LinkCounters:
    """What a source saw. Frame counters count CAN frames (or serial messages).

    Attributes:
        received: every frame read from the bus or port, whatever it was.
        delivered: complete cycles handed to the caller.
        crc: frames of a known message whose end-to-end CRC8 (CAN, AUTOSAR profile 2) or
            CRC32 (serial) does not match.
        malformed: frames of a known message that cannot be one: wrong length, classic
            instead of FD (or back), remote frame, unknown multiplexer value, bad COBS or
            msgpack, wrong field types or counts, non-finite numbers.
        duplicate: a bit-identical repeat of a frame already accepted for the cycle being
            assembled or the cycle delivered last.
        out_of_order: a valid frame of a cycle older than the last delivered one, arriving
            after it (at most ``window`` cycles old), or a classic-profile joint frame whose
            alive counter is behind the last delivered cycle's.
        stale: a valid cycle that does not advance the cycle counter (the same counter
            again with different content, or older than ``window`` cycles), or a frame that
            repeats the last delivered E2E alive counter with new content (a sender whose
            counter is stuck).
        implausible: a valid cycle whose cycle counter jumps ahead further than the link
            believes without confirmation (``reassembly.JUMP_LIMIT`` published cycles) and
            that neither the last heartbeat nor the next cycle confirms: one well-formed frame
            with a wrong counter; the stream goes on from the last good cycle.
        orphaned: valid frames discarded because their cycle never completed (a sibling
            frame was lost, corrupt or late); the cycle itself counts in ``lost``.
        lost: cycles that never completed: gaps in the delivered cycle counter, in
            published cycles (``stride`` controller cycles each).
        resyncs: times the source accepted a cycle counter that went backwards after a
            silence (the controller restarted).
        silences: :class:`~firmware_bridge.errors.ControllerSilent` raised by ``read``.
        foreign: frames that are not part of the protocol (other IDs); ignored.
        error_frames: CAN error frames reported by the interface.
        heartbeats: heartbeats received.
        acks: load acknowledgements received (complete).
        overflow: cycles dropped because the caller did not read them while it waited for
            an acknowledgement (more than ``BUFFERED_CYCLES`` buffered).
        timing: delivered cycles whose controller ``Time`` breaks the protocol's timing
            requirement against the cycle counter (see ``reassembly.TimeUnwrapper``;
            docs/deploying.md states it); delivered with the wire's time, counted and
            reported.
    """

    received: int = 0
    delivered: int = 0
    crc: int = 0
    malformed: int = 0
    duplicate: int = 0
    out_of_order: int = 0
    stale: int = 0
    orphaned: int = 0
    lost: int = 0
    resyncs: int = 0
    silences: int = 0
    foreign: int = 0
    error_frames: int = 0
    heartbeats: int = 0
    acks: int = 0
    overflow: int = 0
    implausible: int = 0
    timing: int = 0

    def as_dict(self) -> dict[str, int]:
        return {f.name: getattr(self, f.name) for f in fields(self)}

    def dropped(self) -> dict[str, int]:
        """Dropped frames by kind (only the kinds with a non-zero count)."""
        return {k: getattr(self, k) for k in DROP_KINDS if getattr(self, k)}

    def summary(self) -> str:
        """One line: received, delivered, drops by kind and lost cycles."""
        drops = ", ".join(f"{k} {v}" for k, v in self.dropped().items()) or "none"
        timing = f"; {self.timing} cycles break the timing requirement" if self.timing else ""
        return (f"{self.received} frames received, {self.delivered} cycles delivered, "
                f"{self.lost} lost; dropped frames: {drops}{timing}")


BUFFERED_CYCLES = 4096
"""Complete cycles a link keeps for the caller while ``wait_ack`` reads the bus."""


@runtime_checkable
class JointStateSource(Protocol):
    """A source of joint states, one complete controller cycle at a time.

    Attributes:
        counters: what the source saw and dropped.
        name: how the link names itself in messages.
        rate_hz: joint states per second it delivers (the wire profile's, or the kind's).
        last_frame_time: receive time (``time.time()``, epoch s) of the frame that completed
            the cycle ``read`` returned last, where frame-to-estimate latency starts; 0.0
            when the link has no receive time (a replayed log).
    """

    counters: LinkCounters
    name: str
    rate_hz: float
    last_frame_time: float

    def read(self, timeout: float | None = None) -> JointState:
        """The next complete cycle; raises ``ControllerSilent`` after ``timeout`` s without one
        (None: the link's default)."""
        ...

    def close(self) -> None: ...


class RecordedSource:
    """The base of a :class:`JointStateSource` over a recording: a subclass implements
    ``read``, which raises :class:`~firmware_bridge.errors.EndOfStream` after the last joint
    state, and ``close`` if it holds something to release; iterating gives every joint state
    up to the end, and ``with`` closes it."""

    def read(self, timeout: float | None = None) -> JointState:
        raise NotImplementedError

    def __iter__(self):
        while True:
            try:
                yield self.read()
            except EndOfStream:
                return

    def close(self) -> None:
        """Release what the source holds (nothing by default)."""

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()


@runtime_checkable
class PayloadSink(Protocol):
    """A sink for payload parameters, with libfranka ``setLoad`` semantics.

    ``send`` never blocks on the controller: its acknowledgement (applied, or refused with
    the controller's ``error`` text) arrives later as ``last_ack``, which the link updates
    while ``read`` runs, or is awaited with ``wait_ack``.
    """

    def send(self, payload) -> int:
        """Send ``payload`` (a :class:`sim.payload.Payload`, or None to clear the load);
        return the command's sequence number (1..255)."""
        ...

    @property
    def last_ack(self):
        """The latest :class:`~firmware_bridge.protocol.LoadAck`, or None."""
        ...

    @property
    def load_report(self):
        """The latest :class:`~firmware_bridge.messages.LoadReport`: the load in force as the
        controller itself reports it (updated while ``read`` runs), or None until the
        controller said anything about it, and always on a link whose controller does not
        report it (``LINKS[kind].load_report`` says what each kind carries). An
        acknowledgement says what a command did; the report says what is in force now,
        whatever happened since (a restart, a load set by another client)."""
        ...

    def wait_ack(self, seq: int, timeout: float = 1.0):
        """Read until the acknowledgement of ``seq`` arrives; raise ``AckTimeout`` after
        ``timeout`` s."""
        ...

    def close(self) -> None: ...


@runtime_checkable
class DiagnosticsSink(Protocol):
    """A link that reports the safety gate's verdict to the robot's own monitoring (the
    ``ros2`` link: ``diagnostic_msgs/msg/DiagnosticArray`` on ``/diagnostics``)."""

    def publish_diagnostics(self, verdict: dict) -> bool:
        """Publish ``verdict`` (``SafetyGate.verdict()``: at least ``reason``, ``detail``,
        ``load_in_force`` and the command counts) now (the caller paces it); True if it went
        out, False if the link has nowhere to publish it."""
        ...


@runtime_checkable
class EstimatePublisher(Protocol):
    """A link with topics for the estimate (the ``ros2`` link: ``/iem/payload`` and its
    standard deviations), which the service hands every estimate."""

    def publish_estimate(self, estimate, phi=None) -> bool:
        """Publish ``estimate`` (a :class:`iem.types.PayloadEstimate`; ``phi``: the values to
        publish instead of its own, e.g. the smoothed ones) at the link's own rate; True if
        it went out."""
        ...


@runtime_checkable
class WireProfiled(Protocol):
    """A link whose loads travel as the DBC signals of a wire profile (the CAN links, a
    replayed CAN log): the gate checks a load against the signals' ranges before it is sent
    (:func:`firmware_bridge.load_range.of_profile`).

    Attributes:
        profile: the link's :class:`~firmware_bridge.protocol.WireProfile`.
    """

    profile: WireProfile


LOAD_REPORTS = ("seq", "values", "")
"""What a sink's controller reports of the load in force: its command's sequence number
(the CAN and serial heartbeats), its values (libfranka's robot state), or nothing."""


@dataclass(frozen=True)
class LinkKind:
    """One kind of link: where its opener lives and what it can do.

    Every opener has one signature, ``opener(kind, channel, *, profile, silence_timeout,
    **kind_options)`` (``profile`` is the CAN wire profile; kinds without one ignore it), and
    is imported only when a link of that kind is opened (python-can's interface table is the
    model).

    Attributes:
        module: the module of the opener, imported lazily.
        opener: the opener's name in ``module``.
        help: what it is, in words (for ``--help`` and error messages).
        bus: the python-can interface name if the kind is a CAN bus (``iem record`` and the
            simulated controller open it with :func:`firmware_bridge.can_link.open_bus`).
        bus_class: ``"module:Class"`` of a python-can bus class to use instead of looking
            ``bus`` up in python-can (a subclass of python-can's own).
        controller: the simulated controller can serve a link of this kind.
        pty: the simulated controller can also serve it on a new pty (``<kind>-pty``).
        sink: the link also writes loads (a :class:`PayloadSink`).
        recorded: the link plays a recording back (its channel is a file): the service
            never writes the model over one (a replay learns in memory only), and a channel
            it cannot read is an error of the configuration.
        fixed_rate_hz: joint states per second the link delivers whatever the profile; None:
            the wire profile's rate (``protocol.dbc``'s ``GenMsgCycleTime``).
        load_report: what a sink's ``load_report`` carries (one of :data:`LOAD_REPORTS`):
            ``"seq"``, ``"values"``, or ``""`` (it stays None).
        arm_model: the one arm model the kind serves (libfranka >= 0.10 serves the FR3
            only: ``"fr3"``), which ``[arm] model`` defaults to and may not differ from;
            None: any.
        load_range: the range of the values its load command can carry
            (:mod:`firmware_bridge.load_range`): ``"dbc"`` (the CAN wire profile's signals),
            ``"float64"`` (any finite double), or ``""`` (a kind that carries no loads).
    """

    module: str
    opener: str
    help: str
    bus: str | None = None
    bus_class: str | None = None
    controller: bool = False
    pty: bool = False
    sink: bool = True
    recorded: bool = False
    fixed_rate_hz: float | None = None
    load_report: str = ""
    arm_model: str | None = None
    load_range: str = ""

    def wire_range(self, profile: str = "fd"):
        """The :class:`~firmware_bridge.load_range.LoadRange` its load command can carry
        (CAN wire profile ``profile`` for a ``"dbc"`` kind), or None for a kind that carries
        no loads."""
        from .load_range import of_declared

        return of_declared(self.load_range, profile)


LINKS: dict[str, LinkKind] = {
    "virtual": LinkKind("firmware_bridge.can_link", "open_can_link",
                        "python-can's in-process virtual bus (tests, the in-process demo)",
                        bus="virtual", controller=True, load_report="seq",
                        load_range="dbc"),
    "socketcan": LinkKind("firmware_bridge.can_link", "open_can_link",
                          "Linux SocketCAN: can0 on a robot-cell PC, vcan0 for tests",
                          bus="socketcan", controller=True, load_report="seq",
                          load_range="dbc"),
    "slcan": LinkKind("firmware_bridge.can_link", "open_can_link",
                      "a serial-line CAN adapter (slcan/LAWICEL; CANable 2.0 for CAN FD): any "
                      "pyserial URL or device",
                      bus="slcan", bus_class="firmware_bridge.slcan_buffered:BufferedSlcanBus",
                      controller=True, pty=True, load_report="seq", load_range="dbc"),
    "serial": LinkKind("firmware_bridge.serial_link", "open_serial_link",
                       "msgpack messages over a serial line (COBS + CRC32 framing): any "
                       "pyserial URL", controller=True, pty=True, fixed_rate_hz=NOMINAL_RATE_HZ,
                       load_report="seq", load_range="float64"),
    "franka": LinkKind("firmware_bridge.franka_link", "open_franka_link",
                       "a Franka Research 3 through pylibfranka (extra 'franka', libfranka >= "
                       "0.10; exclusive FCI); channel: the robot's IP",
                       fixed_rate_hz=NOMINAL_RATE_HZ, load_report="values", arm_model="fr3",
                       load_range="float64"),
    "program": LinkKind("firmware_bridge.program_link", "open_program_link",
                        "the plug-in inside your own franky-control or pylibfranka program: "
                        "states fed from its motion callback, loads through its robot's "
                        "set_load between motions (deploy.service.PayloadPlugin; not iem run)",
                        fixed_rate_hz=NOMINAL_RATE_HZ, load_report="values", arm_model="fr3",
                        load_range="float64"),
    "ros2": LinkKind("firmware_bridge.ros2_link", "open_ros2_link",
                     "a Franka through franka_ros2 over Cyclone DDS (extra 'ros2'); channel: "
                     "the JointState topic", fixed_rate_hz=NOMINAL_RATE_HZ,
                     load_report="values", load_range="float64"),
    "replay": LinkKind("firmware_bridge.replay", "open_replay",
                       "a recorded CAN log (.blf .log .asc .trc); channel: the file",
                       sink=False, recorded=True, load_range="dbc"),
    "recording": LinkKind("firmware_bridge.recordings", "open_recording_link",
                          "a recorded rosbag2 bag (directory, .db3, .mcap; JointState topic "
                          "/franka/joint_states) or joint-state CSV (t,q1..q7,dq1..dq7,"
                          "tau1..tau7); channel: the path", sink=False, recorded=True,
                          fixed_rate_hz=NOMINAL_RATE_HZ),
}
"""The one table of link kinds: the configuration, the service, the simulated controller and
the recorder all take their kinds from it."""


def link_kind(kind: str) -> LinkKind:
    """The entry of ``kind``; BridgeConfigError naming the valid kinds if there is none."""
    try:
        return LINKS[kind]
    except KeyError:
        raise BridgeConfigError(f"unknown link kind {kind!r}; valid kinds are "
                                f"{', '.join(LINKS)}") from None


def bus_kinds() -> tuple[str, ...]:
    """The link kinds that are CAN buses (what ``iem record`` can record)."""
    return tuple(k for k, v in LINKS.items() if v.bus)


def controller_interfaces() -> dict[str, str]:
    """What the simulated controller can serve: kind -> description (``<kind>-pty``: on a new
    pty, whose path it prints on stdout)."""
    out = {}
    for k, v in LINKS.items():
        if v.controller:
            out[k] = v.help
            if v.pty:
                out[f"{k}-pty"] = f"act as the other end of a {k} link on a new pty; " \
                                  "prints the pty path on stdout"
    return out


def rate_hz(kind: str, profile: str = "fd") -> float:
    """Joint states per second a link of ``kind`` delivers with wire profile ``profile``."""
    spec = link_kind(kind)
    if spec.fixed_rate_hz is not None:
        return float(spec.fixed_rate_hz)
    from .protocol import profile as get_profile

    return float(get_profile(profile).joint_state.rate_hz)


def open_link(kind: str, channel: str, *, profile: str = "fd", silence_timeout: float = 0.1,
              **kind_options):
    """Open a link of ``kind`` (see :data:`LINKS`) on ``channel``.

    Every kind takes ``profile`` and ``silence_timeout`` (the default ``read`` timeout, s);
    ``kind_options`` go to that kind's opener (an unknown one is a BridgeConfigError). The
    returned object is a :class:`JointStateSource` and, where ``LINKS[kind].sink``, a
    :class:`PayloadSink`.
    """
    spec = link_kind(kind)
    module = importlib.import_module(spec.module)
    opener = getattr(module, spec.opener)
    try:
        inspect.signature(opener).bind(kind, channel, profile=profile,
                                       silence_timeout=silence_timeout, **kind_options)
    except TypeError as exc:
        raise BridgeConfigError(f"link kind {kind!r}: {exc}; its options are "
                                f"{_options_of(opener)}") from None
    return opener(kind, channel, profile=profile, silence_timeout=silence_timeout,
                  **kind_options)


def _options_of(opener) -> str:
    names = [p.name for p in inspect.signature(opener).parameters.values()
             if p.kind is inspect.Parameter.KEYWORD_ONLY
             and p.name not in ("profile", "silence_timeout")]
    return ", ".join(names) or "none"
