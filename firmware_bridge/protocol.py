"""The wire protocol: ``protocol.dbc`` loaded once with cantools, and the codecs built from it.

The DBC is the single source of truth: frame IDs, lengths, CAN FD or classic, signal
positions, widths, scaling and ranges, cycle times, bitrates and the E2E data identifiers all
come from it. This module turns each DBC message into a :class:`FrameCodec` (bit fields,
little-endian, as the DBC declares them) once, at first use; the hot path then unpacks a
frame with one ``int.from_bytes`` and a shift and mask per signal. The tests check every
codec against cantools' own encoder and decoder on the same DBC.

Two profiles (:func:`profile`):

- ``fd``: the whole joint state in one 64-byte CAN FD frame every 1 ms (``JointStateFD``);
  payload command and acknowledgement in one 32-byte FD frame each.
- ``classic``: 8-byte frames. A cycle is ``JointStateHeader`` (cycle counter, time) and
  ``JointState1..7`` (one joint each), all with the same E2E alive counter, at the rate the
  DBC gives (``GenMsgCycleTime``; 2 ms, the largest standard rate under 60 % of 1 Mbit/s,
  see :mod:`firmware_bridge.busload`). Payload command and acknowledgement are five
  multiplexed frames each (``Mux`` 0..4) with the same ``Seq``.

Both profiles share the ``Heartbeat`` (classic frame, every 100 ms).

Resolutions (all below the default sensor noise of :class:`sim.plant.SensorModel`):
q 1e-5 rad (±5.24 rad), dq 1e-4 rad/s (±3.28 rad/s), tau_J 0.01 N·m (±327 N·m); payload mass
1e-4 kg (0..13.1 kg), CoM 1e-5 m (±1.31 m), inertia 1e-6 kg·m² (±0.524 kg·m²). Joint values
outside their range are saturated by the sender (and counted there); payload values outside
theirs are refused with :class:`~firmware_bridge.errors.EncodeError`.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path as FsPath

import numpy as np

from iem.payload import Payload
from iem.types import N_JOINTS, JointState

from .e2e import Profile2
from .errors import BridgeConfigError, DecodeError, EncodeError

DBC_PATH = FsPath(__file__).with_name("protocol.dbc")

PROFILES = ("fd", "classic")
"""The wire profiles (:func:`profile`): every ``--profile`` and ``[link] profile`` takes its
choices from here."""

STATE_FIELDS: tuple[str, ...] = (
    "Cycle", "Time",
    *(f"Q{j}" for j in range(1, N_JOINTS + 1)),
    *(f"DQ{j}" for j in range(1, N_JOINTS + 1)),
    *(f"Tau{j}" for j in range(1, N_JOINTS + 1)),
)
"""The raw values of one cycle, in the order the reassembly keeps them."""
STATE_INDEX = {name: i for i, name in enumerate(STATE_FIELDS)}

PAYLOAD_FIELDS = ("Mass", "ComX", "ComY", "ComZ", "Ixx", "Ixy", "Ixz", "Iyy", "Iyz", "Izz")

_MESSAGES = {
    "fd": {"joint_state": ("JointStateFD",), "command": "LoadCommandFD",
           "ack": "LoadAckFD", "heartbeat": "Heartbeat"},
    "classic": {"joint_state": ("JointStateHeader",
                                *(f"JointState{j}" for j in range(1, N_JOINTS + 1))),
                "command": "LoadCommand", "ack": "LoadAck", "heartbeat": "Heartbeat"},
}

ACK_STATUS = {0: "applied", 1: "rejected_inconsistent", 2: "refused_moving"}
ACK_ERRORS = {1: "the load is not physically consistent",
              2: "command not possible in the current mode (the arm is moving)"}
"""The error text of a refusal status (the wire carries only the status)."""


# -- value types ---------------------------------------------------------------------------
@dataclass(frozen=True)
class LoadCommand:
    """A payload command as the controller receives it.

    Attributes:
        seq: sequence number, 1..255 (0 is never sent).
        load: the load to set (mass kg, CoM m in the flange frame, inertia kg·m² about the
            CoM), or None to clear it (sent as mass 0).
    """

    seq: int
    load: Payload | None


@dataclass(frozen=True)
class LoadAck:
    """The controller's acknowledgement of a payload command.

    Attributes:
        seq: the command's sequence number.
        applied: True if the load was set; False if refused (not physically consistent,
            or the controller does not take load commands now, e.g. while the arm moves).
        load: the load now in force (after the command, or the previous one if refused);
            None if no load is set.
        t: ``time.perf_counter()`` when it was received, s.
        error: why it was refused, in the controller's words (libfranka's exception text,
            e.g. "command not possible in the current mode"); empty when applied, and on
            the CAN wire, which carries only the status.
    """

    seq: int
    applied: bool
    load: Payload | None
    t: float = 0.0
    error: str = ""


@dataclass(frozen=True)
class Heartbeat:
    """The controller's heartbeat.

    Attributes:
        state: ``"running"`` (playing its path) or ``"holding"`` (at rest at the end).
        load_seq: sequence number of the load in force (0: none set by a command).
        cycle: the controller's cycle counter when it was sent.
        overruns: 1 kHz deadlines missed so far (saturates at 255 on CAN).
        t: ``time.perf_counter()`` when it was received, s.
    """

    state: str
    load_seq: int
    cycle: int
    overruns: int
    t: float = 0.0


# -- one message ---------------------------------------------------------------------------
class Field:
    """One little-endian signal: raw integer at ``start`` (LSB) of ``length`` bits."""

    __slots__ = ("length", "mask", "name", "raw_max", "raw_min", "scale", "sign", "signed",
                 "start", "unit")

    def __init__(self, signal) -> None:
        if signal.byte_order != "little_endian":
            raise BridgeConfigError(f"signal {signal.name}: the bridge expects little-endian "
                                    f"signals, the DBC says {signal.byte_order}")
        if signal.conversion.offset != 0:
            raise BridgeConfigError(f"signal {signal.name}: offsets are not used, got "
                                    f"{signal.conversion.offset}")
        self.name = signal.name
        self.start = signal.start
        self.length = signal.length
        self.signed = signal.is_signed
        self.scale = float(signal.conversion.scale)
        self.unit = signal.unit or ""
        self.mask = (1 << self.length) - 1
        self.sign = 1 << (self.length - 1) if self.signed else 0
        self.raw_min = -(1 << (self.length - 1)) if self.signed else 0
        self.raw_max = (1 << (self.length - 1)) - 1 if self.signed else self.mask

    def get(self, word: int) -> int:
        r = (word >> self.start) & self.mask
        return r - (self.sign << 1) if r & self.sign else r

    def raw_of(self, value: float, where: str) -> int:
        """The raw integer of a physical value; EncodeError if it is outside the range."""
        value = float(value)
        raw = round(value / self.scale) if math.isfinite(value) else None
        if raw is None or not self.raw_min <= raw <= self.raw_max:
            lo, hi = self.raw_min * self.scale, self.raw_max * self.scale
            raise EncodeError(f"{where}: {value!r} {self.unit} does not fit signal {self.name}; "
                              f"valid is [{lo:.10g}, {hi:.10g}] {self.unit} in steps of "
                              f"{self.scale:g}")
        return raw


class FrameCodec:
    """One DBC message: its fields, length, FD flag, E2E protection and cycle time."""

    def __init__(self, message) -> None:
        attrs = message.dbc.attributes if message.dbc else {}
        self.name = message.name
        self.frame_id = message.frame_id
        self.length = message.length
        self.is_fd = bool(message.is_fd)
        self.cycle_ms = message.cycle_time
        self.profile = attrs["IemProfile"].value if "IemProfile" in attrs else ""
        where = f"DBC message {self.name} (0x{self.frame_id:03X})"
        if "E2EDataIDList" not in attrs:
            raise BridgeConfigError(f"{where}: has no E2EDataIDList; every frame is protected")
        self.e2e = Profile2.from_attribute(attrs["E2EDataIDList"].value, where)
        self.label = f"{self.name} (0x{self.frame_id:03X})"
        self.fields = {s.name: Field(s) for s in message.signals}
        mux = [s for s in message.signals if s.is_multiplexer]
        self.mux = self.fields[mux[0].name] if mux else None
        layouts: dict[int | None, list[Field]] = {}
        for s in message.signals:
            if s.name in ("E2E_CRC", "E2E_Counter") or s.is_multiplexer:
                continue
            for key in (s.multiplexer_ids or [None]):
                layouts.setdefault(key, []).append(self.fields[s.name])
        if self.mux is not None:
            shared = layouts.pop(None, [])
            for key in layouts:
                layouts[key] = shared + layouts[key]
        self.layouts = {k: tuple(v) for k, v in layouts.items()}

    def check(self, data, is_fd: bool, is_remote: bool = False) -> int:
        """Validate a received frame; return its alive counter or raise DecodeError."""
        if is_remote:
            raise DecodeError(f"{self.label}: remote frame; only data frames are valid")
        if len(data) != self.length:
            raise DecodeError(f"{self.label}: {len(data)} data bytes; valid is exactly "
                              f"{self.length}")
        if bool(is_fd) != self.is_fd:
            want = "a CAN FD frame" if self.is_fd else "a classic CAN frame"
            raise DecodeError(f"{self.label}: must be {want}, got the other kind")
        if not self.e2e.check(data):
            raise DecodeError(f"{self.label}: E2E CRC8 mismatch (AUTOSAR profile 2, "
                              f"counter {data[1] & 0x0F})", kind="crc")
        return data[1] & 0x0F

    def unpack(self, data) -> dict[str, int]:
        """Raw integers of the frame's fields (including ``Mux``); unknown mux: malformed."""
        word = int.from_bytes(data, "little")
        key = None
        out = {}
        if self.mux is not None:
            key = self.mux.get(word)
            out[self.mux.name] = key
            if key not in self.layouts:
                raise DecodeError(f"{self.label}: multiplexer value {key}; valid is "
                                  f"{sorted(self.layouts)}")
        for f in self.layouts[key]:
            out[f.name] = f.get(word)
        return out

    def pack(self, raw: Mapping[str, int], counter: int, mux: int | None = None) -> bytes:
        """A protected frame from raw integers (range-checked); ``counter`` is the alive
        counter, ``mux`` the multiplexer value for multiplexed messages."""
        word = 0
        if self.mux is not None:
            if mux not in self.layouts:
                raise EncodeError(f"{self.label}: multiplexer value {mux!r}; valid is "
                                  f"{sorted(self.layouts)}")
            word = (mux & self.mux.mask) << self.mux.start
        for f in self.layouts[mux if self.mux is not None else None]:
            r = int(raw[f.name])
            if not f.raw_min <= r <= f.raw_max:
                raise EncodeError(f"{self.label}: raw {f.name} = {r} outside "
                                  f"[{f.raw_min}, {f.raw_max}]")
            word |= (r & f.mask) << f.start
        buf = bytearray(word.to_bytes(self.length, "little"))
        return bytes(self.e2e.protect(buf, counter))


