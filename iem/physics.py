"""IEM+phys: the incremental ensemble as a prior, Bayesian least squares on the physics.

The paper's learners see one instant at a time and know no physics; least squares knows the
physics but needs rich motion and time. This model keeps both, per estimate:

- **The ensemble** (:class:`iem.ensemble.IncrementalEnsemble`, held, not copied): the same
  bags, learners and ``learn_one``, so it never forgets. Its instantaneous estimate at every
  sample is the evidence the robot's motion need not provide.
- **The prior** is a summary of the ensemble's estimates since the last payload change
  (:class:`iem.prior_summary.PriorSummary`): their running mean ``mu_p``, with the covariance
  ``C_p`` = the mean, over those samples, of the covariance of the estimating bag's learner's
  error, plus the mean's own noise: the scatter of the estimates divided by their number
  (shrunk toward the sensor noise's share while there are few). A bag's error covariance
  (:class:`iem.prior_summary.BagCalibration`) is measured on what the model has: the tandem
  samples of the training payloads at the bag's points, noise-free inputs, learner output
  minus true phi (:meth:`PhysicsInformedEnsemble.fit` for the initial bags, every learnt
  point for new ones). ``prior_scale`` multiplies its standard deviations. An estimate whose
  input lies beyond its bag's training distribution (the ensemble's ``ood_score`` above its
  threshold, e.g. a pose met at other velocities) adds its bag's covariance times
  ``(score / threshold)²``: the prior is less sure there, and the physics governs.
  The calibration holds where the learners were trained; far from that an ensemble can be
  off by more than it says, so the data judge the prior: its covariance is scaled by the
  empirical-Bayes factor ``s² >= 1`` that makes the data most likely
  (:func:`prior_inflation`), 1 while they agree.
- **The data**: the regression equations ``r = Y phi + e``, ``e ~ N(0, R)`` of
  :class:`iem.regression.PayloadRegression`: the samples are averaged in blocks of
  ``update_every`` (one addition per sample), the block means go through the ``cutoff_hz``
  low-pass at the block rate (100 Hz by default), ddq is the difference of the filtered dq,
  ``R`` the torque noise plus the ddq noise through the arm's and the payload's inertia (at
  the block rate: the block mean has ``1 / update_every`` of the sample noise's variance);
  one equation per block after the filter has settled, kept in information form since the
  last change (:class:`iem.posterior.EquationWindow`): ``Lambda_d = sum Y^T (c R)^-1 Y``,
  ``eta_d = sum Y^T (c R)^-1 r``. Equations at 100 Hz of a 4 Hz low-pass are not
  independent: ``c`` (11.3 by default) is the sum of the filtered noise's autocorrelation at
  the equations' spacing (:func:`iem.regression.correlation_weight`), so the window's
  information about a constant payload is what the independent information in the signal
  is, no more.
- **The posterior** (:class:`iem.posterior.Posterior`): precision ``Lambda = C_p^-1 +
  Lambda_d``, mean ``phi = Lambda^-1 (C_p^-1 mu_p + eta_d)``, ``std = sqrt(diag(Lambda^-1))``;
  the mean is then projected onto physically consistent parameters in the metric ``Lambda``
  (:func:`iem.consistency.project`), so the least certain parameters move the most. It is
  refreshed every ``refresh_every`` equations (20 Hz by default: the output smoothing's time
  constant is 0.2 s), and between refreshes every estimate is the cached one.
- **Payload change**: each equation's innovation, whitened by its covariance
  ``R + Y Lambda^-1 Y^T``, feeds a CUSUM (:class:`iem.change.ChangeDetector`), beside the
  same innovation judged with the filtered equation's model error (:data:`MODEL_ERROR_GAIN`;
  the CUSUM adds the smaller of the two), from the window's :data:`DETECT_AFTER`-th
  equation on (before, a conflict is the prior's, which the inflation resolves, not a new
  payload's). On a change the data
  window, the prior summary and the detector restart, the equations of the next
  ``holdoff_s`` are skipped (the filter still holds the old payload's torque), and the
  estimate of that sample carries ``extra = {"change": True, "reset": True}`` so the caller
  restarts its smoothing (:class:`iem.online.OnlineIdentifier` does).
- **Before the physics, no smoothing**: until the regression's first equation after a
  start or a change (its filter settles for about 0.3 s), an estimate is the prior alone,
  the mean of the ensemble's estimates since then. Those estimates, and the first whose
  posterior holds an equation, carry ``extra = {"reset": True}``: the caller's smoothing
  restarts at each, so it adds no lag to what is already a mean, and starts from the physics
  instead of averaging it with the prior's estimates (at the demo's start the ensemble reads
  1.44 kg for 1.615 over that 0.3 s, and the smoothing had carried its first, lower,
  readings on for about 0.6 s more).

**What the data do not determine**: an estimate's ``determined`` leaves out the parameter
groups (``mass``, ``com``, ``inertia``) for which the window's equations alone say less than
the prior (a short or slow motion hardly sees the inertia): those come from the
prior, and the safety gate says so when it writes them.

``observe_one(x, flange)`` does everything but train the ensemble: the payload part of
``learn_one`` for a frozen model (the benchmark's runs on the ensemble's own training path).
``reset()`` forgets the payload (a new task), never the ensemble; ``resume()`` restarts only
the regression's filter (the signal stream was interrupted, the payload stays).
"""

