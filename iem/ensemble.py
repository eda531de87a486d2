"""The proposed incremental ensemble model (IEM): the paper's Eq. 1-2 with Algorithms 1-2.

- Initial bags and learners (:meth:`IncrementalEnsemble.fit`): the excitation path's points
  are routed into bags (Algorithm 1); each bag's learner is trained on the tandem samples of
  (a stride of) the points that joined it, all training payloads at each point. (Training
  each learner instead on the points the finished bags would route to it, whose means moved
  while they formed, lowers the excitation-path mass MAE from about 0.014 to 0.0085 kg but
  raises the new-path one from about 0.0045 to 0.0065 kg over seeds 0-3: the new bags' copies
  pass more noise. We keep the paper's rule.)
- Online (:meth:`IncrementalEnsemble.learn_one`): a point inside a bag joins it. A point
  outside every bag starts a new bag, whose learner is a copy of the nearest bag's learner
  (Algorithm 2, line 4), trained at once on the point's tandem samples (``warmup_iters``
  SGD steps) and then on each further point that joins the bag while it forms (``iters``
  steps per point). The bag being formed is the *open* bag; it closes as soon as a point goes
  elsewhere (the path left it) or :meth:`close` is called. A closed bag's learner never
  changes again, so nothing learnt is overwritten.
- Closing a bag: a learner trained one point at a time follows the path and ends fitted to
  the bag's last stretch (re-running a learnt path through such bags gave a mass MAE of
  0.3-0.46 kg against 0.004 kg on the first pass). So the open bag keeps a uniform sample of
  its points' tandem samples (:class:`iem.reservoir.Reservoir`, ``reservoir`` points), and
  when it closes its learner is trained on that sample once more, by the offline training
  of the initial bags (``fit_epochs``), before it is frozen. The estimates made while the
  bag formed are unchanged; ``reservoir = 0`` turns this off (the paper's rule alone).
- Training beyond the path (:mod:`iem.augment`, both off by default, the paper's rule):
  ``reversal`` adds each training sample driven backwards, ``coverage`` samples at the same
  poses with other velocities and accelerations.
- Estimate (Eq. 1-2): the output is that of the learner of the bag the point falls in, or,
  outside every bag, of the nearest bag (``n_s = 1`` for that bag, 0 for the others).
- Learning off the cycle (``background=True``): the cycle only routes, appends the copied
  learner of a new bag (which estimates until its training lands) and submits the training
  (warm-up, the steps of each point that joins the open bag, the refit at close) to a
  :class:`iem.worker.LearningWorker` thread, which runs the jobs in order and swaps each
  trained learner in atomically (one assignment under a lock; a learner once published is
  never changed). A point that joins the open bag hands the job its samples lazily: the
  tandem simulators run in the worker too (a new bag's are made in the cycle, for its
  learner's centre; a lock keeps the two threads off the simulators' robot model at once).
  With ``report_errors``, each job also measures the published learner's errors on its
  point's samples and queues them (:meth:`trained_errors`, IEM+phys's calibration). So the
  estimate never waits for a learner's training, its tandem samples or their calibration.
  Where the worker cannot keep up, the calibration of the points it reaches late lands late
  (docs/method.md, "Learning off the estimate path"). A closed
  bag's learner is never trained again. While more than :data:`MAX_PENDING` jobs wait,
  points that join the open bag are not learnt from (counted in ``skipped_points``): a
  worker that falls behind holds bounded memory. ``background=False`` (the default) runs
  the same jobs at once in the caller's thread: seeded runs reproduce bit for bit.
  :meth:`drain` waits for pending work; saving (:meth:`to_state`) drains first, so a
  saved model has no pending work (it is finished, never dropped). A deep copy of a
  background ensemble (a checkpoint taken in the cycle) does not wait: it holds the
  published learners, with the open bag closed without its refit.
- Out of distribution (:mod:`iem.ood_hold`): an estimate of a closed bag whose input lies
  beyond its learner's training inputs (``ood_threshold``, ``velocity_threshold``) carries
  ``ood = True``; :meth:`predict_one` and :meth:`learn_predict_one` then give the
  last estimate that was not flagged, for at most ``ood_hold_s``. :meth:`predict_raw` and
  :meth:`learn_predict_raw` give the learners' own estimates (IEM+phys takes those, with
  their scores: its physics governs there).
- Bounded growth (``budget_bags``): once the ensemble holds that many bags, a point that fits
  no bag does not add a bag: another bag is retired and its slot starts the new bag. Which
  one is :class:`iem.budget.BagBudget`'s policy: the oldest of the bags formed last, on
  probation (``probation_bags``), unless the motion came back to them; what the model knew
  before stays. What is lost is the retired bag's learner; a later visit there routes to the
  nearest remaining bag (flagged out of distribution when far) or forms a bag again. Bag
  indices stay stable; a reused slot's :meth:`slot_generation` goes up by one.
"""

