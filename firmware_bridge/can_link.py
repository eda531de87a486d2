"""The bridge over python-can: buses by name, the plug-in's link and the controller's port.

The CAN bus kinds are the entries of :data:`firmware_bridge.links.LINKS` with a python-can
interface (``bus``); :data:`BUS_OPTIONS` says how each interface is opened with
``can.Bus(interface=..., **options)`` for a profile:

- ``virtual``: python-can's in-process bus; ``channel`` is any name shared by both ends.
- ``socketcan``: Linux SocketCAN (``can0``, ``vcan0``); FD frames need ``fd=True``, which the
  ``fd`` profile sets. The interface is set up outside (deploy/setup-vcan.sh, docs/deploying.md): a
  real adapter with ``ip link set can0 type can bitrate 1000000 dbitrate 5000000 fd on
  restart-ms 100`` (``restart-ms``: the interface recovers from bus-off by itself instead
  of staying off), vcan0 with ``ip link set vcan0 mtu 72`` (vcan drops CAN FD frames until its
  MTU is 72).
- ``slcan``: a serial-line adapter speaking the LAWICEL/slcan ASCII protocol, on any pyserial
  URL or device. python-can 4.6.1's slcan also sends and receives CAN FD frames (the
  CANable 2.0 firmware's ``d``/``b`` frames, data bitrate 2 or 5 Mbit/s), so both profiles
  run over it. ``sleep_after_open`` defaults to 0 for a pty or URL channel (python-can's 2 s
  wait is for adapters that reset when opened).

python-can imports the interface module itself when a bus of that kind is opened.

:class:`CanDecoder` turns received frames into joint states, heartbeats and acks (shared by
the live link and :mod:`firmware_bridge.replay`); :class:`CanLink` is the plug-in's
:class:`~firmware_bridge.links.JointStateSource` and
:class:`~firmware_bridge.links.PayloadSink` over one bus; :class:`CanControllerPort` is the
controller's side (used by the simulated controller), with optional fault injection. Both
implement only the hooks of :mod:`firmware_bridge.framed`.
"""

from __future__ import annotations

import importlib
import time
from collections.abc import Callable

import can

from iem.payload import Payload
from iem.types import JointState

from .control_codecs import LoadAssembler
from .errors import BridgeConfigError, DecodeError, LinkError
from .faults import FaultSpec
from .framed import FramedControllerPort, FramedLink, heartbeat_text
from .links import LinkCounters, bus_kinds, link_kind
from .messages import ACK_ERRORS, Heartbeat, LoadAck, LoadCommand
from .protocol import PROFILES, WireProfile
from .protocol import profile as get_profile
from .reassembly import CycleAssembler

SEND_TIMEOUT = 0.1
"""Seconds a send may block before it counts as a bus error."""
HEARTBEAT_FRESH_S = 2.0
"""A heartbeat younger than this (by frame time stamps) vouches for a jumping cycle counter."""


# -- bus kinds -----------------------------------------------------------------------------
def _virtual(channel: str, prof: WireProfile) -> dict:
    return {"channel": channel or "iem",
            "protocol": can.CanProtocol.CAN_FD if prof.is_fd else can.CanProtocol.CAN_20}


def _socketcan(channel: str, prof: WireProfile) -> dict:
    return {"channel": channel or "can0", "fd": prof.is_fd}


def _slcan(channel: str, prof: WireProfile) -> dict:
    if not channel:
        raise BridgeConfigError("slcan needs a channel: a serial device (/dev/ttyACM0) or a "
                                "pyserial URL")
    opts: dict = {"channel": channel}
    if channel.startswith("/dev/pts/") or "://" in channel:
        opts["sleep_after_open"] = 0.0
    if prof.is_fd:
        opts["timing"] = can.BitTimingFd.from_sample_point(
            f_clock=80_000_000, nom_bitrate=prof.bitrate, nom_sample_point=80.0,
            data_bitrate=prof.data_bitrate, data_sample_point=75.0)
    else:
        opts["bitrate"] = prof.bitrate
    return opts


BUS_OPTIONS: dict[str, Callable[[str, WireProfile], dict]] = {
    "virtual": _virtual, "socketcan": _socketcan, "slcan": _slcan}
