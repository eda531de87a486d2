"""The open bag's training, as jobs: what the learning worker runs and owns.

:class:`BagTrainer` holds the training state of the bag being formed (its learner as it
trains, the :class:`~iem.reservoir.Reservoir` of its kept samples). The ensemble never
touches it: it submits small jobs (:class:`StartBag`, :class:`Point`, :class:`Refit`) and gets
trained learners back, which it publishes. The same jobs run inline (a synchronous
:class:`~iem.worker.LearningWorker`) or in a child process (:mod:`iem.worker_process`), in
the order they were submitted, so what a learner computes does not depend on where it is
trained: each learner and reservoir draws from its own seeded generator.

A job is a picklable callable ``job(trainer)``; it publishes by
:meth:`BagTrainer.publish`, which keeps only the latest learner per bag until the worker
hands them over (a learner trained on the next point supersedes the last one).
A job for a bag the trainer does not hold (its state was lost with a dead learning process,
or the bag was closed since) does nothing.

A new bag's learner is a copy of the nearest bag's. The ensemble copies the learner it has
published (it estimates with that copy until the warm-up lands), but when the nearest bag
was closed by a refit that has not landed yet, the copy must be of the refit learner, as
inline training would have it: so the trainer keeps the final learners it made
(:data:`FINALS` of them, far more than the closes a worker can be behind on) and the
:class:`StartBag` job copies its source from there when it can.

numpy only at import: the coverage sampler (``sim.coverage``, Pinocchio) is imported by the
first refit that needs it (or :class:`Prepare`).
"""

from __future__ import annotations

import copy
import importlib
from dataclasses import dataclass, field

import numpy as np

from .learner import WeakLearner
from .reservoir import Reservoir

FINALS = 64
"""Final learners of the last closed bags a trainer keeps as sources of new bags' copies."""


def load_sampler(spec: str):
    """The coverage sampler of ``"module:function"`` (a factory, called once)."""
    module, _, attr = spec.partition(":")
    return getattr(importlib.import_module(module), attr)()


def covered(sampler, draws: int, X: np.ndarray, Y: np.ndarray, batch: int, seed) -> tuple:
    """``(X, Y)`` plus, with a ``sampler``, ``draws`` other states at each point's pose
    (``batch`` samples per point, in order), drawn from a generator seeded with ``seed``."""
    if sampler is None or draws <= 0:
        return X, Y
    rng = np.random.default_rng(seed)
    n = X.shape[0]
    # filled in place, not stacked from a list: a bag's samples are tens of MB, and a
    # list of per-point arrays beside its stacked copy doubled the peak (and the heap
    # it leaves behind)
    X_out = np.empty((n * (1 + draws), X.shape[1]))
    Y_out = np.empty((X_out.shape[0], Y.shape[1]))
    X_out[:n], Y_out[:n] = X, Y
    r = n
    for s in range(0, n, batch):
        q, phi = X[s, :7], Y[s:s + batch]
        for _ in range(draws):
            x = sampler(q, phi, rng)
            X_out[r:r + len(x)], Y_out[r:r + len(x)] = x, phi
            r += len(x)
    return X_out[:r], Y_out[:r]


