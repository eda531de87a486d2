"""What the service reads: block points of the link's frames, handed over once a block.

The link gives controller frames (1 kHz on a Franka); the estimator works on block points,
the means of consecutive gap-free frames (:mod:`iem.signals.blocks`). Both readers here form them
with a :class:`iem.signals.blocks.BlockFormer` and hand the service one :class:`Item` per block, a
controller silence (:class:`~firmware_bridge.errors.ControllerSilent`), the end of a replayed
stream or a link failure; a silence or the end first closes the open block (its frames are
the last before it).

- :class:`LinkReader` (a live link) reads in a thread of its own, so reading never waits for
  estimating: while the estimator is slow (a learning step, a host under load) the link keeps
  being drained and every frame keeps its arrival time (the link's receive time stamp). The
  hand-over (a queue put, a wake-up of the service's thread) happens once a block, not once
  a frame. The reader itself wakes a few times a block, not once a frame: after a block's
  first frame it sleeps until :data:`SLEEP_MARGIN` frame periods before the block's last
  frame is due, while the link's own buffer (the kernel's socket buffer, the serial line's,
  python-can's queue) holds what arrives, then reads those at once and waits for the last
  frames as they come, so the block's last frame's latency is what it was. It sleeps once a
  block, from when it read the first frame, never from a frame's own time stamp: an adapter
  without hardware time stamps stamps a frame when it is read, and sleeping after every
  such frame fell behind until the adapter dropped frames. Behind by more than the margin,
  the frames after the first are already waiting and the lag shrinks by the margin a
  block. Each wake-up of a thread costs far more than decoding a frame (the reader thread
  took 0.066 of a core at 1 kHz, a frame's decoding 18 µs of it). If the estimator falls so
  far behind that the queue is full, the oldest block is dropped and counted in
  ``skipped``: never lost silently (the estimator's gap rule then bridges or restarts).
- :class:`BatchReader` (a replay) reads in the service's thread, ``chunk`` frames at a time
  into preallocated arrays, forms their blocks in one vectorised call
  (:meth:`iem.signals.blocks.BlockFormer.push_many`) and hands them over as fast as the
  estimator takes them: the same blocks as frame by frame, to the bit, and nothing is dropped.

An item's ``frame_time`` is the arrival (``time.time()``, epoch s) of the block's last frame
and ``first_time`` that of its first (0.0 where the link has none, as a recording). A block
that a silence or the end of the stream closed is ``flushed``: its last frame's arrival then
measures how long the controller has been quiet, not how far the service is behind. A
silence's ``t`` is on the controller's clock: the last frame's time plus the silence timeout
for each read since that found nothing, so a run that decides on the controller's clock
keeps to it through a silence.
"""

from __future__ import annotations

import math
import queue
import threading
import time
from typing import NamedTuple

import numpy as np

from iem.signals.blocks import N_COLUMNS, BlockFormer

CAPACITY = 50
"""Blocks the live queue holds (0.5 s at 100 points per second): more behind than that, and
the oldest go."""
CHUNK = 4096
"""Frames a replay reads before forming their blocks at once."""
SLEEP_MARGIN = 2
"""Frame periods before a block's last frame is due that the reader is awake again."""


class Item(NamedTuple):
    """What a reader got: ``kind`` is ``"state"`` (``value`` a block point, a
    :class:`iem.types.JointState` of means; ``frame_time`` and ``first_time`` the arrival of
    its last and first frames, epoch s; ``flushed``: a silence or the end closed it),
    ``"silent"`` (``value`` the message; ``t`` when, on the controller's clock, s: NaN
    before the first frame), ``"end"`` or ``"error"`` (``value`` the exception).
    Immutable."""

    kind: str
    value: object = None
    frame_time: float = 0.0
    first_time: float = 0.0
    flushed: bool = False
    t: float = math.nan


