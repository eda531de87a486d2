"""IEM+phys's payload posterior: a Gaussian prior and linear equations in information form.

The data are equations ``r = Y phi + e``, ``e ~ N(0, R)`` (:mod:`iem.physics.regression`), kept in
an :class:`EquationWindow` as their sufficient statistics ``info = sum Y^T (c R)^-1 Y`` and
``eta = sum Y^T (c R)^-1 r`` (``c``: how many equations one independent one is worth, see
:attr:`iem.physics.regression.PayloadRegression.correlation_weight`). :func:`combine` fuses them
with a prior ``N(mu_p, C_p)`` whose covariance the data may inflate (:func:`prior_inflation`) into a
:class:`Posterior`: precision ``Lambda = (s² C_p)^-1 + info``, mean
``Lambda^-1 ((s² C_p)^-1 mu_p + eta)``; its physically consistent point (the mean projected
in the metric ``Lambda``, :func:`iem.physics.consistency.project`) and standard deviations are made
once, on first use.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .consistency import EPS, project
from .small_linalg import cholesky, cholesky_inverse, cholesky_solve, eigh, sym_inv

DEFAULT_PRIOR_STD = (3.0, 0.3, 0.3, 0.3, 0.01, 0.01, 0.01, 0.01, 0.01, 0.01)
"""Prior standard deviation per parameter (kg, kg·m, kg·m²) where nothing else is known: the
Panda's rated payload (LS's prior, IEM+phys's before the ensemble has any bag, the
commissioning identification's)."""

MAX_INFLATION = 1e6
"""Largest factor :func:`prior_inflation` puts on the prior covariance."""


_COARSE = np.linspace(0.0, math.log(MAX_INFLATION), 49)
_FINE = np.linspace(0.0, 1.0, 33)  # a bracket of the coarse grid, refined


def prior_inflation(mu_p, c_p, info, eta, eig=None) -> float:
    """The factor ``s² >= 1`` on the prior covariance that makes the data most likely.

    The data's sufficient statistics ``eta = sum Y^T R^-1 r`` and ``info = sum Y^T R^-1 Y``
    have, under the prior ``phi ~ N(mu_p, s² C_p)``, ``eta ~ N(info mu_p, info + s² info C_p
    info)``. Whitened by ``info`` and diagonalised (``gamma_i``: how much sharper the data
    are than the prior along direction ``i``, ``a_i``: the whitened prior-data difference),
    the log-likelihood is ``-1/2 sum [log(1 + s² gamma_i) + a_i² / (1 + s² gamma_i)]``; this
    returns its maximiser over ``[1, MAX_INFLATION]`` (empirical Bayes). It stays 1 while the
    data agree with the prior, and grows when they show the prior's mean off by more than
    its covariance allows (e.g. an ensemble far outside its training data): then the prior's
    claims elsewhere, e.g. on the inertia the data barely see, are not trusted either.
    ``eig``: ``eigh(0.5 (info + info^T))`` if the caller has it already
    (:meth:`EquationWindow.info_eigh`).
    """
    d, U = eigh(0.5 * (info + info.T)) if eig is None else eig
    keep = d > 1e-9 * max(float(d.max()), 1e-300)
    if not keep.any():
        return 1.0
    U, root = U[:, keep], np.sqrt(d[keep])
    v = (U.T @ (eta - info @ mu_p)) / root
    G = root[:, None] * (U.T @ c_p @ U) * root[None, :]
    gamma, V = eigh(0.5 * (G + G.T))
    gamma = np.maximum(gamma, 0.0)
    a2 = np.square(V.T @ v)

    def slope(log_s2: np.ndarray) -> np.ndarray:  # 2 d(log-likelihood)/d(s²) on a grid
        k = 1.0 + np.exp(log_s2)[:, None] * gamma[None, :]
        return np.sum(gamma * (a2 / (k * k) - 1.0 / k), axis=1)

    grid = _COARSE
    g = slope(grid)
    if g[0] <= 0.0:
        return 1.0
    for _refine in range(2):  # the first sign change of the slope, on finer grids
        down = np.flatnonzero(g <= 0.0)
        if down.size == 0:
            return MAX_INFLATION
        i = int(down[0])
        grid = grid[i - 1] + (grid[i] - grid[i - 1]) * _FINE
        g = slope(grid)
    i = int(np.flatnonzero(g <= 0.0)[0])  # the last bracket: interpolate the slope
    w = g[i - 1] / (g[i - 1] - g[i])
    return float(math.exp(grid[i - 1] + w * (grid[i] - grid[i - 1])))


