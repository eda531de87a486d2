"""The joint-state frames of one wire profile: the parts of a cycle, the hot-path decode into
a :class:`~iem.types.JointState`, and the encode (saturating to the signals' ranges)."""

from __future__ import annotations

import numpy as np

from iem.types import N_JOINTS, JointState

from .errors import BridgeConfigError, EncodeError
from .frame_codec import Field, FrameCodec

STATE_FIELDS: tuple[str, ...] = (
    "Cycle", "Time",
    *(f"Q{j}" for j in range(1, N_JOINTS + 1)),
    *(f"DQ{j}" for j in range(1, N_JOINTS + 1)),
    *(f"Tau{j}" for j in range(1, N_JOINTS + 1)),
)
"""The raw values of one cycle, in the order the reassembly keeps them."""
STATE_INDEX = {name: i for i, name in enumerate(STATE_FIELDS)}


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
        return JointState.of_kept(float(t), v[0:7], v[7:14], v[14:21], int(cycle))

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
        import bitstruct.c as bitstruct  # the C extension, where it is built
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
