"""What the link check suite (:mod:`firmware_bridge.checks`) checks: a :class:`Harness`, a
link of one kind of :data:`~firmware_bridge.links.LINKS` opened on a fresh channel, and the
other end of it.

Two harnesses are here, for what any kind of its sort needs: :class:`ControllerHarness` (a
kind the controller's port serves: ``virtual``, ``socketcan``, ``slcan`` and ``serial``, the
last two on a pty) and :class:`RecordingHarness` (``replay`` of a CAN log, ``recording`` of a
CSV or rosbag2 bag). The others (``franka`` behind a fake pylibfranka, ``ros2`` over loopback
DDS) are the tests'.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable, Sequence

from iem.types import JointState

from .links import LINKS, open_link
from .messages import Heartbeat, LoadAck

N_STATES = 20
"""Joint states a check has the other end send (a few frames: a pty's buffer holds them)."""
READ_TIMEOUT_S = 5.0
"""How long a check waits for a joint state the other end has sent (a loaded machine)."""
CAN_TOLERANCE = (0.5e-5 + 1e-12, 0.5e-4 + 1e-12, 0.005 + 1e-12)
"""Half the CAN wire's steps of q, dq and tau_J (:mod:`firmware_bridge.protocol`): how far a
joint state read from a CAN link or log may lie from what was sent."""


class Harness:
    """A link of one kind, open on a fresh channel, and the other end of it.

    Attributes:
        kind: the link kind (a key of :data:`~firmware_bridge.links.LINKS`).
        channel: the channel the link was opened on.
        profile: the wire profile it was opened with.
        link: the link under check (opened by the harness, closed by :meth:`close`).
        recorded: joint states the recording holds, or None for a live link.
        tolerance: absolute tolerances of ``(q, dq, tau_J)`` against what was sent (the
            wire's resolution; zeros: exact), or None where what was sent is not known.
        bad_channel: ``(channel, error class)``: a channel of this kind that cannot be
            opened and the error the kind documents for it, or None.
    """

    kind: str
    channel: str
    profile: str = "fd"
    link: object
    recorded: int | None = None
    tolerance: tuple[float, float, float] | None = (0.0, 0.0, 0.0)
    bad_channel: tuple[str, type[Exception]] | None = None

    def publish(self, n: int) -> list[JointState] | None:
        """The other end sends ``n`` more joint states (a recording: its next ``n``); what
        it sent, or None where the values are not known."""
        raise NotImplementedError

    def serve(self) -> None:
        """The other end answers the payload commands it received (if it does not by
        itself)."""

    def close(self) -> None:
        """Close the link (again, if a check closed it) and the other end."""
        self.link.close()

    def __enter__(self) -> Harness:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc is None:
            self.close()
            return
        with contextlib.suppress(Exception):  # the check's failure is the one to report
            self.close()


class ControllerHarness(Harness):
    """A kind the simulated controller serves, its other end the controller's port
    (:func:`firmware_bridge.controller_port.open_port`) publishing ``states`` (a function
    ``states(n, stride, start) -> [JointState]`` of cycles ``start, start + stride, ...``)
    and acknowledging every command with the load it carries (then a heartbeat with its
    sequence number, the load in force).

    Args:
        kind: the link kind.
        interface: the controller's interface (``<kind>`` or ``<kind>-pty``).
        channel: the bus channel (not used by the ``-pty`` interfaces, which make a pty).
        states: the joint states' generator.
        profile: the CAN wire profile.
        bad_channel: see :class:`Harness`.
    """

    def __init__(self, kind: str, interface: str, states: Callable[..., Sequence[JointState]],
                 channel: str = "", profile: str = "fd",
                 bad_channel: tuple[str, type[Exception]] | None = None) -> None:
        from .controller_port import open_port

        self.kind, self.profile, self.bad_channel = kind, profile, bad_channel
        self._states = states
        self.port, pty = open_port(interface, channel, profile)
        self.channel = pty or channel
        self.stride = getattr(self.port, "stride", 1)
        if LINKS[kind].bus is not None:
            self.tolerance = CAN_TOLERANCE
        try:
            self.link = open_link(kind, self.channel, profile=profile)
        except BaseException:
            self.port.close()
            raise
        self._next = 0
        self.load_seq = 0
        self._wait_open()

    def _wait_open(self) -> None:
        """An slcan adapter drops frames until the link opens its channel (``O``)."""
        bus = getattr(self.port, "bus", None)
        deadline = time.monotonic() + READ_TIMEOUT_S
        while not getattr(bus, "is_open", True) and time.monotonic() < deadline:
            self.port.poll_commands()
            time.sleep(0.001)

    def publish(self, n: int) -> list[JointState]:
        out = list(self._states(n, self.stride, self._next))
        for s in out:
            self.port.tick(s.cycle, s.t)
            self.port.publish(s)
        self._next = out[-1].cycle + self.stride if out else self._next
        return out

    def serve(self) -> None:
        """Acknowledge every command received as applied, then say so in a heartbeat (the
        sequence number of the load in force)."""
        commands = self.port.poll_commands()
        for cmd in commands:
            self.port.send_ack(LoadAck(seq=cmd.seq, applied=True, load=cmd.load))
            self.load_seq = cmd.seq
        if commands:
            self.port.heartbeat(Heartbeat(state="running", load_seq=self.load_seq,
                                          cycle=max(0, self._next - self.stride), overruns=0))

    def close(self) -> None:
        try:
            self.link.close()
        finally:
            self.port.close()


class RecordingHarness(Harness):
    """A recording (``replay``: a CAN log; ``recording``: a CSV or rosbag2 bag) at ``path``
    that holds ``states``, opened with ``options`` (e.g. ``pace``)."""

    def __init__(self, kind: str, path, states: Sequence[JointState], profile: str = "fd",
                 tolerance: tuple[float, float, float] = (0.0, 0.0, 0.0),
                 bad_channel: tuple[str, type[Exception]] | None = None, **options) -> None:
        self.kind, self.channel, self.profile = kind, str(path), profile
        self.tolerance, self.bad_channel = tolerance, bad_channel
        self._states = list(states)
        self.recorded = len(self._states)
        self._next = 0
        self.link = open_link(kind, self.channel, profile=profile, **options)

    def publish(self, n: int) -> list[JointState]:
        out = self._states[self._next:self._next + n]
        self._next += len(out)
        return out