# -- the joint state -----------------------------------------------------------------------
class JointStateCodec:
    """The joint-state frames of one profile: parts of a cycle, hot-path decode, encode.

    Decoding unpacks each part with a ``bitstruct`` format compiled once from the DBC (the
    frame's bytes reversed make its little-endian signals one big-endian bit string); a
    complete cycle is the concatenation of its parts' tuples, permuted once into
    ``STATE_FIELDS`` order.
    """

    def __init__(self, parts: tuple[FrameCodec, ...], period_us: int) -> None:
        self.parts = parts
        self.period_us = period_us
        cycle_ms = parts[0].cycle_ms
        if not cycle_ms or any(p.cycle_ms != cycle_ms for p in parts):
            raise BridgeConfigError(f"joint-state messages {[p.name for p in parts]} need one "
                                    "common GenMsgCycleTime")
        self.cycle_ms = cycle_ms
        self.rate_hz = 1000.0 / cycle_ms
        self.stride = round(cycle_ms * 1000 / period_us)
        """Controller cycles per published cycle."""
        fields_: dict[str, Field] = {}
        order: list[str] = []
        self.by_id: dict[int, tuple[int, FrameCodec, object]] = {}
        for k, part in enumerate(parts):
            names, unpack = _compile(part)
            for name in names:
                if name not in STATE_INDEX or name in fields_:
                    raise BridgeConfigError(f"{part.label}: unexpected signal {name}")
                fields_[name] = part.fields[name]
            order += names
            self.by_id[part.frame_id] = (k, part, unpack)
            if k == 0:
                if "Time" not in names or "Cycle" not in names:
                    raise BridgeConfigError(f"{part.label}: the first part carries Cycle and "
                                            "Time")
                self.cycle_pos, self.time_pos = names.index("Cycle"), names.index("Time")
        missing = set(STATE_FIELDS) - set(fields_)
        if missing:
            raise BridgeConfigError(f"joint-state messages lack signals {sorted(missing)}")
        self.fields = fields_
        self.time_bits = fields_["Time"].length
        self.time_scale = fields_["Time"].scale
        self.cycle_bits = fields_["Cycle"].length
        names = STATE_FIELDS[2:]
        self._perm = np.array([order.index(n) for n in names])
        self._scale = np.array([fields_[n].scale for n in names])
        self._lo = np.array([fields_[n].raw_min for n in names], dtype=np.int64)
        self._hi = np.array([fields_[n].raw_max for n in names], dtype=np.int64)

    def state(self, values: tuple, cycle: int, t: float) -> JointState:
        """The JointState of a complete cycle: ``values`` are its parts' tuples concatenated
        in part order, ``t`` the unwrapped time in s."""
        v = np.array(values, dtype=float)[self._perm] * self._scale
        v.flags.writeable = False  # the state keeps views of it without copying
        return JointState(t=t, q=v[0:7], dq=v[7:14], tau_J=v[14:21], cycle=cycle)

    def raw_values(self, state: JointState) -> tuple[dict[str, int], int]:
        """Raw integers of a state (saturated to the signal ranges) and how many saturated."""
        values = np.concatenate((state.q, state.dq, state.tau_J)) / self._scale
        if not np.all(np.isfinite(values)):
            raise EncodeError(f"joint state of cycle {state.cycle}: q, dq and tau_J must be "
                              "finite")
        ints = np.rint(values).astype(np.int64)
        clipped = np.clip(ints, self._lo, self._hi)
        saturated = int(np.count_nonzero(clipped != ints))
        raw = dict(zip(STATE_FIELDS[2:], clipped.tolist(), strict=True))
        raw["Cycle"] = int(state.cycle) & ((1 << self.cycle_bits) - 1)
        t_raw = round(state.t / self.time_scale)
        raw["Time"] = t_raw & ((1 << self.time_bits) - 1)
        return raw, saturated

    def encode(self, state: JointState, counter: int) -> tuple[list[tuple[FrameCodec, bytes]], int]:
        """The frames of one cycle (all with alive counter ``counter``) and the number of
        saturated values."""
        raw, saturated = self.raw_values(state)
        return [(p, p.pack(raw, counter)) for p in self.parts], saturated


