"""Periodic saves of the model while the service runs, and the last one at exit.

A periodic save copies the model in the service's thread (a deep copy: the published
learners, with the open bag closed without its refit) and writes the copy in a background
thread, atomically (:func:`iem.persistence.save_model`): a failed save is logged and leaves
the last good file, and the service goes on. A save still writing when the next is due is
not doubled; the next period catches up. :meth:`Checkpointer.save_now` (the service's exit)
waits for a background save, then saves the model itself, at once.
"""

from __future__ import annotations

import copy
import logging
import threading
import time

from iem.persistence import save_model

log = logging.getLogger("iem.service")


class Checkpointer:
    """Saves ``model`` to ``path`` every ``period_s`` s of the caller's clock; with ``saves``
    False (a replay: it never writes the model), never."""

    def __init__(self, path: str, period_s: float, saves: bool = True) -> None:
        self.path = path
        self.period_s = float(period_s)
        self.saves = bool(saves)
        self.count = 0
        """Saves completed."""
        self.cpu_s = 0.0
        """CPU time of the background saves, s."""
        self._next: float | None = None
        self._saver: threading.Thread | None = None

    def start(self, now: float) -> None:
        """The first periodic save is due ``period_s`` after ``now``."""
        self._next = now + self.period_s

    def tick(self, now: float, model) -> None:
        """Save a copy of ``model`` in the background if a save is due."""
        if self._next is None:
            self.start(now)
        if now < self._next or not self.saves:
            return
        self._next = now + self.period_s
        if self._saver is not None and self._saver.is_alive():
            return  # the previous save is still writing; the next period catches up
        snapshot = copy.deepcopy(model)
        path = self.path

        def save() -> None:
            cpu0 = time.thread_time()
            try:
                save_model(snapshot, path)
                self.count += 1
                log.info("checkpoint: model saved to %s (%d bags)", path, snapshot.n_bags,
                         extra={"event": "checkpoint", "bags": snapshot.n_bags})
            except Exception:  # a failed save keeps the last good file; say so and go on
                log.exception("checkpoint to %s failed; the previous file is kept", path)
            finally:
                self.cpu_s += time.thread_time() - cpu0

        self._saver = threading.Thread(target=save, name="iem-checkpoint", daemon=True)
        self._saver.start()

    def save_now(self, model) -> None:
        """Save ``model`` now (atomic), waiting for a background save first (nothing if it
        never saves)."""
        if not self.saves:
            return
        if self._saver is not None:
            self._saver.join()
        save_model(model, self.path)
        self.count += 1
        log.info("model saved to %s (%d bags)", self.path, model.n_bags,
                 extra={"event": "checkpoint", "bags": model.n_bags})
