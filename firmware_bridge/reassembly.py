"""From checked frames to complete cycles, in order, with every drop counted by kind.

:class:`Sequencer` judges complete cycles by their cycle counter (32 bits, compared with
serial-number arithmetic, RFC 1982, so it may wrap): a cycle newer than the last delivered
one is delivered and the gap counts as ``lost``; an older one is ``out_of_order`` (at most
``window`` published cycles old) or ``stale``; the same counter again with other content is
``stale``. After the caller saw a silence (:meth:`Sequencer.resync`), a counter that went
backwards is accepted once as a controller restart (``resyncs``). A counter that jumps ahead
further than ``JUMP_LIMIT`` published cycles must agree with the last heartbeat or be
confirmed by the next cycle; otherwise that cycle is ``implausible`` (dropped).

:class:`CycleAssembler` groups the frames of one cycle by their E2E alive counter (all frames
of a cycle carry the same one; the first part, which holds the cycle counter and the time,
decides whether the cycle is new). A cycle is complete when every part arrived with a valid
CRC; when a newer cycle is delivered, incomplete older ones are discarded (their frames count
as ``orphaned``), and a slot expires 8 alive-counter steps behind the newest frame seen (half
the 4-bit counter's range), so a late frame can never complete another cycle that had the
same counter. With one part per cycle (the FD profile) it reduces to the sequencer plus the
duplicate check.

:class:`TimeUnwrapper` turns the wire's controller time (µs modulo ``2**bits``) into seconds
that keep increasing across the wrap, using the cycle counter and the controller's clock rate
(learnt from consecutive cycles) to resolve gaps longer than one wrap period, and checks the
protocol's timing requirement (``TIMING_TOLERANCE``, ``TIMING_JITTER_S``).
"""

from __future__ import annotations

import itertools
import logging

from iem.types import NOMINAL_RATE_HZ

from .links import LinkCounters

log = logging.getLogger("iem.bridge")

CYCLE_MOD = 1 << 32


JUMP_LIMIT = 64
"""Published cycles a cycle counter may advance in one step without further checks; a longer
jump must agree with the heartbeat or be confirmed by the next cycle (see :class:`Sequencer`)."""
HEARTBEAT_MARGIN_S = 0.25
"""Tolerance of the heartbeat check of a jump: the controller's cycle may be this far (in
controller time) from the heartbeat's cycle plus the time since it arrived."""
CYCLES_PER_S = NOMINAL_RATE_HZ
"""Controller cycles per second (the protocol's 1 ms cycle)."""


class Sequencer:
    """Cycle-level ordering. ``stride``: controller cycles per published cycle.

    A cycle counter that jumps ahead by more than ``JUMP_LIMIT`` published cycles is not
    believed on its own (one well-formed frame with a wrong counter would otherwise make
    every following good cycle look stale): it is delivered if it agrees with the last
    heartbeat (the controller's cycle then, plus the time since, within
    ``HEARTBEAT_MARGIN_S``). Otherwise it is dropped and counted as ``implausible``, and
    remembered: when the next cycle continues from it, the controller really jumped, and the
    stream goes on from there (the gap counts as lost, the first cycle of the jump among
    them); when the next cycle continues the old count, the stream goes on from the last
    good cycle and ``lost`` is not inflated.
    """

    def __init__(self, counters: LinkCounters, stride: int = 1, window: int = 16,
                 jump_limit: int = JUMP_LIMIT) -> None:
        self.counters = counters
        self.stride = max(1, int(stride))
        self.window = int(window)
        self.jump = int(jump_limit) * self.stride
        self.last: int | None = None
        self._resync = False
        self._candidate: int | None = None

    def resync(self) -> None:
        """After a silence: accept the next cycle even if its counter went backwards."""
        self._resync = True

    def judge(self, cycle: int, heartbeat: tuple[int, float] | None = None) -> str:
        """``"deliver"``, ``"out_of_order"``, ``"stale"`` or ``"implausible"`` for a complete
        cycle; ``heartbeat``: ``(its cycle, seconds since it arrived)``, or None."""
        last = self.last
        if last is None:
            return "deliver"
        d = (cycle - last) % CYCLE_MOD
        if 0 < d < CYCLE_MOD // 2:
            if d <= self.jump or self._resync:
                return "deliver"
            return self._judge_jump(cycle, heartbeat)
        if self._resync:
            return "deliver"
        if d == 0:
            return "stale"
        return "out_of_order" if CYCLE_MOD - d <= self.window * self.stride else "stale"

    def _judge_jump(self, cycle: int, heartbeat: tuple[int, float] | None) -> str:
        cand = self._candidate
        if cand is not None and 0 < (cycle - cand) % CYCLE_MOD <= self.jump:
            return "deliver"  # the next cycle continues the jump: the controller jumped
        if heartbeat is not None:
            hb_cycle, age = heartbeat
            expected = hb_cycle + round(max(age, 0.0) * CYCLES_PER_S)
            off = (cycle - expected) % CYCLE_MOD
            off = min(off, CYCLE_MOD - off)
            if off <= max(self.jump, HEARTBEAT_MARGIN_S * CYCLES_PER_S):
                return "deliver"
        self._candidate = cycle
        return "implausible"

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
        self._candidate = None
        self.last = cycle
        self.counters.delivered += 1
        return restart


