"""From checked frames to complete cycles, in order, with every drop counted by kind.

:class:`Sequencer` judges complete cycles by their cycle counter (32 bits, compared with
serial-number arithmetic, RFC 1982, so it may wrap): a cycle newer than the last delivered
one is delivered and the gap counts as ``lost``; an older one is ``out_of_order`` (at most
``window`` published cycles old) or ``stale``; the same counter again with other content is
``stale``. After the caller saw a silence (:meth:`Sequencer.resync`), a counter that went
backwards is accepted once as a controller restart (``resyncs``).

:class:`CycleAssembler` groups the frames of one cycle by their E2E alive counter (all frames
of a cycle carry the same one; the first part, which holds the cycle counter and the time,
decides whether the cycle is new). A cycle is complete when every part arrived with a valid
CRC; when a newer cycle is delivered, incomplete older ones are discarded (their frames count
as ``orphaned``). With one part per cycle (the FD profile) it reduces to the sequencer plus
the duplicate check.

:class:`TimeUnwrapper` turns the wire's controller time (µs modulo ``2**bits``) into seconds
that keep increasing across the wrap, using the cycle counter to resolve gaps longer than
one wrap period.
"""

from __future__ import annotations

import itertools

from .links import LinkCounters

CYCLE_MOD = 1 << 32


class Sequencer:
    """Cycle-level ordering. ``stride``: controller cycles per published cycle."""

    def __init__(self, counters: LinkCounters, stride: int = 1, window: int = 16) -> None:
        self.counters = counters
        self.stride = max(1, int(stride))
        self.window = int(window)
        self.last: int | None = None
        self._resync = False

    def resync(self) -> None:
        """After a silence: accept the next cycle even if its counter went backwards."""
        self._resync = True

    def judge(self, cycle: int) -> str:
        """``"deliver"``, ``"out_of_order"`` or ``"stale"`` for a complete cycle."""
        last = self.last
        if last is None:
            return "deliver"
        d = (cycle - last) % CYCLE_MOD
        if 0 < d < CYCLE_MOD // 2:
            return "deliver"
        if self._resync:
            return "deliver"
        if d == 0:
            return "stale"
        return "out_of_order" if CYCLE_MOD - d <= self.window * self.stride else "stale"

    def is_newer(self, cycle: int) -> bool:
        return self.last is None or 0 < (cycle - self.last) % CYCLE_MOD < CYCLE_MOD // 2

    def deliver(self, cycle: int) -> bool:
        """Record a delivered cycle, count the gap; True if it was a restart (resync)."""
        last = self.last
        restart = False
        if last is not None:
            d = (cycle - last) % CYCLE_MOD
            if 0 < d < CYCLE_MOD // 2:
                gap = d // self.stride - 1
                if gap > 0:
                    self.counters.lost += gap
            else:
                restart = True
                self.counters.resyncs += 1
        self._resync = False
        self.last = cycle
        self.counters.delivered += 1
        return restart


class TimeUnwrapper:
    """Controller time on the wire (``bits`` wide, ``scale`` s per unit) to seconds."""

    def __init__(self, bits: int, scale: float, period_us: int) -> None:
        self.mod = 1 << bits
        self.scale = scale
        self.units_per_cycle = period_us * 1e-6 / scale
        self._wire: int | None = None
        self._cycle = 0
        self._units = 0

    def __call__(self, wire: int, cycle: int, restart: bool = False) -> float:
        if self._wire is None or restart:
            units = wire
        else:
            d = (wire - self._wire) % self.mod
            expected = ((cycle - self._cycle) % CYCLE_MOD) * self.units_per_cycle
            d += self.mod * round((expected - d) / self.mod)
            units = self._units + d
        self._wire, self._cycle, self._units = wire, cycle, units
        return units * self.scale


class _Slot:
    __slots__ = ("cycle", "frames", "mask", "time", "values")

    def __init__(self, n_parts: int) -> None:
        self.mask = 0
        self.cycle = -1
        self.time = 0
        self.values: list[tuple] = [()] * n_parts
        self.frames: list[bytes | None] = [None] * n_parts


