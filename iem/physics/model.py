"""IEM+phys as an estimator: the incremental ensemble as a prior, Bayesian least squares on
the physics (the method: :mod:`iem.physics`; when its heavy work is done:
:mod:`iem.physics.scheduler`; what its model file holds: :mod:`iem.physics.state`).
"""

from __future__ import annotations

import math

import numpy as np

from ..base import BaseEstimator, Samples
from ..ensemble.learners import FAST_LEARNER
from ..ensemble.model import IncrementalEnsemble
from ..errors import InvalidInputError
from ..sensor import DEFAULT_SENSOR
from ..types import DEFAULT_BLOCK_FRAMES, GROUPS, NOMINAL_POINT_RATE_HZ, PayloadEstimate
from .consistency import EPS
from .ensemble_prior import EnsemblePrior
from .innovation import InnovationTest
from .posterior import EquationWindow, Posterior, combine
from .regression import PayloadRegression, required_dynamics
from .scheduler import LIVE_PROJECT_BUDGET, RefreshScheduler
from .state import physics_state, restore_physics
from .torque_noise import TorqueNoise
from .tracking import DETECT_AFTER, PRIOR_FLOOR, PayloadTracking

__all__ = ["PhysicsInformedEnsemble"]



class PhysicsInformedEnsemble(PayloadTracking, BaseEstimator):
    """The IEM's estimate as a prior, fused with Bayesian least squares on the regressor.

    Args:
        ensemble: keyword arguments of the held :class:`IncrementalEnsemble` (seed included;
            its ``learner`` is :data:`iem.ensemble.learners.FAST_LEARNER` unless given).
        dynamics: the robot model (required): ``"module:function[@ARG]"`` of its factory
            (see :mod:`iem.physics.regression`), stored in the model file.
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
        drift, threshold: the change detector's CUSUM (see :mod:`iem.physics.change`).
        holdoff_s: equations skipped after a change, s (-1: the filter's settling time).
        eps: smallest eigenvalue of the projected pseudo-inertia (:mod:`iem.physics.consistency`).
        refresh_every: equations between refreshes of the posterior and its projection.
        torque_noise: what the arm model leaves in the equations
            (:class:`iem.physics.torque_noise.TorqueNoise` as a dict, from the arm file of ``iem
            calibrate``), or None: the sensor noise alone (a simulated, perfect arm). Its
            ``std`` enters ``R`` (the weights, the NIS, the change detector), its ``weight``
            how much one equation counts, and its ``offset_std`` one torque offset per joint
            carried as a marginalised state (:class:`iem.physics.posterior.EquationWindow`); its
            ``bias_std`` is a floor under the estimates' standard deviations, and its
            ``gain_std`` a torque-sensor gain error considered per joint: what it would do to
            the estimate widens the standard deviations, in proportion to the payload.
        project_budget: Newton steps of the consistency projection per sample (0: a
            refreshed posterior is projected at once, in the sample that needs it). With a
            budget (:attr:`spread`, a live link: :meth:`go_live` sets
            :data:`~iem.physics.scheduler.LIVE_PROJECT_BUDGET`) the heavy work is spread over
            samples and estimates lag the at-once model's by a few samples
            (:mod:`iem.physics.scheduler`). The first estimate after a start or a detected
            change is made at once.
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
        self.cutoff_hz = float(cutoff_hz)
        self.rate_hz = float(rate_hz)
        self.update_every = int(update_every)
        self.prior_scale = float(prior_scale)
        self.drift = float(drift)
        self.threshold = float(threshold)
        self.holdoff_s = float(holdoff_s)
        self.eps = float(eps)
        self.refresh_every = int(refresh_every)
        self.torque_noise = None if torque_noise is None else dict(torque_noise)
        noise = self._checked(project_budget)
        self._schedule = RefreshScheduler(project_budget, self.update_every, self.refresh_every)
        # the physics governs out of distribution through the per-input score's inflation;
        # the velocity score serves only the IEM's own hold and the gate: not scored here
        self._ens = IncrementalEnsemble(**{"velocity_threshold": None,
                                           "learner": FAST_LEARNER, **self.ensemble})
        self._ens.report_errors = True  # the prior's calibration: every learnt point
        self._reg = self._regression(noise)
        self._weight = self._reg.correlation_weight
        # the arm model's error is correlated over its own time (noise.weight equations per
        # independent one, not the filter's): the window counts it so, the NIS one by one
        info_var = None if noise is None else self._reg.model_var * np.maximum(
            np.asarray(noise.weight) / self._weight - 1.0, 0.0)
        self._info_cov = None if info_var is None else np.diag(info_var)  # made once
        self._holdoff_n = (self._reg.settle * self.update_every if self.holdoff_s < 0
                           else round(self.holdoff_s * self.rate_hz))
        # with the arm's own noise in R, the misfit the detector's level follows is in R
        self._innovation = InnovationTest(self.drift, self.threshold, level=noise is None)
        self._floor = np.diag(np.square(PRIOR_FLOOR))  # added to every prior's covariance
        self.ensemble_prior = EnsemblePrior(self._ens)
        """The ensemble as the prior: its bags' calibration and the summary since a change."""
        self._window = EquationWindow(None if noise is None else np.square(noise.offset_std),
                                      None if noise is None else np.square(noise.gain_std))
        self._bias_var = None if noise is None or not any(noise.bias_std) else np.square(
            noise.bias_std)
        # the slow part of the arm's error, which the window carries as its offsets: the
        # change detector judges an equation without it (PayloadTracking._detect_error)
        self._slow_var = None if noise is None else np.square(noise.offset_std)
        self._observed_x = np.full(21, math.nan)  # the last sample observed (a copy) and
        self._observed_bag = -2  # its bag (-2: none), so that predict_one at it routes once
        self._report = None  # (posterior, (std, cov)) the last estimate reported
        self.reset()

    def _checked(self, project_budget: int) -> TorqueNoise | None:
        """The torque noise (or None), once the hyper-parameters are checked.

        Raises:
            InvalidInputError: one is out of its range, or the noise was measured at another
                cut-off or equation rate.
        """
        if self.point_frames < 1:
            raise InvalidInputError(f"point_frames must be >= 1 frame, got {self.point_frames}")
        torque_noise = self.torque_noise
        noise = None if torque_noise is None else TorqueNoise.from_dict(torque_noise)
        if noise is not None and (not math.isclose(noise.cutoff_hz, self.cutoff_hz)
                                  or not math.isclose(noise.rate_hz,
                                                      self.rate_hz / self.update_every)):
            raise InvalidInputError(
                f"the torque noise was measured at {noise.cutoff_hz:g} Hz cut-off and "
                f"{noise.rate_hz:g} Hz equations, this model forms them at {self.cutoff_hz:g} "
                f"Hz and {self.rate_hz / self.update_every:g} Hz; calibrate again for it")
        if not self.prior_scale > 0.0:
            raise InvalidInputError(f"prior_scale must be > 0, got {self.prior_scale}")
        if self.refresh_every < 1:
            raise InvalidInputError(f"refresh_every must be >= 1 equation, got "
                                    f"{self.refresh_every}")
        if int(project_budget) < 0:
            raise InvalidInputError(f"project_budget must be >= 0 Newton steps per sample "
                                    f"(0: at once), got {project_budget}")
        return noise

    def _regression(self, noise: TorqueNoise | None) -> PayloadRegression:
        """The regression that forms the equations: block points' noise (a block point's
        mean has ``1 / point_frames`` of a frame's variance), one equation per
        ``update_every`` samples, the arm's own noise in ``R``."""
        root = math.sqrt(self.point_frames)
        return PayloadRegression(self.dynamics, self.sigma_tau / root, self.sigma_dq / root,
                                 self.cutoff_hz, self.rate_hz, every=1, settle=-1,
                                 payload_inertia=True, decimate=self.update_every,
                                 model_error_std=None if noise is None else noise.std,
                                 considered=noise is not None)

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

    # -- views ---------------------------------------------------------------------------
    @property
    def n_bags(self) -> int:
        return self._ens.n_bags

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

    # -- the scheduler -------------------------------------------------------------------
    @property
    def busy(self) -> bool:
        """The last sample did its heavy job (one job per sample): a caller with periodic
        work of its own (the safety gate's decision) may put it in the next sample instead."""
        return self._schedule.busy and self._schedule.one_job

    @property
    def spread(self) -> bool:
        """The heavy work is spread over samples (a live link): with a ``project_budget``."""
        return self._schedule.spread

    @property
    def project_budget(self) -> int:
        """Newton steps of the projection per sample (0: at once; :meth:`go_live` sets it)."""
        return self._schedule.budget

    @project_budget.setter
    def project_budget(self, budget: int) -> None:
        self._schedule.budget = int(budget)

    # -- estimates -----------------------------------------------------------------------
    def _estimate(self, post: Posterior, t: float, bag: int = -1,
                  learning: bool = False) -> PayloadEstimate:
        extra = {"change": True, "reset": True} if self._changed else {}
        if self._reverted:  # back to the posterior before a false alarm
            extra.update(reset=True, reverted=True)
        if self._advice is not None:  # what motion would determine the mass or the CoM
            extra["settle"] = self._advice
        unverified = self._initial is not None and self._window.m < DETECT_AFTER
        shown, phi = self._schedule.show(post)
        extra["mean_mass"] = float(shown.mean[0])  # before the projection: may be < 0
        # the prior alone is already the mean of the ensemble's estimates since the change,
        # and the first estimate with the physics supersedes it: the caller's smoothing
        # restarts at each of them (it would add only lag to a mean)
        if not self._data_shown:
            extra["reset"] = True
            self._data_shown = bool(shown.equations)
        std, cov = self._reported(shown)
        # the physics is the estimate: the learners' out-of-distribution inputs inflate the
        # prior instead of flagging it; the NIS is NaN until the first equation is tested
        return PayloadEstimate(t=t, phi=phi, std=std, cov=cov, bag=bag, learning=learning,
                               nis=self._innovation.nis, ood=False, unverified=unverified,
                               determined=self._determined(unverified),
                               extra=extra, prior=shown.prior)

    def _reported(self, shown: Posterior) -> tuple[np.ndarray, np.ndarray]:
        """The standard deviations and covariance an estimate showing ``shown`` reports
        (:meth:`reported_cov`). Made once per shown posterior (the estimates between two
        refreshes share them; read-only)."""
        if self._report is not None and self._report[0] is shown:
            return self._report[1]
        cov = self.reported_cov(shown)
        std = np.sqrt(np.diag(cov))
        std.flags.writeable = cov.flags.writeable = False
        self._report = (shown, (std, cov))
        return std, cov

    def reported_cov(self, post: Posterior) -> np.ndarray:
        """The covariance an estimate of ``post`` reports: its own, plus what the arm
        model's calibration leaves uncertain along the window's poses (``post.arm_cov``),
        plus the sensors' gain error and, where it is larger than the arm's own part, the
        arm model's bias read by the calibration's folds (``bias_std``) on the diagonal."""
        cov = np.array(post.cov, dtype=float) + post.arm_cov
        extra = np.array(post.gain_var, dtype=float)  # the sensors' gain error on the load
        if self._bias_var is not None:  # what the folds read as payload, where larger
            extra += np.maximum(self._bias_var - np.diag(post.arm_cov), 0.0)
        cov.flat[::11] += extra  # the diagonal
        return cov

    def _determined(self, unverified: bool) -> tuple[str, ...]:
        """The groups the estimate does not take from a guess: those the window's equations
        determine, and, once the live data have tested it, all of a known payload's (a
        payload file or a restored state, :meth:`start_from`): a measurement, not the
        ensemble's guess."""
        if self._initial is not None and not unverified:
            return tuple(GROUPS)
        return tuple(g for g in GROUPS if g not in self._undetermined)

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
        return physics_state(self)

    @classmethod
    def from_state(cls, state: dict):
        return restore_physics(cls(**state["params"]), state)
