"""The BEM baseline: the paper's 2023 batch ensemble (Taie et al., 2023).

The paper compares its IEM with "BEM (the 2023 batch ensemble)": a bagging ensemble of two
kinds of weak learner, single-layer networks (:class:`iem.ensemble.learner.WeakLearner`) and basic
decision trees (:class:`iem.baselines.tree.RegressionTree`), trained once by batch learning on
``(q, dq, tau) -> phi`` along the excitation path with the training payloads, and never
updated afterwards (the paper's Tables 2 and 4: as good as the IEM on the excitation path,
lost on a new task path).

- Training (:meth:`BatchEnsemble.fit`): every ``fit_stride``-th path point's tandem samples
  are pooled into one data set (no bags). Each member is trained on its own bootstrap
  resample of it (same size, drawn with replacement, seeded per member); the networks by
  :meth:`WeakLearner.fit` (which adds the sensor noise to the inputs itself), the trees on
  the resample with the sensor noise added once, so they too see inputs that look like
  measurements.
- Estimate (bagging): the mean of all members' outputs.
- Online: nothing. :meth:`BatchEnsemble.learn_one` is a no-op and never asks for samples.
  BEM has no bags (``n_bags == 0``); its memory is bounded by its fixed number of members.
"""

from __future__ import annotations

import math

import numpy as np

from ..base import BaseEstimator, Samples
from ..ensemble.learner import N_IN, N_OUT, SENSOR_NOISE, WeakLearner, output_range
from ..errors import InvalidInputError
from ..types import PayloadEstimate
from .tree import RegressionTree


