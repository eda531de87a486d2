"""The weak learner: the paper's Algorithm 2, a single-layer network trained by SGD.

Model: ``Y = ReLU(a x + b)`` with ``x`` the scaled input and ``Y`` the scaled output.

Input scaling: ``x = (X - center) / scale`` per feature, ``X = [q, dq, tau]`` (21 values,
rad, rad/s, N·m). ``center`` and ``scale`` are the mean and standard deviation of the
learner's training inputs (including the sensor noise it is trained with). They belong to
the bag: a learner copied for a new bag keeps the weights ``a, b`` and the ``scale`` of the
learner it copies, and takes the mean of the new bag's first tandem samples as its
``center`` (see :meth:`WeakLearner.copy_for`).

Output scaling: ``Y = (phi - lo) / (hi - lo)`` per parameter, with ``lo``/``hi`` the training
family's minimum/maximum widened by a quarter of the range on each side, so every training
target lies in [1/6, 5/6] and the ReLU only ever acts as a floor at ``lo``.

Training: stochastic gradient descent on the mean squared error of a mini-batch (Algorithm 2,
lines 12-15)::

    L = 1/N sum_k |Y_k - ReLU(a x_k + b)|²,   a <- a - alpha dL/da,   b <- b - alpha dL/db

with the normalised step ``alpha = lr / mean_k(|x_k|² + 1)`` (normalised LMS), which keeps the
step stable however far a path point lies from the learner's centre. Each mini-batch's inputs
get fresh Gaussian noise with the sensor model's standard deviations (``input_noise``), since
the measured inputs the learner will see carry that noise and the tandem simulators' do not.

Offline batch training (:meth:`WeakLearner.fit`, used for the initial bags) runs the same SGD
in whitened input coordinates (a change of variables that removes the strong correlations
between q, dq and tau, which otherwise make SGD crawl) and maps the weights back exactly, so
the stored learner always has the form above.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import InvalidInputError
from ..sensor import DEFAULT_SENSOR

N_IN = 21
N_OUT = 10
SENSOR_NOISE = DEFAULT_SENSOR.sigmas
"""The sensor model's standard deviations of one frame, ``[q (rad), dq (rad/s), tau (N·m)]``
x 7 (:data:`iem.sensor.DEFAULT_SENSOR`): the noise the learners are trained with on their
inputs. A block point (:mod:`iem.signals.blocks`) carries a third of it, but the frame's noise
regularises the learners, which generalise better for it: with a block point's noise instead,
the new path's mass MAE rose from 0.0044 to 0.0057 kg (``iem bench paper --quick --seed 0``)
and from 0.067 to 0.096 kg on the realistic plant (``iem bench realistic --quick --seed
0``), the runs this choice was made on."""
FIT_CHUNK_ROWS = 2048
"""Rows of an epoch :meth:`WeakLearner.fit` gathers and draws noise for at once (rounded
down to whole mini-batches): a few hundred kB of buffers, whatever the bag's size."""
OUTPUT_MARGIN = 0.25
"""Widening of the training range on each side for the output scaling (fraction of range)."""
SCALE_FLOOR = np.repeat([1e-3, 1e-3, 1e-3], 7)
"""Smallest input scale per feature (rad, rad/s, N·m): guards features constant in a batch."""


def _gradient(a: np.ndarray, b: np.ndarray, x: np.ndarray, t: np.ndarray):
    """``dL/da``, ``dL/db`` and ``L`` of ``L = 1/N sum_k |t_k - ReLU(a x_k + b)|²``."""
    z = x @ a.T + b
    r = np.maximum(z, 0.0) - t
    loss = float((r * r).sum() / x.shape[0])
    r = np.where(z > 0.0, r, 0.0) * (2.0 / x.shape[0])
    return r.T @ x, r.sum(axis=0), loss