class BagTrainer:
    """The training state of the open bag, owned by whoever runs the jobs."""

    def __init__(self) -> None:
        self.bag = -1
        self.gen = 0
        self.training: WeakLearner | None = None
        self.kept: Reservoir | None = None
        self.finals: dict[int, tuple[int, WeakLearner]] = {}
        """The final learners of the last :data:`FINALS` bags closed here, as published."""
        self.outbox: dict[int, tuple[int, WeakLearner, bool]] = {}
        """Learners to publish, the latest per bag: ``bag -> (slot generation, learner,
        whether it must go whole)``."""
        self._light: tuple[int, int] | None = None  # the open bag, last sent as weights
        self._samplers: dict[str, object] = {}

    def holds(self, bag: int, gen: int) -> bool:
        return self.training is not None and (self.bag, self.gen) == (bag, gen)

    def open(self, bag: int, gen: int, learner: WeakLearner, kept: Reservoir | None) -> None:
        self.bag, self.gen, self.training, self.kept = bag, gen, learner, kept

    def drop(self) -> None:
        self.bag, self.training, self.kept = -1, None, None

    def final(self, bag: int, gen: int, learner: WeakLearner) -> None:
        """Keep ``learner`` as the final one of ``bag`` (generation ``gen``)."""
        self.finals.pop(bag, None)
        self.finals[bag] = (gen, learner)
        while len(self.finals) > FINALS:
            del self.finals[next(iter(self.finals))]

    def source(self, bag: int, gen: int) -> WeakLearner | None:
        """The final learner this trainer made for ``bag`` (generation ``gen``), or None."""
        held = self.finals.get(bag)
        return held[1] if held is not None and held[0] == gen else None

    def publish(self, bag: int, gen: int, learner: WeakLearner, whole: bool = False) -> None:
        """Queue ``learner`` for publication; ``whole``: a new learner (not only new weights
        of the one published last for the bag)."""
        held = self.outbox.get(bag)
        whole = whole or (held is not None and held[0] == gen and held[2])
        self.outbox[bag] = (gen, learner, whole)

    def take(self, light: bool = False) -> list[tuple[int, int, object]]:
        """The learners to publish, emptied: ``[(bag, gen, learner or Weights)]``.

        ``light``: a learner that only took SGD steps since the last one published for its
        bag goes as its :class:`Weights` (two small arrays, not a learner with its generator:
        a tenth of the parent's time to unpickle, at up to 1,000 a second). Otherwise every
        learner goes whole, and the open bag's too if it last went as weights (so a drained
        parent holds exactly the learner trained here, generator state and all)."""
        out = []
        for bag, (gen, learner, whole) in self.outbox.items():
            if light and not whole:
                out.append((bag, gen, Weights(learner.a, learner.b)))
                self._light = (bag, gen)
            else:
                out.append((bag, gen, learner))
                if self._light == (bag, gen):
                    self._light = None
        self.outbox.clear()
        if not light and self._light is not None:
            if self.holds(*self._light):
                out.append((*self._light, self.training))
            self._light = None
        return out

    def sampler(self, spec: str | None):
        if spec is None:
            return None
        if spec not in self._samplers:
            self._samplers[spec] = load_sampler(spec)
        return self._samplers[spec]

    def nbytes(self) -> int:
        """Bytes of the open bag's training state (its learner and kept samples)."""
        return ((0 if self.training is None else self.training.nbytes())
                + (0 if self.kept is None else self.kept.nbytes()))


@dataclass(frozen=True, eq=False)
class Weights:
    """New weights ``a`` ``(10, 21)``, ``b`` ``(10,)`` of the learner published last for a
    bag (the open bag's, after SGD steps: its scaling and hyper-parameters are unchanged)."""

    a: np.ndarray
    b: np.ndarray

    def applied_to(self, learner: WeakLearner) -> WeakLearner:
        """A new learner: ``learner`` with these weights (``learner`` is not changed)."""
        new = copy.copy(learner)
        new.a, new.b = self.a, self.b
        return new


# -- the jobs ------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class StartBag:
    """Open bag ``bag`` (slot generation ``gen``) with ``learner`` (its copied learner, which
    the job trains in place) and train it ``iters`` steps on the first point's samples ``X``
    ``(K, 21)`` [rad, rad/s, N·m], ``Y`` ``(K, 10)`` [phi units]; keep up to ``capacity``
    points (0: none) in a reservoir seeded ``kept_seed``. ``source``: ``(bag, gen)`` the
    learner was copied from (None: a fresh learner); if the trainer made that bag's final
    learner, the copy is made again from it (with ``learner``'s centre and seed, and its
    generator reseeded with ``reseed`` if given)."""

    bag: int
    gen: int
    learner: WeakLearner
    X: np.ndarray
    Y: np.ndarray
    iters: int
    capacity: int
    kept_seed: list = field(default_factory=list)
    source: tuple[int, int] | None = None
    reseed: list | None = None
    urgent = True  # a new bag's warm-up: hand it over at once

    def __call__(self, trainer: BagTrainer) -> None:
        learner = self.learner
        final = None if self.source is None else trainer.source(*self.source)
        if final is not None and final is not learner:
            learner = final.copy_for(learner.center, seed=learner.seed)
            if self.reseed is not None:
                learner._rng = np.random.default_rng(self.reseed)
        kept = Reservoir(self.capacity, self.kept_seed) if self.capacity > 0 else None
        trainer.open(self.bag, self.gen, learner, kept)
        Point(self.bag, self.gen, self.X, self.Y, self.iters)(trainer)
        trainer.publish(self.bag, self.gen, learner, whole=True)


