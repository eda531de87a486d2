"""The controller's messages on the CAN wire: the payload command and its acknowledgement (one
FD frame, or five multiplexed classic ones: :class:`LoadCodec`, :class:`LoadAssembler`) and
the heartbeat (:class:`HeartbeatCodec`), to and from :mod:`firmware_bridge.messages`."""

from __future__ import annotations

from collections.abc import Mapping

from iem.payload import Payload

from .errors import BridgeConfigError, DecodeError, EncodeError
from .frame_codec import FrameCodec
from .messages import ACK_STATUS, Heartbeat

PAYLOAD_FIELDS = ("Mass", "ComX", "ComY", "ComZ", "Ixx", "Ixy", "Ixz", "Iyy", "Iyz", "Izz")


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