"""python-can interface name -> the ``can.Bus`` options of a channel and profile. Which link
kinds are CAN buses, and with which interface and bus class, is said by
:data:`firmware_bridge.links.LINKS`."""


def open_bus(kind: str, channel: str, profile: str = "fd", **overrides) -> can.BusABC:
    """Open a python-can bus of link ``kind`` for ``profile``; ``overrides`` replace options."""
    spec = link_kind(kind)
    if spec.bus is None:
        raise BridgeConfigError(f"link kind {kind!r} is not a CAN bus; the CAN bus kinds are "
                                f"{', '.join(bus_kinds())}")
    prof = get_profile(profile)
    options = {**BUS_OPTIONS[spec.bus](channel, prof), **overrides}
    try:
        if spec.bus_class is None:
            return can.Bus(interface=spec.bus, **options)
        module, _, name = spec.bus_class.partition(":")
        return getattr(importlib.import_module(module), name)(**options)
    except (can.CanError, OSError, ValueError, ImportError) as exc:
        hint = ""
        if kind == "socketcan":
            hint = ("; SocketCAN needs a Linux kernel with AF_CAN and the interface up "
                    "(vcan: 'ip link add dev vcan0 type vcan && ip link set vcan0 mtu 72 && "
                    "ip link set up vcan0'; see deploy/setup-vcan.sh)")
        raise LinkError(f"cannot open {kind} bus on channel {options.get('channel')!r}: "
                        f"{exc}{hint}") from exc


def can_message(codec, data: bytes) -> can.Message:
    """The CAN frame of ``codec`` (its ID, classic or FD) carrying ``data``."""
    return can.Message(arbitration_id=codec.frame_id, data=data, is_extended_id=False,
                       is_fd=codec.is_fd, bitrate_switch=codec.is_fd, check=False)


# -- receiving -----------------------------------------------------------------------------
class CanDecoder:
    """Received CAN frames -> joint states (returned), heartbeats and acks (kept)."""

    def __init__(self, profile: str | WireProfile = "fd", counters: LinkCounters | None = None,
                 window: int = 16) -> None:
        prof = get_profile(profile) if isinstance(profile, str) else profile
        self.profile = prof
        self.counters = LinkCounters() if counters is None else counters
        self._js = prof.joint_state
        self._joint = prof.joint_state.by_id
        self._assembler = CycleAssembler(prof.joint_state, self.counters, window)
        self._ack = LoadAssembler(prof.ack)
        self._ack_id = prof.ack.frame.frame_id
        self._hb_id = prof.heartbeat.frame.frame_id
        self.last_heartbeat: Heartbeat | None = None
        self._hb_stamp = 0.0  # its frame's time stamp (recorded time in a replay)
        self.last_ack: LoadAck | None = None
        self.acks: dict[int, LoadAck] = {}
        self.last_error: DecodeError | None = None
        self.foreign_ids: dict[int, int] = {}

    def resync(self) -> None:
        self._assembler.resync()

    def push(self, msg: can.Message) -> JointState | None:
        """Take one received frame; return the joint state of a cycle it completes."""
        c = self.counters
        c.received += 1
        if msg.is_error_frame:
            c.error_frames += 1
            return None
        fid = msg.arbitration_id
        entry = None if msg.is_extended_id else self._joint.get(fid)
        try:
            if entry is not None:
                part, codec, unpack = entry
                data = bytes(msg.data)
                counter = codec.check(data, msg.is_fd, msg.is_remote_frame)
                hb = self.last_heartbeat
                age = msg.timestamp - self._hb_stamp
                done = self._assembler.push(part, counter, data, unpack,
                                            (hb.cycle, age) if hb and age < HEARTBEAT_FRESH_S
                                            else None)
                if done is None:
                    return None
                return self._js.state(*done)
            if msg.is_extended_id:
                pass
            elif fid == self._hb_id:
                self._heartbeat(msg)
                return None
            elif fid == self._ack_id:
                self._load_ack(msg)
                return None
        except DecodeError as exc:
            setattr(c, exc.kind, getattr(c, exc.kind) + 1)
            self.last_error = exc
            return None
        c.foreign += 1
        if len(self.foreign_ids) < 32 or fid in self.foreign_ids:
            self.foreign_ids[fid] = self.foreign_ids.get(fid, 0) + 1
        return None

    def _heartbeat(self, msg: can.Message) -> None:
        codec = self.profile.heartbeat
        data = bytes(msg.data)
        codec.frame.check(data, msg.is_fd, msg.is_remote_frame)
        self.last_heartbeat = codec.decode(data, t=time.perf_counter())
        self._hb_stamp = msg.timestamp
        self.counters.heartbeats += 1

    def _load_ack(self, msg: can.Message) -> None:
        codec = self.profile.ack
        data = bytes(msg.data)
        codec.frame.check(data, msg.is_fd, msg.is_remote_frame)
        before = self._ack.orphaned
        raw = self._ack.push(data)
        self.counters.orphaned += self._ack.orphaned - before
        if raw is None:
            return
        seq, status, load = codec.values(raw)
        ack = LoadAck(seq=seq, applied=status == 0, load=load, t=time.perf_counter(),
                      error=ACK_ERRORS.get(status, ""))
        self.last_ack = ack
        self.acks[seq] = ack
        self.counters.acks += 1

    def diagnosis(self) -> str:
        """Why frames might not be getting through, in words (for silence messages)."""
        c = self.counters
        parts = [c.summary()]
        if c.error_frames:
            parts.append(f"{c.error_frames} error frames: check bitrate, termination, wiring")
        if self.last_error is not None:
            parts.append(f"last bad frame: {self.last_error}")
        if self.foreign_ids:
            ids = ", ".join(f"0x{k:03X}" for k in sorted(self.foreign_ids)[:8])
            other = next(p for p in PROFILES if p != self.profile.name)
            theirs = {f.frame_id for f in get_profile(other).frames()}
            hint = (f" (the {other} profile's IDs: is the controller running --profile {other}?)"
                    if theirs & set(self.foreign_ids) else "")
            parts.append(f"frames with other IDs seen: {ids}{hint}")
        parts.append(heartbeat_text(self.last_heartbeat))
        return "; ".join(parts)