from __future__ import annotations

import copy
import math
import queue
import threading
import time

import numpy as np

from .augment import TrainingAugment
from .base import BaseEstimator, Samples
from .budget import BagBudget
from .errors import InvalidInputError
from .learner import N_IN, N_OUT, WeakLearner, output_range, saved_numbers
from .ood_hold import OOD_HOLD_S, OOD_THRESHOLD, VELOCITY_THRESHOLD, OodHold
from .reservoir import Reservoir
from .router import DEFAULT_DELTA, DEFAULT_RHO, BagRouter
from .sensor import DEFAULT_SENSOR
from .types import PayloadEstimate
from .worker import LearningWorker

SENSOR_NOISE = DEFAULT_SENSOR.sigmas
"""The sensor model's standard deviations of one frame, ``[q (rad), dq (rad/s), tau (N·m)]``
x 7 (:data:`iem.sensor.DEFAULT_SENSOR`): the noise the learners are trained with on their
inputs. A block point (:mod:`iem.signals.blocks`) carries a third of it, but the frame's noise
regularises the learners, which generalise better for it: with a block point's noise instead,
the new path's mass MAE rose from 0.0044 to 0.0057 kg (``iem bench paper --quick --seed 0``)
and from 0.067 to 0.096 kg on the realistic plant (``iem bench realistic --quick --seed
0``), the runs this choice was made on."""

MAX_PENDING = 256
"""Most training jobs a background ensemble lets wait: beyond, the steps of points that join
the open bag are skipped (counted in ``skipped_points``); new bags and refits always go."""

def _yield() -> None:
    """Let another thread (the estimate path) take the interpreter, if one waits."""
    time.sleep(0)


