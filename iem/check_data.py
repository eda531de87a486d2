"""The data and the helpers the shared check suites run on (:mod:`iem.checks`,
:mod:`iem.capability_checks`): a short path with its tandem samples, and how an estimator
is fitted, trained and compared on it."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from .errors import CheckFailed, InvalidInputError


@dataclass(frozen=True)
class CheckData:
    """A short path with its tandem samples, for the checks.

    Attributes:
        X: measured inputs ``[q, dq, tau]`` of the path's points, ``(N, 21)`` (rad, rad/s, N·m).
        F: flange positions of those points, ``(N, 3)`` m.
        samples_at: ``samples_at(i) -> (Xs (K, 21), Ys (K, 10))``, the training samples at
            point ``i`` (inputs as ``X``, payload parameters phi in kg, kg·m, kg·m²).
        fit_points: indices of the points for an initial ``fit(Q, F, samples_at)`` (only if
            the estimator has ``fit``), or None for none.
        split: the points before ``split`` (not in ``fit_points``) are learnt to train an
            estimator; the points from ``split`` on are the "further points" some checks
            learn afterwards. Default: two thirds of the path.
    """

    X: np.ndarray
    F: np.ndarray
    samples_at: Callable[[int], tuple[np.ndarray, np.ndarray]]
    fit_points: Sequence[int] | None = None
    split: int | None = None

    def __post_init__(self) -> None:
        X = np.asarray(self.X, dtype=float)
        F = np.asarray(self.F, dtype=float)
        if X.ndim != 2 or X.shape[1] != 21 or F.shape != (X.shape[0], 3) or len(X) < 2:
            raise InvalidInputError(f"CheckData needs X (N, 21) and F (N, 3) with N >= 2, "
                             f"got {X.shape} and {F.shape}")
        object.__setattr__(self, "X", X)
        object.__setattr__(self, "F", F)
        split = 2 * len(X) // 3 if self.split is None else int(self.split)
        if not 0 < split < len(X):
            raise InvalidInputError(f"split must lie in 1..{len(X) - 1}, got {split}")
        object.__setattr__(self, "split", split)

    @property
    def n(self) -> int:
        return self.X.shape[0]

    def train_points(self) -> list[int]:
        """The points learnt one by one to train an estimator (before ``split``)."""
        skip = set() if self.fit_points is None else {int(i) for i in self.fit_points}
        return [i for i in range(self.split) if i not in skip]

    def further_points(self) -> list[int]:
        """The points learnt after training (from ``split`` on)."""
        return list(range(self.split, self.n))


# -- helpers -----------------------------------------------------------------------------
def fail(check: str, message: str) -> CheckFailed:
    """The failure of ``check``, saying ``message``."""
    return CheckFailed(f"{check}: {message}")


def identical(a, b) -> bool:
    """Same shape and the same bits (NaN where the other has NaN)."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    return a.shape == b.shape and a.tobytes() == b.tobytes()


def same_params(a, b) -> bool:
    """Equality of plain hyper-parameter values (NaN equals NaN, arrays by value)."""
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(same_params(a[k], b[k]) for k in a)
    if isinstance(a, list | tuple | np.ndarray) or isinstance(b, list | tuple | np.ndarray):
        try:
            return np.array_equal(np.asarray(a), np.asarray(b), equal_nan=True)
        except TypeError:
            return np.array_equal(np.asarray(a), np.asarray(b))
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    return type(a) is type(b) and a == b


def fit(est, data: CheckData, readonly: bool = False) -> None:
    """``est.fit`` on the data's fit points, where the data have them and ``est`` has ``fit``
    (``readonly``: its inputs not writeable)."""
    if data.fit_points is None or not hasattr(est, "fit"):
        return
    idx = np.asarray(data.fit_points, dtype=int)
    Q = data.X[idx, :7].copy()
    F = data.F[idx].copy()
    if readonly:
        Q.flags.writeable = False
        F.flags.writeable = False

    def samples_at(i: int):
        return samples(data, int(idx[i]), readonly)

    est.fit(Q, F, samples_at)


def samples(data: CheckData, i: int, readonly: bool = False):
    """The training samples at point ``i`` as fresh arrays (``readonly``: not writeable)."""
    Xs, Ys = data.samples_at(i)
    Xs = np.array(Xs, dtype=float)
    Ys = np.array(Ys, dtype=float)
    if readonly:
        Xs.flags.writeable = False
        Ys.flags.writeable = False
    return Xs, Ys


def learn(est, data: CheckData, i: int) -> None:
    """``est`` learns point ``i``."""
    est.learn_one(data.X[i].copy(), data.F[i].copy(), samples(data, i))


def train(est, data: CheckData):
    """Fit (if the data and the estimator allow) and learn the training points."""
    fit(est, data)
    for i in data.train_points():
        learn(est, data, i)
    return est


def predictions(est, data: CheckData) -> np.ndarray:
    """``est``'s estimates at every point of the path, by ``predict_many``."""
    return np.asarray(est.predict_many(data.X.copy(), data.F.copy()), dtype=float)


def predictions_one(est, data: CheckData) -> np.ndarray:
    """``est``'s estimates at every point of the path, by ``predict_one``."""
    return np.array([np.asarray(est.predict_one(data.X[i].copy(), data.F[i].copy()).phi,
                                dtype=float) for i in range(data.n)])


def learn_together(a, b, data: CheckData, points):
    """``a`` and ``b`` learn each point in turn and estimate at it; the first point where the
    estimates differ, as ``(i, phi_a, phi_b)``, or None."""
    for i in points:
        learn(a, data, i)
        learn(b, data, i)
        pa = a.predict_one(data.X[i].copy(), data.F[i].copy()).phi
        pb = b.predict_one(data.X[i].copy(), data.F[i].copy()).phi
        if not identical(pa, pb):
            return i, pa, pb
    return None
