"""How the IEM learns: Algorithms 1-2 on its bags, from the initial bags of a path to each
bag's refit when it closes (the rules: :mod:`iem.ensemble`).

:class:`BagTraining` is the learning half of :class:`~iem.ensemble.IncrementalEnsemble`,
which inherits it and holds the state it works on (the router, the bags' published learners
and slot generations, the open bag with its kept sample and its training copy, the output
scaling, the budget, the training augment) and the :class:`~iem.ensemble.scheduler.
LearningScheduler` its jobs go to. Here is what each job does; the scheduler decides where
and when it runs.
"""

from __future__ import annotations

import numpy as np

from ..base import Samples
from ..errors import InvalidInputError
from .expected import BagStatistics, refit
from .learner import WeakLearner, output_range
from .reservoir import Reservoir

__all__ = ["BagTraining"]


class BagTraining:
    """The initial bags (:meth:`fit`), a point that joins or starts a bag (:meth:`learn_one`)
    and the refit of a bag that closes (:meth:`close`), for
    :class:`~iem.ensemble.IncrementalEnsemble`."""

    def _new_learner(self, X: np.ndarray, Y: np.ndarray, bag: int, nearest: int) -> WeakLearner:
        if self._out is None:
            self._out = output_range(Y)
        seed = [self.seed, bag]
        if nearest < 0:  # the very first bag of an untrained model: a fresh learner
            center, scale = X.mean(axis=0), X.std(axis=0)
            return self._learner_cls(*self._out, center, scale, lr=self.lr,
                                     input_noise=self.input_noise, seed=seed)
        return self._learners[nearest].copy_for(X.mean(axis=0), seed=seed)

    def fit(self, Q, F, samples_at):
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
            self._learners.append(self._learner_cls.fit(
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
            X, Y = self._schedule.resolve(samples)  # now: the new learner's centre needs them
            return self._start_bag(q, flange, nearest, X, Y)
        if bag == self._open:
            if self._schedule.behind():  # memory stays bounded: the point is skipped
                return bag
            # the samples too are learning: a lazy caller's are made in the job
            self._schedule.submit(self._training_job(bag, samples, self.iters))
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
            with self._schedule.lock:
                self._gen[bag] += 1
                self._router.replace(bag, q, flange)
                self._learners[bag] = learner
        else:
            bag = len(self._router)
            learner = self._new_learner(X, Y, bag, nearest)
            with self._schedule.lock:
                self._router.new_bag(q, flange)
                self._learners.append(learner)
                self._gen.append(0)
        if self._budget is not None:
            self._budget.admit(bag, len(self._router))
        gen = self._gen[bag]
        if gen:  # a reused slot: its own noise, not the retired bag's
            learner._rng = np.random.default_rng([self.seed, bag, 4, gen])
        training = learner.copy() if self.background else learner
        if learner.keeps_statistics:  # every point, with its training beyond the path
            kept = BagStatistics(learner)
        else:
            kept = (Reservoir(self.reservoir, [self.seed, bag, 2] + ([gen] if gen else []))
                    if self.reservoir > 0 else None)
        self._open, self._kept, self._training = bag, kept, training
        self._schedule.submit(self._training_job(bag, (X, Y), self.warmup_iters))
        return bag

    def _training_job(self, bag: int, samples: Samples, iters: int):
        """The job that makes one point's samples (if lazy), trains the open bag's learner
        ``iters`` steps on them, keeps them for the refit at close, publishes the learner,
        and, with :attr:`report_errors`, queues the published learner's errors on them
        (:meth:`trained_errors`). Bound now: the job may run after the bag is closed or its
        slot reused."""
        training, kept, gen = self._training, self._kept, self._gen[bag]

        def job():
            X, Y = self._schedule.resolve(samples)
            if isinstance(kept, BagStatistics):  # the point's steps add it to them
                seed = [self.seed, bag, 5] + ([gen] if gen else []) + [len(kept)]
                training.learn(X, Y, iters, keep=kept, loss=False)
                beyond = self._augment.beyond(X, Y, X.shape[0], seed)
                if beyond is not None:
                    kept.add(*beyond)
            else:
                training.learn(X, Y, iters)
                if kept is not None:
                    kept.add(X, Y)
            self._publish(bag, gen, training)
            if self.report_errors and self._gen[bag] == gen:  # not a retired bag's job
                Y = np.asarray(Y, dtype=float)
                self._schedule.report((bag, gen, self._learners[bag].predict_many(X) - Y, Y))

        return job

    def trained_errors(self):
        """``(bag, slot generation, errors (K, 10), truth (K, 10))`` of each point learnt
        since the last call, in order: the bag's learner as published after the point, on
        the point's own samples (only with :attr:`report_errors`; IEM+phys calibrates its
        prior with them). Taken in the caller's thread; the worker only queues them."""
        return self._schedule.trained_errors()

    def close(self) -> None:
        """Close the open bag (the path left it, or a task ended): its learner is trained
        once more on the bag's kept points (in the worker if ``background``), then it is
        final: by SGD on its reservoir, or, for the ``expected`` learner, by the solve on
        its statistics (:func:`iem.ensemble.expected.refit`)."""
        bag, kept = self._open, self._kept
        self._open, self._kept, self._training = -1, None, None
        if bag < 0 or kept is None:
            return
        gen = self._gen[bag]
        epochs = self.fit_epochs if self.close_epochs is None else self.close_epochs
        seed = [self.seed, bag, 3] + ([gen] if gen else [])

        def refit_job():
            if len(kept) < 2:
                return
            if isinstance(kept, BagStatistics):  # the solve of the expected loss
                self._publish(bag, gen, refit(kept, self._learners[bag], seed))
                return
            X, Y = self._augment(*kept.stacked(), kept.batch(), [*seed, 5])
            learner = self._learner_cls.fit(
                X, Y, *self._out, lr=self.lr, input_noise=self.input_noise, seed=seed,
                epochs=epochs, batch=kept.batch(), fit_lr=self.fit_lr,
                pause=self._schedule.pause)
            self._publish(bag, gen, learner)

        self._schedule.submit(refit_job)

    def _publish(self, bag: int, gen: int, learner: WeakLearner) -> None:
        """Swap a trained learner in (unless its slot was reused since): one assignment."""
        with self._schedule.lock:
            if self._gen[bag] == gen:
                self._learners[bag] = learner if not self.background else learner.copy()


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
