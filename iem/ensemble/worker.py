"""Learning off the estimate path: a worker thread that runs the ensemble's training jobs.

The ensemble's cycle (:meth:`iem.ensemble.IncrementalEnsemble.learn_one`) only routes,
appends a copied learner for a new bag and submits the training: the warm-up of a new bag,
the steps on each point that joins the open bag, the refit when a bag closes. A job is a
zero-argument callable; the worker runs the jobs one at a time in the order they were
submitted, so what each job computes does not depend on when it runs (each learner draws its
noise from its own seeded generator): only *when* a trained learner lands in the ensemble
does. A job publishes its result itself, by one assignment under the lock of the ensemble's
:class:`~iem.ensemble.scheduler.LearningScheduler` (the swap is atomic: a cycle predicts with
the old learner or with the new one, never with a learner half trained).

``synchronous=True`` runs every job at once in the caller's thread (no thread at all):
seeded runs then reproduce bit for bit, as tests and benchmarks need. :meth:`drain` waits for
every submitted job; :meth:`close` drains and stops the thread. A job that raises stops
nothing else: the error is kept and raised by the next :meth:`drain` (so it is not lost).

Copies: a deep copy or a pickle of a worker is a new idle worker of the same mode (a thread
cannot be copied); the scheduler's copies get one so.

The interpreter lock: a Python thread runs numpy's small products holding it, and by default
holds it up to 5 ms before another thread may take it. So the worker gives it up between jobs
and between the mini-batches of a refit (``time.sleep(0)``): an estimate waits at most one
mini-batch step (about 0.1 ms), not a switch interval. It does not make the worker run in
parallel with the estimate path: on a loaded machine it lags (docs/method.md).
"""

from __future__ import annotations

import queue
import threading
import time
import weakref
from collections.abc import Callable

from ..errors import IemError


class LearningError(IemError):
    """A training job in the worker failed."""


class LearningWorker:
    """Runs training jobs in order, in one background thread (or inline if synchronous).

    Args:
        synchronous: run each job at once in the submitting thread.
    """

    def __init__(self, synchronous: bool = False) -> None:
        self.synchronous = bool(synchronous)
        self._queue: queue.Queue | None = None
        self._thread: threading.Thread | None = None
        self._status = {"error": None, "cpu_s": 0.0}  # shared with the thread

    def submit(self, job: Callable[[], None]) -> None:
        """Queue ``job`` (run it now if synchronous)."""
        if self.synchronous:
            cpu0 = time.thread_time()
            job()
            self._status["cpu_s"] += time.thread_time() - cpu0
            return
        if self._thread is None or not self._thread.is_alive():
            self._queue = queue.Queue()
            self._thread = threading.Thread(target=_loop, args=(self._queue, self._status),
                                            name="iem-learning", daemon=True)
            self._thread.start()
            # a worker dropped without close() still ends its thread
            weakref.finalize(self, self._queue.put, None)
        self._queue.put(job)

    @property
    def cpu_s(self) -> float:
        """CPU time the jobs took, s (the thread's, or the caller's when synchronous)."""
        return self._status["cpu_s"]

    @property
    def pending(self) -> int:
        """Jobs submitted and not finished (0 if synchronous)."""
        return 0 if self._queue is None else self._queue.unfinished_tasks

    def drain(self) -> None:
        """Wait until every submitted job has run; raise a job's failure if one failed."""
        if self._queue is not None:
            self._queue.join()
        exc = self._status["error"]
        if exc is not None:
            self._status["error"] = None
            raise LearningError(f"a training job failed: {exc!r}") from exc

    def close(self) -> None:
        """Drain, then stop the thread (a later submit starts a new one)."""
        try:
            self.drain()
        finally:
            if self._thread is not None and self._thread.is_alive():
                self._queue.put(None)
                self._thread.join()
            self._thread = None
            self._queue = None

    def __deepcopy__(self, memo) -> LearningWorker:
        return LearningWorker(self.synchronous)

    def __getstate__(self) -> dict:
        return {"synchronous": self.synchronous}

    def __setstate__(self, state: dict) -> None:
        self.__init__(state["synchronous"])


def _loop(q: queue.Queue, status: dict) -> None:
    """The worker thread: run jobs until ``None``; a failure is kept in ``status``."""
    while True:
        job = q.get()
        try:
            if job is None:
                return
            cpu0 = time.thread_time()
            try:
                job()
            finally:
                status["cpu_s"] += time.thread_time() - cpu0
        except BaseException as exc:  # kept for drain(); the worker goes on
            status["error"] = exc
        finally:
            job = None  # holds nothing (the ensemble) while idle
            q.task_done()
        time.sleep(0)  # a waiting estimate takes the interpreter between jobs