from __future__ import annotations

import math

import numpy as np

from .base import BaseEstimator, Samples
from .consistency import EPS
from .ensemble.model import IncrementalEnsemble
from .ensemble_prior import EnsemblePrior
from .errors import InvalidInputError
from .innovation import MODEL_ERROR_GAIN, NIS_WINDOW, InnovationTest
from .least_squares import DEFAULT_PRIOR_STD
from .live_projection import SpreadProjection
from .posterior import EquationWindow, Posterior, combine, prior_inflation
from .regression import PayloadRegression, required_dynamics
from .sensor import DEFAULT_SENSOR
from .torque_noise import TorqueNoise
from .types import DEFAULT_BLOCK_FRAMES, GROUPS, NOMINAL_POINT_RATE_HZ, PayloadEstimate

__all__ = ["DETECT_AFTER", "LIVE_PROJECT_BUDGET", "MODEL_ERROR_GAIN", "NIS_WINDOW",
           "PRIOR_FLOOR", "SPREAD_WAIT", "PhysicsInformedEnsemble", "prior_inflation"]

PRIOR_FLOOR = (1e-4, 1e-5, 1e-5, 1e-5, 1e-6, 1e-6, 1e-6, 1e-6, 1e-6, 1e-6)
"""Smallest prior standard deviation per parameter (kg, kg·m, kg·m²): keeps ``C_p``
invertible where the learners happen to agree with every training payload."""
DETECT_AFTER = 10
"""Equations a window holds before the change detector tests new ones (0.1 s by default)."""
LIVE_PROJECT_BUDGET = 20
"""Newton steps of the consistency projection per block point on a live link
(``project_budget``, set by :meth:`PhysicsInformedEnsemble.go_live`): well under a
millisecond; the longest projection (200 steps) is then spread over about 10 points (0.1 s),
instead of stalling one point for several milliseconds."""
SPREAD_WAIT = 3
"""Samples a due posterior refresh may wait for one without other heavy work (spread)."""