def _sgd_step(a: np.ndarray, b: np.ndarray, x: np.ndarray, t: np.ndarray, lr: float) -> None:
    """One SGD step of ``lr`` on ``a``, ``b`` in place: :func:`_gradient`'s arithmetic,
    operation for operation (the same numbers to the bit), without the loss nobody reads,
    and without the mask when every ReLU is active (the usual case: it keeps every value)."""
    z = x @ a.T
    z += b
    r = np.maximum(z, 0.0)
    r -= t
    if not z.min() > 0.0:  # (a NaN takes the mask too)
        r = np.where(z > 0.0, r, 0.0)
    r *= 2.0 / x.shape[0]
    a -= lr * (r.T @ x)
    b -= lr * r.sum(axis=0)


def velocity_precision(DQ: np.ndarray, noise: np.ndarray) -> np.ndarray:
    """The inverse of the covariance of joint velocities ``DQ`` ``(N, 7)`` plus the noise's
    variance ``noise**2`` (7; at least :data:`SCALE_FLOOR`'s, so it is always invertible)."""
    DQ = np.asarray(DQ, dtype=float)
    floor = np.maximum(np.asarray(noise, dtype=float), SCALE_FLOOR[7:14])
    d = DQ - DQ.mean(axis=0)
    cov = d.T @ d / max(1, len(DQ)) + np.diag(floor ** 2)
    return np.linalg.inv(cov)


def rng_state(rng: np.random.Generator) -> dict:
    """A generator's state with its 128-bit integers as hex text (msgpack packs 64 bits)."""
    st = rng.bit_generator.state
    inner = {k: hex(v) for k, v in st["state"].items()}
    return {"bit_generator": st["bit_generator"], "state": inner,
            "has_uint32": st["has_uint32"], "uinteger": st["uinteger"]}


def set_rng_state(rng: np.random.Generator, state: dict) -> None:
    inner = {k: int(v, 16) for k, v in state["state"].items()}
    rng.bit_generator.state = {"bit_generator": state["bit_generator"], "state": inner,
                               "has_uint32": state["has_uint32"],
                               "uinteger": state["uinteger"]}


def saved_numbers(value, shape: tuple[int, ...], what: str) -> np.ndarray:
    """The numbers ``value`` of a saved state as a float array of ``shape``;
    InvalidInputError if one of them is not a finite number (a None reads as NaN): a model
    file that loads holds a model that estimates."""
    out = np.array(value, dtype=float).reshape(shape)
    if not np.all(np.isfinite(out)):
        raise InvalidInputError(f"{what} holds {np.count_nonzero(~np.isfinite(out))} values "
                                f"that are not finite numbers (None, NaN or inf)")
    return out


def output_range(phi: np.ndarray, margin: float = OUTPUT_MARGIN) -> tuple[np.ndarray, np.ndarray]:
    """``lo, hi`` of the output scaling from a training family's ``(K, 10)`` phi."""
    phi = np.asarray(phi, dtype=float)
    span = phi.max(axis=0) - phi.min(axis=0)
    span = np.where(span > 0, span, np.maximum(np.abs(phi).max(axis=0), 1e-6))
    return phi.min(axis=0) - margin * span, phi.max(axis=0) + margin * span


