"""When and where the ensemble's training runs: at once in the caller's thread, or off the cycle.

:class:`~iem.ensemble.IncrementalEnsemble` decides what to learn (the warm-up of a new bag,
the steps of each point that joins the open bag, the refit when a bag closes) and hands each
as a job to its :class:`LearningScheduler`, which runs it:

- ``background=False`` (the default): at once, in the caller's thread; seeded runs
  reproduce bit for bit.
- ``background=True`` (a live link): in a :class:`~iem.ensemble.worker.LearningWorker`
  thread, which runs the jobs in order; the cycle only routes, appends the copied learner
  of a new bag (which estimates until its training lands) and submits. A job swaps its
  trained learner in atomically, one assignment under :attr:`LearningScheduler.lock` (a
  learner once published is never changed). A point that joins the open bag hands its job
  its samples lazily: the tandem simulators run in the worker too (a new bag's are made in
  the cycle, for its learner's centre); :meth:`LearningScheduler.resolve` keeps the two
  threads off the simulators' robot model at once. The estimate never waits for a
  learner's training, its tandem samples or their calibration; where the worker cannot
  keep up, the calibration of the points it reaches late lands late (docs/method.md,
  "Learning off the estimate path"). While more than :data:`MAX_PENDING` jobs wait, points
  that join the open bag are not learnt from (counted in ``skipped_points``): a worker that
  falls behind holds bounded memory.

With ``report_errors`` (IEM+phys's calibration), each job also queues the published
learner's errors on its point's samples (:meth:`LearningScheduler.report`), which the
caller's thread takes (:meth:`LearningScheduler.trained_errors`).

:meth:`~LearningScheduler.drain` waits for pending work; saving drains first, so a saved
model has no pending work (it is finished, never dropped). A deep copy or a pickle of a
scheduler has new locks, a new idle worker and an empty error queue (a thread cannot be
copied; a copy's own points report to it); the ensemble's deep copy does not wait for the
worker (a checkpoint taken in the cycle): it holds the published learners, with the open bag
closed without its refit.
"""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable

from ..base import Samples
from .worker import LearningWorker

__all__ = ["MAX_PENDING", "LearningScheduler"]

MAX_PENDING = 256
"""Most training jobs a background ensemble lets wait: beyond, the steps of points that join
the open bag are skipped (counted in ``skipped_points``); new bags and refits always go."""


def _yield() -> None:
    """Let another thread (the estimate path) take the interpreter, if one waits."""
    time.sleep(0)


class LearningScheduler:
    """Runs an ensemble's training jobs inline or in its worker thread (see the module
    docstring).

    Args:
        background: train in a worker thread, off the estimate path; False: at once, in
            the caller's thread (deterministic).
    """

    def __init__(self, background: bool = False) -> None:
        self.background = bool(background)
        self.skipped_points = 0
        """Points of the open bag not learnt from because the worker was too far behind."""
        self._make_thread_parts()

    def _make_thread_parts(self) -> None:
        """The parts a copy or a pickle makes anew: locks, the worker, the error queue (what
        it held is not carried: a copy's own points report to it)."""
        self.lock = threading.Lock()
        """Held while a trained learner is swapped in, or the learners are read as a whole."""
        self._resolve_lock = threading.Lock()
        self._errors: queue.SimpleQueue = queue.SimpleQueue()
        self._worker = LearningWorker(synchronous=not self.background)

    @property
    def worker(self) -> LearningWorker:
        """The worker the jobs run in (synchronous when not ``background``)."""
        return self._worker

    def submit(self, job: Callable[[], None]) -> None:
        """Run ``job`` now (inline) or queue it for the worker thread."""
        self._worker.submit(job)

    def behind(self) -> bool:
        """The worker is too far behind to take a point's steps: more than
        :data:`MAX_PENDING` jobs wait (counted in ``skipped_points``)."""
        if self.background and self._worker.pending > MAX_PENDING:
            self.skipped_points += 1
            return True
        return False

    @property
    def pause(self) -> Callable[[], None] | None:
        """What a refit calls between its mini-batches: give the interpreter to a waiting
        estimate when in the background, nothing inline."""
        return _yield if self.background else None

    def resolve(self, samples: Samples):
        """:func:`iem.base.resolve`, one thread at a time: the cycle (a new bag) and the
        worker (a point joining the open bag) may both make samples, and the simulators'
        robot model is not for two threads at once."""
        if not callable(samples):
            return samples
        with self._resolve_lock:
            return samples()

    def report(self, item: tuple) -> None:
        """Queue one learnt point's ``(bag, generation, errors, truth)`` (any thread)."""
        self._errors.put(item)

    def trained_errors(self) -> list[tuple]:
        """What :meth:`report` queued since the last call, in order (the caller's thread)."""
        errors, out = self._errors, []
        while not errors.empty():  # one consumer: what it saw is there (no exception per
            out.append(errors.get_nowait())  # cycle for an empty queue, the usual case)
        return out

    @property
    def pending(self) -> int:
        """Training jobs submitted and not finished (always 0 unless ``background``)."""
        return self._worker.pending

    @property
    def cpu_s(self) -> float:
        """CPU time of the training jobs of the current worker, s."""
        return self._worker.cpu_s

    def drain(self) -> None:
        """Wait until every submitted training job has landed."""
        self._worker.drain()

    def stop(self) -> None:
        """Drain and stop the worker thread (a later job starts it again)."""
        self._worker.close()

    def set_background(self, on: bool) -> None:
        """Train in the worker thread (True) or inline (False) from now on; what is pending
        lands first."""
        on = bool(on)
        if on == self.background:
            return
        self._worker.close()
        self.background = on
        self._worker = LearningWorker(synchronous=not on)

    def __deepcopy__(self, memo) -> LearningScheduler:
        new = LearningScheduler.__new__(LearningScheduler)
        memo[id(self)] = new
        new.background, new.skipped_points = self.background, self.skipped_points
        new._make_thread_parts()
        return new

    def __getstate__(self) -> dict:
        self.drain()
        return {"background": self.background, "skipped_points": self.skipped_points}

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._make_thread_parts()