@dataclass(frozen=True, eq=False)
class Resume:
    """Hold an open bag's training state that was kept elsewhere (a loaded model, a copy,
    a switch of mode): its ``learner`` and reservoir ``kept`` (or None)."""

    bag: int
    gen: int
    learner: WeakLearner
    kept: Reservoir | None
    urgent = False

    def __call__(self, trainer: BagTrainer) -> None:
        trainer.open(self.bag, self.gen, self.learner, self.kept)


@dataclass(frozen=True, eq=False)
class Point:
    """Train the open bag's learner ``iters`` SGD steps on one point's samples ``X`` ``(K,
    21)``, ``Y`` ``(K, 10)``, keep them in its reservoir and publish the learner."""

    bag: int
    gen: int
    X: np.ndarray
    Y: np.ndarray
    iters: int
    urgent = False

    def __call__(self, trainer: BagTrainer) -> None:
        if not trainer.holds(self.bag, self.gen):
            return
        trainer.training.learn(self.X, self.Y, self.iters)
        if trainer.kept is not None:
            trainer.kept.add(self.X, self.Y)
        trainer.publish(self.bag, self.gen, trainer.training)


@dataclass(frozen=True, eq=False)
class Refit:
    """Close the open bag: train a learner on its kept samples (plus ``coverage_draws``
    states of the ``coverage`` sampler per kept point) by :meth:`WeakLearner.fit` with these
    arguments, publish it, and drop the bag's training state."""

    bag: int
    gen: int
    out: tuple
    lr: float
    input_noise: np.ndarray | None
    epochs: int
    fit_lr: float
    seed: list
    coverage: str | None
    coverage_draws: int
    urgent = True  # the bag's final learner

    def __call__(self, trainer: BagTrainer) -> None:
        if not trainer.holds(self.bag, self.gen):
            return
        kept, training = trainer.kept, trainer.training
        trainer.drop()
        if kept is None or len(kept) < 2:
            trainer.final(self.bag, self.gen, training)
            return
        sampler = trainer.sampler(self.coverage) if self.coverage_draws > 0 else None
        batch = kept.batch()
        X, Y = covered(sampler, self.coverage_draws, *kept.stacked(), batch, [*self.seed, 5])
        del kept
        learner = WeakLearner.fit(
            X, Y, *self.out, lr=self.lr, input_noise=self.input_noise, seed=self.seed,
            epochs=self.epochs, batch=batch, fit_lr=self.fit_lr)
        trainer.final(self.bag, self.gen, learner)
        trainer.publish(self.bag, self.gen, learner, whole=True)


@dataclass(frozen=True, eq=False)
class Prepare:
    """Import and build the ``coverage`` sampler now (a refit then does not wait for it)."""

    coverage: str | None
    urgent = False

    def __call__(self, trainer: BagTrainer) -> None:
        trainer.sampler(self.coverage)


@dataclass(frozen=True, eq=False)
class OpenState:
    """The training state of bag ``bag`` (generation ``gen``) if held: ``(learner,
    reservoir)``, else None (a query: the worker returns it to the caller)."""

    bag: int
    gen: int
    urgent = True

    def __call__(self, trainer: BagTrainer):
        if not trainer.holds(self.bag, self.gen):
            return None
        return trainer.training, trainer.kept
