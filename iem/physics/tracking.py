"""How IEM+phys follows the payload: each sample's equation tested against the posterior and
added to the window of equations since the last change, a change detected, the prior chosen,
the posterior refreshed (the method: :mod:`iem.physics`).

:class:`PayloadTracking` is the payload half of
:class:`~iem.physics.PhysicsInformedEnsemble`, which inherits it and holds the state it works
on (the held ensemble and its prior, the regression, the window of equations, the innovation
test, the cached posterior, the :class:`~iem.physics.scheduler.RefreshScheduler`).
"""

from __future__ import annotations

import numpy as np

from ..errors import InvalidInputError
from ..types import GROUPS
from .advice import advice
from .candidate import DECIDE_S, Candidate, log_likelihood
from .posterior import DEFAULT_PRIOR_STD, Posterior, combine

__all__ = ["DETECT_AFTER", "PRIOR_FLOOR", "PayloadTracking"]

PRIOR_FLOOR = (1e-4, 1e-5, 1e-5, 1e-5, 1e-6, 1e-6, 1e-6, 1e-6, 1e-6, 1e-6)
"""Smallest prior standard deviation per parameter (kg, kg·m, kg·m²): keeps ``C_p``
invertible where the learners happen to agree with every training payload."""
RESTART_STD_FLOOR = 1e-4
"""The smallest standard deviation a restored payload keeps as a prior (kg, kg·m, kg·m²):
the prior after a restart is never so sharp that the live data cannot move it."""
DETECT_AFTER = 10
"""Equations a window holds before the change detector tests new ones (0.1 s by default)."""
ADVICE_EQUATIONS = 100
"""Equations between two makings of the advice on what motion would settle the payload
(1 s by default; :mod:`iem.physics.advice`)."""


