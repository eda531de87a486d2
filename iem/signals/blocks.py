"""Block points: the estimator's input, the means of consecutive gap-free controller frames.

A payload does not change at 1 kHz, and one frame carries the sensor's whole noise. The
estimator (state filter, router, learners, tandem samples, physics, change detector,
smoothing, gate) therefore works on *block points*: the means of ``q``, ``dq`` and
``tau_J`` over ``frames`` consecutive frames (10 by default: 100 points per second from a
1 kHz controller), each carrying a tenth of the frame noise's variance. A block point's time
is the mean of its frames' time stamps (the instant its means describe) and its cycle counter
the last frame's.

Frames are checked by the one gap rule (:class:`iem.signals.gaps.GapRule`, at the frame rate) as
they come:

- a frame not newer than the last one used (a duplicate, a frame overtaken by newer ones) is
  not used (``skipped``);
- lost frames, up to the rule's ``max_bridge_s`` (20 ms), are bridged: the block gets them
  linearly interpolated between the frames on either side, as every filter of the path
  bridged them at the frame rate (counted in ``bridged``). Blocks then stay whole, one every
  ``frames`` nominal cycles, and the filters downstream keep their even spacing: closing a
  block at every lost frame would make its points unevenly spaced (4 to 15 ms), which a
  fixed-rate derivative reads as acceleration (with 5 % of frames lost, 2 % late and 2 %
  repeated, IEM+phys's mass error is 3.9 g that way, 0.1 g bridged);
- a gap the rule does not bridge (a silence, time going back: a restart) closes the block
  early: the frames before it make a shorter block, and the frame after it starts the next.
  A block never spans such a gap.

:class:`BlockFormer` takes frames one at a time (:meth:`BlockFormer.push`, the link reader's
thread) or a chunk of them at once (:meth:`BlockFormer.push_many`, a replay: the gap rule
walks the time stamps, the means are one vectorised reduction); both keep the open block
between calls and give the same blocks, to the bit: the bridged frames are the same
arithmetic and the means the same reduction (``numpy.add.reduceat`` over the block's rows,
then one division) either way.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InvalidInputError
from ..types import DEFAULT_BLOCK_FRAMES, NOMINAL_RATE_HZ, JointState
from .gaps import DEFAULT_MAX_BRIDGE_S, RESTART, SKIP, GapRule

N_COLUMNS = 21
"""Values a frame carries to a block: ``q``, ``dq`` and ``tau_J`` (7 each)."""
_FIRST = np.zeros(1, dtype=np.intp)
"""The one block of :meth:`BlockFormer._close`'s reduction starts at row 0."""


@dataclass(frozen=True)
class Blocks:
    """Block points in arrays (``n`` blocks).

    Attributes:
        t: mean time stamp of each block's frames, s (n).
        X: means of ``[q, dq, tau_J]`` (n, 21).
        frames: frames in each block (n).
        cycle: the last frame's cycle counter (n).
        last: index of each block's last received frame among the frames given to the call
            that closed it (n); -1 where that frame came in an earlier call.
    """

    t: np.ndarray
    X: np.ndarray
    frames: np.ndarray
    cycle: np.ndarray
    last: np.ndarray

    def __len__(self) -> int:
        return len(self.t)

    def state(self, i: int) -> JointState:
        """Block ``i`` as a :class:`iem.types.JointState` of its means."""
        x = self.X[i]
        if x.flags.writeable or x.dtype != np.float64:  # the state keeps read-only copies
            return JointState(t=float(self.t[i]), q=x[:7], dq=x[7:14], tau_J=x[14:],
                              cycle=int(self.cycle[i]))
        return JointState.of_kept(float(self.t[i]), x[:7], x[7:14], x[14:],
                                  int(self.cycle[i]))


def _means(T: np.ndarray, X: np.ndarray, starts: np.ndarray, counts: np.ndarray
           ) -> tuple[np.ndarray, np.ndarray]:
    """The mean time and the mean row of each block (rows ``starts[i]`` on, ``counts[i]``
    of them): the one reduction both :meth:`BlockFormer.push` and ``push_many`` use."""
    n = counts.astype(float)
    return (np.add.reduceat(T, starts) / n,
            np.add.reduceat(X, starts, axis=0) / n[:, None])


