"""One DBC message as the bridge encodes and decodes it: its little-endian bit fields
(:class:`Field`), its length, FD flag, E2E protection and cycle time (:class:`FrameCodec`),
built once from cantools' message; the hot path unpacks a frame with one ``int.from_bytes``
and a shift and mask per signal."""

from __future__ import annotations

import math
from collections.abc import Mapping

from .e2e import Profile2
from .errors import BridgeConfigError, DecodeError, EncodeError


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