def _compile(part: FrameCodec):
    """``(names, unpack)``: ``unpack(data)`` returns the raw values of the part's fields (E2E
    fields excluded) in the order ``names``; built with bitstruct's compiled formats."""
    try:
        import bitstruct.c as bitstruct  # the C extension: about 2 µs for a 64-byte frame
    except ImportError:  # pragma: no cover - the pure-Python fallback has the same API
        import bitstruct
    fields_ = sorted(part.layouts[None], key=lambda f: -f.start)
    fmt, pos = "", part.length * 8
    for f in fields_:
        gap = pos - (f.start + f.length)
        if gap < 0:
            raise BridgeConfigError(f"{part.label}: signal {f.name} overlaps another")
        fmt += (f"p{gap}" if gap else "") + ("s" if f.signed else "u") + str(f.length)
        pos = f.start
    if pos:
        fmt += f"p{pos}"
    compiled = bitstruct.compile(fmt)

    def unpack(data, _unpack=compiled.unpack):
        return _unpack(data[::-1])

    return [f.name for f in fields_], unpack


# -- payload command and acknowledgement ---------------------------------------------------
class LoadCodec:
    """Payload command or acknowledgement frames (1 FD frame, or 5 multiplexed classic ones)."""

    def __init__(self, frame: FrameCodec, is_ack: bool) -> None:
        self.frame = frame
        self.is_ack = is_ack
        self.muxes = sorted(frame.layouts) if frame.mux is not None else [None]
        for name in (*PAYLOAD_FIELDS, "Seq") + (("Status",) if is_ack else ()):
            if name not in frame.fields:
                raise BridgeConfigError(f"{frame.label}: lacks signal {name}")

    @property
    def n_frames(self) -> int:
        return len(self.muxes)

    def raw_of(self, seq: int, load, status: int | None = None) -> dict[str, int]:
        """Raw integers of a command/ack. ``load`` None clears (mass 0, all zero)."""
        f = self.frame.fields
        where = f"{self.frame.label} seq {seq}"
        if not 0 <= int(seq) <= 255:
            raise EncodeError(f"{where}: sequence number must be 0..255")
        raw = {"Seq": int(seq)}
        if self.is_ack:
            raw["Status"] = int(status or 0)
        if load is None:
            raw.update(dict.fromkeys(PAYLOAD_FIELDS, 0))
            return raw
        values = (load.mass, *load.com, *load.inertia)
        for name, value in zip(PAYLOAD_FIELDS, values, strict=True):
            raw[name] = f[name].raw_of(value, f"payload {getattr(load, 'name', '')!r} "
                                              f"({where})")
        if raw["Mass"] == 0:
            raise EncodeError(f"{where}: payload mass {load.mass!r} kg rounds to 0 on the wire "
                              f"(which means 'no load'); valid is >= {f['Mass'].scale:g} kg, or "
                              "send None to clear the load")
        return raw

    def encode(self, seq: int, load, counter: int, status: int | None = None
               ) -> tuple[list[bytes], int]:
        """The frames of one command/ack and the next alive counter."""
        raw = self.raw_of(seq, load, status)
        out = []
        for mux in self.muxes:
            out.append(self.frame.pack(raw, counter, mux))
            counter = (counter + 1) & 0x0F
        return out, counter

    def values(self, raw: Mapping[str, int]):
        """(seq, status, load) of a complete raw set; load None when mass is 0."""
        f = self.frame.fields
        seq = raw["Seq"]
        status = raw.get("Status", 0)
        if self.is_ack and status not in ACK_STATUS:
            raise DecodeError(f"{self.frame.label}: Status {status}; valid is "
                              + ", ".join(f"{k} ({v})" for k, v in ACK_STATUS.items()))
        if raw["Mass"] == 0:
            return seq, status, None
        v = {n: raw[n] * f[n].scale for n in PAYLOAD_FIELDS}
        load = Payload(name=f"seq-{seq}", mass=v["Mass"], com=(v["ComX"], v["ComY"], v["ComZ"]),
                       inertia=tuple(v[n] for n in PAYLOAD_FIELDS[4:]))
        return seq, status, load


