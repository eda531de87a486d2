"""The proposed incremental ensemble model (IEM) as an estimator: its hyper-parameters, its
estimates (the paper's Eq. 1-2), its copies and its model file. How it learns (Algorithms
1-2) is :mod:`iem.ensemble.training`, where its training runs :mod:`iem.ensemble.scheduler`,
what its model file holds :mod:`iem.ensemble.state`; the rules: :mod:`iem.ensemble`.
"""

from __future__ import annotations

import copy
import math

import numpy as np

from ..base import BaseEstimator, Samples
from ..errors import InvalidInputError
from ..types import PayloadEstimate
from .augment import TrainingAugment
from .budget import BagBudget
from .learner import N_IN, SENSOR_NOISE, WeakLearner
from .learners import DEFAULT_LEARNER, learner_class
from .ood_hold import OOD_HOLD_S, OOD_THRESHOLD, VELOCITY_THRESHOLD, OodHold
from .reservoir import Reservoir
from .router import DEFAULT_DELTA, DEFAULT_RHO, BagRouter
from .scheduler import LearningScheduler
from .state import ensemble_state, restore_ensemble
from .training import BagTraining


class IncrementalEnsemble(BagTraining, BaseEstimator):
    """The proposed IEM.

    Args:
        delta: joint-space bag radius, rad (paper: 30°).
        rho: flange-position bag radius, m (paper: 0.2 m).
        lr: learning rate of the online SGD steps (normalised, see :mod:`iem.ensemble.learner`).
        iters: SGD steps on each point that joins the open bag.
        warmup_iters: SGD steps on the point that starts a new bag.
        input_noise: noise added to the training inputs (21 values; default: the sensor
            model, since the measurements the learner sees carry it), or None.
        fit_epochs, fit_lr, fit_stride: offline training of the initial bags: epochs, the
            SGD step in whitened coordinates, and every how many path points to take.
        reservoir: points of the open bag kept for its training at close (0: none).
        close_epochs: epochs of that training (None: ``fit_epochs``).
        seed: seed of everything random (the noise of each learner).
        background: train in a worker thread, off the estimate path
            (:mod:`iem.ensemble.scheduler`); False: at once, in the caller's thread
            (deterministic).
        budget_bags: largest number of bags (None: unbounded); beyond it another bag's slot
            is reused (:mod:`iem.ensemble.budget`).
        probation_bags: the budget's probation pool (None: 10 % of ``budget_bags``; 0: the
            least-used bag is retired, whatever its age); only with ``budget_bags``.
        ood_threshold: the out-of-distribution threshold of :meth:`ood_score`.
        coverage: ``"module:function"`` of a factory of ``f(q, phi (K, 10), rng) -> X (K,
            21)``, the training family's samples at pose ``q`` with another velocity and
            acceleration (``"sim.coverage:other_velocities"``), or None: each bag's learner
            is then also trained (at fit and at close) on ``coverage_draws`` such states
            per kept point, so it covers motions through its poses other than those that
            formed it.
        coverage_draws: other states per point.
        ood_hold_s: longest run of out-of-distribution estimates answered with the last
            estimate that was not (s of estimate time; 0: none held).
        velocity_threshold: a closed bag's estimate whose joint velocities score above this
            (:meth:`iem.ensemble.learner.WeakLearner.velocity_score`, a distance that knows how the
            training velocities go together) is out of distribution too; None: not scored.
        reversal: ``"module:function[@ARG]"`` of a factory of ``f(X (N, 21)) -> X (N, 21)``,
            the samples of the same motion driven backwards
            (``"sim.coverage:reversed_velocities"``, ``...@arm:CRC32`` on a calibrated arm:
            :mod:`sim.coverage`), or None: each bag's learner is then also trained (at fit
            and at close, after any coverage) on those, so a pose met again the other way
            reads as it did the first.
        learner: how the learners are trained, a name of
            :data:`iem.ensemble.learners.LEARNERS`: ``"sgd"`` (the paper's Algorithm 2) or
            ``"expected"`` (the same in expectation over its input noise, exact: microseconds
            a point and a refit). With ``"expected"``, ``reservoir`` and ``close_epochs``,
            and ``fit_epochs`` and ``fit_lr`` are not used (the open bag keeps every point,
            in its statistics; nothing iterates), and ``seed`` only seeds the coverage.
    """

    name = "IEM"
    background_learning = True

    def __init__(self, delta: float = DEFAULT_DELTA, rho: float = DEFAULT_RHO, lr: float = 0.5,
                 iters: int = 5, warmup_iters: int = 100, input_noise=SENSOR_NOISE,
                 fit_epochs: int = 10, fit_lr: float = 0.1, fit_stride: int = 10,
                 reservoir: int = 100, close_epochs: int | None = None,
                 seed: int = 0, background: bool = False, budget_bags: int | None = None,
                 ood_threshold: float = OOD_THRESHOLD, coverage: str | None = None,
                 coverage_draws: int = 1, ood_hold_s: float = OOD_HOLD_S,
                 reversal: str | None = None,
                 velocity_threshold: float | None = VELOCITY_THRESHOLD,
                 probation_bags: int | None = None, learner: str = DEFAULT_LEARNER) -> None:
        self._learner_cls = learner_class(learner)
        self.learner_kind = learner
        self.delta = float(delta)
        self.rho = float(rho)
        self.lr = float(lr)
        self.iters = int(iters)
        self.warmup_iters = int(warmup_iters)
        self.input_noise = None if input_noise is None else np.asarray(input_noise, float)
        self.fit_epochs = int(fit_epochs)
        self.fit_lr = float(fit_lr)
        self.fit_stride = int(fit_stride)
        self.reservoir = int(reservoir)
        self.close_epochs = None if close_epochs is None else int(close_epochs)
        self.seed = int(seed)
        self.budget_bags = None if budget_bags is None else int(budget_bags)
        self.probation_bags = None if probation_bags is None else int(probation_bags)
        if self.budget_bags is None and self.probation_bags is not None:
            raise InvalidInputError(f"probation_bags={probation_bags} needs a budget_bags")
        self._budget = (None if self.budget_bags is None
                        else BagBudget(self.budget_bags, self.probation_bags))
        self._ood = OodHold(ood_threshold, velocity_threshold, ood_hold_s)
        # built now: a bad reversal spec or arm file fails here
        self._augment = TrainingAugment(coverage, coverage_draws, reversal)
        self._router = BagRouter(self.delta, self.rho)
        self._learners: list[WeakLearner] = []
        self._gen: list[int] = []  # per slot: how many times it was reused
        self._open = -1
        self._kept: Reservoir | None = None
        self._training: WeakLearner | None = None  # the open bag's learner, the jobs' own
        self._out: tuple[np.ndarray, np.ndarray] | None = None
        self.report_errors = False
        """Queue each learnt point's errors for :meth:`trained_errors` (IEM+phys sets it)."""
        self._schedule = LearningScheduler(background)

    def params(self) -> dict:
        """The hyper-parameters as given (``type(self)(**self.params())`` is a fresh clone)."""
        return {"delta": self.delta, "rho": self.rho, "lr": self.lr, "iters": self.iters,
                "warmup_iters": self.warmup_iters,
                "input_noise": None if self.input_noise is None else self.input_noise.tolist(),
                "fit_epochs": self.fit_epochs, "fit_lr": self.fit_lr,
                "fit_stride": self.fit_stride, "reservoir": self.reservoir,
                "close_epochs": self.close_epochs, "seed": self.seed,
                "background": self.background, "budget_bags": self.budget_bags,
                "ood_threshold": self.ood_threshold, "coverage": self.coverage,
                "coverage_draws": self.coverage_draws, "ood_hold_s": self.ood_hold_s,
                "reversal": self.reversal, "velocity_threshold": self.velocity_threshold,
                "probation_bags": self.probation_bags, "learner": self.learner_kind}

    def clone(self):
        """A fresh, untrained estimator with the same hyper-parameters."""
        return type(self)(**self.params())

    # -- views ---------------------------------------------------------------------------
    @property
    def ood_threshold(self) -> float:
        return self._ood.threshold

    @property
    def velocity_threshold(self) -> float | None:
        return self._ood.velocity_threshold

    @property
    def ood_hold_s(self) -> float:
        return self._ood.hold_s

    @property
    def coverage(self) -> str | None:
        return self._augment.coverage

    @property
    def coverage_draws(self) -> int:
        return self._augment.draws

    @property
    def reversal(self) -> str | None:
        return self._augment.reversal

    @property
    def background(self) -> bool:
        """Training runs in the worker thread (:meth:`set_background`)."""
        return self._schedule.background

    @property
    def skipped_points(self) -> int:
        """Points of the open bag not learnt from because the worker was too far behind."""
        return self._schedule.skipped_points

    @property
    def n_bags(self) -> int:
        return len(self._router)

    @property
    def router(self) -> BagRouter:
        return self._router

    @property
    def open_bag(self) -> int:
        """Index of the bag being formed, or -1."""
        return self._open

    def learner(self, bag: int) -> WeakLearner:
        """The learner bag ``bag`` estimates with now (published learners never change)."""
        return self._learners[bag]

    @property
    def retired(self) -> int:
        """Bags retired to stay within the budget."""
        return 0 if self._budget is None else self._budget.retired

    @property
    def budget(self) -> BagBudget | None:
        """The budget's bookkeeping (which bags are on probation), or None: unbounded."""
        return self._budget

    def slot_generation(self, bag: int) -> int:
        """How many times slot ``bag`` was reused for a new bag (budget): anything kept per
        bag index (e.g. IEM+phys's error covariances) is stale when this changes."""
        return self._gen[bag]

    def nbytes(self) -> int:
        kept = 0 if self._kept is None else self._kept.nbytes()
        training = (self._training.nbytes() if self._training is not None
                    and self.background else 0)
        return (self._router.nbytes() + sum(lr.nbytes() for lr in self._learners) + kept
                + training)

    # -- the scheduler -------------------------------------------------------------------
    @property
    def pending(self) -> int:
        """Training jobs submitted and not finished (always 0 unless ``background``)."""
        return self._schedule.pending

    @property
    def learning_cpu_s(self) -> float:
        """CPU time of the training jobs of the current worker, s (its thread's on a live
        link: what learning costs beside the cycle)."""
        return self._schedule.cpu_s

    def drain(self) -> None:
        """Wait until every submitted training job has landed."""
        self._schedule.drain()

    def stop(self) -> None:
        """Drain and stop the worker thread (a later learn starts it again)."""
        self._schedule.stop()

    def set_background(self, on: bool) -> None:
        """Train in the worker thread (True) or inline (False) from now on; what is pending
        lands first. :meth:`go_live` turns it on for a live link; a replay and the benchmarks
        keep it off (inline training makes a run reproducible to the bit)."""
        self._schedule.set_background(on)

    def __deepcopy__(self, memo):
        """A copy. Of a background ensemble: its published state, taken without waiting for
        the worker (a checkpoint from the cycle must not wait): the learners as they are now,
        the open bag closed without its refit; the pending work stays with the original."""
        new = type(self).__new__(type(self))
        memo[id(self)] = new
        skip = ("_learners", "_kept", "_training", "_open") if self.background else ()
        if self.background:
            with self._schedule.lock:
                published = list(self._learners)
        for key, value in self.__dict__.items():
            if key not in skip:
                setattr(new, key, copy.deepcopy(value, memo))
        if self.background:
            new._learners = [copy.deepcopy(lr, memo) for lr in published]
            new._open, new._kept, new._training = -1, None, None
        return new

    def __getstate__(self) -> dict:
        self.drain()
        return self.__dict__

    def learn_predict_one(self, x, flange, samples: Samples, t: float = 0.0) -> PayloadEstimate:
        """:meth:`learn_one` then :meth:`predict_one` with one routing instead of two.

        The bag Algorithm 1 put the point in is the bag :meth:`predict_one` would route it
        to: a joined bag's mean only moved toward the point, and a new bag's mean is it.
        """
        return self._ood.held(self.learn_predict_raw(x, flange, samples, t))

    def learn_predict_raw(self, x, flange, samples: Samples, t: float = 0.0) -> PayloadEstimate:
        """:meth:`learn_predict_one` without the hold: the learner's own estimate."""
        bag = self._learn_one(x, flange, samples)
        if bag is None:
            return self.predict_raw(x, flange, t)
        return self._estimate(np.asarray(x, dtype=float), bag, t)

    # -- estimation ----------------------------------------------------------------------
    def _bag_for(self, q: np.ndarray, flange) -> int:
        bag, nearest = self._router.route(q, flange)
        return bag if bag >= 0 else nearest

    def ood_score(self, x, bag: int) -> float:
        """How far input ``x = [q, dq, tau]`` lies outside the training distribution of bag
        ``bag``'s learner: the largest ``|x - center| / scale`` over the 21 inputs (its
        training inputs' standard deviations). Above :attr:`ood_threshold` it is out of
        distribution."""
        learner = self._learners[bag]
        z = (np.asarray(x, dtype=float) - learner.center) * learner._inv_scale
        return float(np.abs(z).max())

    def _estimate(self, x: np.ndarray, bag: int, t: float) -> PayloadEstimate:
        learner = self._learners[bag]  # one read: the learner published now
        learning = bag == self._open  # the open bag trains on this very point: not flagged
        ood = self._ood
        phi, score, vscore = learner.estimate(x, ood.scores_velocity(learning))
        extra = ood.flags(score, vscore, learning)
        # the paper's learner has no standard deviation and tests no data: it says so
        return PayloadEstimate(t=t, phi=phi, std=None, bag=bag, learning=learning, nis=None,
                               ood=extra.pop("ood"), determined=None, extra=extra)

    def reset(self) -> None:
        """A new task, perhaps with another payload: nothing is held until an estimate is
        in distribution again (what was learnt stays). A restart of the signal stream alone
        keeps the hold (a silence is not a new payload; it lasts ``ood_hold_s`` at most)."""
        self._ood.reset()

    def predict_one(self, x, flange, t: float = 0.0) -> PayloadEstimate:
        """The estimate at ``x`` (held while out of distribution, see :mod:`iem.ensemble`)."""
        return self._ood.held(self.predict_raw(x, flange, t))

    def predict_raw(self, x, flange, t: float = 0.0) -> PayloadEstimate:
        """The estimate of the bag's learner at ``x``, flagged but never held."""
        x = np.asarray(x, dtype=float)
        if x.shape != (N_IN,):
            raise InvalidInputError(f"x must be [q, dq, tau] with {N_IN} values, got {x.shape}")
        bag = self._bag_for(x[:7], flange)
        if bag < 0:
            return PayloadEstimate(t=t, phi=np.full(10, math.nan), std=None, bag=-1,
                                   nis=None, ood=None, determined=None)
        return self._estimate(x, bag, t)

    def predict_many(self, X, F) -> np.ndarray:
        X = np.asarray(X, dtype=float)
        F = np.asarray(F, dtype=float)
        out = np.full((X.shape[0], 10), math.nan)
        if not self._learners:
            return out
        bags = self._router.route_many(X[:, :7], F)
        outside = np.flatnonzero(bags < 0)
        for i in outside:
            bags[i] = self._router.route(X[i, :7], F[i])[1]
        for bag in np.unique(bags):
            rows = bags == bag
            out[rows] = self._learners[bag].predict_many(X[rows])
        return out

    # -- persistence ---------------------------------------------------------------------
    def to_state(self) -> dict:
        """Plain data of the model; pending training is finished first (:meth:`drain`)."""
        self.drain()
        return ensemble_state(self)

    @classmethod
    def from_state(cls, state: dict):
        return restore_ensemble(cls(**state["params"]), state)
