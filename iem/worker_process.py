"""The learning worker's child process: training that never holds the cycle's interpreter.

A Python thread that trains competes with the estimate path for the interpreter lock (a
trivial call of the cycle waited up to 5 ms behind it). So the background
:class:`~iem.worker.LearningWorker` runs its jobs (:mod:`iem.bag_trainer`) in a child
process, which owns the open bag's training state. In the parent:

- :meth:`Child.submit` only puts the job on an unbounded in-process queue (no pickling, no
  system call in the caller); a *sender* thread pickles it onto the child's pipe (a pipe
  write that blocks when the child is behind blocks only that thread).
- A *listener* thread receives the child's reports and publishes the learners in them
  through the ``publish(bag, gen, learner)`` callback (the ensemble's atomic swap).

The child sends a report (the jobs done since the last one, their CPU time, the learners to
publish, the latest per bag, a failure) after a job whenever no further job waits (so a
child that keeps up hands over the learner trained on a point before the next point
arrives: the open bag's estimates are as fresh as inline training makes them, give or take
a point), at once after a job marked ``urgent`` (a new bag's warm-up, a refit), a failure,
a query or a flush (:meth:`Child.drain`), and otherwise (a child working through a backlog)
at most every :data:`REPORT_S`. A learner that only took SGD steps goes as its weights
(:class:`~iem.bag_trainer.Weights`): at up to 1,000 reports a second, unpickling whole
learners (generator and all, about 40 us each) would take the parent's interpreter for 4 %
of the time, the weights a tenth of that.

The child is a fresh interpreter (``python -c``, the parent's ``sys.path``), never a fork
(unsafe in a multi-threaded parent), and unlike multiprocessing's ``spawn`` it does not run
the parent's main script again. It ignores SIGINT (the parent decides when it ends), ends
when its pipe closes (the parent exited, even killed), and the parent's exit terminates it
(no refit in progress outlives it). It runs at a lower priority (:data:`NICE`). Its CPU
time (``time.process_time`` deltas, all of it: the jobs and their messages) and the parent
threads' (``time.thread_time``) are counted in :attr:`Child.cpu_s`.
"""

from __future__ import annotations

import atexit
import contextlib
import json
import multiprocessing.reduction
import os
import queue
import signal
import subprocess
import sys
import threading
import time
import traceback
import weakref
from collections.abc import Callable
from multiprocessing.connection import Connection

REPORT_S = 0.01
"""Longest a trained learner waits in a busy child (one with more jobs waiting) before it
is sent to the parent, s."""

NICE = 19
"""How much lower the learning process's CPU priority is than the plug-in's (``os.nice``).
Learning is background work: on a busy machine the cycle, the link's reader (and a
controller simulated in the process) take the cores first and training lands later (a
backlog beyond :data:`iem.ensemble.MAX_PENDING` skips points, counted). Measured with
``iem demo`` on the shared 2-core machine (load 2.9): at nice 0 the cycles of an open bag
had a latency p50 of 1.4-1.5 ms and p99 4.5-80 ms (the child took a core the cycle
needed); at nice 19 p50 0.39 ms and p99 1.2-1.4 ms, MAE and writes unchanged."""

JOIN_S = 10.0
"""How long :meth:`Child.stop` waits for the child to end before it terminates it, s."""

_PICKLER = multiprocessing.reduction.ForkingPickler
_LIVE: weakref.WeakSet = weakref.WeakSet()
"""The children running now: the parent's exit ends them (:func:`_end_children`)."""

_BOOT = ("import sys, json; sys.path[:0] = json.loads(sys.argv[1]); "
         "from iem.worker_process import _entry; _entry(int(sys.argv[2]), int(sys.argv[3]))")


@atexit.register
def _end_children() -> None:
    """At the parent's exit: every learning process still running is terminated (it would
    end anyway when it next reads its pipe, which the exit closes, but a refit in progress
    would keep it running until done)."""
    for child in list(_LIVE):
        child._stopping = True
        if child.process.poll() is None:
            child.process.terminate()