TIMING_TOLERANCE = 0.01
"""The protocol's timing requirement, relative part: between two published cycles the
controller's ``Time`` advances by ``ΔCycle × period`` within 1 % (plus ``TIMING_JITTER_S``)."""
TIMING_JITTER_S = 200e-6
"""The protocol's timing requirement, absolute part, s."""


class TimeUnwrapper:
    """Controller time on the wire (``bits`` wide, ``scale`` s per unit) to seconds.

    A step of the cycle counter short enough to be unambiguous (its time below a quarter of
    the wire's wrap even at the tolerance) is taken as the wire says; its ratio of time to
    cycles teaches the controller's actual clock rate (a crystal off by 0.6 % is off by
    0.6 % for good). A longer step (a gap) is resolved to the wrap count that agrees with the
    cycle counter at that learnt rate, so a steady drift is unwrapped exactly across any gap.
    A step that breaks the timing requirement (``TIMING_TOLERANCE``, ``TIMING_JITTER_S``), or
    a gap whose time the wrap leaves in doubt, is counted in ``counters.timing``, kept in
    ``last_violation`` and logged (``iem.bridge``, event ``timing_violation``: the 1st, the
    10th and every 1000th); the time is still the wire's.
    """

    def __init__(self, bits: int, scale: float, period_us: int,
                 counters: LinkCounters | None = None) -> None:
        self.mod = 1 << bits
        self.scale = scale
        self.nominal = period_us * 1e-6 / scale
        self.units_per_cycle = self.nominal
        self.counters = counters
        self.last_violation = ""
        self.violations = 0
        self._short = self.mod / 4 / (1 + TIMING_TOLERANCE) / self.nominal
        self._jitter = TIMING_JITTER_S / scale
        self._wire: int | None = None
        self._cycle = 0
        self._units = 0
        self._sum_units = 0
        self._sum_cycles = 0

    def _violation(self, text: str) -> None:
        self.last_violation = text
        self.violations += 1
        if self.counters is not None:
            self.counters.timing += 1
        if self.violations in (1, 10) or self.violations % 1000 == 0:  # said, not flooded
            log.warning("controller timing: %s (%d so far)", text, self.violations,
                        extra={"event": "timing_violation", "count": self.violations})

    def __call__(self, wire: int, cycle: int, restart: bool = False) -> float:
        if self._wire is None or restart:
            units = wire
            self._sum_units = self._sum_cycles = 0
            self.units_per_cycle = self.nominal
        else:
            d = (wire - self._wire) % self.mod
            dc = (cycle - self._cycle) % CYCLE_MOD
            if dc < self._short:
                nominal = dc * self.nominal
                if abs(d - nominal) > TIMING_TOLERANCE * nominal + self._jitter:
                    self._violation(f"cycle {cycle}: Time advanced {d * self.scale * 1e3:.3f} ms "
                                    f"over {dc} cycles; the protocol allows "
                                    f"{nominal * self.scale * 1e3:.3f} ms ± "
                                    f"{TIMING_TOLERANCE:.0%} ± {TIMING_JITTER_S * 1e6:.0f} µs")
                else:
                    self._sum_units += d
                    self._sum_cycles += dc
                    self.units_per_cycle = self._sum_units / self._sum_cycles
            else:
                expected = dc * self.units_per_cycle
                d += self.mod * round((expected - d) / self.mod)
                if abs(d - expected) > self.mod / 4:
                    self._violation(f"cycle {cycle}: after a gap of {dc} cycles, Time is "
                                    f"{(d - expected) * self.scale:+.3f} s off the cycle "
                                    f"counter at the controller's clock rate; the wrap of "
                                    f"{self.mod * self.scale:.3f} s leaves it in doubt")
            units = self._units + d
        self._wire, self._cycle, self._units = wire, cycle, units
        return units * self.scale


