"""The serial link's wire: msgpack messages, framed so a bad byte costs one message.

Framing (both directions): ``COBS(body + CRC32(body)) + b"\\x00"``, where ``body`` is one
msgpack message and CRC32 is ``zlib.crc32`` as 4 bytes little-endian. COBS (consistent
overhead byte stuffing, Cheshire and Baker 1999) removes every 0x00 from the frame, so 0x00
only ever delimits frames: after garbage or lost bytes the receiver drops what it has up to
the next 0x00 and is in step again. (A plain msgpack stream cannot do this: its streaming
Unpacker cannot find the next message after a lost byte.) Frames longer than ``MAX_FRAME``
bytes without a delimiter are discarded up to the next one.

Messages (msgpack arrays; numbers as msgpack floats/ints):

- ``["J", cycle, t, q[7], dq[7], tau_J[7]]``: joint state (cycle modulo 2**32, t in s,
  rad, rad/s, N·m); about 215 bytes framed, so 1 kHz needs about 2.2 Mbit/s of line rate;
- ``["H", state, load_seq, cycle, overruns]``: heartbeat (state 0 running, 1 holding);
- ``["L", seq, mass, [x, y, z], [9 values]]``: payload command, exactly libfranka's
  ``setLoad(load_mass, F_x_Cload, load_inertia)`` (inertia column-major); mass 0 clears;
- ``["A", seq, applied, mass, [x, y, z], [9 values]]``: acknowledgement with the load in
  force (mass 0: none); a refusal may add a seventh field, the error text (a string).
"""

from __future__ import annotations

import math
import zlib

import msgpack

from iem.payload import Payload, set_load_values
from iem.types import N_JOINTS, JointState

from .errors import DecodeError
from .messages import Heartbeat, LoadAck
from .reassembly import CYCLE_MOD

MAX_FRAME = 4096
"""Longest frame accepted (bytes between delimiters)."""
HEARTBEAT_STATES = ("running", "holding")


# -- COBS ----------------------------------------------------------------------------------
def cobs_encode(data: bytes) -> bytes:
    """COBS-encode ``data`` (the result contains no 0x00; the delimiter is not added)."""
    out = bytearray()
    for chunk in data.split(b"\x00"):
        while len(chunk) >= 254:
            out.append(0xFF)
            out += chunk[:254]
            chunk = chunk[254:]
        out.append(len(chunk) + 1)
        out += chunk
    return bytes(out)


def cobs_decode(data: bytes) -> bytes:
    """Inverse of :func:`cobs_encode`; DecodeError (malformed) for an invalid encoding."""
    out = bytearray()
    i, n = 0, len(data)
    while i < n:
        code = data[i]
        if code == 0:
            raise DecodeError("serial frame: a 0x00 inside a COBS frame")
        end = i + code
        if end > n:
            raise DecodeError(f"serial frame: COBS block of {code - 1} bytes runs past the "
                              f"end of the {n}-byte frame")
        out += data[i + 1:end]
        i = end
        if code < 0xFF and i < n:
            out.append(0)
    return bytes(out)


def frame(body: bytes) -> bytes:
    """``COBS(body + CRC32(body)) + 0x00``."""
    return cobs_encode(body + zlib.crc32(body).to_bytes(4, "little")) + b"\x00"


def unframe(encoded: bytes) -> bytes:
    """The body of one frame (delimiter already removed); DecodeError if bad."""
    raw = cobs_decode(encoded)
    if len(raw) < 5:
        raise DecodeError(f"serial frame: {len(raw)} bytes after COBS; valid is at least 5 "
                          "(a message and its CRC32)")
    body, crc = raw[:-4], int.from_bytes(raw[-4:], "little")
    if zlib.crc32(body) != crc:
        raise DecodeError("serial frame: CRC32 mismatch", kind="crc")
    return body


class Deframer:
    """Bytes in, complete frames out (delimiters stripped, empty frames skipped)."""

    def __init__(self, max_frame: int = MAX_FRAME) -> None:
        self.max_frame = max_frame
        self._buf = bytearray()
        self._skipping = False
        self.oversize = 0

    def feed(self, data: bytes) -> list[bytes]:
        self._buf += data
        if b"\x00" not in data:
            if len(self._buf) > self.max_frame:
                self._buf.clear()
                if not self._skipping:
                    self.oversize += 1
                self._skipping = True
            return []
        parts = bytes(self._buf).split(b"\x00")
        tail = parts.pop()
        if self._skipping:
            parts = parts[1:]  # the rest of the oversize frame
            self._skipping = False
        self._buf = bytearray(tail)
        out = []
        for p in parts:
            if len(p) > self.max_frame:
                self.oversize += 1
            elif p:
                out.append(p)
        return out