class Child:
    """One learning process and the parent's two threads that talk to it.

    Args:
        publish: ``publish(bag, gen, learner)``, called from the listener thread; returns
            nothing. It must not hold the ensemble alive (pass a weak method's caller).
        first: a job the child runs at start, before any submitted one, not counted (e.g.
            the import of the coverage sampler).
    """

    def __init__(self, publish: Callable, first=None) -> None:
        self._publish = publish
        self._cond = threading.Condition()
        self.submitted = 0
        self.acked = 0
        self.cpu_s = 0.0
        self.nbytes = 0
        self.error: BaseException | None = None
        self.died: str | None = None  # why the child ended unasked
        self._stopping = False
        self._replies: dict[int, object] = {}
        self._token = 0
        self._outbox: queue.SimpleQueue = queue.SimpleQueue()
        child_in, parent_out = os.pipe()
        parent_in, child_out = os.pipe()
        path = [p or os.getcwd() for p in sys.path]  # the jobs' modules import as here
        self.process = subprocess.Popen(
            [sys.executable, "-c", _BOOT, json.dumps(path), str(child_in), str(child_out)],
            pass_fds=(child_in, child_out), stdin=subprocess.DEVNULL, close_fds=True)
        os.close(child_in)  # the parent keeps only its ends: the child's EOF is the parent's
        os.close(child_out)  # exit, the parent's EOF the child's
        parent_in = Connection(parent_in, writable=False)
        parent_out = Connection(parent_out, readable=False)
        self.pid = self.process.pid
        _LIVE.add(self)
        self._outbox.put(("first", first))
        self._sender = threading.Thread(target=self._send_loop, args=(parent_out,),
                                        name="iem-learning-send", daemon=True)
        self._listener = threading.Thread(target=self._listen, args=(parent_in,),
                                          name="iem-learning-listen", daemon=True)
        self._sender.start()
        self._listener.start()

    @property
    def alive(self) -> bool:
        return self.died is None and not self._stopping

    @property
    def pending(self) -> int:
        return self.submitted - self.acked

    def submit(self, job) -> None:
        with self._cond:
            self.submitted += 1
        self._outbox.put(("job", job))

    def drain(self) -> None:
        """Wait until every job submitted so far was reported done (or the child died)."""
        with self._cond:
            target = self.submitted
            if self.acked >= target or self.died is not None:
                return
        self.call(None)  # the child's answer comes after its reports of every job before

    def call(self, job):
        """Run ``job(trainer)`` in the child after every submitted job; return its result
        (None if the child died, or ``job`` is None: a flush)."""
        with self._cond:
            self._token += 1
            token = self._token
        self._outbox.put(("call", token, job))
        with self._cond:
            self._cond.wait_for(lambda: token in self._replies or self.died is not None)
            return self._replies.pop(token, None)

    def stop(self) -> None:
        """Ask the child to end after its jobs, wait for it (terminate it after
        :data:`JOIN_S`), and end the threads."""
        self._stopping = True
        self._outbox.put(None)
        self._listener.join(JOIN_S)  # it ends when the child closes its pipe, and reaps it
        if self.process.poll() is None:
            self.process.terminate()
            self._listener.join(JOIN_S)
        self._sender.join(JOIN_S)

    def request_stop(self) -> None:
        """Ask the child to end, without waiting (a finaliser's call)."""
        self._stopping = True
        self._outbox.put(None)

    # -- the parent's threads ------------------------------------------------------------
    def _send_loop(self, conn) -> None:
        carried = 0.0  # the last write's CPU, counted with the next item (a drain that the
        try:  # write let return must not see the count move after it)
            while True:
                item = self._outbox.get()
                cpu0 = time.thread_time()
                try:
                    data = _PICKLER.dumps(item)
                except Exception as exc:  # a job that cannot be sent failed; the rest go on
                    with self._cond:
                        self.error = self.error or exc
                        self.acked += item[0] == "job"
                        if item[0] == "call":
                            self._replies[item[1]] = None
                        self._cond.notify_all()
                    continue
                cpu1 = time.thread_time()
                self._add_cpu(cpu1 - cpu0 + carried)
                try:
                    conn.send_bytes(data)
                except (OSError, ValueError):  # the child is gone: the listener reports it
                    return
                finally:
                    del data
                    carried = time.thread_time() - cpu1
                if item is None:
                    return
        finally:
            conn.close()

    def _listen(self, conn) -> None:
        try:
            while True:
                try:
                    report = conn.recv()
                except (EOFError, OSError):
                    break
                cpu0 = time.thread_time()
                for bag, gen, learner in report["publish"]:
                    self._publish(bag, gen, learner)
                with self._cond:
                    self.acked += report["done"]
                    self.cpu_s += report["cpu_s"]
                    self.nbytes = report["nbytes"]
                    if report["error"] is not None:
                        self.error = report["error"]
                    if "reply" in report:
                        self._replies[report["reply"][0]] = report["reply"][1]
                    self.cpu_s += time.thread_time() - cpu0
                    self._cond.notify_all()
        finally:
            conn.close()
            try:
                self.process.wait(JOIN_S)  # reaps it
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
            _LIVE.discard(self)
            with self._cond:
                if not self._stopping:
                    lost = self.submitted - self.acked
                    self.died = (f"the learning process (pid {self.pid}) ended with exit code "
                                 f"{self.process.returncode}; {lost} training jobs were lost")
                self.acked = self.submitted
                self._cond.notify_all()
            self._outbox.put(None)  # ends the sender if it waits

    def _add_cpu(self, seconds: float) -> None:
        with self._cond:
            self.cpu_s += seconds


