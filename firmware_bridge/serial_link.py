"""The serial link: msgpack messages over pyserial, framed so a bad byte costs one message.

The wire (COBS + CRC32 framing, msgpack messages) is :mod:`firmware_bridge.serial_wire`.

Drops are counted as on CAN (see :class:`~firmware_bridge.links.LinkCounters`): ``crc``
(CRC32 mismatch), ``malformed`` (bad COBS, too short, not msgpack, wrong schema),
``duplicate`` (the same message bytes as the last delivered), ``out_of_order``/``stale``
(cycle order), ``lost`` (cycle gaps, in published cycles of ``stride``).
"""

from __future__ import annotations

import time
import zlib

import numpy as np

from iem.payload import Payload
from iem.types import NOMINAL_RATE_HZ, JointState

from .errors import DecodeError, LinkError
from .faults import FaultSpec
from .framed import FramedControllerPort, FramedLink, heartbeat_text
from .links import LinkCounters
from .messages import Heartbeat, LoadAck, LoadCommand
from .reassembly import Sequencer
from .serial_wire import (
    Deframer,
    cobs_encode,
    decode_message,
    encode_ack,
    encode_command,
    encode_heartbeat,
    encode_joint_state,
    frame,
    unframe,
)


# -- the plug-in's side --------------------------------------------------------------------
def open_serial(url: str, baudrate: int = 1_000_000, timeout: float = 0.01):
    """A pyserial port on a device or URL (``loop://``, ``socket://``, ``rfc2217://``)."""
    import serial

    try:
        return serial.serial_for_url(url, baudrate=baudrate, timeout=timeout)
    except (serial.SerialException, ValueError, OSError) as exc:
        raise LinkError(f"cannot open serial port {url!r}: {exc}") from exc


class SerialDecoder:
    """Bytes in, joint states out; heartbeats and acks kept."""

    def __init__(self, counters: LinkCounters | None = None, stride: int = 1,
                 window: int = 16) -> None:
        self.counters = LinkCounters() if counters is None else counters
        self.deframer = Deframer()
        self.seq = Sequencer(self.counters, stride=stride, window=window)
        self._last_body: bytes | None = None
        self.last_heartbeat: Heartbeat | None = None
        self.last_ack: LoadAck | None = None
        self.acks: dict[int, LoadAck] = {}
        self.last_error: DecodeError | None = None

    def feed(self, data: bytes) -> list[JointState]:
        c = self.counters
        before = self.deframer.oversize
        frames = self.deframer.feed(data)
        c.malformed += self.deframer.oversize - before
        out = []
        for encoded in frames:
            c.received += 1
            try:
                state = self._message(unframe(encoded))
            except DecodeError as exc:
                setattr(c, exc.kind, getattr(c, exc.kind) + 1)
                self.last_error = exc
                continue
            if state is not None:
                out.append(state)
        return out

    def _message(self, body: bytes) -> JointState | None:
        c = self.counters
        tag, f = decode_message(body)
        if tag == "J":
            if body == self._last_body:
                c.duplicate += 1
                return None
            cycle = f[0]
            hb = self.last_heartbeat
            verdict = self.seq.judge(cycle, None if hb is None else
                                     (hb.cycle, time.perf_counter() - hb.t))
            if verdict != "deliver":
                setattr(c, verdict, getattr(c, verdict) + 1)
                return None
            self.seq.deliver(cycle)
            self._last_body = body
            return JointState(t=f[1], q=np.array(f[2]), dq=np.array(f[3]),
                              tau_J=np.array(f[4]), cycle=cycle)
        now = time.perf_counter()
        if tag == "H":
            self.last_heartbeat = Heartbeat(*f, t=now)
            c.heartbeats += 1
        elif tag == "A":
            seq, applied, load, error = f
            self.last_ack = self.acks[seq] = LoadAck(seq=seq, applied=applied, load=load, t=now,
                                                     error=error)
            c.acks += 1
        else:
            c.foreign += 1  # a command: the other direction
        return None

    def resync(self) -> None:
        self.seq.resync()

    def diagnosis(self) -> str:
        """Why messages might not be getting through, in words (for silence messages)."""
        parts = [self.counters.summary()]
        if self.last_error is not None:
            parts.append(f"last bad message: {self.last_error}")
        parts.append(heartbeat_text(self.last_heartbeat))
        return "; ".join(parts)