class LoadAssembler:
    """Collects the frames of one command/ack (classic: Mux 0..4 with the same Seq)."""

    def __init__(self, codec: LoadCodec) -> None:
        self.codec = codec
        self._seq: int | None = None
        self._parts: dict[int | None, dict[str, int]] = {}
        self.orphaned = 0

    def push(self, data) -> dict[str, int] | None:
        """Add one checked frame; return the complete raw set when it is complete."""
        raw = self.codec.frame.unpack(data)
        if self.codec.frame.mux is None:
            return raw
        seq = raw["Seq"]
        if seq != self._seq:
            self.orphaned += len(self._parts)
            self._seq, self._parts = seq, {}
        self._parts[raw["Mux"]] = raw
        if len(self._parts) < self.codec.n_frames:
            return None
        merged: dict[str, int] = {}
        for part in self._parts.values():
            merged.update(part)
        self._seq, self._parts = None, {}
        return merged


# -- the heartbeat -------------------------------------------------------------------------
class HeartbeatCodec:
    """The heartbeat; its state names come from the DBC's value table of ``State``."""

    def __init__(self, frame: FrameCodec, states: Mapping[int, str]) -> None:
        self.frame = frame
        self.states = dict(states)
        self._codes = {v: k for k, v in self.states.items()}

    def encode(self, state: str, load_seq: int, cycle: int, overruns: int, counter: int) -> bytes:
        f = self.frame.fields
        if state not in self._codes:
            raise EncodeError(f"{self.frame.label}: state {state!r}; valid are "
                              f"{', '.join(self._codes)}")
        raw = {"State": self._codes[state], "LoadSeq": int(load_seq) & 0xFF,
               "Cycle": int(cycle) & f["Cycle"].mask,
               "Overruns": min(int(overruns), f["Overruns"].raw_max)}
        return self.frame.pack(raw, counter)

    def decode(self, data, t: float = 0.0) -> Heartbeat:
        raw = self.frame.unpack(data)
        state = self.states.get(raw["State"])
        if state is None:
            raise DecodeError(f"{self.frame.label}: State {raw['State']}; valid is "
                              + ", ".join(f"{k} ({v})" for k, v in self.states.items()))
        return Heartbeat(state=state, load_seq=raw["LoadSeq"], cycle=raw["Cycle"],
                         overruns=raw["Overruns"], t=t)


