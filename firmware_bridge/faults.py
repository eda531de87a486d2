"""Fault injection on the controller's transmit side: drop, corrupt, duplicate, delay, silence.

Each frame the controller sends (CAN frame, or serial message before framing) draws one
uniform number ``u`` from a seeded generator and gets at most one fault:
``u < drop`` dropped; then ``corrupt`` (one random bit flipped, which the receiver's
check always catches: CRC32 by its polynomial, the CAN frames' E2E CRC8 by its polynomial
and the DBC's DataID lists, see :mod:`firmware_bridge.e2e`), ``duplicate`` (sent twice,
back to back), ``delay`` (held back ``delay_cycles`` controller cycles, so it arrives after
newer frames). During ``silence_for`` s of controller time from ``silence_at`` nothing is sent
at all (joint state, acknowledgements, heartbeats).

``FaultInjector(spec, record=True)`` keeps a log of ``(key, action)`` per frame so tests can
compare the receiver's counters with what was done.
"""

from __future__ import annotations

import random
from dataclasses import dataclass, fields

from .errors import BridgeConfigError

ACTIONS = ("ok", "drop", "corrupt", "duplicate", "delay")
MAX_EVENTS = 1_000_000
"""Fault events kept in :attr:`FaultInjector.events` (about 40 MB at most)."""


@dataclass(frozen=True)
class FaultSpec:
    """What to do to the frames a controller sends.

    Attributes:
        drop, corrupt, duplicate, delay: fractions of frames, each in [0, 1], sum <= 1.
        delay_cycles: how long a delayed frame is held, in controller cycles (1 ms each).
        silence_at: controller time (s) when a silence starts; None: no silence.
        silence_for: length of the silence, s.
        seed: seed of the fault draws.
    """

    drop: float = 0.0
    corrupt: float = 0.0
    duplicate: float = 0.0
    delay: float = 0.0
    delay_cycles: int = 3
    silence_at: float | None = None
    silence_for: float = 0.0
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("drop", "corrupt", "duplicate", "delay"):
            v = getattr(self, name)
            if not 0.0 <= v <= 1.0:
                raise BridgeConfigError(f"fault fraction {name} = {v!r}; valid is 0 .. 1")
        total = self.drop + self.corrupt + self.duplicate + self.delay
        if total > 1.0 + 1e-12:
            raise BridgeConfigError(f"fault fractions add up to {total:g}; valid is at most 1 "
                                    "(each frame gets one fault at most)")
        if self.delay_cycles < 1:
            raise BridgeConfigError(f"delay_cycles = {self.delay_cycles}; valid is >= 1")
        if self.silence_for < 0:
            raise BridgeConfigError(f"silence_for = {self.silence_for}; valid is >= 0 s")

    @property
    def active(self) -> bool:
        return any(getattr(self, f.name) for f in fields(self)
                   if f.name in ("drop", "corrupt", "duplicate", "delay")) or (
            self.silence_at is not None and self.silence_for > 0)


class FaultInjector:
    """Applies a :class:`FaultSpec` frame by frame (single-threaded, on the sender)."""

    def __init__(self, spec: FaultSpec, record: bool = False) -> None:
        self.spec = spec
        self._rng = random.Random(spec.seed)
        self._held: list[tuple[int, object, bytes]] = []
        self.counts = dict.fromkeys(ACTIONS, 0)
        self.silenced = 0
        self.by_message: dict[str, dict[str, int]] = {}
        """Actions per message name (``key.name``, else ``str(key)``), silenced included."""
        self.events: list[tuple[int, str, str]] = []
        """``(cycle, message name, action)`` of every frame that got a fault or was kept back
        by the silence (the first :data:`MAX_EVENTS`), so a reader can be checked against
        the faults of the cycles it saw."""
        self.log: list[tuple[object, str]] | None = [] if record else None
        s = spec
        self._edges = (s.drop, s.drop + s.corrupt, s.drop + s.corrupt + s.duplicate,
                       s.drop + s.corrupt + s.duplicate + s.delay)

    def silent(self, t: float) -> bool:
        """True while the controller is to say nothing (controller time ``t`` in s)."""
        s = self.spec
        return s.silence_at is not None and s.silence_at <= t < s.silence_at + s.silence_for

    def apply(self, key, data: bytes, cycle: int) -> list[bytes]:
        """The frames to send now for ``data`` (0, 1 or 2); a delayed one is kept for
        :meth:`due`. ``key`` identifies the message (kept with delayed frames and in the log)."""
        u = self._rng.random()
        d, c, du, de = self._edges
        if u < d:
            action, out = "drop", []
        elif u < c:
            buf = bytearray(data)
            i = self._rng.randrange(len(buf) * 8)
            buf[i // 8] ^= 1 << (i % 8)
            action, out = "corrupt", [bytes(buf)]
        elif u < du:
            action, out = "duplicate", [data, data]
        elif u < de:
            self._held.append((cycle + self.spec.delay_cycles, key, data))
            action, out = "delay", []
        else:
            action, out = "ok", [data]
        self.counts[action] += 1
        self._count(key, action, cycle)
        if self.log is not None:
            self.log.append((key, action))
        return out

    def silence(self, key, cycle: int = -1) -> None:
        """Count a frame of ``key`` that the silence kept back at ``cycle``."""
        self.silenced += 1
        self._count(key, "silenced", cycle)

    def _count(self, key, action: str, cycle: int) -> None:
        name = getattr(key, "name", None) or str(key)
        counts = self.by_message.get(name)
        if counts is None:
            counts = self.by_message[name] = dict.fromkeys((*ACTIONS, "silenced"), 0)
        counts[action] += 1
        if action != "ok" and len(self.events) < MAX_EVENTS:
            self.events.append((int(cycle), name, action))

    def due(self, cycle: int) -> list[tuple[object, bytes]]:
        """Delayed frames whose time has come, in the order they were held."""
        if not self._held:
            return []
        ready = [(k, d) for when, k, d in self._held if when <= cycle]
        self._held = [h for h in self._held if h[0] > cycle]
        return ready