class IncrementalEnsemble(BaseEstimator):
    """The proposed IEM.

    Args:
        delta: joint-space bag radius, rad (paper: 30°).
        rho: flange-position bag radius, m (paper: 0.2 m).
        lr: learning rate of the online SGD steps (normalised, see :mod:`iem.learner`).
        iters: SGD steps on each point that joins the open bag.
        warmup_iters: SGD steps on the point that starts a new bag.
        input_noise: noise added to the training inputs (21 values; default: the sensor
            model, since the measurements the learner sees carry it), or None.
        fit_epochs, fit_lr, fit_stride: offline training of the initial bags: epochs, the
            SGD step in whitened coordinates, and every how many path points to take.
        reservoir: points of the open bag kept for its training at close (0: none).
        close_epochs: epochs of that training (None: ``fit_epochs``).
        seed: seed of everything random (the noise of each learner).
        background: train in a worker thread, off the estimate path (see the module
            docstring); False: at once, in the caller's thread (deterministic).
        budget_bags: largest number of bags (None: unbounded); beyond it another bag's slot
            is reused (:mod:`iem.budget`).
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
            (:meth:`iem.learner.WeakLearner.velocity_score`, a distance that knows how the
            training velocities go together) is out of distribution too; None: not scored.
        reversal: ``"module:function[@ARG]"`` of a factory of ``f(X (N, 21)) -> X (N, 21)``,
            the samples of the same motion driven backwards
            (``"sim.coverage:reversed_velocities"``, ``...@ARM_FILE`` on a calibrated arm:
            :mod:`sim.coverage`), or None: each bag's learner is then also trained (at fit
            and at close, after any coverage) on those, so a pose met again the other way
            reads as it did the first.
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
                 probation_bags: int | None = None) -> None:
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
        self.background = bool(background)
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
        self.skipped_points = 0
        """Points of the open bag not learnt from because the worker was too far behind."""
        self.report_errors = False
        """Queue each learnt point's errors for :meth:`trained_errors` (IEM+phys sets it)."""
        self._make_thread_parts()

    def _make_thread_parts(self) -> None:
        """The parts a copy or a pickle makes anew: locks, the worker, the error queue (what
        it held is not carried: a copy's own points report to it)."""
        self._lock = threading.Lock()
        self._resolve_lock = threading.Lock()
        self._errors: queue.SimpleQueue = queue.SimpleQueue()
        self._worker = LearningWorker(synchronous=not self.background)

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
                "probation_bags": self.probation_bags}

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

    # -- the worker ----------------------------------------------------------------------
    @property
    def pending(self) -> int:
        """Training jobs submitted and not finished (always 0 unless ``background``)."""
        return self._worker.pending

    @property
    def learning_cpu_s(self) -> float:
        """CPU time of the training jobs of the current worker, s (its thread's on a live
        link: what learning costs beside the cycle)."""
        return self._worker.cpu_s

    def drain(self) -> None:
        """Wait until every submitted training job has landed."""
        self._worker.drain()

    def stop(self) -> None:
        """Drain and stop the worker thread (a later learn starts it again)."""
        self._worker.close()

    def set_background(self, on: bool) -> None:
        """Train in the worker thread (True) or inline (False) from now on; what is pending
        lands first. :meth:`go_live` turns it on for a live link; a replay and the benchmarks
        keep it off (inline training makes a run reproducible to the bit)."""
        on = bool(on)
        if on == self.background:
            return
        self._worker.close()
        self.background = on
        self._worker = LearningWorker(synchronous=not on)

    def _publish(self, bag: int, gen: int, learner: WeakLearner) -> None:
        """Swap a trained learner in (unless its slot was reused since): one assignment."""
        with self._lock:
            if self._gen[bag] == gen:
                self._learners[bag] = learner if not self.background else learner.copy()

    def __deepcopy__(self, memo):
        """A copy. Of a background ensemble: its published state, taken without waiting for
        the worker (a checkpoint from the cycle must not wait): the learners as they are now,
        the open bag closed without its refit; the pending work stays with the original."""
        new = type(self).__new__(type(self))
        memo[id(self)] = new
        skip = ("_lock", "_resolve_lock", "_errors", "_worker")
        if self.background:
            skip += ("_learners", "_kept", "_training", "_open")
            with self._lock:
                published = list(self._learners)
        for key, value in self.__dict__.items():
            if key not in skip:
                setattr(new, key, copy.deepcopy(value, memo))
        if self.background:
            new._learners = [copy.deepcopy(lr, memo) for lr in published]
            new._open, new._kept, new._training = -1, None, None
        new._make_thread_parts()
        return new

    def __getstate__(self) -> dict:
        self.drain()
        return {k: v for k, v in self.__dict__.items()
                if k not in ("_lock", "_resolve_lock", "_errors", "_worker")}

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._make_thread_parts()

    # -- training ------------------------------------------------------------------------
    def _new_learner(self, X: np.ndarray, Y: np.ndarray, bag: int, nearest: int) -> WeakLearner:
        if self._out is None:
            self._out = output_range(Y)
        seed = [self.seed, bag]
        if nearest < 0:  # the very first bag of an untrained model: a fresh learner
            center, scale = X.mean(axis=0), X.std(axis=0)
            return WeakLearner(*self._out, center, scale, lr=self.lr,
                               input_noise=self.input_noise, seed=seed)
        return self._learners[nearest].copy_for(X.mean(axis=0), seed=seed)

    def fit(self, Q, F, samples_at) -> IncrementalEnsemble:
        """Initial bags and learners from a path (the paper uses the excitation path).

        Args:
            Q: joint positions of the path's points, ``(N, 7)`` rad.
            F: their flange positions, ``(N, 3)`` m.
            samples_at: ``samples_at(i) -> (X (K, 21), Y (K, 10))``, the tandem samples at
                point ``i``.
        """
        self.drain()
        Q = np.asarray(Q, dtype=float)
        F = np.asarray(F, dtype=float)
        if Q.ndim != 2 or Q.shape[1] != 7 or F.shape != (Q.shape[0], 3) or len(Q) == 0:
            raise InvalidInputError(f"fit needs Q (N, 7) and F (N, 3) with N >= 1, "
                                    f"got {Q.shape} and {F.shape}")
        first = len(self._router)
        # each point trains the learner of the bag Algorithm 1 put it in when it arrived
        labels = np.array([self._router.add(q, f)[0] for q, f in zip(Q, F, strict=True)])
        for bag in range(first, len(self._router)):
            idx = np.flatnonzero(labels == bag)[:: self.fit_stride]
            if idx.size == 0:
                idx = np.flatnonzero(labels == bag)[:1]
            X, Y = _stacked(samples_at, idx)
            if self._out is None:
                self._out = output_range(Y)
            batch = Y.shape[0] // len(idx)
            X, Y = self._augment(X, Y, batch, [self.seed, bag, 5])
            self._learners.append(WeakLearner.fit(
                X, Y, *self._out, lr=self.lr, input_noise=self.input_noise,
                seed=[self.seed, bag], epochs=self.fit_epochs, batch=batch,
                fit_lr=self.fit_lr))
            self._gen.append(0)
        self._open = -1
        return self

    def learn_one(self, x, flange, samples: Samples) -> None:
        """Algorithm 1 for the point, then Algorithm 2 if it starts or joins the open bag."""
        self._learn_one(x, flange, samples)

    def _learn_one(self, x, flange, samples: Samples) -> int | None:
        """:meth:`learn_one`; returns the bag the point is in now."""
        q = np.asarray(x, dtype=float)[:7]
        flange = np.asarray(flange, dtype=float)
        bag, nearest = self._router.route_join(q, flange)  # a point inside a bag joins it
        if bag < 0:
            self.close()  # the path left the open bag
            X, Y = self._resolve(samples)  # now: the new learner's centre needs them
            return self._start_bag(q, flange, nearest, X, Y)
        if bag == self._open:
            if self.background and self._worker.pending > MAX_PENDING:
                self.skipped_points += 1  # the worker is behind: memory stays bounded
                return bag
            # the samples too are learning: a lazy caller's are made in the job
            self._worker.submit(self._training_job(bag, samples, self.iters))
        else:
            self.close()  # the path left the open bag: it is closed for good
            if self._budget is not None:
                self._budget.revisited(bag)  # the motion came back: kept
        return bag

    def _start_bag(self, q, flange, nearest: int, X, Y) -> int:
        """A new open bag at the point: its learner is a copy of the nearest bag's (it
        estimates with that copy until the warm-up lands)."""
        if self._budget is not None and self._budget.full(len(self._router)):
            bag = self._budget.victim(self._router.counts, self._open)
            learner = self._new_learner(X, Y, bag, nearest)
            with self._lock:
                self._gen[bag] += 1
                self._router.replace(bag, q, flange)
                self._learners[bag] = learner
        else:
            bag = len(self._router)
            learner = self._new_learner(X, Y, bag, nearest)
            with self._lock:
                self._router.new_bag(q, flange)
                self._learners.append(learner)
                self._gen.append(0)
        if self._budget is not None:
            self._budget.admit(bag, len(self._router))
        gen = self._gen[bag]
        if gen:  # a reused slot: its own noise, not the retired bag's
            learner._rng = np.random.default_rng([self.seed, bag, 4, gen])
        training = learner.copy() if self.background else learner
        kept = (Reservoir(self.reservoir, [self.seed, bag, 2] + ([gen] if gen else []))
                if self.reservoir > 0 else None)
        self._open, self._kept, self._training = bag, kept, training
        self._worker.submit(self._training_job(bag, (X, Y), self.warmup_iters))
        return bag

    def _resolve(self, samples: Samples) -> tuple[np.ndarray, np.ndarray]:
        """:func:`iem.base.resolve`, one thread at a time: the cycle (a new bag) and the
        worker (a point joining the open bag) may both make samples, and the simulators'
        robot model is not for two threads at once."""
        if not callable(samples):
            return samples
        with self._resolve_lock:
            return samples()

    def _training_job(self, bag: int, samples: Samples, iters: int):
        """The job that makes one point's samples (if lazy), trains the open bag's learner
        ``iters`` steps on them, keeps them for the refit at close, publishes the learner,
        and, with :attr:`report_errors`, queues the published learner's errors on them
        (:meth:`trained_errors`). Bound now: the job may run after the bag is closed or its
        slot reused."""
        training, kept, gen = self._training, self._kept, self._gen[bag]

        def job():
            X, Y = self._resolve(samples)
            training.learn(X, Y, iters)
            if kept is not None:
                kept.add(X, Y)
            self._publish(bag, gen, training)
            if self.report_errors and self._gen[bag] == gen:  # not a retired bag's job
                Y = np.asarray(Y, dtype=float)
                self._errors.put((bag, gen, self._learners[bag].predict_many(X) - Y, Y))

        return job

    def trained_errors(self):
        """``(bag, slot generation, errors (K, 10), truth (K, 10))`` of each point learnt
        since the last call, in order: the bag's learner as published after the point, on
        the point's own samples (only with :attr:`report_errors`; IEM+phys calibrates its
        prior with them). Taken in the caller's thread; the worker only queues them."""
        errors, out = self._errors, []
        while not errors.empty():  # one consumer: what it saw is there (no exception per
            out.append(errors.get_nowait())  # cycle for an empty queue, the usual case)
        return out

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

    def close(self) -> None:
        """Close the open bag (the path left it, or a task ended): its learner is trained
        once more on the bag's kept points (in the worker if ``background``), then it is
        final."""
        bag, kept = self._open, self._kept
        self._open, self._kept, self._training = -1, None, None
        if bag < 0 or kept is None:
            return
        gen = self._gen[bag]
        epochs = self.fit_epochs if self.close_epochs is None else self.close_epochs
        seed = [self.seed, bag, 3] + ([gen] if gen else [])

        def refit():
            if len(kept) < 2:
                return
            X, Y = self._augment(*kept.stacked(), kept.batch(), [*seed, 5])
            learner = WeakLearner.fit(
                X, Y, *self._out, lr=self.lr, input_noise=self.input_noise, seed=seed,
                epochs=epochs, batch=kept.batch(), fit_lr=self.fit_lr,
                pause=_yield if self.background else None)
            self._publish(bag, gen, learner)

        self._worker.submit(refit)

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
        """The estimate at ``x`` (held while out of distribution, see the module docstring)."""
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
        return {"params": self.params(), "router": self._router.to_state(),
                "learners": [lr.to_state() for lr in self._learners], "open": self._open,
                "kept": None if self._kept is None else self._kept.to_state(),
                "out": None if self._out is None else [v.tolist() for v in self._out],
                "gen": list(self._gen),
                **(self._budget.to_state() if self._budget is not None else {"retired": 0})}

    @classmethod
    def from_state(cls, state: dict):
        model = cls(**state["params"])
        model._router = BagRouter.from_state(state["router"])
        model._learners = [WeakLearner.from_state(s) for s in state["learners"]]
        if len(model._learners) != len(model._router):
            raise InvalidInputError(f"model state has {len(model._router)} bags but "
                                    f"{len(model._learners)} learners")
        model._gen = [int(g) for g in state.get("gen", [0] * len(model._learners))]
        if len(model._gen) != len(model._learners):
            raise InvalidInputError(f"model state has {len(model._learners)} bags but "
                                    f"{len(model._gen)} slot generations")
        if model._budget is not None:
            model._budget.load_state(state, len(model._learners))
        model._open = int(state["open"])
        if not -1 <= model._open < len(model._learners):
            raise InvalidInputError(f"model state's open bag {model._open} is not one of its "
                                    f"{len(model._learners)} bags (or -1)")
        kept = state["kept"]
        model._kept = None if kept is None else Reservoir.from_state(kept)
        if model._open >= 0:  # the jobs train their own copy; the published one stays
            model._training = model._learners[model._open].copy()
        out = state["out"]  # the output scaling (lo, hi) new bags' learners start from
        if out is not None:
            lo, hi = out
            out = (saved_numbers(lo, (N_OUT,), "model state's out[0]"),
                   saved_numbers(hi, (N_OUT,), "model state's out[1]"))
        model._out = out
        return model


def _stacked(samples_at, idx) -> tuple[np.ndarray, np.ndarray]:
    """The samples of the points ``idx`` stacked, ``(len(idx) K, n_in)`` and
    ``(len(idx) K, n_out)``: filled one point at a time into arrays allocated once (a list of
    every point's samples beside the stacked copy doubled the peak of a bag's fit)."""
    X0, Y0 = samples_at(int(idx[0]))
    k = X0.shape[0]
    X = np.empty((len(idx) * k, X0.shape[1]))
    Y = np.empty((len(idx) * k, Y0.shape[1]))
    for j, i in enumerate(idx):
        Xi, Yi = (X0, Y0) if j == 0 else samples_at(int(i))
        if Xi.shape != X0.shape or Yi.shape != Y0.shape:
            raise InvalidInputError(f"samples_at gave {Xi.shape} and {Yi.shape} samples at "
                                    f"point {int(i)}, {X0.shape} and {Y0.shape} at the first; "
                                    f"every point must give as many")
        X[j * k:(j + 1) * k], Y[j * k:(j + 1) * k] = Xi, Yi
    return X, Y
