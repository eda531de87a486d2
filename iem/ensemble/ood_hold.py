"""The IEM's estimates out of distribution: how they are flagged and what is given instead.

Each learner standardises its inputs (``center``, ``scale``: the mean and standard deviation
of its training inputs). The *score* of an input is the largest ``|x - center| / scale``
over the 21 inputs; above ``threshold`` (default :data:`OOD_THRESHOLD`) an estimate of a
closed bag carries ``ood = True``. So does one whose joint velocities score above
``velocity_threshold`` (default :data:`VELOCITY_THRESHOLD`; ``extra["velocity_score"]``): a
Mahalanobis distance to the learner's training velocities
(:meth:`iem.ensemble.learner.WeakLearner.velocity_score`), which knows how they go together. A bag's
samples lie on one stretch of path, along one direction of motion (and its reverse); a later
visit at another velocity has each velocity within range but not the combination, and a
learner without the acceleration among its inputs reads such a visit kilograms off (over
1 kg for 98 % of the closed-bag estimates of ``iem bench longrun`` on seed 3). The open
bag's estimates are never flagged: its learner trains on the very point (its copied scale
is another bag's, so its score says little). Every estimate carries ``extra["ood_score"]``.

A flagged estimate is not the IEM's answer: :meth:`OodHold.held` gives instead the last
estimate that was not flagged (``extra["held"] = True``, still flagged), for at most
``hold_s`` of estimate time in a row; after that, or with none to hold, the learner's own.
A learner far outside its training inputs is wrong by kilograms (12-15 kg on average in the
long run's flagged estimates), while the payload rarely changes within the second it takes
the path to come back.
"""

from __future__ import annotations

import numpy as np

from ..errors import InvalidInputError
from ..types import PayloadEstimate

__all__ = ["OOD_HOLD_S", "OOD_THRESHOLD", "VELOCITY_THRESHOLD", "OodHold"]

OOD_THRESHOLD = 4.0
"""Default largest ``|x - center| / scale`` of an input (in its learner's standard
deviations) that is in distribution; tuned in ``iem bench longrun`` (docs/decisions.md)."""

VELOCITY_THRESHOLD = 4.0
"""Default largest :meth:`iem.ensemble.learner.WeakLearner.velocity_score` of an input that is in
distribution (about 1 for the learner's own training inputs)."""

OOD_HOLD_S = 2.0
"""Default longest run of flagged estimates, in s of estimate time, for which the IEM gives
the last estimate not flagged instead; set from ``iem bench longrun``'s seed 3 with the
velocity score (1 s let a 2.7 kg error through there; 2 s or more did not;
docs/decisions.md)."""


class OodHold:
    """The flags of one ensemble's estimates and the estimate it holds.

    Args:
        threshold: the largest input score in distribution (> 0).
        velocity_threshold: the largest velocity score in distribution (> 0), or None: not
            scored.
        hold_s: longest run of flagged estimates answered with the last one not flagged (s
            of estimate time, >= 0; 0: none held).
    """

    def __init__(self, threshold: float = OOD_THRESHOLD,
                 velocity_threshold: float | None = VELOCITY_THRESHOLD,
                 hold_s: float = OOD_HOLD_S) -> None:
        self.threshold = float(threshold)
        if not self.threshold > 0:
            raise InvalidInputError(f"ood_threshold must be > 0, got {threshold}")
        self.velocity_threshold = (None if velocity_threshold is None
                                   else float(velocity_threshold))
        if self.velocity_threshold is not None and not self.velocity_threshold > 0:
            raise InvalidInputError(f"velocity_threshold must be None or > 0, got "
                                    f"{velocity_threshold}")
        self.hold_s = float(hold_s)
        if not self.hold_s >= 0:
            raise InvalidInputError(f"ood_hold_s must be >= 0, got {hold_s}")
        self.reset()

    def reset(self) -> None:
        """Hold nothing until an estimate is in distribution again."""
        self._trusted: np.ndarray | None = None  # the last estimate not flagged
        self._flagged_since: float | None = None  # estimate time of the run's first flag

    def scores_velocity(self, learning: bool) -> bool:
        """Whether an estimate's velocity score is asked for (a closed bag's, with a
        ``velocity_threshold``): the learner computes it only then."""
        return not learning and self.velocity_threshold is not None

    def flags(self, score: float, vscore: float, learning: bool) -> dict:
        """The ``extra`` of an estimate whose input scores ``score`` (the largest ``|z|``) and
        ``vscore`` (:meth:`~iem.ensemble.learner.WeakLearner.velocity_score`, read only if
        :meth:`scores_velocity`); ``learning``: the open bag's (never flagged)."""
        extra = {"ood_score": score}
        ood = False
        if not learning:
            ood = score > self.threshold
            if self.scores_velocity(learning):
                extra["velocity_score"] = vscore
                ood = ood or vscore > self.velocity_threshold
        extra["ood"] = ood  # taken out into the estimate's typed ood by the ensemble
        return extra

    def held(self, est: PayloadEstimate) -> PayloadEstimate:
        """``est``, or, if it is flagged, the last estimate that was not (see the module
        docstring)."""
        if not est.ood:
            if est.bag >= 0:
                self._trusted = est.phi.copy()
                self._flagged_since = None
            return est
        if self._flagged_since is None:
            self._flagged_since = est.t
        if self._trusted is None or est.t - self._flagged_since >= self.hold_s:
            return est
        return PayloadEstimate(t=est.t, phi=self._trusted.copy(), std=est.std, bag=est.bag,
                               learning=est.learning, nis=est.nis, ood=est.ood,
                               determined=est.determined, extra={**est.extra, "held": True})
