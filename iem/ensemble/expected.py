"""The fast weak learner: Algorithm 2 in expectation over its input noise, computed exactly.

The model is the weak learner's, ``Y = ReLU(a x + b)`` on the scaled inputs and outputs of
:mod:`iem.ensemble.learner`, and so are its estimates and its file. What differs is how it
is trained. Algorithm 2 takes gradient steps on mini-batches whose inputs get fresh Gaussian
noise of covariance ``N`` (the sensor's, scaled). Every training target lies inside [1/6,
5/6], so the ReLU only floors, and in expectation over the noise the loss of ``K`` samples
is the least-squares loss plus a Tikhonov term::

    E L(W) = 1/K sum_k |t_k - W x̃_k|²  +  tr(a N aᵀ),     W = [a b],  x̃ = [x, 1]

a quadratic in ``W`` whose Hessian is ``2 (G / K + D)``, with ``G = sum_k x̃_k x̃_kᵀ`` (22 x
22) and ``D = diag(N, 0)``. :class:`ExpectedLearner` computes exactly what Algorithm 2
computes on average, and draws no random numbers:

- **a point that joins the open bag** (:meth:`ExpectedLearner.learn`): the ``iters``
  normalised gradient steps of :meth:`WeakLearner.learn <iem.ensemble.learner.WeakLearner.
  learn>` (its step size ``lr / (mean |x|² + sum N + 1)``) on that expected loss, each a
  22 x 22 product;
- **the refit of a bag that closes** (:func:`refit`): the minimiser of the expected loss over
  all the bag's points, where the refit's SGD converges::

      W (G + n D + eps I) = H + eps W0,     H = sum x̃ tᵀ

  one 22 x 22 solve on the bag's sufficient statistics (:class:`BagStatistics`), which each
  point adds to as it comes, with its training beyond the path (:mod:`iem.ensemble.augment`)
  (so every point counts, not a reservoir's sample of them). ``eps W0`` is the learner the
  bag started from, counted as :data:`PRIOR_WEIGHT` samples in every direction: it decides
  only the directions the bag's samples never excite (a bag of few points);
- **the initial bags** (:meth:`ExpectedLearner.fit`): the same minimiser, from a fresh
  learner's weights.

The input scaling of a refitted or fitted learner is its samples' mean and standard
deviation plus the input noise's variance, and its velocity precision theirs, as
:meth:`WeakLearner.fit <iem.ensemble.learner.WeakLearner.fit>` sets them.
"""

from __future__ import annotations

import numpy as np

from ..errors import InvalidInputError
from .learner import N_IN, N_OUT, SCALE_FLOOR, WeakLearner, saved_numbers

__all__ = ["PRIOR_WEIGHT", "BagStatistics", "ExpectedLearner", "refit"]

PRIOR_WEIGHT = 1.0
"""``eps``: how many samples' worth the weights a bag starts from count in its refit, per
direction of the scaled inputs: one sample, against the hundreds a single point brings
wherever its samples vary."""

N_AUG = N_IN + 1
"""Inputs with the constant 1 of the bias."""
_EYE = np.eye(N_AUG)
_EYE.flags.writeable = False
_DIAG = np.arange(N_IN)


def _augmented(X: np.ndarray, center: np.ndarray, scale: np.ndarray,
               inverse: bool) -> np.ndarray:
    """``[x, 1]`` ``(K, 22)`` of inputs ``X`` ``(K, 21)`` scaled, ``x = (X - center) *
    scale`` (``inverse``: ``/ scale``), written in place: no array between."""
    xa = np.empty((X.shape[0], N_AUG))
    x = xa[:, :N_IN]
    np.subtract(X, center, out=x)
    (np.divide if inverse else np.multiply)(x, scale, out=x)
    xa[:, N_IN] = 1.0
    return xa


_TARGETS: list = [None]
"""The last read-only targets scaled: ``(Y, lo, span, t, tt)``."""


def _targets(Y: np.ndarray, lo: np.ndarray, span: np.ndarray) -> tuple[np.ndarray, float]:
    """``t = (Y - lo) / span`` and ``sum t²``. The tandem simulators' targets are one
    read-only array, the family's, point after point: those are scaled once per output
    scaling (the same numbers)."""
    kept = _TARGETS[0]
    if (kept is not None and kept[0] is Y and np.array_equal(kept[1], lo)
            and np.array_equal(kept[2], span)):
        return kept[3], kept[4]
    t = (Y - lo) / span
    tt = float(np.einsum("ij,ij->", t, t))
    if Y.base is None and not Y.flags.writeable:  # no one writes it: kept
        t.flags.writeable = False
        _TARGETS[0] = (Y, lo.copy(), span.copy(), t, tt)
    return t, tt


