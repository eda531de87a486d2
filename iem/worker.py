"""Learning off the estimate path: the worker that runs the ensemble's training jobs.

The ensemble's cycle (:meth:`iem.ensemble.IncrementalEnsemble.learn_one`) only routes,
appends a copied learner for a new bag and submits the training: the warm-up of a new bag,
the steps on each point that joins the open bag, the refit when a bag closes. The jobs
(:mod:`iem.bag_trainer`) are small picklable messages run in order by one
:class:`~iem.bag_trainer.BagTrainer`, which owns the open bag's training state; each
learner draws its noise from its own seeded generator, so what a job computes does not
depend on when or where it runs: only *when* a trained learner lands in the ensemble does.
The worker hands each trained learner to its ``publish(bag, gen, learner)`` callback (the
ensemble's swap: one assignment under its lock, so a cycle predicts with the old learner
or the new one, never with a learner half trained).

- ``synchronous=True`` runs every job at once in the caller's thread (no process at all):
  seeded runs reproduce bit for bit, as tests, benchmarks and replays need; a failing job
  raises in the caller.
- Otherwise the jobs run in a child process (:mod:`iem.worker_process`), started by the
  first submit (or :meth:`LearningWorker.start`): a Python thread would hold the cycle's
  interpreter lock while it trains. The learners trained there are published by a listener
  thread. A job that raises stops nothing else: the error is kept and raised by the next
  :meth:`drain`. A child that dies (killed) is reported by the next :meth:`drain` as a
  :class:`LearningError` (its pending jobs and the open bag's training state are lost:
  :attr:`losses` counts it) and a new child is started by the next submit.

:meth:`drain` waits for every submitted job; :meth:`close` drains and stops the child.
Copies: a deep copy or a pickle of a worker is a new idle worker of the same mode (a process
cannot be copied); :class:`~iem.ensemble.IncrementalEnsemble` hands over its open bag.
"""

from __future__ import annotations

import time
import weakref
from collections.abc import Callable

from .bag_trainer import BagTrainer
from .errors import IemError


class LearningError(IemError):
    """A training job in the worker failed, or the learning process died."""