class CycleAssembler:
    """Checked joint-state frames of one profile -> complete, ordered cycles.

    The alive counter: a first part (the FD frame, the classic header) that repeats the last
    delivered cycle's counter with other content is ``stale`` (the sender did not advance
    it); classic joint frames are grouped by it. Loss and order are judged on the 32-bit
    cycle counter, which is wider (a gap of exactly 16k cycles costs one more cycle).

    ``push(part, counter, data, unpack)`` takes one frame that passed the length and CRC
    checks and returns ``(values, cycle, t)`` when it completes a cycle that is delivered
    (``values``: the parts' raw tuples concatenated), else None (the frame is counted under
    the kind that says why).
    """

    def __init__(self, codec, counters: LinkCounters, window: int = 16) -> None:
        self.codec = codec
        self.counters = counters
        self.n_parts = len(codec.parts)
        self.full = (1 << self.n_parts) - 1
        self.seq = Sequencer(counters, stride=codec.stride, window=window)
        self.clock = TimeUnwrapper(codec.time_bits, codec.time_scale, codec.period_us)
        self._cycle_pos, self._time_pos = codec.cycle_pos, codec.time_pos
        self._slots: dict[int, _Slot] = {}
        self._last_counter: int | None = None
        self._last_frames: list[bytes | None] = [None] * self.n_parts

    def resync(self) -> None:
        """After a silence: forget incomplete cycles, accept the next one whatever its number."""
        for slot in self._slots.values():
            self.counters.orphaned += bin(slot.mask).count("1")
        self._slots.clear()
        self._last_counter = None
        self.seq.resync()

    def _drop_slot(self, counter: int, kind: str) -> None:
        slot = self._slots.pop(counter)
        setattr(self.counters, kind, getattr(self.counters, kind) + bin(slot.mask).count("1"))

    def push(self, part: int, counter: int, data: bytes, unpack) -> tuple | None:
        c = self.counters
        last_c = self._last_counter
        if counter == last_c and self._last_frames[part] == data:
            c.duplicate += 1
            return None
        bit = 1 << part
        slot = self._slots.get(counter)
        if slot is not None and slot.mask & bit:
            if slot.frames[part] == data:
                c.duplicate += 1
                return None
            self._drop_slot(counter, "orphaned")  # the alive counter wrapped: an old cycle
            slot = None
        if slot is None:
            if part == 0 and counter == last_c:
                c.stale += 1  # the sender repeated its alive counter (AUTOSAR P02: REPEATED)
                return None
            if part != 0 and last_c is not None and not 0 < (counter - last_c) % 16 < 8:
                c.out_of_order += 1  # a joint frame behind the last delivered cycle
                return None
            slot = self._slots[counter] = _Slot(self.n_parts)
        values = unpack(data)
        slot.values[part] = values
        slot.mask |= bit
        slot.frames[part] = data
        if part == 0:
            slot.cycle = values[self._cycle_pos]
            slot.time = values[self._time_pos]
            verdict = self.seq.judge(slot.cycle)
            if verdict != "deliver":
                self._drop_slot(counter, verdict)
                return None
        if slot.mask != self.full:
            return None
        del self._slots[counter]
        cycle = slot.cycle
        verdict = self.seq.judge(cycle)
        if verdict != "deliver":
            setattr(c, verdict, getattr(c, verdict) + self.n_parts)
            return None
        restart = self.seq.deliver(cycle)
        t = self.clock(slot.time, cycle, restart)
        self._last_counter = counter
        self._last_frames = slot.frames
        if self._slots:
            self._discard_older(counter)
        values = slot.values[0] if self.n_parts == 1 else tuple(
            itertools.chain.from_iterable(slot.values))
        return values, cycle, t

    def _discard_older(self, counter: int) -> None:
        """After delivering: drop incomplete cycles that can no longer be delivered."""
        for k in list(self._slots):
            slot = self._slots[k]
            if slot.mask & 1:
                older = not self.seq.is_newer(slot.cycle)
            else:
                older = not 0 < (k - counter) % 16 < 8
            if older:
                self._drop_slot(k, "orphaned")