def _checked(X, Y, what: str) -> tuple[np.ndarray, np.ndarray]:
    X = np.asarray(X, dtype=float)
    Y = np.asarray(Y, dtype=float)
    if X.ndim != 2 or X.shape[1] != N_IN or Y.shape != (X.shape[0], N_OUT):
        raise InvalidInputError(f"{what} needs X (N, {N_IN}) and Y (N, {N_OUT}), got "
                                f"{X.shape} and {Y.shape}")
    return X, Y


class ExpectedLearner(WeakLearner):
    """A weak learner trained as the module docstring says; the arguments are
    :class:`~iem.ensemble.learner.WeakLearner`'s (nothing draws from ``seed``)."""

    keeps_statistics = True

    def learn(self, X, Y, iters: int = 1, keep: BagStatistics | None = None,
              loss: bool = True) -> float:
        """``iters`` normalised gradient steps on the expected loss of one point's samples
        ``(N, 21) -> (N, 10)``, in place; returns the least-squares loss (without the noise's
        term) before the last step, as :meth:`WeakLearner.learn` returns its last step's
        (NaN, not computed, with ``loss`` False). ``keep``: the bag's statistics, in this
        learner's coordinates (made from it), to add the point to (its products are the
        steps' own)."""
        X, Y = _checked(X, Y, "learn")
        n = X.shape[0]
        xa = _augmented(X, self.center, self._inv_scale, inverse=False)
        t, tt = _targets(Y, self.lo, self._span)
        gram = xa.T @ xa
        cross = xa.T @ t  # (22, 10)
        if keep is not None:
            keep.add_products(gram, cross)
        hess = gram / n  # G / n + D
        norm2 = float(hess.diagonal()[:N_IN].sum())  # the trace of its inputs' block
        if self._noise_scaled is not None:
            var = self._noise_scaled ** 2
            hess.reshape(-1)[:N_IN * (N_AUG + 1):N_AUG + 1] += var  # the inputs' diagonal
            norm2 += float(var.sum())
        step = 2.0 * self.lr / (norm2 + 1.0)  # WeakLearner.learn's alpha times the MSE's 2
        move = _EYE - step * hess  # W <- W (I - step hess) + step H / n
        pull = cross.T * (step / n)
        w = np.empty((N_OUT, N_AUG))
        w[:, :N_IN], w[:, N_IN] = self.a, self.b
        last = float("nan")
        iters = int(iters)
        for i in range(iters):
            if loss and i == iters - 1:  # |xa wᵀ - t|² / n from the products: no residual
                last = (float(((w @ gram) * w).sum())
                        - 2.0 * float(np.einsum("ij,ji->", w, cross)) + tt) / n
            w = w @ move
            w += pull
        self.a, self.b = w[:, :N_IN].copy(), w[:, N_IN].copy()
        return last

    @classmethod
    def fit(cls, X, Y, lo, hi, lr: float = 0.5, input_noise=None, seed=0, epochs: int = 10,
            batch: int = 77, fit_lr: float = 0.1, pause=None) -> ExpectedLearner:
        """A learner fitted to a whole bag's samples ``X (N, 21)``, ``Y (N, 10)`` at once,
        from a fresh learner's weights (``epochs``, ``batch``, ``fit_lr`` and ``pause``
        are :meth:`WeakLearner.fit`'s and not used: nothing iterates)."""
        X, Y = _checked(X, Y, "fit")
        noise = np.zeros(N_IN) if input_noise is None else np.asarray(input_noise, float)
        start = cls(lo, hi, X.mean(axis=0), np.sqrt(X.var(axis=0) + noise ** 2), lr=lr,
                    input_noise=input_noise, seed=seed)
        stats = BagStatistics(start)
        stats.add(X, Y)
        stats.points = 1  # (one batch)
        return refit(stats, start)


def refit(stats: BagStatistics, like: WeakLearner, seed=None) -> ExpectedLearner:
    """The learner of a bag whose samples ``stats`` holds: the minimiser of the expected
    loss over them (the module docstring), with the input scaling and velocity precision of
    those samples, and the output scaling, ``lr`` and input noise of ``like`` (its seed
    unless ``seed`` is given)."""
    learner = like
    w = stats.solve()
    mean, cov = stats.moments()  # of x = (X - c) / s in the statistics' coordinates
    c, s = stats.center, stats.scale
    noise = np.zeros(N_IN) if stats.noise is None else stats.noise
    scale = np.sqrt(np.maximum(np.diag(cov), 0.0) * s ** 2 + noise ** 2)
    out = ExpectedLearner(learner.lo, learner.hi, c + mean * s, scale, lr=learner.lr,
                          input_noise=learner.input_noise,
                          seed=learner.seed if seed is None else seed)
    # a x + b with x = (X - c) / s is a' x' + b' with x' = (X - c') / s':
    # a' = a s' / s, b' = b + a mean (the same function, to rounding)
    a = w[:, :N_IN]
    out.a = a * (out.scale / s)
    out.b = w[:, N_IN] + a @ mean
    dq = slice(7, 14)
    floor = np.maximum(noise[dq], SCALE_FLOOR[dq])
    out.dq_precision = np.linalg.inv(cov[dq, dq] * np.outer(s[dq], s[dq])
                                     + np.diag(floor ** 2))
    return out