# -- profiles ------------------------------------------------------------------------------
@dataclass(frozen=True)
class WireProfile:
    """Everything one profile puts on the bus.

    Attributes:
        name: ``"fd"`` or ``"classic"``.
        joint_state: the joint-state frames (one cycle).
        command, ack: payload command and acknowledgement.
        heartbeat: the heartbeat.
        bitrate: nominal (arbitration) bitrate, bit/s.
        data_bitrate: CAN FD data-phase bitrate, bit/s (None for classic).
        period_us: the controller's cycle, µs (1000).
    """

    name: str
    joint_state: JointStateCodec
    command: LoadCodec
    ack: LoadCodec
    heartbeat: HeartbeatCodec
    bitrate: int
    data_bitrate: int | None
    period_us: int

    @property
    def is_fd(self) -> bool:
        return self.data_bitrate is not None

    def frames(self) -> list[FrameCodec]:
        """Every frame codec of the profile."""
        return [*self.joint_state.parts, self.command.frame, self.ack.frame,
                self.heartbeat.frame]


@functools.cache
def database():
    """The DBC, loaded once (cantools, strict: overlapping signals are an error)."""
    import cantools

    return cantools.database.load_file(str(DBC_PATH), strict=True)


@functools.cache
def profile(name: str = "fd") -> WireProfile:
    """The codecs of profile ``name`` (``"fd"`` or ``"classic"``), built once."""
    if name not in _MESSAGES:
        raise BridgeConfigError(f"unknown profile {name!r}; valid profiles are "
                                f"{', '.join(PROFILES)}")
    db = database()
    attrs = db.dbc.attributes
    period_us = int(attrs["IemControllerPeriodUs"].value)
    names = _MESSAGES[name]

    def codec(msg_name: str) -> FrameCodec:
        c = FrameCodec(db.get_message_by_name(msg_name))
        if c.profile not in (name, "both"):
            raise BridgeConfigError(f"{c.label} is for profile {c.profile!r}, not {name!r}")
        return c

    hb = codec(names["heartbeat"])
    states = db.get_message_by_name(names["heartbeat"]).get_signal_by_name("State").choices
    return WireProfile(
        name=name,
        joint_state=JointStateCodec(tuple(codec(n) for n in names["joint_state"]), period_us),
        command=LoadCodec(codec(names["command"]), is_ack=False),
        ack=LoadCodec(codec(names["ack"]), is_ack=True),
        heartbeat=HeartbeatCodec(hb, {int(k): str(v) for k, v in states.items()}),
        bitrate=int(attrs["Baudrate"].value),
        data_bitrate=int(attrs["IemDataBitrateFD"].value) if name == "fd" else None,
        period_us=period_us,
    )


def payload_wire_error(payload, profile: str) -> str | None:
    """Why the load command of profile ``profile`` cannot carry ``payload``, or None if it can.

    The encoder's own range checks (:meth:`LoadCodec.raw_of`, the DBC's signal ranges and
    steps), without encoding a frame: the message names the signal, the value and the valid
    range. The safety gate asks this before it lets a load through, so a load the wire cannot
    carry is refused there instead of failing in ``send``.
    """
    codecs = globals()["profile"](profile)  # the argument shadows the module's profile()
    try:
        codecs.command.raw_of(1, payload)
    except EncodeError as exc:
        return str(exc)
    return None