class LinkReader:
    """Reads ``link`` in a daemon thread into a queue of at most ``capacity`` blocks.

    Args:
        link: an open joint-state source.
        timeout: the silence timeout passed to ``link.read``, s.
        former: forms the frames into block points (default: 10 frames at 1 kHz).
        capacity: blocks the queue holds before the oldest is dropped.
    """

    def __init__(self, link, timeout: float, former: BlockFormer | None = None,
                 capacity: int = CAPACITY, sleep: bool = True) -> None:
        self.link = link
        self.sleep = bool(sleep)
        """Sleep through the middle of a block (see the module docstring)."""
        self.timeout = float(timeout)
        self.former = BlockFormer() if former is None else former
        self.capacity = int(capacity)
        self.skipped = 0
        """Blocks dropped because the queue was full."""
        self.cpu_s = 0.0
        """CPU time the reader thread used, s (when it has stopped)."""
        self._queue: queue.SimpleQueue[Item] = queue.SimpleQueue()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._last = 0.0  # arrival of the frame before this one

    def start(self) -> LinkReader:
        self._thread = threading.Thread(target=self._loop, name="iem-reader", daemon=True)
        self._thread.start()
        return self

    def _loop(self) -> None:
        from firmware_bridge.errors import ControllerSilent, EndOfStream

        cpu0 = time.thread_time()
        link, former, put = self.link, self.former, self._put
        first = 0.0
        last_t, quiet = math.nan, 0  # the last frame's time; reads since that found none
        # after a block's first frame: asleep until SLEEP_MARGIN periods before its last is
        # due (none for blocks too short to gain from it)
        nap = (former.frames - 1 - SLEEP_MARGIN) / former.rate_hz if self.sleep else 0.0
        try:
            while not self._stop.is_set():
                try:
                    frame = link.read(self.timeout)
                except ControllerSilent as exc:
                    self._flush(first)
                    quiet += 1
                    put(Item("silent", str(exc), t=last_t + quiet * self.timeout))
                    continue
                except EndOfStream:
                    self._flush(first)
                    put(Item("end"))
                    return
                except Exception as exc:  # a link failure: the service ends with it
                    put(Item("error", exc))
                    return
                last_t, quiet = frame.t, 0
                arrived = link.last_frame_time
                if former.pending == 0:
                    first = arrived
                points = former.push(frame.t, frame.q, frame.dq, frame.tau_J, frame.cycle)
                for point in points:  # this frame closed a block (after bridged lost
                    # frames, perhaps more than one), or a restart closed one before it
                    ends_here = former.pending == 0 and point is points[-1]
                    put(Item("state", point, arrived if ends_here else self._last, first))
                    first = arrived
                self._last = arrived
                if nap > 0.0 and former.pending == 1:  # the frames between wait in the
                    time.sleep(nap)  # link's buffer
        finally:
            self.cpu_s = time.thread_time() - cpu0

    def _flush(self, first: float) -> None:
        point = self.former.flush()
        if point is not None:
            self._put(Item("state", point, self._last, first, flushed=True))

    def _put(self, item: Item) -> None:
        q = self._queue
        if item.kind == "state" and q.qsize() >= self.capacity:
            try:  # only this thread puts, so the queue is at most full
                dropped = q.get_nowait()  # the oldest: a block, or old news of a silence
            except queue.Empty:  # the consumer took the last ones meanwhile
                dropped = None
            self.skipped += dropped is not None and dropped.kind == "state"
        q.put(item)

    def get(self, timeout: float) -> Item | None:
        """The next item, or None after ``timeout`` s without one."""
        try:
            return self._queue.get(timeout=timeout)
        except queue.Empty:
            return None

    def stop(self, timeout: float | None = None) -> None:
        """Stop after the current read (at most the silence timeout)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(self.timeout + 1.0 if timeout is None else timeout)
            self._thread = None


class BatchReader:
    """Reads a replayed ``link`` in the caller's thread, ``chunk`` frames at a time (in one
    call where the link offers ``read_many``, as a recording read whole does), and hands
    over their blocks (see the module docstring). Same interface as
    :class:`LinkReader` (``get``, ``stop``, ``skipped``, ``cpu_s``: the reading is the
    caller's own CPU)."""

    def __init__(self, link, timeout: float, former: BlockFormer | None = None,
                 chunk: int = CHUNK) -> None:
        self.link = link
        self.timeout = float(timeout)
        self.former = BlockFormer() if former is None else former
        self.chunk = int(chunk)
        self.skipped = 0
        self.cpu_s = 0.0
        self._T = np.empty(self.chunk)
        self._X = np.empty((self.chunk, N_COLUMNS))
        self._cycles = np.empty(self.chunk, dtype=np.int64)
        self._ready: list[Item] = []
        self._next = 0
        self._last_t = math.nan  # the last frame's time
        self._quiet = 0  # reads since it that found none

    def start(self) -> BatchReader:
        return self

    def stop(self, timeout: float | None = None) -> None:
        """Nothing runs between calls."""

    def get(self, timeout: float | None = None) -> Item:
        """The next item (reads the next chunk when the last one's are handed over)."""
        while self._next >= len(self._ready):
            self._ready, self._next = self._read_chunk(), 0
        item = self._ready[self._next]
        self._next += 1
        return item

    def _read_chunk(self) -> list[Item]:
        from firmware_bridge.errors import ControllerSilent, EndOfStream

        link, T, X, cycles = self.link, self._T, self._X, self._cycles
        n, tail = 0, None
        read_many = getattr(link, "read_many", None)  # a recording read whole: in bulk
        many = None if read_many is None else read_many(self.chunk, T, X, cycles)
        if many is not None:
            n = many
            if n < self.chunk:
                tail = Item("end")
        while many is None and n < self.chunk:
            try:
                frame = link.read(self.timeout)
            except ControllerSilent as exc:
                if n:  # frames before it in this chunk: the last of them
                    self._last_t, self._quiet = float(T[n - 1]), 0
                self._quiet += 1
                tail = Item("silent", str(exc), t=self._last_t + self._quiet * self.timeout)
                break
            except EndOfStream:
                tail = Item("end")
                break
            except Exception as exc:  # a link failure: the service ends with it
                tail = Item("error", exc)
                break
            T[n] = frame.t
            X[n, :7] = frame.q
            X[n, 7:14] = frame.dq
            X[n, 14:] = frame.tau_J
            cycles[n] = frame.cycle
            n += 1
        if n and (tail is None or tail.kind != "silent"):
            self._last_t, self._quiet = float(T[n - 1]), 0
        blocks = self.former.push_many(T[:n], X[:n], cycles[:n])
        items = [Item("state", blocks.state(i)) for i in range(len(blocks))]
        if tail is not None:
            if tail.kind != "error":  # the open block's frames end before the silence
                point = self.former.flush()
                if point is not None:
                    items.append(Item("state", point, flushed=True))
            items.append(tail)
        return items
