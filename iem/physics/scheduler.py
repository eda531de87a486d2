"""When IEM+phys does its heavy work: at once, or spread over the samples of a live link.

Per sample IEM+phys may form an equation, test it and add it to its window, refresh its
posterior (at most every ``refresh_every`` equations) and project the posterior's mean onto
consistent parameters (up to 200 Newton steps, most often about five). Offline (a replay, a
benchmark: ``project_budget`` 0) each is done at once, in the sample that needs it.
:class:`RefreshScheduler` decides, per sample, what is done now and what waits:

- On a live link (``project_budget > 0``, set by :meth:`iem.base.Estimator.go_live`:
  :data:`LIVE_PROJECT_BUDGET`) a projection takes at most ``project_budget`` Newton steps
  per sample (:class:`~iem.physics.live_projection.SpreadProjection`), and estimates
  meanwhile show the last finished one (phi and std of the same posterior, the same
  arithmetic as at once), so they lag the at-once model's by a few samples.
- At the block points' rate (``update_every == 1``) every point still forms, tests and adds
  its equation and refreshes at once; only the Newton steps are spread.
- Fed frames (``update_every > 1``, *one job* per sample), each sample does at most one
  heavy job: form an equation; test and add the one formed the sample before (queued);
  refresh the posterior, at most :data:`SPREAD_WAIT` samples late; or Newton steps. A
  payload change is then detected one sample later.

The first estimate after a start or a detected change is made at once (:meth:`clear`). What
a model file keeps of the schedule: whether the posterior is due (``stale``) and the
equations since its last refresh (``since_refresh``).
"""

from __future__ import annotations

import numpy as np

from .live_projection import SpreadProjection
from .posterior import Posterior

__all__ = ["LIVE_PROJECT_BUDGET", "SPREAD_WAIT", "RefreshScheduler"]

LIVE_PROJECT_BUDGET = 10
"""Newton steps of the consistency projection per block point on a live link
(``project_budget``, set by :meth:`PhysicsInformedEnsemble.go_live`): about 60 µs a step,
so well under a millisecond. A payload just outside the consistent set takes about five
steps (one point); the longest projection (200 steps) is spread over 20 points (0.2 s),
instead of stalling one point for several milliseconds."""
SPREAD_WAIT = 3
"""Samples a due posterior refresh may wait for one without other heavy work (spread)."""


class RefreshScheduler:
    """What IEM+phys's heavy work does in this sample (see the module docstring).

    Args:
        budget: Newton steps of the projection per sample (0: every projection at once).
        update_every: samples per equation (1: block points; more: frames, one job each).
        refresh_every: equations between refreshes of the posterior.
    """

    def __init__(self, budget: int, update_every: int, refresh_every: int) -> None:
        self.budget = int(budget)
        self.update_every = int(update_every)
        self.refresh_every = int(refresh_every)
        self._spread = SpreadProjection()
        self.clear()

    def clear(self) -> None:
        """A start or a payload change: nothing due, queued or shown (the next posterior is
        projected at once)."""
        self.stale = False
        """New equations or estimates since the posterior: refresh it."""
        self.stale_for = 0
        """Samples it has been stale."""
        self.busy = False
        """This sample did heavy work (one job: the rest waits)."""
        self.queued = None
        """One job: an equation formed, tested and added at the next sample."""
        self.since_refresh = 0
        """Equations added since the last refresh."""
        self._spread.clear()

    @property
    def spread(self) -> bool:
        """The heavy work is spread over samples (a live link): with a ``budget``."""
        return self.budget > 0

    @property
    def one_job(self) -> bool:
        """Spread, one heavy job per sample: forming an equation, testing and adding it, a
        refresh, or Newton steps, each in a sample of its own (``update_every > 1``: samples
        at the frame rate). At the block points' rate (``update_every == 1``) every point
        forms, tests and adds its equation and refreshes when due, at once; only the
        projection's Newton steps are spread, ``budget`` per point."""
        return self.spread and self.update_every > 1

    def take_queued(self):
        """The equation the last sample queued, or None; it is no longer queued."""
        equation, self.queued = self.queued, None
        return equation

    def equation_added(self, m: int) -> None:
        """An equation joined the window, which now holds ``m``: the posterior is due after
        each of the first ``refresh_every`` and then every ``refresh_every`` (at the next
        estimate; one job: the next sample without other work)."""
        self.since_refresh += 1
        if m <= self.refresh_every or self.since_refresh >= self.refresh_every:
            self.stale = True

    def sample_done(self) -> None:
        """The end of a sample's observation: a due refresh has waited one sample more."""
        if self.stale:
            self.stale_for += 1

    def due(self, post: Posterior | None) -> bool:
        """Refresh the posterior ``post`` now: there is none, or it is stale and this is not
        a busy one-job sample within :data:`SPREAD_WAIT` samples of its falling due."""
        return post is None or (self.stale and not (
            self.busy and self.one_job and self.stale_for <= SPREAD_WAIT))

    def refreshed(self) -> None:
        """The posterior was refreshed: that was this sample's heavy work."""
        self.since_refresh = 0
        self.stale, self.stale_for = False, 0
        self.busy = True

    def show(self, post: Posterior) -> tuple[Posterior, np.ndarray]:
        """The posterior an estimate shows and its consistent phi: ``post`` projected at
        once, or, with a ``budget``, spread (the last finished projection is shown
        meanwhile)."""
        if self.budget <= 0:
            return post, post.phi
        return self._spread.show(post, self.budget, self.busy and self.one_job)