def _bridged(t0: float, x0: np.ndarray, t: float, x: np.ndarray, steps: int):
    """The ``steps - 1`` lost frames between ``(t0, x0)`` and ``(t, x)``, linearly
    interpolated (the one arithmetic :meth:`BlockFormer.push` and ``push_many`` share)."""
    for j in range(1, steps):
        yield t0 + (t - t0) * (j / steps), x0 + (x - x0) * (j / steps)


class BlockFormer:
    """Forms block points from controller frames.

    Args:
        frames: frames per block (>= 1).
        rate_hz: the controller's nominal frame rate, Hz (the gap rule's).
        max_bridge_s: the gap rule's longest bridged gap, s: a longer one is a restart,
            which closes the open block.
    """

    def __init__(self, frames: int = DEFAULT_BLOCK_FRAMES, rate_hz: float = NOMINAL_RATE_HZ,
                 max_bridge_s: float = DEFAULT_MAX_BRIDGE_S) -> None:
        if type(frames) is not int or frames < 1:
            raise InvalidInputError(f"frames per block must be an integer >= 1, got {frames!r}")
        self.frames = frames
        self.rate_hz = float(rate_hz)
        self.gaps = GapRule(rate_hz, max_bridge_s)
        self._T = np.empty(frames)
        self._X = np.empty((frames, N_COLUMNS))
        self._cycle = 0
        self._n = 0
        self._prev: tuple[float, np.ndarray] | None = None  # the last frame used (t, row)
        self.blocks = 0
        """Blocks formed so far."""
        self.short = 0
        """Blocks closed early by a restart (fewer than ``frames`` frames)."""

    @property
    def point_rate_hz(self) -> float:
        """Block points per second on a gap-free stream."""
        return self.rate_hz / self.frames

    @property
    def skipped(self) -> int:
        """Frames not used: not newer than the last one used (the gap rule's count)."""
        return self.gaps.skipped

    @property
    def bridged(self) -> int:
        """Lost frames bridged by interpolation (the gap rule's count)."""
        return self.gaps.bridged

    @property
    def pending(self) -> int:
        """Frames in the open block."""
        return self._n

    def reset(self) -> None:
        """Drop the open block and forget the last time stamp (a new stream)."""
        self._n = 0
        self._prev = None
        self.gaps.reset()

    def _close(self) -> JointState:
        n = self._n
        t, x = _means(self._T[:n], self._X[:n], _FIRST, np.array([n]))
        x.flags.writeable = False  # its own array: the state keeps views of it
        self._n = 0
        self.blocks += 1
        self.short += n < self.frames
        return Blocks(t, x, np.array([n]), np.array([self._cycle]), np.array([-1])).state(0)

    def flush(self) -> JointState | None:
        """Close the open block now (a silence, the end of a stream): its point, or None if
        it holds no frame."""
        return self._close() if self._n else None

    def _add(self, t: float, row: np.ndarray, out: list) -> None:
        n = self._n
        self._T[n] = t
        self._X[n] = row
        self._n = n + 1
        if self._n == self.frames:
            out.append(self._close())

    def push(self, t: float, q, dq, tau, cycle: int = 0) -> list[JointState]:
        """Add one frame: the block points it closes, in order (usually none or one; a
        bridged gap may close more)."""
        steps = self.gaps(t)
        if steps == SKIP:
            return []
        out: list[JointState] = []
        if steps == RESTART:
            if self._n:
                out.append(self._close())  # the frames before the gap
        elif steps > 1:  # lost frames: bridged into the block
            row = np.empty(N_COLUMNS)
            row[:7] = q
            row[7:14] = dq
            row[14:] = tau
            t0, x0 = self._prev  # a row of the buffer, which the bridge may fill again
            for tj, xj in _bridged(t0, x0.copy(), t, row, steps):
                self._add(tj, xj, out)
        self._cycle = cycle
        n = self._n  # the frame goes straight into the block's buffer
        row = self._X[n]
        row[:7] = q
        row[7:14] = dq
        row[14:] = tau
        self._T[n] = t
        self._prev = (t, row)  # valid until the buffer's row n is filled again
        self._n = n + 1
        if self._n == self.frames:
            out.append(self._close())
        return out

    def push_many(self, T, X, cycles=None) -> Blocks:
        """Add ``len(T)`` frames at once (``X``: ``(n, 21)`` rows of ``[q, dq, tau_J]``;
        ``cycles``: their counters, default 0): the blocks they close, in order, exactly as
        :meth:`push` frame by frame would give them. The open block carries over."""
        T = np.asarray(T, dtype=float).reshape(-1)
        X = np.asarray(X, dtype=float)
        if X.shape != (len(T), N_COLUMNS):
            raise InvalidInputError(f"frames must be (n, {N_COLUMNS}) rows of [q, dq, tau_J] "
                                    f"for n = {len(T)} time stamps, got shape {X.shape}")
        cycles = (np.zeros(len(T), dtype=np.int64) if cycles is None
                  else np.asarray(cycles, dtype=np.int64).reshape(-1))
        plan = _Plan(self)
        rule, prev = self.gaps, self._prev  # (the plan fills the buffer only in finish)
        for i, t in enumerate(T.tolist()):
            steps = rule(t)
            if steps == SKIP:
                continue
            if steps == RESTART:
                plan.close_early()
            elif steps > 1:
                for tj, xj in _bridged(*prev, t, X[i], steps):
                    plan.bridge(tj, xj)
            plan.frame(i)
            prev = (t, X[i])
        self._prev = None if prev is None else (prev[0], np.array(prev[1]))
        return plan.finish(T, X, cycles)