class EquationWindow:
    """The equations since the last payload change, in information form.

    Args:
        offset_var: prior variance (7, (N·m)²) of a constant torque offset per joint that
            every equation of the window shares (:attr:`iem.physics.torque_noise.TorqueNoise.
            offset_std` squared), or None: no offsets. The offsets are states ``o`` of the
            equations ``r = Y phi + o + e``, marginalised: the window keeps the sums
            ``sum Y^T W``, ``sum W`` and ``sum W r`` beside ``info`` and ``eta`` (``W =
            (c R)^-1``), and :attr:`info` and :attr:`eta` are those of ``phi`` alone,
            ``info_phi - S (sum W + P_o)^-1 S^T`` and likewise for ``eta`` (``S = sum Y^T
            W``, ``P_o`` the offsets' prior precision): what the data say about the payload
            once any constant offset within its prior is allowed for.
        gain_var: variance (7, -) of a relative gain error per joint that scales the
            payload's torque in every equation of the window, ``r = (I + diag(g)) Y phi +
            o + e`` (:attr:`iem.physics.torque_noise.TorqueNoise.gain_std` squared), or
            None: none. The gains are considered, not estimated: the window keeps
            ``sum Y^T W diag(Y e_b)`` and ``sum W diag(Y e_b)`` per parameter ``b`` (linear
            in ``phi``), from which :meth:`gain_sensitivity` gives what a unit gain error
            adds to ``eta``, and :func:`combine` the covariance the gains add to the
            estimate (:attr:`Posterior.gain_var`).
    """

    def __init__(self, offset_var=None, gain_var=None) -> None:
        self._priors = (offset_var, gain_var)
        self.offset_prec = (None if offset_var is None else
                            1.0 / np.asarray(offset_var, dtype=float).reshape(7))
        self._offset_prec_matrix = None if offset_var is None else np.diag(self.offset_prec)
        self.gain_var = (None if gain_var is None or not np.any(gain_var) else
                         np.asarray(gain_var, dtype=float).reshape(7))
        self._info = np.zeros((10, 10))
        self._eta = np.zeros(10)
        self._cross = np.zeros((10, 7))
        self._w = np.zeros((7, 7))
        self._eta_o = np.zeros(7)
        self._gain = np.zeros((10, 7, 10))  # sum Y^T W diag(Y e_b), b the last axis
        self._gain_o = np.zeros((7, 7, 10))  # sum W diag(Y e_b)
        self._arm: np.ndarray | None = None  # sum Y^T W A, A the arm's sensitivity (10 x k)
        self._arm_o: np.ndarray | None = None  # sum W A (7 x k)
        self._marginal: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self._factor: np.ndarray | None = None  # Cholesky factor of sum W + P_o, made once
        self._eig: tuple[np.ndarray, np.ndarray] | None = None  # of info, made once
        self.m = 0
        """Equations in the window."""

    def fresh(self) -> EquationWindow:
        """An empty window with the same offsets' and gains' priors."""
        return EquationWindow(*self._priors)

    def clear(self) -> None:
        for a in self._sums():
            a[:] = 0.0
        self._arm = self._arm_o = None
        self._marginal = self._factor = self._eig = None
        self.m = 0

    def _sums(self) -> tuple[np.ndarray, ...]:
        return (self._info, self._eta, self._cross, self._w, self._eta_o, self._gain,
                self._gain_o)

    def add(self, Y: np.ndarray, r: np.ndarray, R: np.ndarray, weight: float = 1.0,
            A: np.ndarray | None = None) -> None:
        """Add ``r = Y phi + e``, ``e ~ N(0, R)``, counted as ``1 / weight`` independent
        equations (its covariance taken as ``weight * R``). ``A`` (7 x k): how the arm
        model's torques at the equation move per unit of its considered parameters
        (:meth:`arm_sensitivity`), or None."""
        W = sym_inv(R * weight)
        YtRi = Y.T @ W
        self._info += YtRi @ Y
        self._eta += YtRi @ r
        if A is not None:
            if self._arm is None:
                self._arm = np.zeros((10, A.shape[1]))
                self._arm_o = np.zeros((7, A.shape[1]))
            self._arm += YtRi @ A
            if self.offset_prec is not None:
                self._arm_o += W @ A
        if self.gain_var is not None:
            self._gain += YtRi[:, :, None] * Y[None, :, :]
        if self.offset_prec is not None:
            self._cross += YtRi
            self._w += W
            self._eta_o += W @ r
            if self.gain_var is not None:
                self._gain_o += W[:, :, None] * Y[None, :, :]
            self._marginal = self._factor = None
        self._eig = None
        self.m += 1

    def _marginalised(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(info, eta, S G)`` with the offsets marginalised (``S G``: the cross sums times
        the offsets' posterior covariance, what carries an offset's share to ``phi``)."""
        if self._marginal is None:
            G = cholesky_inverse(self._offset_factor())
            SG = self._cross @ G
            info = self._info - SG @ self._cross.T
            self._marginal = (0.5 * (info + info.T), self._eta - SG @ self._eta_o, SG)
        return self._marginal

    def _offset_factor(self) -> np.ndarray:
        """The lower Cholesky factor of the offsets' posterior precision ``sum W + P_o``,
        made once per state of the window: the test of each new equation (:meth:`offsets`)
        and the refresh after it (:meth:`_marginalised`) share it."""
        if self._factor is None:
            A = self._w + self._offset_prec_matrix
            self._factor = cholesky(0.5 * (A + A.T))
        return self._factor

    def offset_cov(self) -> np.ndarray | None:
        """The covariance (7x7, (N·m)²) of the torque offsets the window gives for a known
        payload, ``(sum W + P_o)^-1`` (its prior's while the window is empty), or None
        without offsets: how far :meth:`offsets` may still be off."""
        if self.offset_prec is None:
            return None
        return cholesky_inverse(self._offset_factor())

    def info_eigh(self) -> tuple[np.ndarray, np.ndarray]:
        """Eigenvalues (ascending) and eigenvectors of :attr:`info` (symmetrised), made once
        per state of the window: a refresh's :func:`prior_inflation` and :meth:`data_std`
        share them (read them, do not write them)."""
        if self._eig is None:
            info = self.info
            self._eig = eigh(0.5 * (info + info.T))
        return self._eig

    def gain_sensitivity(self, phi: np.ndarray) -> np.ndarray | None:
        """What a unit gain error of each joint adds to :attr:`eta` if the payload is
        ``phi`` (10x7; the estimate moves by the posterior covariance times it), with the
        offsets marginalised; None without gains."""
        if self.gain_var is None:
            return None
        K = self._gain @ phi
        if self.offset_prec is not None:
            K = K - self._marginalised()[2] @ (self._gain_o @ phi)
        return K

    def arm_sensitivity(self) -> np.ndarray | None:
        """What a unit change of each of the arm model's considered parameters adds to
        :attr:`eta` (10 x k; the estimate moves by the posterior covariance times it), with
        the offsets marginalised; None without any (no equation carried a sensitivity)."""
        if self._arm is None:
            return None
        if self.offset_prec is None:
            return self._arm
        return self._arm - self._marginalised()[2] @ self._arm_o

    def offsets(self, phi: np.ndarray) -> np.ndarray | None:
        """The torque offsets (7, N·m) the window's equations give for the payload ``phi``
        (their posterior mean given it), or None without offsets: what a new equation's
        innovation is to be judged net of."""
        if self.offset_prec is None:
            return None
        return cholesky_solve(self._offset_factor(), self._eta_o - self._cross.T @ phi)

    @property
    def info(self) -> np.ndarray:
        """``sum Y^T (c R)^-1 Y``, with the offsets marginalised if there are any."""
        return self._info if self.offset_prec is None else self._marginalised()[0]

    @property
    def eta(self) -> np.ndarray:
        """``sum Y^T (c R)^-1 r``, with the offsets marginalised if there are any."""
        return self._eta if self.offset_prec is None else self._marginalised()[1]

    @property
    def empty(self) -> bool:
        return self.m == 0

    def data_std(self) -> np.ndarray:
        """Standard deviation per parameter from the equations alone (inf along directions
        they do not see)."""
        d, U = self.info_eigh()
        if not d.size or d.max() <= 0.0:
            return np.full(10, math.inf)
        seen = d > 1e-12 * d.max()
        var = (U[:, seen] ** 2) @ (1.0 / d[seen])
        var[np.any(np.abs(U[:, ~seen]) > 1e-6, axis=1)] = math.inf
        return np.sqrt(var)

    def nbytes(self) -> int:
        arm = 0 if self._arm is None else self._arm.nbytes + self._arm_o.nbytes
        return sum(a.nbytes for a in self._sums()) + arm

    def to_state(self) -> dict:
        state = {"info": self._info.tolist(), "eta": self._eta.tolist(), "m": self.m}
        if self.offset_prec is not None:
            state["offsets"] = [self._cross.tolist(), self._w.tolist(), self._eta_o.tolist()]
        if self.gain_var is not None:
            state["gains"] = [self._gain.tolist(), self._gain_o.tolist()]
        if self._arm is not None:
            state["arm"] = [self._arm.tolist(), self._arm_o.tolist()]
        return state

    def set_state(self, state: dict) -> None:
        self._info = np.array(state["info"], dtype=float).reshape(10, 10)
        self._eta = np.array(state["eta"], dtype=float).reshape(10)
        self.m = int(state["m"])
        self._marginal = self._factor = self._eig = None
        offsets = state.get("offsets")
        if self.offset_prec is not None and offsets is not None:
            self._cross = np.array(offsets[0], dtype=float).reshape(10, 7)
            self._w = np.array(offsets[1], dtype=float).reshape(7, 7)
            self._eta_o = np.array(offsets[2], dtype=float).reshape(7)
        elif self.offset_prec is not None and self.m:  # a window of equations without
            self.clear()  # offset sums cannot be marginalised: start it again
        gains = state.get("gains")
        if self.gain_var is not None and gains is not None:
            self._gain = np.array(gains[0], dtype=float).reshape(10, 7, 10)
            self._gain_o = np.array(gains[1], dtype=float).reshape(7, 7, 10)
        elif self.gain_var is not None and self.m:  # without its gain sums a window
            self.clear()  # cannot say what the gains do to its estimate: start it again
        arm = state.get("arm")
        self._arm = self._arm_o = None
        if arm is not None and self.m:
            self._arm = np.array(arm[0], dtype=float).reshape(10, -1)
            self._arm_o = np.array(arm[1], dtype=float).reshape(7, -1)


@dataclass
class Posterior:
    """The payload's posterior before the projection, and its consistent point.

    Attributes:
        mean: posterior mean (10, paper order).
        cov: posterior covariance (10x10).
        precision: its inverse (10x10), the projection's metric.
        inflation: the factor the data put on the prior's covariance (1: they agree).
        equations: how many equations it holds (0: the prior alone).
        gain_var: the variance per parameter (10) the torque sensors' gain errors add to
            the estimate (:class:`EquationWindow`'s ``gain_var``; zeros without). Not
            saved: the window's sums are, and the next refresh makes it again.
        arm_cov: the covariance (10x10) the arm model's considered parameters add to the
            estimate along the window's poses (``J J^T``, ``J`` the posterior covariance
            times :meth:`EquationWindow.arm_sensitivity`; zeros without). Not saved, as
            ``gain_var``.
        prior: the prior's mean it was combined from (10; None: not known). Not saved.
    """

    mean: np.ndarray
    cov: np.ndarray
    precision: np.ndarray
    inflation: float = 1.0
    eps: float = EPS
    equations: int = 0
    gain_var: np.ndarray = field(default_factory=lambda: np.zeros(10))
    arm_cov: np.ndarray = field(default_factory=lambda: np.zeros((10, 10)))
    prior: np.ndarray | None = None
    _phi: np.ndarray | None = field(default=None, repr=False)
    _std: np.ndarray | None = field(default=None, repr=False)

    @property
    def phi(self) -> np.ndarray:
        """The mean projected onto physically consistent parameters in the metric
        ``precision`` (made once; read-only)."""
        if self._phi is None:
            self._phi = project(self.mean, self.precision, eps=self.eps)
            self._phi.flags.writeable = False
        return self._phi

    @property
    def std(self) -> np.ndarray:
        """Standard deviations of the parameters (read-only)."""
        if self._std is None:
            self._std = np.sqrt(np.maximum(np.diag(self.cov), 0.0))
            self._std.flags.writeable = False
        return self._std

    @staticmethod
    def nbytes(n: int = 10) -> int:
        """Bytes a posterior of ``n`` parameters holds: mean, projected phi, std and gain
        variance (``n`` floats each), covariance, precision and the arm's covariance (``n x
        n`` each); what a model reserves for one whether it has been made yet or not."""
        return np.dtype(float).itemsize * (4 * n + 3 * n * n)

    def to_state(self) -> dict:
        return {"mean": self.mean.tolist(), "cov": self.cov.tolist(),
                "precision": self.precision.tolist(), "inflation": self.inflation,
                "equations": self.equations}

    @classmethod
    def from_state(cls, state, eps: float = EPS, equations: int = 0) -> Posterior:
        """From :meth:`to_state`'s dict, or the list ``[mean, cov, precision, inflation]``
        of files from before it (their ``equations`` given by the caller)."""
        if isinstance(state, dict):
            values = [state["mean"], state["cov"], state["precision"]]
            inflation, equations = state["inflation"], state["equations"]
        else:
            values, inflation = state[:3], state[3]
        mean, cov, precision = (np.array(v, dtype=float) for v in values)
        return cls(mean.reshape(10), cov.reshape(10, 10), precision.reshape(10, 10),
                   float(inflation), eps, int(equations))


def combine(mu_p: np.ndarray, c_p: np.ndarray, window: EquationWindow,
            eps: float = EPS) -> Posterior:
    """The posterior of the prior ``N(mu_p, C_p)`` (its covariance inflated by
    :func:`prior_inflation` if the data contradict it) and the window's equations, with the
    variance the window's considered gain errors add to its mean (``J = cov K``, ``K`` the
    window's :meth:`~EquationWindow.gain_sensitivity` at the mean: ``gain_var = sum_j
    g_j² J[:, j]²``) and the covariance its arm model's considered parameters add
    (``J = cov K``, ``K`` the window's :meth:`~EquationWindow.arm_sensitivity`: ``arm_cov =
    J J^T``)."""
    inflation = 1.0
    if not window.empty:
        inflation = prior_inflation(mu_p, c_p, window.info, window.eta, window.info_eigh())
        c_p = c_p * inflation
    prec_p = sym_inv(c_p)
    precision = prec_p + window.info
    precision = 0.5 * (precision + precision.T)
    cov = sym_inv(precision)
    mean = cov @ (prec_p @ mu_p + window.eta)
    gain_var = np.zeros(10)
    K = None if window.empty else window.gain_sensitivity(mean)
    if K is not None:
        J = cov @ K
        gain_var = np.square(J) @ window.gain_var
    arm_cov = np.zeros((10, 10))
    K = None if window.empty else window.arm_sensitivity()
    if K is not None:
        J = cov @ K
        arm_cov = J @ J.T
    return Posterior(mean, cov, precision, inflation, eps, window.m, gain_var=gain_var,
                     arm_cov=arm_cov, prior=np.array(mu_p, dtype=float))