class LearningWorker:
    """Runs training jobs in order, in a child process (or inline if synchronous).

    Args:
        synchronous: run each job at once in the submitting thread.
        publish: ``publish(bag, gen, learner)`` for each trained learner (held weakly if it
            is a bound method, so a worker does not keep its ensemble alive), or None.
        first: a job the child process runs when it starts (not counted, e.g. an import).
    """

    def __init__(self, synchronous: bool = False, publish: Callable | None = None,
                 first=None) -> None:
        self.synchronous = bool(synchronous)
        self._publish = (None if publish is None else
                         weakref.WeakMethod(publish) if hasattr(publish, "__self__")
                         else (lambda f: lambda: f)(publish))
        self._first = first
        self.trainer = BagTrainer()  # the synchronous worker's (a child holds its own)
        self._child = None
        self._done = 0
        self._cpu_s = 0.0  # of the children that ended
        self._error: BaseException | None = None
        self._losses = 0

    # -- counters ------------------------------------------------------------------------
    @property
    def jobs_done(self) -> int:
        """Jobs run so far."""
        child = self._child
        return self._done + (0 if child is None else child.acked)

    @property
    def cpu_s(self) -> float:
        """CPU time of the jobs, s: the caller's when synchronous; else the child process's
        (the jobs and their messages) plus the parent's threads that talk to it."""
        child = self._child
        return self._cpu_s + (0.0 if child is None else child.cpu_s)

    @property
    def pending(self) -> int:
        """Jobs submitted and not reported done (0 if synchronous)."""
        child = self._child
        return 0 if child is None else child.pending

    @property
    def losses(self) -> int:
        """Learning processes that died unasked (each lost its pending jobs and the open
        bag's training state)."""
        child = self._child
        return self._losses + (child is not None and child.died is not None)

    @property
    def pid(self) -> int | None:
        """The learning process's pid, or None (synchronous, or not started)."""
        child = self._child
        return None if child is None or not child.alive else child.pid

    def nbytes(self) -> int:
        """Bytes of the open bag's training state (as last reported by a child)."""
        if self.synchronous:  # its learner is the published one: only the kept samples
            return 0 if self.trainer.kept is None else self.trainer.kept.nbytes()
        return 0 if self._child is None else self._child.nbytes

    # -- work ----------------------------------------------------------------------------
    def start(self, wait: bool = False) -> None:
        """Start the child process now (its imports then do not delay the first job);
        ``wait``: until it has imported what the jobs need and run ``first`` (a service
        starting, not a cycle: the first bag of a run is not trained late)."""
        if self.synchronous:
            return
        child = self._child
        if child is not None and child.alive:
            return
        if child is not None:
            self._retire(child)
        from .worker_process import Child

        ref = self._publish  # not the worker: a dropped worker must be collectable

        def publish(bag: int, gen: int, learner) -> None:
            target = None if ref is None else ref()
            if target is not None:
                target(bag, gen, learner)

        self._child = Child(publish, self._first)
        weakref.finalize(self, self._child.request_stop)  # a dropped worker ends its child
        if wait:
            self._child.call(None)

    def submit(self, job) -> None:
        """Queue ``job`` (run it now if synchronous)."""
        if self.synchronous:
            cpu0 = time.thread_time()
            try:
                job(self.trainer)
                for bag, gen, learner in self.trainer.take():
                    self._publish_one(bag, gen, learner)
            finally:
                self._cpu_s += time.thread_time() - cpu0
                self._done += 1
            return
        child = self._child
        if child is None or not child.alive:
            self.start()
            child = self._child
        child.submit(job)

    def call(self, job):
        """``job(trainer)`` after every submitted job, its result returned (None if the
        learning process died meanwhile)."""
        if self.synchronous:
            return job(self.trainer)
        child = self._child
        if child is None or not child.alive:
            return None
        return child.call(job)

    def drain(self) -> None:
        """Wait until every submitted job has run; raise a job's failure if one failed, or
        the death of the learning process."""
        child = self._child
        if child is not None:
            child.drain()
            if child.died is not None:
                self._retire(child)
        exc, self._error = self._error, None
        if exc is None and child is not None and child.error is not None:
            exc, child.error = child.error, None
        if isinstance(exc, LearningError):
            raise exc
        if exc is not None:
            raise LearningError(f"a training job failed: {exc!r}") from exc

    def close(self) -> None:
        """Drain, then stop the child process (a later submit starts a new one)."""
        try:
            self.drain()
        finally:
            child, self._child = self._child, None
            if child is not None:
                child.stop()
                self._fold(child)

    def _retire(self, child) -> None:
        """Forget a child that died: its error is kept for the next :meth:`drain`."""
        if child is not self._child:
            return
        self._child = None
        self._fold(child)
        self._losses += 1
        also = "" if self._error is None else f" (and a training job failed: {self._error!r})"
        self._error = LearningError(
            f"{child.died}; the open bag keeps its last published learner and is not "
            f"trained further (the next bag starts a new learning process){also}")

    def _fold(self, child) -> None:
        self._done += child.acked
        self._cpu_s += child.cpu_s
        if child.error is not None and self._error is None:
            self._error = child.error
            child.error = None

    def _publish_one(self, bag: int, gen: int, learner) -> None:
        publish = None if self._publish is None else self._publish()
        if publish is not None:
            publish(bag, gen, learner)

    def __deepcopy__(self, memo) -> LearningWorker:
        return LearningWorker(self.synchronous)

    def __getstate__(self) -> dict:
        return {"synchronous": self.synchronous}

    def __setstate__(self, state: dict) -> None:
        self.__init__(state["synchronous"])