# -- the child -----------------------------------------------------------------------------
def _entry(fd_in: int, fd_out: int) -> None:
    """The child process's start (``_BOOT``): its two pipe ends, then :func:`_main`."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    with contextlib.suppress(OSError):
        os.nice(NICE)  # background work: on a busy machine the estimate path gets the core
    conn_in = Connection(fd_in, writable=False)
    conn_out = Connection(fd_out, readable=False)
    try:
        _, first = conn_in.recv()
    except (EOFError, OSError):
        return
    _main(conn_in, conn_out, first)


def _main(conn_in, conn_out, first) -> None:
    """The child's loop: run jobs in order, report (see the module docstring)."""
    from .bag_trainer import BagTrainer

    trainer = BagTrainer()
    if first is not None:
        with contextlib.suppress(Exception):  # a failed preparation: the refit retries it
            first(trainer)
    cpu_mark = time.process_time()
    done, error, last = 0, None, time.monotonic()

    def report(light: bool = True, **extra) -> None:
        nonlocal done, error, last, cpu_mark
        cpu = time.process_time()
        conn_out.send({"done": done, "cpu_s": cpu - cpu_mark, "publish": trainer.take(light),
                       "error": error, "nbytes": trainer.nbytes(), **extra})
        cpu_mark, done, error, last = cpu, 0, None, time.monotonic()

    while True:
        owed = done > 0 or bool(trainer.outbox)
        wait = max(0.0, last + REPORT_S - time.monotonic()) if owed else None
        try:
            if not conn_in.poll(wait):
                report()  # idle with something owed: it goes now
                continue
            item = conn_in.recv()
        except (EOFError, OSError):  # the parent is gone
            return
        if item is None:
            report(light=False)
            return
        kind, urgent = item[0], True
        if kind == "job":
            job = item[1]
            urgent = getattr(job, "urgent", False)
            try:
                job(trainer)
            except Exception as exc:  # kept for the parent's drain()
                error, urgent = _picklable(exc), True
            done += 1
            job = None
        elif kind == "call":  # a flush (drain) is a call of nothing
            try:
                value = None if item[2] is None else item[2](trainer)
            except Exception as exc:
                error, value = _picklable(exc), None
            report(light=False, reply=(item[1], value))
            continue
        if urgent or time.monotonic() - last >= REPORT_S or not conn_in.poll(0):
            report()  # urgent, due, or idle: the parent gets the newest learner at once


def _picklable(exc: BaseException) -> BaseException:
    """``exc`` if it pickles, else a RuntimeError with its text and traceback."""
    import pickle

    try:
        pickle.dumps(exc)
        return exc
    except Exception:
        text = "".join(traceback.format_exception(exc))
        return RuntimeError(f"{exc!r} in the learning process {os.getpid()}:\n{text}")