class CanLink(FramedLink):
    """The plug-in's end of the CAN protocol on one bus: joint-state source and payload sink
    (``read``, ``send``, ``wait_ack``, ``close``: :class:`~firmware_bridge.framed.FramedLink`).

    Args:
        bus: an open python-can bus.
        profile: ``"fd"`` or ``"classic"``.
        silence_timeout: default ``read`` timeout, s.
        window: how many published cycles back a late cycle counts as ``out_of_order``
            rather than ``stale``.
        name: how the link names itself in messages.
        owns_bus: close the bus with the link.
    """

    profile: WireProfile
    """Its wire profile: the gate checks a load against the DBC signals' ranges before it is
    sent (:class:`~firmware_bridge.links.WireProfiled`)."""

    def __init__(self, bus: can.BusABC, profile: str = "fd", *, silence_timeout: float = 0.1,
                 window: int = 16, name: str | None = None, owns_bus: bool = True) -> None:
        self.bus = bus
        self.profile = get_profile(profile)
        self.decoder = CanDecoder(self.profile, window=window)
        super().__init__(
            name=name or f"{getattr(bus, 'channel_info', 'CAN bus')} ({profile} profile)",
            rate_hz=self.profile.joint_state.rate_hz, silence_timeout=silence_timeout)
        self._owns_bus = owns_bus
        self._cmd_counter = 0

    @classmethod
    def open(cls, kind: str, channel: str, profile: str = "fd", *,
             bus_options: dict | None = None, **link_options) -> CanLink:
        """Open a bus of link ``kind`` (a CAN bus kind of ``LINKS``) and a link on it."""
        bus = open_bus(kind, channel, profile, **(bus_options or {}))
        return cls(bus, profile, name=f"{kind} bus {channel!r} ({profile} profile)",
                   **link_options)

    def _receive(self, timeout: float) -> None:
        try:
            msg = self.bus.recv(timeout)
        except can.CanError as exc:
            raise LinkError(f"{self.name}: receiving failed: {exc}") from exc
        if msg is not None:
            state = self.decoder.push(msg)
            if state is not None:
                self._deliver(state, msg.timestamp)

    def _transmit(self, seq: int, payload: Payload | None) -> None:
        codec = self.profile.command
        frames, self._cmd_counter = codec.encode(seq, payload, self._cmd_counter)
        for data in frames:
            try:
                self.bus.send(can_message(codec.frame, data), timeout=SEND_TIMEOUT)
            except can.CanError as exc:
                raise LinkError(f"{self.name}: sending the payload command failed: {exc}"
                                ) from exc

    def _shutdown(self) -> None:
        if self._owns_bus:
            try:
                self.bus.shutdown()
            except (can.CanError, OSError) as exc:
                raise LinkError(f"{self.name}: closing the bus failed: {exc}") from exc


