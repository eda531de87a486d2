"""The payload before an alarm, kept as a candidate until the data choose (IEM+phys).

A payload-change alarm restarts IEM+phys's posterior from the prior. An alarm the data do
not bear out (a motion the detector misread: a sharp stop, the end of a recording) would
then cost the estimate its whole window and leave a user reading the prior's guess while
the new window fills. So the posterior before the alarm is kept (:class:`Candidate`): its
window goes on taking every equation, and each equation after the alarm's hold-off is
judged under both, by its one-step-ahead predictive likelihood (the equation's innovation
``nu`` against ``S = R + Y P Y^T``: what each hypothesis, "the payload before the alarm" and
"a new payload since", predicted of it before seeing it). Their log-likelihood ratio, in
units of independent equations (divided by how many equations count as one), is the
evidence (:meth:`Candidate.judge`):

- above :data:`EVIDENCE`, the old payload explains the data better: the alarm was false and
  the estimate returns to the old posterior, with the equations since the alarm added;
- below ``-EVIDENCE``, the change stands and the candidate is dropped;
- at :data:`DECIDE_S` after the alarm, whichever the evidence favours, so that a false
  alarm costs at most that long.

A sequence of one-step-ahead predictive densities is the data's marginal likelihood under
each hypothesis (the chain rule), so the comparison is the Bayes factor of "no change" to
"a change at the alarm", priors included: the new posterior starts from the ensemble's
prior, which predicts widely, and wins only where the old payload predicts worse still.
"""

from __future__ import annotations

import copy
import math

import numpy as np

from .small_linalg import cholesky, cholesky_solve

__all__ = ["DECIDE_S", "EVIDENCE", "Candidate", "log_likelihood"]

EVIDENCE = math.log(100.0)
"""Log-likelihood ratio, in independent equations, that decides before :data:`DECIDE_S`
(odds of a hundred to one)."""
DECIDE_S = 0.9
"""Seconds after the alarm by which the candidate is chosen or dropped, whatever the
evidence: a false alarm's estimate is back within this."""


def log_likelihood(nu: np.ndarray, S: np.ndarray) -> float:
    """``log N(nu; 0, S)`` up to the constant ``-n/2 log 2 pi`` (the same for any model of
    the same equation); ``-inf`` if ``S`` is not positive definite."""
    try:
        L = cholesky(0.5 * (S + S.T))
    except np.linalg.LinAlgError:
        return -math.inf
    z = cholesky_solve(L, nu)
    return -0.5 * (float(nu @ z) + 2.0 * float(np.sum(np.log(np.diag(L)))))


class Candidate:
    """The posterior before an alarm and what the data since say of it.

    Args:
        window: the equation window before the alarm (taken over, not copied: the caller
            starts a new one).
        post: its posterior at the alarm (:class:`iem.physics.posterior.Posterior`), held
            fixed while the candidate lives.
        summary: the prior summary before the alarm (a copy is kept).
        initial: the known payload the model had started from, or None.
        decide_n: samples after the alarm by which it is decided (:data:`DECIDE_S` at the
            sample rate).
        weight: equations that count as one independent equation (the window's
            correlation weight): the evidence is counted per independent equation.
    """

    def __init__(self, window, post, summary, initial, decide_n: int, weight: float) -> None:
        self.window = window
        self.post = post
        self.summary = copy.deepcopy(summary)
        self.initial = initial
        self.decide_n = int(decide_n)
        self.weight = float(weight)
        self.evidence = 0.0
        """Log-likelihood ratio of the old payload over the new one, per independent
        equation, over the equations compared so far."""
        self.compared = 0
        """Equations compared."""
        self.samples = 0
        """Samples since the alarm."""

    def old_log_likelihood(self, Y, r, R_fast) -> float:
        """The log predictive density of the equation ``(Y, r)`` under the old posterior,
        net of the old window's offsets (``R_fast``: the equation's error without the slow
        part the offsets carry, or None: as the window has it)."""
        mean, cov = self.post.mean, self.post.cov
        offsets = self.window.offsets(mean)
        nu = r - Y @ mean if offsets is None else r - offsets - Y @ mean
        S = _with_offsets(R_fast, self.window) + Y @ cov @ Y.T
        return log_likelihood(nu, S)

    def judge(self, ll_old: float, ll_new: float) -> str | None:
        """Count one compared equation (its log-likelihoods under the old and the new
        posterior); ``"revert"``, ``"drop"`` or None (not yet decided)."""
        if math.isfinite(ll_old) and math.isfinite(ll_new):
            self.evidence += (ll_old - ll_new) / self.weight
            self.compared += 1
        if self.evidence > EVIDENCE:
            return "revert"
        if self.evidence < -EVIDENCE:
            return "drop"
        return None

    def due(self) -> str | None:
        """Count one sample; at :data:`DECIDE_S` the choice the evidence favours (a tie
        keeps the change), else None."""
        self.samples += 1
        if self.samples < self.decide_n:
            return None
        return "revert" if self.compared and self.evidence > 0.0 else "drop"


def _with_offsets(R_fast, window) -> np.ndarray:
    """``R_fast`` plus the window's offsets' remaining uncertainty (none without offsets)."""
    G = window.offset_cov()
    return R_fast if G is None else R_fast + G