class PayloadTracking:
    """The payload's posterior since the last change, sample by sample, for
    :class:`~iem.physics.PhysicsInformedEnsemble`: :meth:`reset`, :meth:`resume`,
    :meth:`gap`, :meth:`start_from`, what the data say (:attr:`data_std`, :attr:`nis`,
    :attr:`prior_inflation`, :meth:`posterior`) and each observed sample's equation."""

    starts_from_payload = True
    """:meth:`start_from` takes a known payload as the prior."""

    def reset(self) -> None:
        """Forget the payload (a new task or a new payload); the ensemble is kept."""
        self._reg.reset()
        self._forget()
        self._holdoff = 0
        self.changes = 0
        self.reverts = 0
        """Alarms the data did not bear out: the estimate went back to the posterior before
        them (:mod:`iem.physics.candidate`); counted in :attr:`changes` too."""
        self._steps = 1

    def resume(self) -> None:
        """The signal stream restarted (a silence, a restart from a checkpoint, a new
        recording), the payload did not: the regression's filter starts again (its settling
        samples give no equations), the window of equations and the prior summary stay."""
        self._reg.reset()

    def gap(self, steps: int) -> None:
        """The next sample comes ``steps`` nominal cycles after the last one (``steps - 1``
        were lost, :mod:`iem.signals.gaps`): the regression bridges them, so no equation straddles
        the gap as if it were one cycle."""
        self._steps = int(steps)

    def start_from(self, phi, std) -> None:
        """Start from a known payload (e.g. ``iem identify``'s): ``phi`` with standard
        deviations ``std`` is the prior (instead of the ensemble's summary) until the data
        show a payload change; its estimates say ``unverified`` until the window
        holds :data:`DETECT_AFTER` equations, so a gate can wait for the live data to judge
        it (a wrong file then inflates the prior, or is detected as a change)."""
        phi = np.asarray(phi, dtype=float).reshape(10)
        std = np.asarray(std, dtype=float).reshape(10)
        if not (np.all(np.isfinite(phi)) and np.all(np.isfinite(std)) and np.all(std > 0)):
            raise InvalidInputError(f"start_from needs a finite phi and std > 0 (10 values "
                                    f"each), got {phi}, {std}")
        self._forget()
        self._initial = (phi.copy(), np.diag(np.square(std)))

    def distrust(self) -> None:
        """A restart from a saved state: the restored posterior becomes the known payload
        :meth:`start_from` takes (its mean, its standard deviations floored at
        :data:`RESTART_STD_FLOOR`), so its estimates say ``unverified`` until the live data
        have tested it and a payload swapped while the plug-in was down is detected as a
        change rather than written. Nothing restored: nothing to distrust."""
        post = self._posterior()
        if post is None:
            return
        phi = np.array(post.phi, dtype=float)
        var = np.diag(self.reported_cov(post))  # as its estimates reported it
        std = np.maximum(np.nan_to_num(np.sqrt(var), nan=1.0, posinf=1.0), RESTART_STD_FLOOR)
        self.start_from(phi, std)

    def _forget(self) -> None:
        self._candidate: Candidate | None = None  # the posterior before an alarm
        self._reverted = False
        self._window.clear()
        self.ensemble_prior.summary.clear()
        self._innovation.reset()
        self._changed = False
        self._post: Posterior | None = None
        self._initial: tuple[np.ndarray, np.ndarray] | None = None
        self._schedule.clear()  # nothing due, queued or shown: the next estimate at once
        self._data_shown = False  # an estimate with equations was given since the change
        self._undetermined: tuple[str, ...] = tuple(GROUPS)  # groups from the prior alone
        self._advice: str | None = None  # what motion would determine them (advice)
        self._advice_m = 0  # the window's equations when it was made

    # -- views ---------------------------------------------------------------------------
    @property
    def _m(self) -> int:
        """Equations in the window since the last change."""
        return self._window.m

    @property
    def _info(self) -> np.ndarray:
        return self._window.info

    @property
    def prior_inflation(self) -> float:
        """The factor the data currently put on the prior covariance (1: they agree)."""
        self._flush()
        post = self._posterior()
        return 1.0 if post is None else post.inflation

    @property
    def data_std(self) -> np.ndarray:
        """Standard deviation per parameter from the window's equations alone, without the
        prior (inf along directions they do not see): what the motion since the last change
        told about the payload."""
        return self._window.data_std()

    @property
    def nis(self) -> float:
        """The mean normalised innovation squared per degree of freedom of the last
        :data:`~iem.physics.innovation.NIS_WINDOW` equations (about 1 while the data agree with the
        model; NaN before the first): the gate's check that the data fit the physics."""
        return self._innovation.nis

    # -- samples in -------------------------------------------------------------------------
    def _observe(self, x: np.ndarray, flange, est) -> None:
        """:meth:`observe_one`, given the ensemble's estimate at ``x`` if already made."""
        self._changed = self._reverted = False
        self._schedule.busy = self._take_queued()  # one job: the last sample's equation
        steps, self._steps = self._steps, 1
        equation = self._reg(x, self._mean_for_noise, steps)
        if equation is not None:
            # the test's model error, and the arm's considered parameters' sensitivity
            equation = (*equation, self._reg.curvature, self._reg.sensitivity)
            self._schedule.busy = True  # forming it was this sample's work
            if self._holdoff <= 0:
                if self._schedule.one_job:
                    self._schedule.queued = equation
                else:
                    self._take(equation)
            elif self._candidate is not None:  # the hold-off's equations: the old window's
                Y, r, R, _, A = equation
                self._add(self._candidate.window, Y, r, R, A)
        if self._holdoff > 0:
            self._holdoff = max(0, self._holdoff - steps)
        if self._candidate is not None:
            self._decide_candidate()
        self._observed_bag = -2
        if not self._ens.n_bags:
            return
        if est is None:
            est = self._ens.predict_raw(x, flange)
        self._observed_x[:] = x
        self._observed_bag = est.bag
        if self.ensemble_prior.add(est, x):
            n = self.ensemble_prior.summary.n
            if self._window.empty and (n % self.update_every == 1 or self.update_every == 1):
                self._schedule.stale = True  # no data yet: refresh the prior-only posterior every
                # few samples (with data, the equations refresh it)
        self._schedule.sample_done()

    def _take(self, equation) -> None:
        """Test an equation against the posterior, then add it to the window (or restart
        on a detected change, the posterior before it kept as a candidate)."""
        Y, r, R, curvature, A = equation
        if self._candidate is not None and self._compare(Y, r, R, A):
            return  # the alarm was false: the old window, this equation added, is back
        if self._test(Y, r, R, curvature):
            self._alarm()
        else:
            self._add(self._window, Y, r, R, A)
            self._schedule.equation_added(self._window.m)

    def _add(self, window, Y, r, R, A) -> None:
        """Add an equation to ``window`` with the arm's correlated error counted in (``A``:
        the arm's considered parameters' sensitivity, or None)."""
        if self._info_cov is not None:
            R = R + self._info_cov
        window.add(Y, r, R, weight=self._weight, A=A)

    def _alarm(self) -> None:
        """A detected payload change: the window, the prior and the detector restart; the
        posterior before it is kept as a candidate (:mod:`iem.physics.candidate`) until
        the data choose between them."""
        old = None
        post = self._post
        if post is not None and not self._window.empty:
            old = Candidate(self._window, post, self.ensemble_prior.summary, self._initial,
                            round(DECIDE_S * self.rate_hz), self._weight)
            self._window = self._window.fresh()
        self._forget()
        self._candidate = old
        self._changed = True
        self.changes += 1
        self._holdoff = self._holdoff_n

    def _compare(self, Y, r, R, A) -> bool:
        """Judge an equation after an alarm under the candidate and the new posterior, add
        it to the candidate's window; True if the candidate is chosen (and restored)."""
        cand = self._candidate
        post = self._posterior()
        verdict = None
        if post is not None:
            R_fast = self._fast_error(R)
            G = self._window.offset_cov()
            offsets = self._window.offsets(post.mean)
            nu = r - Y @ post.mean if offsets is None else r - offsets - Y @ post.mean
            S = (R_fast if G is None else R_fast + G) + Y @ post.cov @ Y.T
            verdict = cand.judge(cand.old_log_likelihood(Y, r, R_fast),
                                 log_likelihood(nu, S))
        self._add(cand.window, Y, r, R, A)
        if verdict == "revert":
            self._revert()
            return True
        if verdict == "drop":
            self._candidate = None
        return False

    def _revert(self) -> None:
        """Back to the candidate: its window (with the equations since the alarm), its
        prior summary and known payload; the detector starts afresh."""
        cand = self._candidate
        self._forget()
        self._window = cand.window
        self.ensemble_prior.summary = cand.summary
        self._initial = cand.initial
        self._holdoff = 0
        self._reverted = True
        self.reverts += 1
        self._schedule.equation_added(self._window.m)

    def _decide_candidate(self) -> None:
        """A sample after an alarm: at :data:`~iem.physics.candidate.DECIDE_S`, the
        candidate is restored if the evidence favours it, else dropped."""
        verdict = self._candidate.due()
        if verdict == "revert":
            self._revert()
        elif verdict == "drop":
            self._candidate = None

    def _take_queued(self) -> bool:
        """Test and add the equation a spread sample queued, if any; True if there was one."""
        equation = self._schedule.take_queued()
        if equation is None:
            return False
        self._take(equation)
        return True

    def _flush(self) -> None:
        """Do the work a spread cycle left for the next samples (for a view of the state
        outside the cycle): the queued equation, then the refresh as soon as asked."""
        self._take_queued()
        self._schedule.busy = False

    def _mean_for_noise(self) -> np.ndarray | None:
        post = self._post if self.spread and self._post is not None else self._posterior()
        return None if post is None else post.mean

    def _test(self, Y, r, R, curvature=None) -> bool:
        """Test one equation against the current posterior (whose prior the data have
        already inflated if they contradict it, :class:`iem.physics.innovation.InnovationTest`): its
        NIS always, the change detector from the window's :data:`DETECT_AFTER`-th equation
        on (before, a conflict is the prior's, not a new payload's).

        The equation is judged net of the torque offsets the window carries as states; the
        detector judges it against :meth:`_detect_error`: the error of the equation without
        the slow part those offsets stand for, plus how uncertain they still are."""
        post = self._posterior()
        if post is None:
            return False
        offsets = self._window.offsets(post.mean)  # the equation is judged net of them
        if offsets is not None:
            r = r - offsets
        detect = self._window.m >= DETECT_AFTER
        R_detect = None
        if detect and self._slow_var is not None:
            G = self._window.offset_cov()
            R_detect = None if G is None else self._fast_error(R) + G
        return self._innovation(Y, r, R, post.mean, post.cov, detect, curvature, R_detect)

    def _fast_error(self, R: np.ndarray) -> np.ndarray:
        """The equation error ``R`` without the slow part the window's offsets carry (the
        change detector's and the candidate's; ``R`` itself without a noise model).

        ``R`` holds the arm's whole measured error per joint, its slow drift included
        (:attr:`iem.physics.torque_noise.TorqueNoise.offset_std`); the window carries that
        drift as one offset per joint and the test takes their estimate out of the
        innovation, whose remaining uncertainty (:meth:`EquationWindow.offset_cov`) the
        caller adds. Counting the drift again in ``R`` would hide a payload change of the
        drift's size: a 0.275 kg swap (about 1 N·m on the shoulder) stood at chi² 15-27
        per equation against a slow part of 0.3 N·m on a realistic arm, under the
        detector's drift. The drift's variance comes off the model error only, never off
        the sensor's own noise."""
        if self._slow_var is None:
            return R
        out = R.copy()
        out[np.diag_indices(7)] -= np.minimum(self._slow_var, self._reg.model_var)
        return out

    def _prior(self, x=None, flange=None):
        """``(mu_p, C_p)``: a payload to start from (:meth:`start_from`), else the summary
        since the last change, or the ensemble at ``x``.

        The ensemble's learners learnt from the arm model's simulations, and their covariance
        is measured there: on the arm itself their error is at least what the arm model's
        leftover reads as payload, which no simulated sample shows. So a prior from the
        ensemble carries the arm's ``bias_std`` (:class:`~iem.physics.torque_noise.TorqueNoise`,
        measured by the calibration on bare traffic) on its diagonal. On franky-sim's FR3, whose
        leftover reads as 0.057 kg, the ensemble's own covariance gives the mass 0.007-0.014
        kg after a change, the data alone 0.025-0.06 kg, and the estimate errs by 0.02-0.05
        kg: the prior would be surer than it is right, and the mass would stay "the prior's
        guess" (:meth:`_from_prior`). An arm without a measured leftover (the model's own
        noise) keeps the ensemble's covariance as it is."""
        learnt = False
        if self._initial is not None:
            mean, cov = self._initial
        elif self.ensemble_prior.summary.n > 0:
            mean, cov = self.ensemble_prior.summarised()
            learnt = True
        elif x is not None and self._ens.n_bags:
            at = self.ensemble_prior.at(x, flange)
            if at is None:
                return None
            mean, cov = at
            learnt = True
        else:
            mean = np.zeros(10)
            cov = np.diag(np.square(DEFAULT_PRIOR_STD))
        cov = cov * self.prior_scale ** 2
        if learnt and self._bias_var is not None:
            cov = cov + np.diag(self._bias_var)  # see the docstring: the arm's own leftover
        return mean, 0.5 * (cov + cov.T) + self._floor

    def posterior(self, x=None, flange=None):
        """``(mean, cov)`` of the payload before the projection, or None.

        The posterior of the samples since the last change; before any, the ensemble's
        estimate at ``x`` with its bag's covariance (None if there is none to go on).
        """
        self._flush()
        post = self._posterior()
        if post is None and x is not None:
            prior = self._prior(np.asarray(x, dtype=float), flange)
            post = None if prior is None else combine(*prior, self._window, self.eps)
        return None if post is None else (post.mean.copy(), post.cov.copy())

    def _posterior(self) -> Posterior | None:
        """The posterior of the state (cached: refreshed every ``refresh_every`` equations
        and every ``update_every`` samples of the prior summary before the first; when
        :attr:`spread`, in the next sample that has no other heavy work, at most
        :data:`~iem.physics.scheduler.SPREAD_WAIT` samples late)."""
        if self._schedule.due(self._post):
            if (self.ensemble_prior.summary.n == 0 and self._ens.n_bags
                    and self._initial is None):
                return None  # nothing seen yet: predict_one uses the ensemble at its x
            try:
                prior = self._prior()
                self._post = combine(*prior, self._window, self.eps)
            except np.linalg.LinAlgError:
                return None
            self._undetermined = self._from_prior(prior[1])
            self._settle(prior[1])
            self._schedule.refreshed()
        return self._post

    def _settle(self, c_p: np.ndarray) -> None:
        """While the data do not determine the mass or the CoM, what motion would
        (:mod:`iem.physics.advice`), made again after each :data:`ADVICE_EQUATIONS` equations
        at most (the estimate's ``extra["settle"]``)."""
        q = self._observed_x[:7]
        if (not {"mass", "com"} & set(self._undetermined) or self._window.m < ADVICE_EQUATIONS
                or not np.isfinite(q).all()):
            self._advice = None  # determined, or too few equations to say what they lack
            return
        if self._advice is not None and self._window.m < self._advice_m + ADVICE_EQUATIONS:
            return
        f = self._reg.model()
        zero = np.zeros(7)
        var = np.array(self._reg.r_diag, dtype=float)
        if self._info_cov is not None:
            var = var + np.diag(self._info_cov)
        limits = getattr(f, "q_limits", None)
        self._advice = advice(lambda pose: f(pose, zero, zero)[1], q,
                              self._post.cov, self._window.data_std(),
                              np.sqrt(np.maximum(np.diag(c_p), 0.0)), var * self._weight,
                              self.rate_hz / self.update_every,
                              *(limits if limits is not None else (None, None)))
        self._advice_m = self._window.m

    def _from_prior(self, c_p: np.ndarray) -> tuple[str, ...]:
        """The parameter groups the window's equations do not determine: where, for some
        parameter of the group, they say less than the prior (their standard deviation
        alone is wider than the prior's); the estimate there is the prior's."""
        if self._window.empty:
            return tuple(GROUPS)
        data = self._window.data_std()
        prior = np.sqrt(np.maximum(np.diag(c_p), 0.0))
        return tuple(g for g, idx in GROUPS.items() if np.any(data[list(idx)] > prior[list(idx)]))