def open_can_link(kind: str, channel: str, *, profile: str = "fd", silence_timeout: float = 0.1,
                  window: int = 16, bus_options: dict | None = None) -> CanLink:
    """Opener for :func:`firmware_bridge.links.open_link` (the CAN bus kinds)."""
    return CanLink.open(kind, channel, profile, bus_options=bus_options,
                        silence_timeout=silence_timeout, window=window)


# -- the controller's side -----------------------------------------------------------------
class CanControllerPort(FramedControllerPort):
    """The controller's end: publishes joint state, heartbeats and acks; receives commands.

    ``publish`` is called every controller cycle and sends every ``stride``-th (the
    profile's rate). Frames pass through the optional fault injector
    (:class:`~firmware_bridge.framed.FramedControllerPort`).
    """

    def __init__(self, bus: can.BusABC, profile: str = "fd", faults: FaultSpec | None = None,
                 owns_bus: bool = True, record_faults: bool = False) -> None:
        super().__init__(faults, record_faults, owns=owns_bus)
        self.bus = bus
        self.profile = get_profile(profile)
        self.stride = self.profile.joint_state.stride
        self._js_counter = 0
        self._hb_counter = 0
        self._ack_counter = 0
        self._cmd = LoadAssembler(self.profile.command)
        self._cmd_id = self.profile.command.frame.frame_id
        self.saturated = 0

    def _open(self) -> bool:
        return getattr(self.bus, "is_open", True)

    def _emit(self, codec, data: bytes) -> None:
        try:
            self.bus.send(can_message(codec, data), timeout=SEND_TIMEOUT)
            self.sent += 1
        except can.CanError as exc:
            self._send_failed(codec, exc)

    def _shutdown(self) -> None:
        self.bus.shutdown()

    def publish(self, state: JointState) -> None:
        if state.cycle % self.stride:
            return
        frames, saturated = self.profile.joint_state.encode(state, self._js_counter)
        self._js_counter = (self._js_counter + 1) & 0x0F
        self.saturated += saturated
        for codec, data in frames:
            self._send(codec, data)

    def heartbeat(self, hb: Heartbeat) -> None:
        codec = self.profile.heartbeat
        data = codec.encode(hb.state, hb.load_seq, hb.cycle, hb.overruns, self._hb_counter)
        self._hb_counter = (self._hb_counter + 1) & 0x0F
        self._send(codec.frame, data)

    def send_ack(self, ack: LoadAck) -> None:
        codec = self.profile.ack
        status = 0 if ack.applied else (2 if ack.error == ACK_ERRORS[2] else 1)
        frames, self._ack_counter = codec.encode(ack.seq, ack.load, self._ack_counter,
                                                 status=status)
        for data in frames:
            self._send(codec.frame, data)

    def poll_commands(self) -> list[LoadCommand]:
        """Every complete payload command received since the last call (non-blocking)."""
        out = []
        c = self.counters
        codec = self.profile.command
        while True:
            try:
                msg = self.bus.recv(0.0)
            except can.CanError as exc:
                raise LinkError(f"controller port: receiving failed: {exc}") from exc
            if msg is None:
                return out
            c.received += 1
            if msg.is_error_frame:
                c.error_frames += 1
                continue
            if msg.is_extended_id or msg.arbitration_id != self._cmd_id:
                c.foreign += 1
                continue
            try:
                data = bytes(msg.data)
                codec.frame.check(data, msg.is_fd, msg.is_remote_frame)
                before = self._cmd.orphaned
                raw = self._cmd.push(data)
                c.orphaned += self._cmd.orphaned - before
                if raw is not None:
                    seq, _, load = codec.values(raw)
                    out.append(LoadCommand(seq=seq, load=load))
            except DecodeError as exc:
                setattr(c, exc.kind, getattr(c, exc.kind) + 1)