class PhysicsInformedEnsemble(BaseEstimator):
    """The IEM's estimate as a prior, fused with Bayesian least squares on the regressor.

    Args:
        ensemble: keyword arguments of the held :class:`IncrementalEnsemble` (seed included).
        dynamics: the robot model (required): ``"module:function[@ARG]"`` of its factory
            (see :mod:`iem.regression`), stored in the model file.
        sigma_tau: torque noise of one measured frame, N·m.
        sigma_dq: velocity noise of one measured frame, rad/s.
        point_frames: frames averaged into each sample the model is given (a block point's,
            :mod:`iem.signals.blocks`; 1: samples are frames): a sample's noise is a frame's over
            its square root.
        cutoff_hz: low-pass cut-off of the regression, Hz (default 4: the motion of a task
            path is below 1 Hz, and the ddq noise grows with the cut-off cubed).
        rate_hz: sample rate, Hz (the block points' rate, :mod:`iem.signals.blocks`: 100 Hz).
        update_every: samples per regression block: one equation every this many samples
            (1: each block point is already the mean of a block of frames).
        prior_scale: factor on the calibrated prior standard deviations.
        drift, threshold: the change detector's CUSUM (see :mod:`iem.change`).
        holdoff_s: equations skipped after a change, s (-1: the filter's settling time).
        eps: smallest eigenvalue of the projected pseudo-inertia (:mod:`iem.consistency`).
        refresh_every: equations between refreshes of the posterior and its projection.
        torque_noise: what the arm model leaves in the equations
            (:class:`iem.torque_noise.TorqueNoise` as a dict, from the arm file of ``iem
            calibrate``), or None: the sensor noise alone (a simulated, perfect arm). Its
            ``std`` enters ``R`` (the weights, the NIS, the change detector), its ``weight``
            how much one equation counts, and its ``offset_std`` one torque offset per joint
            carried as a marginalised state (:class:`iem.posterior.EquationWindow`); its
            ``bias_std`` is a floor under the estimates' standard deviations.
        project_budget: Newton steps of the consistency projection per sample (0: a
            refreshed posterior is projected at once, in the sample that needs it). With a
            budget (:attr:`spread`, a live link: :meth:`go_live` sets
            :data:`LIVE_PROJECT_BUDGET`), a projection in progress takes at most this many
            steps per sample, and estimates meanwhile show the last finished one (phi and
            std of the same posterior, the same arithmetic as at once:
            :func:`iem.consistency.project_steps`), so they lag the at-once model's by a
            few samples. At the block points' rate (``update_every == 1``) every point still
            forms, tests and adds its equation and refreshes at once; fed frames
            (``update_every > 1``) each sample does at most one heavy job (form an
            equation, test and add the one formed the sample before, refresh at most
            :data:`SPREAD_WAIT` samples late, or the Newton steps), and a payload change is
            detected one sample later. The first estimate after a start or a detected change
            is made at once.
    """

    name = "IEM+phys"
    detects_changes = True
    """Its estimates report payload changes (``extra["change"]``)."""
    tracks_payload = True
    """The posterior of the samples since the last change carries from sample to sample."""
    background_learning = True
    """Its ensemble trains in a worker thread on a live link."""

    def __init__(self, ensemble: dict | None = None,
                 dynamics: str | None = None,
                 sigma_tau: float = DEFAULT_SENSOR.sigma_tau,
                 sigma_dq: float = DEFAULT_SENSOR.sigma_dq, cutoff_hz: float = 4.0,
                 rate_hz: float = NOMINAL_POINT_RATE_HZ,
                 update_every: int = 1, prior_scale: float = 1.0, drift: float = 21.0,
                 threshold: float = 300.0, holdoff_s: float = -1.0, eps: float = EPS,
                 refresh_every: int = 5, project_budget: int = 0,
                 torque_noise: dict | None = None,
                 point_frames: int = DEFAULT_BLOCK_FRAMES) -> None:
        self.ensemble = dict(ensemble or {})
        self.dynamics = required_dynamics(dynamics, "PhysicsInformedEnsemble (IEM+phys)")
        self.sigma_tau = float(sigma_tau)
        self.sigma_dq = float(sigma_dq)
        self.point_frames = int(point_frames)
        if self.point_frames < 1:
            raise InvalidInputError(f"point_frames must be >= 1 frame, got {point_frames}")
        self.cutoff_hz = float(cutoff_hz)
        self.rate_hz = float(rate_hz)
        self.update_every = int(update_every)
        self.prior_scale = float(prior_scale)
        self.drift = float(drift)
        self.threshold = float(threshold)
        self.holdoff_s = float(holdoff_s)
        self.eps = float(eps)
        self.refresh_every = int(refresh_every)
        self.project_budget = int(project_budget)
        self.torque_noise = None if torque_noise is None else dict(torque_noise)
        noise = None if torque_noise is None else TorqueNoise.from_dict(torque_noise)
        if noise is not None and (not math.isclose(noise.cutoff_hz, self.cutoff_hz)
                                  or not math.isclose(noise.rate_hz,
                                                      self.rate_hz / self.update_every)):
            raise InvalidInputError(
                f"the torque noise was measured at {noise.cutoff_hz:g} Hz cut-off and "
                f"{noise.rate_hz:g} Hz equations, this model forms them at {self.cutoff_hz:g} "
                f"Hz and {self.rate_hz / self.update_every:g} Hz; calibrate again for it")
        if not self.prior_scale > 0.0:
            raise InvalidInputError(f"prior_scale must be > 0, got {prior_scale}")
        if self.refresh_every < 1:
            raise InvalidInputError(f"refresh_every must be >= 1 equation, got {refresh_every}")
        if self.project_budget < 0:
            raise InvalidInputError(f"project_budget must be >= 0 Newton steps per sample "
                                    f"(0: at once), got {project_budget}")
        # the physics governs out of distribution through the per-input score's inflation;
        # the velocity score serves only the IEM's own hold and the gate: not scored here
        self._ens = IncrementalEnsemble(**{"velocity_threshold": None, **self.ensemble})
        self._ens.report_errors = True  # the prior's calibration: every learnt point
        root = math.sqrt(self.point_frames)  # a block point's mean has 1/n of the variance
        self._reg = PayloadRegression(dynamics, self.sigma_tau / root, self.sigma_dq / root,
                                      self.cutoff_hz,
                                      self.rate_hz, every=1, settle=-1, payload_inertia=True,
                                      decimate=self.update_every,
                                      model_error_std=None if noise is None else noise.std)
        self._weight = self._reg.correlation_weight
        # the arm model's error is correlated over its own time (noise.weight equations per
        # independent one, not the filter's): the window counts it so, the NIS one by one
        self._info_var = None if noise is None else self._reg.model_var * np.maximum(
            np.asarray(noise.weight) / self._weight - 1.0, 0.0)
        self._holdoff_n = (self._reg.settle * self.update_every if self.holdoff_s < 0
                           else round(self.holdoff_s * self.rate_hz))
        # with the arm's own noise in R, the misfit the detector's level follows is in R
        self._innovation = InnovationTest(self.drift, self.threshold, level=noise is None)
        self._spread = SpreadProjection()
        self._floor = np.square(PRIOR_FLOOR)
        self.ensemble_prior = EnsemblePrior(self._ens)
        """The ensemble as the prior: its bags' calibration and the summary since a change."""
        self._window = EquationWindow(None if noise is None else np.square(noise.offset_std))
        self._bias_var = None if noise is None or not any(noise.bias_std) else np.square(
            noise.bias_std)
        self._observed_x = np.full(21, math.nan)  # the last sample observed (a copy) and
        self._observed_bag = -2  # its bag (-2: none), so that predict_one at it routes once
        self.reset()

    def params(self) -> dict:
        """The hyper-parameters as given (``type(self)(**self.params())`` is a fresh clone)."""
        return {"ensemble": dict(self.ensemble), "dynamics": self.dynamics,
                "sigma_tau": self.sigma_tau, "sigma_dq": self.sigma_dq,
                "cutoff_hz": self.cutoff_hz, "rate_hz": self.rate_hz,
                "update_every": self.update_every, "prior_scale": self.prior_scale,
                "drift": self.drift, "threshold": self.threshold, "holdoff_s": self.holdoff_s,
                "eps": self.eps, "refresh_every": self.refresh_every,
                "project_budget": self.project_budget, "torque_noise": self.torque_noise,
                "point_frames": self.point_frames}

    def prepare(self) -> None:
        """Load now what the first equations and refreshes would load (the robot model,
        SciPy's LAPACK), so that a live link's first cycles do not stall on imports (they
        took 165 ms of CPU in the first cycle of ``iem bench e2e``)."""
        from . import small_linalg

        self._reg.model()
        small_linalg.cholesky(np.eye(2))

    def _go_live(self, on: bool) -> None:
        """A live link: a long consistency projection is spread over samples
        (:data:`LIVE_PROJECT_BUDGET` Newton steps each); offline, each is done at once. Then
        :meth:`prepare`, either way."""
        self.project_budget = LIVE_PROJECT_BUDGET if on else 0
        self.prepare()

    def set_background(self, on: bool) -> None:
        """The held ensemble's training in its worker thread (True) or inline (False)."""
        self._ens.set_background(on)

    @property
    def learning_cpu_s(self) -> float:
        """CPU time of the held ensemble's training, s."""
        return self._ens.learning_cpu_s

    def drain(self) -> None:
        """Wait until the held ensemble's submitted training has landed."""
        self._ens.drain()

    def stop(self) -> None:
        """Drain and stop the held ensemble's worker thread."""
        self._ens.stop()

    def clone(self):
        """A fresh, untrained estimator with the same hyper-parameters."""
        return type(self)(**self.params())

    def reset(self) -> None:
        """Forget the payload (a new task or a new payload); the ensemble is kept."""
        self._reg.reset()
        self._forget()
        self._holdoff = 0
        self.changes = 0
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

    def _forget(self) -> None:
        self._window.clear()
        self.ensemble_prior.summary.clear()
        self._innovation.reset()
        self._changed = False
        self._post: Posterior | None = None
        self._stale = False  # new equations or estimates since _post: refresh it
        self._stale_for = 0  # samples it has been stale
        self._busy = False  # this sample did heavy work (spread: the rest waits)
        self._queued = None  # spread: an equation formed, tested at the next sample
        self._since_refresh = 0
        self._initial: tuple[np.ndarray, np.ndarray] | None = None
        self._spread.clear()  # what a live link's estimates show
        self._data_shown = False  # an estimate with equations was given since the change
        self._undetermined: tuple[str, ...] = tuple(GROUPS)  # groups from the prior alone

    # -- views ---------------------------------------------------------------------------
    @property
    def n_bags(self) -> int:
        return self._ens.n_bags

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
        :data:`NIS_WINDOW` equations (about 1 while the data agree with the model; NaN
        before the first): the gate's check that the data fit the physics."""
        return self._innovation.nis

    @property
    def ensemble_model(self) -> IncrementalEnsemble:
        """The held ensemble (read it, do not train it behind this model's back)."""
        return self._ens

    def nbytes(self) -> int:
        return (self._ens.nbytes() + self.ensemble_prior.nbytes() + self._innovation.nbytes()
                + self._window.nbytes() + self._reg._acc.nbytes
                + Posterior.nbytes())

    def fit(self, Q, F, samples_at) -> PhysicsInformedEnsemble:
        """The ensemble's initial bags and learners, then each bag's error covariance on the
        tandem samples of (a stride of) the points routed to it."""
        self._ens.fit(Q, F, samples_at)
        prior = self.ensemble_prior
        prior.calib.grow(self._ens.n_bags)
        Q = np.asarray(Q, dtype=float)
        F = np.asarray(F, dtype=float)
        router = self._ens.router
        labels = router.route_many(Q, F)
        for i in np.flatnonzero(labels < 0):
            labels[i] = router.route(Q[i], F[i])[1]
        stride = max(1, int(self._ens.fit_stride))
        for bag in range(self._ens.n_bags):
            idx = np.flatnonzero(labels == bag)[::stride]
            for i in idx:
                X, Y = samples_at(int(i))
                prior.calibrate(bag, X, Y)
        self._post = None
        return self

    # -- estimator seam ------------------------------------------------------------------
    def learn_one(self, x, flange, samples: Samples) -> None:
        """The ensemble learns the point (Algorithms 1-2); then :meth:`observe_one`."""
        x = np.asarray(x, dtype=float)
        est = self._ens.learn_predict_raw(x, flange, samples)  # one routing for both
        self.ensemble_prior.calibrate_trained()  # each learnt point's errors, as they land
        self._observe(x, flange, est)

    def learn_predict_one(self, x, flange, samples: Samples, t: float = 0.0) -> PayloadEstimate:
        """:meth:`learn_one` then :meth:`predict_one` (the point is routed once)."""
        x = np.asarray(x, dtype=float)
        self.learn_one(x, flange, samples)
        if self._observed_bag > -2:  # its bag, as just routed
            return self._predict(self._observed_bag, t, x, flange)
        return self.predict_one(x, flange, t)

    def observe_one(self, x, flange) -> None:
        """Update the payload's posterior with one sample (the ensemble is not trained)."""
        self._observe(np.asarray(x, dtype=float), flange, None)

    def _observe(self, x: np.ndarray, flange, est) -> None:
        """:meth:`observe_one`, given the ensemble's estimate at ``x`` if already made."""
        self._changed = False
        self._busy = self._take_queued()  # spread: the last sample's equation, tested now
        steps, self._steps = self._steps, 1
        equation = self._reg(x, self._mean_for_noise, steps)
        if equation is not None:
            equation = (*equation, self._reg.curvature)  # for the test's model error
            self._busy = True  # forming it was this sample's work
            if self._holdoff <= 0:
                if self._one_job:
                    self._queued = equation
                else:
                    self._take(equation)
        if self._holdoff > 0:
            self._holdoff = max(0, self._holdoff - steps)
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
                self._stale = True  # no data yet: refresh the prior-only posterior every
                # few samples (with data, the equations refresh it)
        if self._stale:
            self._stale_for += 1

    def _take(self, equation) -> None:
        """Test an equation against the posterior, then add it to the window (or restart
        on a detected change)."""
        Y, r, R, curvature = equation
        if self._test(Y, r, R, curvature):
            self._forget()
            self._changed = True
            self.changes += 1
            self._holdoff = self._holdoff_n
        else:
            if self._info_var is not None:
                R = R + np.diag(self._info_var)
            self._window.add(Y, r, R, weight=self._weight)
            self._since_refresh += 1
            if self._window.m <= self.refresh_every or \
                    self._since_refresh >= self.refresh_every:
                self._stale = True  # refreshed at the next estimate (spread: the next
                # sample without other work)

    def _take_queued(self) -> bool:
        """Test and add the equation a spread sample queued, if any; True if there was one."""
        if self._queued is None:
            return False
        equation, self._queued = self._queued, None
        self._take(equation)
        return True

    def _flush(self) -> None:
        """Do the work a spread cycle left for the next samples (for a view of the state
        outside the cycle): the queued equation, then the refresh as soon as asked."""
        self._take_queued()
        self._busy = False

    def _mean_for_noise(self) -> np.ndarray | None:
        post = self._post if self.spread and self._post is not None else self._posterior()
        return None if post is None else post.mean

    def _test(self, Y, r, R, curvature=None) -> bool:
        """Test one equation against the current posterior (whose prior the data have
        already inflated if they contradict it, :class:`iem.innovation.InnovationTest`): its
        NIS always, the change detector from the window's :data:`DETECT_AFTER`-th equation
        on (before, a conflict is the prior's, not a new payload's)."""
        post = self._posterior()
        if post is None:
            return False
        offsets = self._window.offsets(post.mean)  # the equation is judged net of them
        if offsets is not None:
            r = r - offsets
        return self._innovation(Y, r, R, post.mean, post.cov,
                                self._window.m >= DETECT_AFTER, curvature)

    def _prior(self, x=None, flange=None):
        """``(mu_p, C_p)``: a payload to start from (:meth:`start_from`), else the summary
        since the last change, or the ensemble at ``x``."""
        if self._initial is not None:
            mean, cov = self._initial
        elif self.ensemble_prior.summary.n > 0:
            mean, cov = self.ensemble_prior.summarised()
        elif x is not None and self._ens.n_bags:
            at = self.ensemble_prior.at(x, flange)
            if at is None:
                return None
            mean, cov = at
        else:
            mean = np.zeros(10)
            cov = np.diag(np.square(DEFAULT_PRIOR_STD))
        cov = cov * self.prior_scale ** 2
        return mean, 0.5 * (cov + cov.T) + np.diag(self._floor)

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

    @property
    def busy(self) -> bool:
        """The last sample did its heavy job (spread): a caller with periodic work of its
        own (the safety gate's decision) may put it in the next sample instead."""
        return self._busy and self._one_job

    @property
    def spread(self) -> bool:
        """The heavy work is spread over samples (a live link): with a ``project_budget``."""
        return self.project_budget > 0

    @property
    def _one_job(self) -> bool:
        """Spread, one heavy job per sample: forming an equation, testing and adding it, a
        refresh, or Newton steps, each in a sample of its own (``update_every > 1``: samples
        at the frame rate). At the block points' rate (``update_every == 1``) every point
        forms, tests and adds its equation and refreshes when due, at once; only the
        projection's Newton steps are spread, ``project_budget`` per point."""
        return self.spread and self.update_every > 1

    def _posterior(self) -> Posterior | None:
        """The posterior of the state (cached: refreshed every ``refresh_every`` equations
        and every ``update_every`` samples of the prior summary before the first; when
        :attr:`spread`, in the next sample that has no other heavy work, at most
        :data:`SPREAD_WAIT` samples late)."""
        if self._post is None or (self._stale and not (
                self._busy and self._one_job and self._stale_for <= SPREAD_WAIT)):
            if (self.ensemble_prior.summary.n == 0 and self._ens.n_bags
                    and self._initial is None):
                return None  # nothing seen yet: predict_one uses the ensemble at its x
            try:
                prior = self._prior()
                self._post = combine(*prior, self._window, self.eps)
            except np.linalg.LinAlgError:
                return None
            self._undetermined = self._from_prior(prior[1])
            self._since_refresh = 0
            self._stale, self._stale_for = False, 0
            self._busy = True
        return self._post

    def _from_prior(self, c_p: np.ndarray) -> tuple[str, ...]:
        """The parameter groups the window's equations do not determine: where, for some
        parameter of the group, they say less than the prior (their standard deviation
        alone is wider than the prior's); the estimate there is the prior's."""
        if self._window.empty:
            return tuple(GROUPS)
        data = self._window.data_std()
        prior = np.sqrt(np.maximum(np.diag(c_p), 0.0))
        return tuple(g for g, idx in GROUPS.items() if np.any(data[list(idx)] > prior[list(idx)]))

    def _estimate(self, post: Posterior, t: float, bag: int = -1,
                  learning: bool = False) -> PayloadEstimate:
        extra = {"change": True, "reset": True} if self._changed else {}
        unverified = self._initial is not None and self._window.m < DETECT_AFTER
        shown, phi = self._projected(post)
        # the prior alone is already the mean of the ensemble's estimates since the change,
        # and the first estimate with the physics supersedes it: the caller's smoothing
        # restarts at each of them (it would add only lag to a mean)
        if not self._data_shown:
            extra["reset"] = True
            self._data_shown = bool(shown.equations)
        std = shown.std
        if self._bias_var is not None:  # what the arm model's error reads as payload
            std = np.sqrt(np.square(std) + self._bias_var)
        # the physics is the estimate: the learners' out-of-distribution inputs inflate the
        # prior instead of flagging it; the NIS is NaN until the first equation is tested
        return PayloadEstimate(t=t, phi=phi, std=std, bag=bag, learning=learning,
                               nis=self._innovation.nis, ood=False, unverified=unverified,
                               determined=tuple(g for g in GROUPS
                                                if g not in self._undetermined),
                               extra=extra)

    def _projected(self, post: Posterior) -> tuple[Posterior, np.ndarray]:
        """The posterior an estimate shows and its consistent phi: ``post`` projected at
        once, or, with a ``project_budget``, spread (:class:`iem.live_projection.
        SpreadProjection`: the last finished projection is shown meanwhile)."""
        if self.project_budget <= 0:
            return post, post.phi
        return self._spread.show(post, self.project_budget, self._busy and self._one_job)

    def predict_one(self, x, flange, t: float = 0.0) -> PayloadEstimate:
        x = np.asarray(x, dtype=float)
        if x.shape != (21,):
            raise InvalidInputError(f"x must be [q, dq, tau] with 21 values, got {x.shape}")
        bag = -1
        if self._ens.n_bags:
            if self._observed_bag > -2 and (self._observed_x == x).all():
                bag = self._observed_bag  # the sample just observed (the online loop's case)
            else:
                inside, nearest = self._ens.router.route(x[:7], flange)
                bag = inside if inside >= 0 else nearest
        return self._predict(bag, t, x, flange)

    def _predict(self, bag: int, t: float, x, flange) -> PayloadEstimate:
        """The estimate at ``x``, whose bag (-1: none) is known."""
        learning = bag >= 0 and bag == self._ens.open_bag
        post = self._posterior()
        if post is None:
            prior = self._prior(x, flange)
            if prior is None:
                return PayloadEstimate(t=t, phi=np.full(10, math.nan), std=None, bag=bag,
                                       nis=None, ood=None, determined=None)
            post = combine(*prior, self._window, self.eps)
        return self._estimate(post, t, bag, learning)

    def predict_many(self, X, F) -> np.ndarray:
        X = np.asarray(X, dtype=float)
        F = np.asarray(F, dtype=float)
        if self._posterior() is not None:
            return np.tile(self.predict_one(X[0], F[0]).phi, (X.shape[0], 1))
        return np.array([self.predict_one(x, f).phi for x, f in zip(X, F, strict=True)])

    def close(self) -> None:
        """Close the ensemble's open bag (end of a task)."""
        self._ens.close()

    # -- persistence ---------------------------------------------------------------------
    def to_state(self) -> dict:
        return {"params": self.params(), "ensemble": self._ens.to_state(),
                **self.ensemble_prior.calib.to_state(),
                "calib_gen": list(self.ensemble_prior.calib_gen),
                "regression": self._reg.to_state(),
                **self._window.to_state(), **self.ensemble_prior.summary.to_state(),
                "detector": self._innovation.detector.to_state(), "changed": self._changed,
                "post": None if self._post is None else self._post.to_state(),
                "data_shown": self._data_shown,
                "holdoff": self._holdoff, "changes": self.changes,
                # when the cached posterior is refreshed next, and what it does not determine
                "stale": self._stale, "since_refresh": self._since_refresh,
                "undetermined": list(self._undetermined),
                "initial": None if self._initial is None else [
                    self._initial[0].tolist(), self._initial[1].tolist()]}

    @classmethod
    def from_state(cls, state: dict):
        model = cls(**state["params"])
        model._ens = IncrementalEnsemble.from_state(state["ensemble"])
        model._ens.report_errors = True
        prior = model.ensemble_prior = EnsemblePrior(model._ens)
        prior.calib.set_state(state)
        prior.calib_gen = [int(g) for g in state.get("calib_gen", [])]
        if len(prior.calib) > model.n_bags:
            raise InvalidInputError(f"model state has {len(prior.calib)} bag covariances "
                                    f"for {model.n_bags} bags")
        model._reg.set_state(state["regression"])
        model._window.set_state(state)
        prior.summary.set_state(state)
        model._innovation.detector.set_state(state["detector"])
        model._changed = bool(state["changed"])
        if state["post"] is not None:
            model._post = Posterior.from_state(state["post"], model.eps, model._window.m)
        model._data_shown = bool(state.get("data_shown", model._window.m > 0))
        model._holdoff = int(state["holdoff"])
        model.changes = int(state["changes"])
        model._stale = bool(state["stale"])
        model._since_refresh = int(state["since_refresh"])
        model._undetermined = tuple(str(g) for g in state["undetermined"])
        initial = state.get("initial")  # files from before start_from have none
        if initial is not None:
            model._initial = (np.array(initial[0], dtype=float).reshape(10),
                              np.array(initial[1], dtype=float).reshape(10, 10))
        return model
