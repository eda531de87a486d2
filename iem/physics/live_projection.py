"""The posterior an IEM+phys estimate shows on a live link, projected a few steps per sample.

Projecting a posterior's mean onto physically consistent parameters
(:func:`iem.physics.consistency.project_steps`) takes up to 200 Newton steps of about 60 µs
(most often about five): in one 1 kHz cycle the longest would stall the estimate.
:class:`SpreadProjection` spreads it: each sample does ``budget`` Newton steps of the oldest
projection in progress, and estimates meanwhile show the last finished one (its phi and std,
the same posterior, the same arithmetic as at once). The first posterior after a start or a
change is projected at once.
"""

from __future__ import annotations

import numpy as np

from .consistency import project_steps
from .posterior import Posterior


class SpreadProjection:
    """The shown posterior and its consistent phi; the projection in progress."""

    def __init__(self) -> None:
        self.clear()

    def clear(self) -> None:
        """Nothing shown (a start or a payload change): the next posterior at once."""
        self.shown: tuple[Posterior, np.ndarray] | None = None
        """``(posterior, its consistent phi)`` estimates show."""
        self._pending = None  # (posterior, its projection's generator)

    def __getstate__(self) -> dict:
        state = self.__dict__.copy()
        state["_pending"] = None  # a projection in progress: a copy starts it again
        return state

    def show(self, post: Posterior, budget: int, busy: bool) -> tuple[Posterior, np.ndarray]:
        """What an estimate shows when ``post`` is the newest posterior: ``budget`` more
        Newton steps of the oldest projection in progress (none if this sample was
        ``busy`` with other heavy work), then the last finished one."""
        shown = self.shown
        if shown is not None and shown[0] is post:
            return shown
        if shown is None:  # nothing shown since the start or a change: at once
            self._pending = None
            self.shown = (post, post.phi)
            return self.shown
        if busy:
            return shown  # this sample did its heavy work: the steps go on at the next
        if self._pending is None:
            self._pending = (post, project_steps(post.mean, post.precision, eps=post.eps))
        target, steps = self._pending
        for _ in range(budget):
            try:
                next(steps)
            except StopIteration as done:
                phi = done.value
                phi.flags.writeable = False
                self.shown, self._pending = (target, phi), None
                break
        return self.shown