class SerialLink(FramedLink):
    """The plug-in's end of the serial link: joint-state source and payload sink (``read``,
    ``send``, ``wait_ack``, ``close``: :class:`~firmware_bridge.framed.FramedLink`).

    Args:
        port: an open pyserial port (or anything with ``read``, ``write``, ``in_waiting``).
        silence_timeout: default ``read`` timeout, s.
        stride: controller cycles per published cycle (for ``lost``).
        name: how the link names itself in messages.
    """

    def __init__(self, port, *, silence_timeout: float = 0.1, stride: int = 1,
                 window: int = 16, name: str | None = None, owns_port: bool = True) -> None:
        self.port = port
        self.decoder = SerialDecoder(stride=stride, window=window)
        super().__init__(name=name or f"serial link {getattr(port, 'name', port)!r}",
                         rate_hz=NOMINAL_RATE_HZ / max(1, int(stride)),
                         silence_timeout=silence_timeout)
        self._owns_port = owns_port

    def _receive(self, timeout: float) -> None:
        """Read what is there (waiting up to the port's own timeout)."""
        try:
            data = self.port.read(max(1, self.port.in_waiting))
        except Exception as exc:  # pyserial raises SerialException and OSError subclasses
            raise LinkError(f"{self.name}: reading failed: {exc}") from exc
        if data:
            states = self.decoder.feed(data)
            if states:
                now = time.time()
                for state in states:
                    self._deliver(state, now)

    def _transmit(self, seq: int, payload: Payload | None) -> None:
        body = encode_command(seq, payload)
        try:
            self.port.write(frame(body))
        except Exception as exc:
            raise LinkError(f"{self.name}: sending the payload command failed: {exc}") from exc

    def _shutdown(self) -> None:
        if self._owns_port:
            self.port.close()


def open_serial_link(kind: str, channel: str, *, profile: str = "fd",
                     silence_timeout: float = 0.1, baudrate: int = 1_000_000, stride: int = 1,
                     window: int = 16) -> SerialLink:
    """Opener for :func:`firmware_bridge.links.open_link`: ``channel`` is a device or URL
    (``profile`` is a CAN notion and not used)."""
    return SerialLink(open_serial(channel, baudrate), name=f"serial link {channel!r}",
                      silence_timeout=silence_timeout, stride=stride, window=window)


# -- the controller's side -----------------------------------------------------------------
class SerialControllerPort(FramedControllerPort):
    """The controller's end of the serial link (see
    :class:`deploy.simcell.controller.SimController`).

    Faults apply to ``body + CRC32`` before COBS, so a corrupted message fails its CRC.
    """

    def __init__(self, port, faults: FaultSpec | None = None, stride: int = 1,
                 owns_port: bool = True, record_faults: bool = False) -> None:
        super().__init__(faults, record_faults, owns=owns_port)
        self.port = port
        self.stride = max(1, int(stride))
        self.deframer = Deframer()

    def _emit(self, key, raw: bytes) -> None:
        try:
            if self.port.write(cobs_encode(raw) + b"\x00") == 0:  # a full backlog: dropped
                raise OSError("the serial port's backlog is full: the message was dropped")
            self.sent += 1
        except Exception as exc:  # a controller keeps its cycle; the count tells
            self._send_failed(key, exc)

    def _send(self, body: bytes, key: str) -> None:
        super()._send(key, body + zlib.crc32(body).to_bytes(4, "little"))

    def _shutdown(self) -> None:
        self.port.close()

    def publish(self, state: JointState) -> None:
        if state.cycle % self.stride == 0:
            self._send(encode_joint_state(state), "J")

    def heartbeat(self, hb: Heartbeat) -> None:
        self._send(encode_heartbeat(hb), "H")

    def send_ack(self, ack: LoadAck) -> None:
        self._send(encode_ack(ack), "A")

    def poll_commands(self) -> list[LoadCommand]:
        out = []
        try:
            waiting = self.port.in_waiting
            data = self.port.read(waiting) if waiting else b""
        except Exception as exc:
            raise LinkError(f"controller port: reading failed: {exc}") from exc
        if not data:
            return out
        c = self.counters
        before = self.deframer.oversize
        frames = self.deframer.feed(data)
        c.malformed += self.deframer.oversize - before
        for encoded in frames:
            c.received += 1
            try:
                tag, f = decode_message(unframe(encoded))
            except DecodeError as exc:
                setattr(c, exc.kind, getattr(c, exc.kind) + 1)
                continue
            if tag == "L":
                out.append(LoadCommand(seq=f[0], load=f[1]))
            else:
                c.foreign += 1
        return out