class _Slot:
    __slots__ = ("cycle", "frames", "lap", "mask", "time", "values")

    def __init__(self, n_parts: int, lap: int) -> None:
        self.lap = lap
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
        self.clock = TimeUnwrapper(codec.time_bits, codec.time_scale, codec.period_us, counters)
        self._cycle_pos, self._time_pos = codec.cycle_pos, codec.time_pos
        self._slots: dict[int, _Slot] = {}
        self._last_counter: int | None = None
        self._last_frames: list[bytes | None] = [None] * self.n_parts
        self._head: int | None = None  # the newest alive counter seen
        self._pos = 0  # ... unwrapped: how many alive-counter steps the stream has advanced

    def resync(self) -> None:
        """After a silence: forget incomplete cycles, accept the next one whatever its number."""
        for slot in self._slots.values():
            self.counters.orphaned += bin(slot.mask).count("1")
        self._slots.clear()
        self._last_counter = None
        self._head = None
        self.seq.resync()

    def _lap(self, counter: int) -> int:
        """The unwrapped alive-counter position of a frame with ``counter``; advances the head
        for a newer one and expires slots 8 or more steps behind it (half the counter's
        range: beyond that a counter value means another cycle)."""
        head = self._head
        if head is None:
            self._head = counter
            return self._pos
        d = (counter - head) % 16
        if 0 < d < 8:
            self._head = counter
            self._pos += d
            for k in [k for k, v in self._slots.items() if self._pos - v.lap >= 8]:
                self._drop_slot(k, "orphaned")
            return self._pos
        return self._pos - (head - counter) % 16

    def _drop_slot(self, counter: int, kind: str) -> None:
        slot = self._slots.pop(counter)
        setattr(self.counters, kind, getattr(self.counters, kind) + bin(slot.mask).count("1"))

    def push(self, part: int, counter: int, data: bytes, unpack,
             heartbeat: tuple[int, float] | None = None) -> tuple | None:
        c = self.counters
        last_c = self._last_counter
        if counter == last_c and self._last_frames[part] == data:
            c.duplicate += 1
            return None
        bit = 1 << part
        lap = self._lap(counter) if self.n_parts > 1 else 0
        slot = self._slots.get(counter)
        if slot is not None and slot.lap != lap:
            self._drop_slot(counter, "orphaned")  # same counter, another lap: never splice
            slot = None
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
            slot = self._slots[counter] = _Slot(self.n_parts, lap)
        values = unpack(data)
        slot.values[part] = values
        slot.mask |= bit
        slot.frames[part] = data
        if part == 0:
            slot.cycle = values[self._cycle_pos]
            slot.time = values[self._time_pos]
            verdict = self.seq.judge(slot.cycle, heartbeat)
            if verdict != "deliver":
                self._drop_slot(counter, verdict)
                return None
        if slot.mask != self.full:
            return None
        del self._slots[counter]
        cycle = slot.cycle
        verdict = self.seq.judge(cycle, heartbeat) if self.n_parts > 1 else "deliver"
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