_BRIDGED = 1 << 40
"""Row references at or above this name a bridged row (``ref - _BRIDGED``)."""


class _Plan:
    """The rows :meth:`BlockFormer.push_many` lays out (the carried open block's, the used
    frames', the bridged ones) and where each block starts; then the means at once."""

    def __init__(self, former: BlockFormer) -> None:
        self.former = former
        self.carry = former._n
        self.rows: list[int] = list(range(-1, -self.carry - 1, -1))  # carried: -1, -2, ...
        self.bridged: list[tuple[float, np.ndarray]] = []
        self.starts: list[int] = []
        self.open_at = 0
        self.n = self.carry

    def _row(self, ref: int) -> None:
        self.rows.append(ref)
        self.n += 1
        if self.n == self.former.frames:
            self.starts.append(self.open_at)
            self.open_at, self.n = len(self.rows), 0

    def close_early(self) -> None:
        if self.n:
            self.starts.append(self.open_at)
            self.open_at, self.n = len(self.rows), 0

    def bridge(self, t: float, row: np.ndarray) -> None:
        self._row(_BRIDGED + len(self.bridged))
        self.bridged.append((t, row))

    def frame(self, i: int) -> None:
        self._row(i)

    def finish(self, T, X, cycles) -> Blocks:
        f = self.former
        refs = np.asarray(self.rows, dtype=np.int64)
        m = len(refs)
        carried, bridged = refs < 0, refs >= _BRIDGED
        real = ~(carried | bridged)
        rows_T, rows_X = np.empty(m), np.empty((m, N_COLUMNS))
        rows_T[carried], rows_X[carried] = f._T[-refs[carried] - 1], f._X[-refs[carried] - 1]
        if self.bridged:
            rows_T[bridged] = [t for t, _ in self.bridged]
            rows_X[bridged] = np.array([x for _, x in self.bridged])
        rows_T[real], rows_X[real] = T[refs[real]], X[refs[real]]
        # each row's last real frame (its cycle counter; -1: none in this call)
        last_real = np.maximum.accumulate(np.where(real, refs, -1)) if m else refs
        rows_c = np.where(last_real >= 0, cycles[np.maximum(last_real, 0)] if len(cycles)
                          else 0, f._cycle)
        open_at, n = self.open_at, self.n
        f._n = n  # the open block stays for the next call
        if n:
            f._T[:n] = rows_T[open_at:]
            f._X[:n] = rows_X[open_at:]
        if m:
            f._cycle = int(rows_c[-1])
        if not self.starts:
            return Blocks(np.empty(0), np.empty((0, N_COLUMNS)), np.empty(0, dtype=np.int64),
                          np.empty(0, dtype=np.int64), np.empty(0, dtype=np.int64))
        s = np.asarray(self.starts, dtype=np.intp)
        ends = np.append(s[1:], open_at)
        counts = ends - s
        t, x = _means(rows_T[:open_at], rows_X[:open_at], s, counts)
        f.blocks += len(s)
        f.short += int(np.count_nonzero(counts < f.frames))
        return Blocks(t, x, counts.astype(np.int64), rows_c[ends - 1], last_real[ends - 1])