class BatchEnsemble(BaseEstimator):
    """The BEM: bagged single-layer networks and regression trees, trained once.

    Members are numbered networks first (``0 .. n_networks-1``), then trees; member ``i``
    draws its resample from seed ``[seed, i, 1]`` (see :meth:`resample`), a network's SGD
    noise comes from ``[seed, i]``, a tree's input noise from ``[seed, i, 2]`` and its
    feature draws (``max_features``) from ``[seed, i]``.

    Args:
        n_networks: number of single-layer network members.
        n_trees: number of tree members.
        max_depth, min_samples_leaf, max_features: the trees' hyper-parameters
            (see :class:`iem.baselines.tree.RegressionTree`).
        fit_epochs, fit_lr: the networks' offline SGD (see :meth:`WeakLearner.fit`).
        fit_stride: every how many excitation-path points to take.
        input_noise: noise added to the training inputs (21 values; default: the sensor
            model), or None.
        seed: seed of everything random.
    """

    name = "BEM"

    def __init__(self, n_networks: int = 5, n_trees: int = 5, max_depth: int = 6,
                 min_samples_leaf: int = 20, max_features: int | None = None,
                 fit_epochs: int = 10, fit_lr: float = 0.1, fit_stride: int = 10,
                 input_noise=SENSOR_NOISE, seed: int = 0) -> None:
        if int(n_networks) < 0 or int(n_trees) < 0 or int(n_networks) + int(n_trees) == 0:
            raise InvalidInputError(f"BEM needs n_networks, n_trees >= 0 and at least one "
                                    f"member, got {n_networks} and {n_trees}")
        if int(fit_stride) < 1:
            raise InvalidInputError(f"fit_stride must be >= 1, got {fit_stride}")
        self.n_networks = int(n_networks)
        self.n_trees = int(n_trees)
        self.max_depth = int(max_depth)
        self.min_samples_leaf = int(min_samples_leaf)
        self.max_features = None if max_features is None else int(max_features)
        self.fit_epochs = int(fit_epochs)
        self.fit_lr = float(fit_lr)
        self.fit_stride = int(fit_stride)
        self.input_noise = None if input_noise is None else np.asarray(input_noise, float)
        self.seed = int(seed)
        self._learners: list[WeakLearner] = []
        self._trees: list[RegressionTree] = []

    def params(self) -> dict:
        """The hyper-parameters as given (``type(self)(**self.params())`` is a fresh clone)."""
        return {"n_networks": self.n_networks, "n_trees": self.n_trees,
                "max_depth": self.max_depth, "min_samples_leaf": self.min_samples_leaf,
                "max_features": self.max_features, "fit_epochs": self.fit_epochs,
                "fit_lr": self.fit_lr, "fit_stride": self.fit_stride,
                "input_noise": None if self.input_noise is None else self.input_noise.tolist(),
                "seed": self.seed}

    def clone(self):
        """A fresh, untrained estimator with the same hyper-parameters."""
        return type(self)(**self.params())

    # -- views ---------------------------------------------------------------------------
    @property
    def fitted(self) -> bool:
        return bool(self._learners or self._trees)

    @property
    def learners(self) -> tuple[WeakLearner, ...]:
        """The network members (empty before :meth:`fit`)."""
        return tuple(self._learners)

    @property
    def trees(self) -> tuple[RegressionTree, ...]:
        """The tree members (empty before :meth:`fit`)."""
        return tuple(self._trees)

    @property
    def n_bags(self) -> int:
        """Always 0: BEM has no bags (one global data set, a fixed number of members)."""
        return 0

    def nbytes(self) -> int:
        return (sum(lr.nbytes() for lr in self._learners)
                + sum(tr.nbytes() for tr in self._trees))

    # -- training ------------------------------------------------------------------------
    def resample(self, member: int, n: int) -> np.ndarray:
        """Row indices of member ``member``'s bootstrap resample of ``n`` pooled rows."""
        return np.random.default_rng([self.seed, member, 1]).integers(0, n, size=n)

    def fit(self, Q, F, samples_at) -> BatchEnsemble:
        """Train every member from scratch on the path's pooled tandem samples.

        Args:
            Q: joint positions of the path's points, ``(N, 7)`` rad.
            F: their flange positions, ``(N, 3)`` m (unused: BEM has no router; accepted so
                every estimator fits the same way).
            samples_at: ``samples_at(i) -> (X (K, 21), Y (K, 10))``, the tandem samples at
                point ``i``; called for every ``fit_stride``-th point.
        """
        Q = np.asarray(Q, dtype=float)
        F = np.asarray(F, dtype=float)
        if Q.ndim != 2 or Q.shape[1] != 7 or F.shape != (Q.shape[0], 3) or len(Q) == 0:
            raise InvalidInputError(f"fit needs Q (N, 7) and F (N, 3) with N >= 1, "
                                    f"got {Q.shape} and {F.shape}")
        idx = range(0, len(Q), self.fit_stride)
        pairs = [samples_at(i) for i in idx]
        X = np.vstack([np.asarray(p[0], dtype=float) for p in pairs])
        Y = np.vstack([np.asarray(p[1], dtype=float) for p in pairs])
        if X.shape != (Y.shape[0], N_IN) or Y.shape[1:] != (N_OUT,):
            raise InvalidInputError(f"samples_at must give X (K, {N_IN}) and Y (K, {N_OUT}), "
                                    f"pooled {X.shape} and {Y.shape}")
        lo, hi = output_range(Y)
        batch = max(1, Y.shape[0] // len(idx))  # one point's samples per mini-batch
        n = Y.shape[0]
        learners, trees = [], []
        for i in range(self.n_networks):
            rows = self.resample(i, n)
            learners.append(WeakLearner.fit(
                X[rows], Y[rows], lo, hi, input_noise=self.input_noise, seed=[self.seed, i],
                epochs=self.fit_epochs, batch=batch, fit_lr=self.fit_lr))
        for j in range(self.n_trees):
            i = self.n_networks + j
            rows = self.resample(i, n)
            Xb = X[rows]
            if self.input_noise is not None:
                noise = np.random.default_rng([self.seed, i, 2]).standard_normal(Xb.shape)
                Xb += noise * self.input_noise
            trees.append(RegressionTree(self.max_depth, self.min_samples_leaf,
                                        self.max_features, seed=[self.seed, i]).fit(Xb, Y[rows]))
        self._learners, self._trees = learners, trees
        return self

    def learn_one(self, x, flange, samples: Samples) -> None:
        """Nothing: the BEM is never updated (``samples`` is never resolved)."""

    # -- estimation ----------------------------------------------------------------------
    def predict_one(self, x, flange, t: float = 0.0) -> PayloadEstimate:
        """The mean of the members' outputs for one input ``[q, dq, tau]`` (21)."""
        x = np.asarray(x, dtype=float)
        if x.shape != (N_IN,):
            raise InvalidInputError(f"x must be [q, dq, tau] with {N_IN} values, got {x.shape}")
        if not self.fitted:
            return PayloadEstimate(t=t, phi=np.full(N_OUT, math.nan), std=None, bag=-1,
                                   nis=None, ood=None, determined=None)
        phi = np.zeros(N_OUT)
        for learner in self._learners:
            phi += learner.predict_one(x)
        for tree in self._trees:
            phi += tree.predict_one(x)
        phi /= len(self._learners) + len(self._trees)
        # the paper's baseline: no standard deviation, no test of its data, no OOD verdict
        return PayloadEstimate(t=t, phi=phi, std=None, bag=-1, nis=None, ood=None,
                               determined=None)

    def predict_many(self, X, F) -> np.ndarray:
        """The mean of the members' outputs, ``(N, 10)`` for inputs ``(N, 21)``."""
        X = np.asarray(X, dtype=float)
        if X.ndim != 2 or X.shape[1] != N_IN:
            raise InvalidInputError(f"X must be (N, {N_IN}) rows of [q, dq, tau], "
                                    f"got {X.shape}")
        if not self.fitted:
            return np.full((X.shape[0], N_OUT), math.nan)
        out = np.zeros((X.shape[0], N_OUT))
        for learner in self._learners:
            out += learner.predict_many(X)
        for tree in self._trees:
            out += tree.predict_many(X)
        out /= len(self._learners) + len(self._trees)
        return out

    # -- persistence ---------------------------------------------------------------------
    def to_state(self) -> dict:
        return {"params": self.params(),
                "learners": [lr.to_state() for lr in self._learners],
                "trees": [tr.to_state() for tr in self._trees]}

    @classmethod
    def from_state(cls, state: dict):
        model = cls(**state["params"])
        learners = [WeakLearner.from_state(s) for s in state["learners"]]
        trees = [RegressionTree.from_state(s) for s in state["trees"]]
        if (learners or trees) and (len(learners), len(trees)) != (model.n_networks,
                                                                   model.n_trees):
            raise InvalidInputError(f"model state has {len(learners)} networks and "
                                    f"{len(trees)} trees, its params say {model.n_networks} "
                                    f"and {model.n_trees}")
        model._learners, model._trees = learners, trees
        return model
