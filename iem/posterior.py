"""IEM+phys's payload posterior: a Gaussian prior and linear equations in information form.

The data are equations ``r = Y phi + e``, ``e ~ N(0, R)`` (:mod:`iem.regression`), kept in an
:class:`EquationWindow` as their sufficient statistics ``info = sum Y^T (c R)^-1 Y`` and
``eta = sum Y^T (c R)^-1 r`` (``c``: how many equations one independent one is worth, see
:attr:`iem.regression.PayloadRegression.correlation_weight`). :func:`combine` fuses them with a
prior ``N(mu_p, C_p)`` whose covariance the data may inflate (:func:`prior_inflation`) into a
:class:`Posterior`: precision ``Lambda = (s² C_p)^-1 + info``, mean
``Lambda^-1 ((s² C_p)^-1 mu_p + eta)``; its physically consistent point (the mean projected
in the metric ``Lambda``, :func:`iem.consistency.project`) and standard deviations are made
once, on first use.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .consistency import EPS, project
from .small_linalg import eigh, sym_inv

MAX_INFLATION = 1e6
"""Largest factor :func:`prior_inflation` puts on the prior covariance."""


_COARSE = np.linspace(0.0, math.log(MAX_INFLATION), 49)
_FINE = np.linspace(0.0, 1.0, 33)  # a bracket of the coarse grid, refined


def prior_inflation(mu_p, c_p, info, eta) -> float:
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
    """
    d, U = eigh(0.5 * (info + info.T))
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
    """The equations since the last payload change, in information form."""

    def __init__(self) -> None:
        self.info = np.zeros((10, 10))
        self.eta = np.zeros(10)
        self.m = 0
        """Equations in the window."""

    def clear(self) -> None:
        self.info[:] = 0.0
        self.eta[:] = 0.0
        self.m = 0

    def add(self, Y: np.ndarray, r: np.ndarray, R: np.ndarray, weight: float = 1.0) -> None:
        """Add ``r = Y phi + e``, ``e ~ N(0, R)``, counted as ``1 / weight`` independent
        equations (its covariance taken as ``weight * R``)."""
        YtRi = Y.T @ sym_inv(R * weight)
        self.info += YtRi @ Y
        self.eta += YtRi @ r
        self.m += 1

    @property
    def empty(self) -> bool:
        return self.m == 0

    def data_std(self) -> np.ndarray:
        """Standard deviation per parameter from the equations alone (inf along directions
        they do not see)."""
        d, U = np.linalg.eigh(0.5 * (self.info + self.info.T))
        if not d.size or d.max() <= 0.0:
            return np.full(10, math.inf)
        seen = d > 1e-12 * d.max()
        var = (U[:, seen] ** 2) @ (1.0 / d[seen])
        var[np.any(np.abs(U[:, ~seen]) > 1e-6, axis=1)] = math.inf
        return np.sqrt(var)

    def to_state(self) -> dict:
        return {"info": self.info.tolist(), "eta": self.eta.tolist(), "m": self.m}

    def set_state(self, state: dict) -> None:
        self.info = np.array(state["info"], dtype=float).reshape(10, 10)
        self.eta = np.array(state["eta"], dtype=float).reshape(10)
        self.m = int(state["m"])


@dataclass
class Posterior:
    """The payload's posterior before the projection, and its consistent point.

    Attributes:
        mean: posterior mean (10, paper order).
        cov: posterior covariance (10x10).
        precision: its inverse (10x10), the projection's metric.
        inflation: the factor the data put on the prior's covariance (1: they agree).
        equations: how many equations it holds (0: the prior alone).
    """

    mean: np.ndarray
    cov: np.ndarray
    precision: np.ndarray
    inflation: float = 1.0
    eps: float = EPS
    equations: int = 0
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
        """Bytes a posterior of ``n`` parameters holds: mean, projected phi and std (``n``
        floats each), covariance and precision (``n x n`` each); what a model reserves for
        one whether it has been made yet or not."""
        return np.dtype(float).itemsize * (3 * n + 2 * n * n)

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
    :func:`prior_inflation` if the data contradict it) and the window's equations."""
    inflation = 1.0
    if not window.empty:
        inflation = prior_inflation(mu_p, c_p, window.info, window.eta)
        c_p = c_p * inflation
    prec_p = sym_inv(c_p)
    precision = prec_p + window.info
    precision = 0.5 * (precision + precision.T)
    cov = sym_inv(precision)
    mean = cov @ (prec_p @ mu_p + window.eta)
    return Posterior(mean, cov, precision, inflation, eps, window.m)
