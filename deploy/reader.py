"""Reading the bus never waits for estimating: the link is read in a thread of its own.

:class:`LinkReader` calls the link's ``read`` in a loop, in its own thread, and puts what it
gets into a bounded queue with the time it arrived: each complete controller cycle, a
controller silence (:class:`~firmware_bridge.errors.ControllerSilent`), the end of a replayed
stream, or a link failure. The service's loop takes them out at its own pace. While the
estimator is slow (a learning step, a host under load) the link keeps being drained, so the
adapter's and the kernel's buffers never overflow and every cycle keeps its arrival time.

If the estimator falls so far behind that the queue is full, the oldest cycle is dropped and
counted in ``skipped``: never lost silently. The estimator then meets a gap in the time
stamps, which its gap rule (:mod:`iem.gaps`) bridges or restarts on.
"""

from __future__ import annotations

import queue
import threading
import time
from typing import NamedTuple

CAPACITY = 500
"""Cycles the queue holds (0.5 s at 1 kHz): more behind than that, and the oldest go."""


class Item(NamedTuple):
    """What the reader got: ``kind`` is ``"state"`` (``value`` a joint state, ``frame_time``
    its arrival, epoch s), ``"silent"`` (``value`` the message), ``"end"`` or ``"error"``
    (``value`` the exception). Immutable (a named tuple: one is made every cycle)."""

    kind: str
    value: object = None
    frame_time: float = 0.0


class LinkReader:
    """Reads ``link`` in a daemon thread into a queue of at most ``capacity`` cycles.

    Args:
        link: an open joint-state source.
        timeout: the silence timeout passed to ``link.read``, s.
        capacity: cycles the queue holds before the oldest is dropped.
    """

    def __init__(self, link, timeout: float, capacity: int = CAPACITY) -> None:
        self.link = link
        self.timeout = float(timeout)
        self.capacity = int(capacity)
        self.skipped = 0
        """Cycles dropped because the queue was full."""
        self.cpu_s = 0.0
        """CPU time the reader thread used, s (when it has stopped)."""
        # the C queue: a put and a blocking get cost a fraction of a Condition's
        # Python-level wait and notify, on both threads, every cycle
        self._queue: queue.SimpleQueue[Item] = queue.SimpleQueue()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> LinkReader:
        self._thread = threading.Thread(target=self._loop, name="iem-reader", daemon=True)
        self._thread.start()
        return self

    def _loop(self) -> None:
        from firmware_bridge.errors import ControllerSilent, EndOfStream

        cpu0 = time.thread_time()
        try:
            while not self._stop.is_set():
                try:
                    state = self.link.read(self.timeout)
                except ControllerSilent as exc:
                    self._put(Item("silent", str(exc)))
                    continue
                except EndOfStream:
                    self._put(Item("end"))
                    return
                except Exception as exc:  # a link failure: the service ends with it
                    self._put(Item("error", exc))
                    return
                self._put(Item("state", state, getattr(self.link, "last_frame_time", 0.0)))
        finally:
            self.cpu_s = time.thread_time() - cpu0

    def _put(self, item: Item) -> None:
        q = self._queue
        if item.kind == "state" and q.qsize() >= self.capacity:
            try:  # only this thread puts, so the queue is at most full
                dropped = q.get_nowait()  # the oldest: a cycle, or old news of a silence
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