class BagStatistics:
    """The sufficient statistics of a bag's samples, in the input and output coordinates of
    the learner it starts from (``start``, whose weights are the refit's ``W0``).

    Args:
        start: the bag's learner as the bag starts (its scaling, noise and weights).
    """

    def __init__(self, start: WeakLearner) -> None:
        self.center = start.center.copy()
        self.scale = start.scale.copy()
        self.lo = start.lo.copy()
        self.span = start.hi - start.lo
        self.noise = None if start.input_noise is None else start.input_noise.copy()
        self.prior = np.hstack((start.a, start.b[:, None]))
        self.gram = np.zeros((N_AUG, N_AUG))
        """``sum x̃ x̃ᵀ``; its last element is the count of samples."""
        self.cross = np.zeros((N_AUG, N_OUT))
        """``sum x̃ tᵀ``."""
        self.points = 0
        """Calls of :meth:`add`: the points of the bag."""

    def __len__(self) -> int:
        return self.points

    @property
    def n(self) -> float:
        """Samples taken."""
        return float(self.gram[-1, -1])

    def add(self, X, Y) -> None:
        """Add samples ``X (K, 21)``, ``Y (K, 10)``: a point's training beyond the path (a
        point's own samples come with :meth:`add_products`)."""
        X, Y = _checked(X, Y, "the bag's statistics")
        xa = _augmented(X, self.center, self.scale, inverse=True)
        self.gram += xa.T @ xa
        self.cross += xa.T @ _targets(Y, self.lo, self.span)[0]

    def add_products(self, gram: np.ndarray, cross: np.ndarray) -> None:
        """Add one point: the products ``sum x̃ x̃ᵀ`` ``(22, 22)`` and ``sum x̃ tᵀ``
        ``(22, 10)`` of its samples in these coordinates."""
        self.gram += gram
        self.cross += cross
        self.points += 1

    def solve(self) -> np.ndarray:
        """``W = [a b]`` ``(10, 22)`` in these coordinates: the module docstring's
        minimiser."""
        lhs = self.gram + PRIOR_WEIGHT * _EYE
        if self.noise is not None:
            lhs[_DIAG, _DIAG] += self.n * (self.noise / self.scale) ** 2
        # C order, as every learner's weights (a file's are: the products then round alike)
        return np.ascontiguousarray(np.linalg.solve(lhs, self.cross + PRIOR_WEIGHT
                                                    * self.prior.T).T)

    def moments(self) -> tuple[np.ndarray, np.ndarray]:
        """Mean ``(21)`` and covariance ``(21, 21)`` (over the count) of the scaled
        inputs."""
        n = self.n
        mean = self.gram[:N_IN, N_IN] / n
        return mean, self.gram[:N_IN, :N_IN] / n - np.outer(mean, mean)

    def nbytes(self) -> int:
        return self.gram.nbytes + self.cross.nbytes + self.prior.nbytes

    def to_state(self) -> dict:
        return {"center": self.center.tolist(), "scale": self.scale.tolist(),
                "lo": self.lo.tolist(), "span": self.span.tolist(),
                "noise": None if self.noise is None else self.noise.tolist(),
                "prior": self.prior.tolist(), "gram": self.gram.tolist(),
                "cross": self.cross.tolist(), "points": self.points}

    @classmethod
    def from_state(cls, state: dict) -> BagStatistics:
        out = cls.__new__(cls)
        what = "the open bag's statistics'"
        out.center = saved_numbers(state["center"], (N_IN,), f"{what} center")
        out.scale = saved_numbers(state["scale"], (N_IN,), f"{what} scale")
        out.lo = saved_numbers(state["lo"], (N_OUT,), f"{what} lo")
        out.span = saved_numbers(state["span"], (N_OUT,), f"{what} span")
        noise = state["noise"]
        out.noise = None if noise is None else saved_numbers(noise, (N_IN,), f"{what} noise")
        out.prior = saved_numbers(state["prior"], (N_OUT, N_AUG), f"{what} prior")
        out.gram = saved_numbers(state["gram"], (N_AUG, N_AUG), f"{what} gram")
        out.cross = saved_numbers(state["cross"], (N_AUG, N_OUT), f"{what} cross")
        out.points = int(state["points"])
        if np.any(out.scale <= 0.0) or np.any(out.span <= 0.0):
            raise InvalidInputError(f"{what} scale and span must be > 0")
        return out
