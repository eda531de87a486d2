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
  (processed while ``read`` runs) or is awaited with ``wait_ack(seq, timeout)``.

:data:`LINKS` is the one table of link kinds: name -> (module, opener, what it is). Modules
are imported only when a link of that kind is opened (python-can's style), so the serial link
never imports python-can and the CAN link never imports pylibfranka.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass, fields
from typing import Protocol, runtime_checkable

from iem.types import JointState

from .errors import BridgeConfigError

DROP_KINDS = ("crc", "malformed", "duplicate", "out_of_order", "stale", "orphaned")
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

    def as_dict(self) -> dict[str, int]:
        return {f.name: getattr(self, f.name) for f in fields(self)}

    def dropped(self) -> dict[str, int]:
        """Dropped frames by kind (only the kinds with a non-zero count)."""
        return {k: getattr(self, k) for k in DROP_KINDS if getattr(self, k)}

    def summary(self) -> str:
        """One line: received, delivered, drops by kind and lost cycles."""
        drops = ", ".join(f"{k} {v}" for k, v in self.dropped().items()) or "none"
        return (f"{self.received} frames received, {self.delivered} cycles delivered, "
                f"{self.lost} lost; dropped frames: {drops}")


BUFFERED_CYCLES = 4096
"""Complete cycles a link keeps for the caller while ``wait_ack`` reads the bus."""


@runtime_checkable
class JointStateSource(Protocol):
    """A source of joint states, one complete controller cycle at a time."""

    counters: LinkCounters

    def read(self, timeout: float | None = None) -> JointState:
        """The next complete cycle; raises ``ControllerSilent`` after ``timeout`` s without one
        (None: the link's default)."""
        ...

    def close(self) -> None: ...


@runtime_checkable
class PayloadSink(Protocol):
    """A sink for payload parameters, with libfranka ``setLoad`` semantics."""

    def send(self, payload) -> int:
        """Send ``payload`` (a :class:`sim.payload.Payload`, or None to clear the load);
        return the command's sequence number (1..255)."""
        ...

    @property
    def last_ack(self):
        """The latest :class:`~firmware_bridge.protocol.LoadAck`, or None."""
        ...

    def wait_ack(self, seq: int, timeout: float = 1.0):
        """Read until the acknowledgement of ``seq`` arrives; raise ``AckTimeout`` after
        ``timeout`` s."""
        ...

    def close(self) -> None: ...


LINKS: dict[str, tuple[str, str, str]] = {
    "virtual": ("firmware_bridge.can_link", "open_can_link",
                "python-can's in-process virtual bus (tests, the in-process demo)"),
    "socketcan": ("firmware_bridge.can_link", "open_can_link",
                  "Linux SocketCAN: can0 on a robot-cell PC, vcan0 for tests"),
    "slcan": ("firmware_bridge.can_link", "open_can_link",
              "a serial-line CAN adapter (slcan/LAWICEL; CANable 2.0 for CAN FD): "
              "any pyserial URL or device"),
    "serial": ("firmware_bridge.serial_link", "open_serial_link",
               "msgpack messages over a serial line (COBS + CRC32 framing): any pyserial URL"),
    "franka": ("firmware_bridge.franka_link", "open_franka_link",
               "a Franka robot through pylibfranka (extra 'franka'); channel: the robot's IP"),
    "ros2": ("firmware_bridge.ros2_link", "open_ros2_link",
             "a Franka through franka_ros2 over Cyclone DDS (extra 'ros2'); channel: the "
             "JointState topic"),
    "replay": ("firmware_bridge.replay", "open_replay",
               "a recorded CAN log (.blf .log .asc .trc); channel: the file"),
}
"""Link kinds: name -> (module, opener function, description)."""


def open_link(kind: str, channel: str, **options):
    """Open a link of ``kind`` (see :data:`LINKS`) on ``channel``; options go to its opener.

    The returned object is a :class:`JointStateSource` and, except for ``replay``, a
    :class:`PayloadSink`.
    """
    try:
        module_name, opener, _ = LINKS[kind]
    except KeyError:
        raise BridgeConfigError(f"unknown link kind {kind!r}; valid kinds are "
                                f"{', '.join(LINKS)}") from None
    module = importlib.import_module(module_name)
    return getattr(module, opener)(kind, channel, **options)
