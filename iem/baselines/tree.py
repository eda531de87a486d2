"""A CART regression tree (numpy only): the decision-tree weak learner of the BEM baseline.

The paper's BEM (Taie et al., 2023, recalled in the paper's introduction) bags two kinds of
weak learner, a single-layer network and "a basic decision tree"; this is that tree
(Breiman's CART for regression), used by :mod:`iem.baselines.bem`.

Model: a binary tree of axis-aligned tests ``x[f] <= threshold``; a leaf predicts the mean of
the training targets that reach it. Multi-output: ``Y`` is ``(N, m)`` (``m = 10`` payload
parameters here) and the split criterion is the sum over outputs of the squared errors (SSE).

Growth is greedy and level by level up to ``max_depth``. At a node with rows ``Y`` (centred by
their mean, so ``sum Y = 0``), splitting off the first ``n_L`` rows in the order of feature
``f`` lowers the SSE by::

    gain = |S_L|² · n / (n_L · n_R),   S_L = sum of the left rows' centred Y

(the ``sum Y²`` terms of the left and right SSEs add up to the node's and cancel), so one
sort and one cumulative sum of ``Y`` per feature score every split position at once. Only
positions between distinct feature values with at least ``min_samples_leaf`` rows on each
side are candidates; the threshold is the midpoint of the two values. Ties go to the lowest
feature index, then the lowest threshold. A node becomes a leaf when no candidate lowers the
SSE (for instance when its targets are all equal).

The tree is stored as flat arrays (``feature``, ``threshold``, ``left``, ``right``,
``value``; ``feature == -1`` marks a leaf) so :meth:`RegressionTree.predict_many` walks all
rows one level at a time.
"""

from __future__ import annotations

import numpy as np

from ..errors import InvalidInputError

LEAF = -1
_REL_GAIN = 1e-12
"""Smallest SSE decrease, relative to the node's SSE, that counts as a split (rounding)."""