class WeakLearner:
    """A single-layer network ``Y = ReLU(a x + b)`` on scaled inputs and outputs.

    Args:
        lo, hi: output scaling (10 values each, phi units), see :func:`output_range`.
        center, scale: input scaling (21 values each, input units).
        lr: SGD learning rate of the normalised step (see module docstring).
        input_noise: standard deviation of the noise added to the inputs during training
            (21 values in input units, or None for none).
        seed: seed of that noise.
    """

    keeps_statistics = False
    """How a bag keeps what its refit at close trains on: False, a reservoir of its points
    (:class:`~iem.ensemble.reservoir.Reservoir`); True, its sufficient statistics
    (:class:`~iem.ensemble.expected.BagStatistics`, :mod:`iem.ensemble.expected`)."""

    def __init__(self, lo, hi, center, scale, lr: float = 0.5, input_noise=None,
                 seed: int | list[int] = 0) -> None:
        self.lo = np.array(lo, dtype=float).reshape(N_OUT)
        self.hi = np.array(hi, dtype=float).reshape(N_OUT)
        if np.any(self.hi <= self.lo):
            raise InvalidInputError("output scaling needs hi > lo for every parameter")
        self.center = np.array(center, dtype=float).reshape(N_IN)
        self.scale = np.maximum(np.array(scale, dtype=float).reshape(N_IN), SCALE_FLOOR)
        self.lr = float(lr)
        self.input_noise = None if input_noise is None else np.array(
            input_noise, dtype=float).reshape(N_IN)
        self.seed = seed
        self._rng = np.random.default_rng(seed)
        self.a = np.zeros((N_OUT, N_IN))
        self.b = np.full(N_OUT, 0.5)
        self.dq_precision: np.ndarray | None = None
        """Inverse covariance (7x7) of the training inputs' joint velocities plus the input
        noise's variance, set by :meth:`fit`; None for a learner trained only online."""
        self._refresh()

    def _refresh(self) -> None:
        self._inv_scale = 1.0 / self.scale
        self._span = self.hi - self.lo
        self._noise_scaled = (None if self.input_noise is None
                              else self.input_noise * self._inv_scale)

    def velocity_score(self, X) -> float:
        """How far the joint velocities of input ``X = [q, dq, tau]`` lie from those of the
        training inputs, knowing how they go together: ``sqrt(d^T P d / 7)`` with ``d`` the
        velocities less their training mean and ``P`` :attr:`dq_precision` (about 1 for a
        training input; 0 without ``dq_precision``)."""
        if self.dq_precision is None:
            return 0.0
        d = np.asarray(X, dtype=float)[7:14] - self.center[7:14]
        return math.sqrt(max(0.0, float(d @ self.dq_precision @ d)) / 7.0)

    # -- prediction ----------------------------------------------------------------------
    def predict_one(self, X) -> np.ndarray:
        """phi (10) for one input ``X = [q, dq, tau]`` (21): :meth:`estimate`'s phi."""
        X = np.asarray(X, dtype=float)
        if X.shape != (N_IN,):
            raise InvalidInputError(f"X must be [q, dq, tau] with {N_IN} values, got {X.shape}")
        return self._phi((X - self.center) * self._inv_scale)  # (no score: nobody asked)

    def _phi(self, x: np.ndarray) -> np.ndarray:
        """phi of an input already scaled, ``x = (X - center) / scale``."""
        y = self.a @ x + self.b
        np.maximum(y, 0.0, out=y)
        return self.lo + y * self._span

    def estimate(self, X: np.ndarray, velocity: bool) -> tuple[np.ndarray, float, float]:
        """The cycle's one call: ``(phi, score, velocity_score)`` at input ``X`` (21 floats):
        ``phi = lo + ReLU(a x + b) * (hi - lo)`` with ``x = (X - center) / scale``, the
        largest ``|x|`` (the out-of-distribution score) and, if ``velocity``,
        :meth:`velocity_score` (else 0.0)."""
        if X.shape != (N_IN,):
            raise InvalidInputError(f"X must be [q, dq, tau] with {N_IN} values, got {X.shape}")
        x = (X - self.center) * self._inv_scale
        score = max(float(x.max()), -float(x.min()))  # the largest |x|
        return self._phi(x), score, self.velocity_score(X) if velocity else 0.0

    def predict_many(self, X) -> np.ndarray:
        """phi ``(N, 10)`` for inputs ``(N, 21)``."""
        x = (np.asarray(X, dtype=float) - self.center) * self._inv_scale
        y = np.maximum(x @ self.a.T + self.b, 0.0)
        return self.lo + y * self._span

    # -- Algorithm 2 ---------------------------------------------------------------------
    def gradient(self, x: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        """``dL/da``, ``dL/db`` and ``L`` of the MSE for scaled inputs ``x`` and targets ``t``."""
        return _gradient(self.a, self.b, x, t)

    def learn(self, X, Y, iters: int = 1) -> float:
        """``iters`` normalised SGD steps on one mini-batch ``(N, 21) -> (N, 10)``.

        One fresh draw of input noise per call (if ``input_noise``), shared by its steps:
        drawing it is most of the cost, and across the points of a bag the draws still
        average out. The normalised step uses the expected squared input norm,
        ``mean_k |x_k|² + sum_j sigma_j²`` (exactly ``mean_k |x_k|²`` without noise).
        Returns the loss of the last step.
        """
        x0 = (np.asarray(X, dtype=float) - self.center) * self._inv_scale
        t = (np.asarray(Y, dtype=float) - self.lo) / self._span
        n = x0.shape[0]
        if x0.shape != (n, N_IN) or t.shape != (n, N_OUT):
            raise InvalidInputError(f"learn needs X (N, {N_IN}) and Y (N, {N_OUT}), got "
                                    f"{x0.shape} and {t.shape}")
        iters = int(iters)
        norm2 = float(np.einsum("ij,ij->", x0, x0)) / n
        x = x0
        if self._noise_scaled is not None and iters > 0:
            noise = self._rng.standard_normal((n, N_IN))
            noise *= self._noise_scaled
            x = x0 + noise
            norm2 += float(self._noise_scaled @ self._noise_scaled)
        step = 2.0 * self.lr / ((norm2 + 1.0) * n)  # alpha times the MSE's 2/N
        a, b = self.a, self.b
        loss = float("nan")
        for i in range(iters):
            z = x @ a.T
            z += b
            if z.min() > 0.0:  # every ReLU active (the usual case): it is the identity
                active = None
            else:
                active = z > 0.0
                np.maximum(z, 0.0, out=z)
            z -= t  # residual ReLU(z) - t
            if i == iters - 1:
                loss = float(np.einsum("ij,ij->", z, z)) / n
            if active is not None:
                z *= active  # no gradient through an inactive ReLU
            a -= step * (z.T @ x)
            b -= step * z.sum(axis=0)
        return loss

    # -- offline batch training ----------------------------------------------------------
    @classmethod
    def fit(cls, X, Y, lo, hi, lr: float = 0.5, input_noise=None, seed=0,
            epochs: int = 10, batch: int = 77, fit_lr: float = 0.1,
            pause=None) -> WeakLearner:
        """A learner trained on a whole bag's samples by SGD in whitened coordinates.

        The scaling is fitted to ``X`` (plus the input noise's variance); the SGD runs on
        ``u = W (x)`` with ``W`` the whitening of the scaled inputs, then the weights are
        mapped back, so the returned learner is an ordinary :class:`WeakLearner`.
        ``pause``, if given, is called after every mini-batch (a worker thread passes
        ``time.sleep(0)`` there, so a waiting estimate gets the interpreter within a step).
        """
        X = np.asarray(X, dtype=float)
        Y = np.asarray(Y, dtype=float)
        if X.ndim != 2 or X.shape[1] != N_IN or Y.shape != (X.shape[0], N_OUT):
            raise InvalidInputError(f"fit needs X (N, {N_IN}) and Y (N, {N_OUT}), "
                                    f"got {X.shape} and {Y.shape}")
        noise = np.zeros(N_IN) if input_noise is None else np.asarray(input_noise, float)
        center = X.mean(axis=0)
        scale = np.sqrt(X.var(axis=0) + noise ** 2)
        learner = cls(lo, hi, center, scale, lr=lr, input_noise=input_noise, seed=seed)
        learner.dq_precision = velocity_precision(X[:, 7:14], noise[7:14])
        inv = learner._inv_scale
        x_all = X - center
        x_all *= inv  # in place: one bag-sized temporary fewer (the same arithmetic)
        cov = np.cov(x_all.T) + np.diag((noise * inv) ** 2)
        lam, vec = np.linalg.eigh(cov)
        lam = np.maximum(lam, 1e-6 * lam.max())
        white = vec / np.sqrt(lam)  # u = x @ white
        t_all = (Y - learner.lo) / learner._span
        a_u = np.zeros((N_OUT, N_IN))  # weights in whitened coordinates
        b = learner.b
        rng = learner._rng
        noise_scaled = noise * inv
        n = X.shape[0]
        # an epoch goes in chunks of whole mini-batches, each gathered and given its noise
        # at once: the generator's stream is the same as that of a draw per mini-batch in
        # turn, so each mini-batch gets the same numbers; chunks keep the buffers small
        rows = min(n, batch * max(1, FIT_CHUNK_ROWS // batch))
        x, t = np.empty((rows, N_IN)), np.empty((rows, N_OUT))
        draw = None if input_noise is None else np.empty((rows, N_IN))
        for _ in range(int(epochs)):
            order = rng.permutation(n)
            for c in range(0, n, rows):
                j = order[c:c + rows]
                m = j.shape[0]
                xc, tc = x[:m], t[:m]
                np.take(x_all, j, axis=0, out=xc)
                np.take(t_all, j, axis=0, out=tc)
                if draw is not None:
                    noise_c = draw[:m]
                    rng.standard_normal(out=noise_c)
                    noise_c *= noise_scaled
                    xc += noise_c
                for s in range(0, m, batch):
                    _sgd_step(a_u, b, xc[s:s + batch] @ white, tc[s:s + batch], fit_lr)
                    if pause is not None:
                        pause()
        learner.a = a_u @ white.T  # a_u (W^T x) = (a_u W^T) x
        learner.b = b
        return learner

    # -- copies --------------------------------------------------------------------------
    def copy(self, seed=None) -> WeakLearner:
        """An independent copy (same weights, scaling and hyper-parameters)."""
        other = type(self)(self.lo, self.hi, self.center, self.scale, lr=self.lr,
                            input_noise=self.input_noise,
                            seed=self.seed if seed is None else seed)
        other.a = self.a.copy()
        other.b = self.b.copy()
        other.dq_precision = self.dq_precision  # never changed in place: shared
        if seed is None:
            other._rng.bit_generator.state = self._rng.bit_generator.state
        return other

    def copy_for(self, center, seed=None) -> WeakLearner:
        """A copy for a new bag: same weights and scale, the new bag's input ``center``."""
        other = self.copy(seed=seed)
        other.center = np.array(center, dtype=float).reshape(N_IN)
        other.dq_precision = None  # the velocities it knows are the other bag's
        return other

    # -- persistence ---------------------------------------------------------------------
    def to_state(self) -> dict:
        return {
            "lo": self.lo.tolist(), "hi": self.hi.tolist(),
            "center": self.center.tolist(), "scale": self.scale.tolist(),
            "lr": self.lr,
            "input_noise": None if self.input_noise is None else self.input_noise.tolist(),
            "seed": self.seed, "rng": rng_state(self._rng),
            "a": self.a.tolist(), "b": self.b.tolist(),
            "dq_precision": None if self.dq_precision is None else self.dq_precision.tolist(),
        }

    @classmethod
    def from_state(cls, state: dict) -> WeakLearner:
        noise = state["input_noise"]
        learner = cls(saved_numbers(state["lo"], (N_OUT,), "learner state's lo"),
                      saved_numbers(state["hi"], (N_OUT,), "learner state's hi"),
                      saved_numbers(state["center"], (N_IN,), "learner state's center"),
                      saved_numbers(state["scale"], (N_IN,), "learner state's scale"),
                      lr=state["lr"], seed=state["seed"], input_noise=None if noise is None
                      else saved_numbers(noise, (N_IN,), "learner state's input_noise"))
        learner.a = saved_numbers(state["a"], (N_OUT, N_IN), "learner state's a")
        learner.b = saved_numbers(state["b"], (N_OUT,), "learner state's b")
        set_rng_state(learner._rng, state["rng"])
        prec = state.get("dq_precision")  # absent from files made before it
        learner.dq_precision = None if prec is None else saved_numbers(
            prec, (7, 7), "learner state's dq_precision")
        return learner

    def nbytes(self) -> int:
        return (self.a.nbytes + self.b.nbytes + self.center.nbytes + self.scale.nbytes
                + (0 if self.dq_precision is None else self.dq_precision.nbytes))