# -- messages ------------------------------------------------------------------------------
def _unpack(body: bytes):
    try:
        return msgpack.unpackb(body, raw=False, use_list=True, strict_map_key=True)
    except (ValueError, TypeError, msgpack.UnpackException, UnicodeDecodeError,
            OverflowError, RecursionError) as exc:
        raise DecodeError(f"serial message: not valid msgpack ({type(exc).__name__}: {exc})"
                          ) from None


def _number(value, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise DecodeError(f"serial message: {what} must be a number, got "
                          f"{type(value).__name__}")
    value = float(value)
    if not math.isfinite(value):
        raise DecodeError(f"serial message: {what} must be finite, got {value}")
    return value


def _int(value, what: str, lo: int, hi: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
        raise DecodeError(f"serial message: {what} must be an integer in {lo}..{hi}, "
                          f"got {value!r}")
    return value


def _numbers(value, n: int, what: str) -> list[float]:
    if not isinstance(value, list) or len(value) != n:
        raise DecodeError(f"serial message: {what} must be a list of {n} numbers, got "
                          f"{type(value).__name__}"
                          + (f" of {len(value)}" if isinstance(value, list) else ""))
    return [_number(v, f"{what}[{i}]") for i, v in enumerate(value)]


def _shape(msg, tag: str, n: int) -> None:
    if len(msg) != n:
        raise DecodeError(f"serial message {tag!r}: {len(msg)} fields; valid is {n}")


def decode_message(body: bytes):
    """``(tag, fields)`` of a checked body; every schema problem is a DecodeError."""
    msg = _unpack(body)
    if not isinstance(msg, list) or not msg or msg[0] not in ("J", "H", "L", "A"):
        tag = msg[0] if isinstance(msg, list) and msg else msg
        raise DecodeError(f"serial message: must be an array starting with 'J', 'H', 'L' or "
                          f"'A', got {str(tag)[:40]!r}")
    tag = msg[0]
    if tag == "J":
        _shape(msg, tag, 6)
        return tag, (_int(msg[1], "cycle", 0, CYCLE_MOD - 1), _number(msg[2], "t"),
                     _numbers(msg[3], N_JOINTS, "q"), _numbers(msg[4], N_JOINTS, "dq"),
                     _numbers(msg[5], N_JOINTS, "tau_J"))
    if tag == "H":
        _shape(msg, tag, 5)
        state = _int(msg[1], "state", 0, len(HEARTBEAT_STATES) - 1)
        return tag, (HEARTBEAT_STATES[state], _int(msg[2], "load_seq", 0, 255),
                     _int(msg[3], "cycle", 0, CYCLE_MOD - 1),
                     _int(msg[4], "overruns", 0, 1 << 62))
    if tag == "L":
        _shape(msg, tag, 5)
        return tag, (_int(msg[1], "seq", 0, 255), _load(msg[2], msg[3], msg[4]))
    if len(msg) != 7:
        _shape(msg, tag, 6)
    if not isinstance(msg[2], bool):
        raise DecodeError(f"serial message 'A': applied must be true or false, got {msg[2]!r}")
    error = msg[6] if len(msg) == 7 else ""
    if not isinstance(error, str):
        raise DecodeError(f"serial message 'A': the error text must be a string, got "
                          f"{type(error).__name__}")
    return tag, (_int(msg[1], "seq", 0, 255), msg[2], _load(msg[3], msg[4], msg[5]), error)


def _load(mass, com, inertia) -> Payload | None:
    m = _number(mass, "mass")
    c = _numbers(com, 3, "F_x_Cload")
    i9 = _numbers(inertia, 9, "load_inertia")
    if m == 0.0:
        return None
    return Payload.from_set_load(m, c, i9, name="serial")


def _load_args(load) -> list:
    return list(set_load_values(load))


def encode_joint_state(state: JointState) -> bytes:
    return msgpack.packb(["J", int(state.cycle) % CYCLE_MOD, float(state.t), state.q.tolist(),
                          state.dq.tolist(), state.tau_J.tolist()])


def encode_heartbeat(hb: Heartbeat) -> bytes:
    state = HEARTBEAT_STATES.index(hb.state)
    return msgpack.packb(["H", state, hb.load_seq, hb.cycle % CYCLE_MOD, hb.overruns])


def encode_command(seq: int, load: Payload | None) -> bytes:
    return msgpack.packb(["L", seq, *_load_args(load)])


def encode_ack(ack: LoadAck) -> bytes:
    error = [ack.error] if ack.error else []
    return msgpack.packb(["A", ack.seq, bool(ack.applied), *_load_args(ack.load), *error])