class RegressionTree:
    """A multi-output CART regression tree.

    Args:
        max_depth: largest number of tests on any root-to-leaf path (0: a single leaf).
        min_samples_leaf: fewest training rows in a leaf.
        max_features: None to search every feature at each node, or an int: the number of
            features drawn at random (without replacement) at each node.
        seed: seed of that draw (int or list of ints, as :func:`numpy.random.default_rng`).
    """

    def __init__(self, max_depth: int = 6, min_samples_leaf: int = 20,
                 max_features: int | None = None, seed: int | list[int] = 0) -> None:
        if int(max_depth) < 0 or int(min_samples_leaf) < 1:
            raise InvalidInputError(f"need max_depth >= 0 and min_samples_leaf >= 1, got "
                                    f"{max_depth} and {min_samples_leaf}")
        if max_features is not None and int(max_features) < 1:
            raise InvalidInputError(f"max_features must be None or >= 1, got {max_features}")
        self.max_depth = int(max_depth)
        self.min_samples_leaf = int(min_samples_leaf)
        self.max_features = None if max_features is None else int(max_features)
        self.seed = seed
        self.n_features = 0
        self.n_outputs = 0
        self._set_arrays([LEAF], [0.0], [LEAF], [LEAF], np.zeros((1, 0)), [0])

    def params(self) -> dict:
        """The hyper-parameters as given (``RegressionTree(**t.params())`` is a fresh clone)."""
        return {"max_depth": self.max_depth, "min_samples_leaf": self.min_samples_leaf,
                "max_features": self.max_features, "seed": self.seed}

    def _set_arrays(self, feature, threshold, left, right, value, n_samples) -> None:
        self.feature = np.asarray(feature, dtype=np.intp)
        self.threshold = np.asarray(threshold, dtype=float)
        self.left = np.asarray(left, dtype=np.intp)
        self.right = np.asarray(right, dtype=np.intp)
        self.value = np.asarray(value, dtype=float).reshape(len(self.feature), -1)
        self.n_samples = np.asarray(n_samples, dtype=np.intp)
        self._depth = self._compute_depth()

    def _compute_depth(self) -> int:
        depth, level = 0, np.array([0])
        while True:
            level = level[self.feature[level] != LEAF]
            if level.size == 0:
                return depth
            level = np.concatenate((self.left[level], self.right[level]))
            depth += 1

    # -- views ---------------------------------------------------------------------------
    @property
    def fitted(self) -> bool:
        return self.n_features > 0

    @property
    def depth(self) -> int:
        """Depth of the grown tree (at most ``max_depth``)."""
        return self._depth

    def leaves(self) -> np.ndarray:
        """Indices of the leaf nodes."""
        return np.flatnonzero(self.feature == LEAF)

    def nbytes(self) -> int:
        return sum(a.nbytes for a in (self.feature, self.threshold, self.left, self.right,
                                      self.value, self.n_samples))

    # -- training ------------------------------------------------------------------------
    def fit(self, X, Y) -> RegressionTree:
        """Grow the tree on inputs ``X (N, d)`` and targets ``Y (N, m)``; returns self."""
        X = _finite("X", X, 2)
        Y = _finite("Y", Y, 2)
        if Y.shape[0] != X.shape[0] or X.shape[0] == 0 or X.shape[1] == 0 or Y.shape[1] == 0:
            raise InvalidInputError(f"fit needs X (N, d) and Y (N, m) with the same N >= 1, "
                                    f"got {X.shape} and {Y.shape}")
        d = X.shape[1]
        if self.max_features is not None and self.max_features > d:
            raise InvalidInputError(f"max_features must be at most the {d} features, "
                                    f"got {self.max_features}")
        rng = np.random.default_rng(self.seed)
        XT = np.ascontiguousarray(X.T)  # one contiguous row per feature: fast sort and take
        feature, threshold, left, right = [LEAF], [0.0], [LEAF], [LEAF]
        value, count = [Y.mean(axis=0)], [X.shape[0]]
        frontier = [(0, np.arange(X.shape[0]))]
        for _ in range(self.max_depth):
            nxt = []
            for node, rows in frontier:
                split = self._best_split(XT[:, rows], Y[rows], rng)
                if split is None:
                    continue
                f, thr = split
                go = XT[f, rows] <= thr
                for child, side in ((left, rows[go]), (right, rows[~go])):
                    child[node] = len(feature)
                    nxt.append((len(feature), side))
                    feature.append(LEAF)
                    threshold.append(0.0)
                    left.append(LEAF)
                    right.append(LEAF)
                    value.append(Y[side].mean(axis=0))
                    count.append(side.size)
                feature[node], threshold[node] = f, thr
            if not nxt:
                break
            frontier = nxt
        self.n_features, self.n_outputs = d, Y.shape[1]
        self._set_arrays(feature, threshold, left, right, np.array(value), count)
        return self

    def _best_split(self, XT: np.ndarray, Y: np.ndarray, rng: np.random.Generator):
        """``(feature, threshold)`` of the node's best split, or None (see module docstring).

        ``XT`` is the node's inputs transposed ``(d, n)``, ``Y`` its targets ``(n, m)``.
        """
        d, n = XT.shape
        msl = self.min_samples_leaf
        feats = (np.arange(d) if self.max_features is None
                 else np.sort(rng.choice(d, self.max_features, replace=False)))
        if n < 2 * msl:
            return None
        Yc = Y - Y.mean(axis=0)
        sse = float(np.einsum("ij,ij->", Yc, Yc))
        if sse <= 0.0 or not np.ptp(Y, axis=0).any():  # all targets equal
            return None
        n_left = np.arange(msl, n - msl + 1)  # left sizes of the candidate positions
        weight = n / (n_left * (n - n_left))
        best_gain, best = _REL_GAIN * sse, None
        for f in feats:
            order = np.argsort(XT[f])
            xs = XT[f, order]
            cs = np.take(Yc, order[: n - msl], axis=0)
            np.cumsum(cs, axis=0, out=cs)
            cs = cs[msl - 1:]
            gain = np.einsum("ij,ij->i", cs, cs) * weight
            gain[xs[msl - 1: n - msl] >= xs[msl: n - msl + 1]] = -np.inf  # equal values
            i = int(np.argmax(gain))
            if gain[i] > best_gain:
                lo, hi = xs[msl - 1 + i], xs[msl + i]
                thr = 0.5 * (lo + hi)
                if not lo <= thr < hi:  # the midpoint rounded onto ``hi``
                    thr = lo
                best_gain, best = gain[i], (int(f), float(thr))
        return best

    # -- prediction ----------------------------------------------------------------------
    def _check_fitted(self) -> None:
        if not self.fitted:
            raise InvalidInputError("the tree is not fitted: call fit(X, Y) before predicting")

    def apply(self, X) -> np.ndarray:
        """Index of the leaf each input row ``(N, d)`` falls in: all rows walk level by level."""
        self._check_fitted()
        X = _finite("X", X, 2)
        if X.shape[1] != self.n_features:
            raise InvalidInputError(f"X must have {self.n_features} features per row, "
                                    f"got shape {X.shape}")
        node = np.zeros(X.shape[0], dtype=np.intp)
        rows = np.arange(X.shape[0])
        for _ in range(self._depth):
            f = self.feature[node]
            inner = f != LEAF
            go = X[rows, np.where(inner, f, 0)] <= self.threshold[node]
            node = np.where(inner, np.where(go, self.left[node], self.right[node]), node)
        return node

    def predict_many(self, X) -> np.ndarray:
        """Predictions ``(N, m)`` for inputs ``(N, d)``: the means of their leaves."""
        return self.value[self.apply(X)]

    def predict_one(self, x) -> np.ndarray:
        """The prediction ``(m,)`` for one input ``(d,)``."""
        self._check_fitted()
        x = _finite("x", x, 1)
        if x.shape != (self.n_features,):
            raise InvalidInputError(f"x must have {self.n_features} values, got {x.shape}")
        node = 0
        feature, threshold = self.feature, self.threshold
        while feature[node] != LEAF:
            node = (self.left[node] if x[feature[node]] <= threshold[node]
                    else self.right[node])
        return self.value[node].copy()

    # -- persistence ---------------------------------------------------------------------
    def to_state(self) -> dict:
        """Plain data (lists, ints, floats) for msgpack."""
        return {"params": self.params(), "n_features": self.n_features,
                "n_outputs": self.n_outputs, "feature": self.feature.tolist(),
                "threshold": self.threshold.tolist(), "left": self.left.tolist(),
                "right": self.right.tolist(), "value": self.value.tolist(),
                "n_samples": self.n_samples.tolist()}

    @classmethod
    def from_state(cls, state: dict) -> RegressionTree:
        tree = cls(**state["params"])
        n = len(state["feature"])
        sizes = [len(state[k]) for k in ("threshold", "left", "right", "value", "n_samples")]
        if n == 0 or any(s != n for s in sizes):
            raise InvalidInputError(f"tree state needs equally long node arrays, got {n} "
                                    f"features and {sizes} for the others")
        feature = np.asarray(state["feature"], dtype=np.intp)
        left = np.asarray(state["left"], dtype=np.intp)
        right = np.asarray(state["right"], dtype=np.intp)
        inner = np.flatnonzero(feature != LEAF)
        parent = np.concatenate((inner, inner))
        children = np.concatenate((left[inner], right[inner]))
        if np.any(feature[inner] >= int(state["n_features"])) or np.any(
                (children <= parent) | (children >= n)):
            raise InvalidInputError("tree state has a feature or child index out of range "
                                    "(children must come after their parent)")
        tree.n_features, tree.n_outputs = int(state["n_features"]), int(state["n_outputs"])
        tree._set_arrays(feature, state["threshold"], left, right,
                         np.array(state["value"], dtype=float).reshape(n, -1),
                         state["n_samples"])
        return tree


def _finite(name: str, value, ndim: int) -> np.ndarray:
    arr = np.asarray(value, dtype=float)
    if arr.ndim != ndim:
        raise InvalidInputError(f"{name} must be a {ndim}-D array, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise InvalidInputError(f"{name} must be finite, got NaN or infinite values")
    return arr
