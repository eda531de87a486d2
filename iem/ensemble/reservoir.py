"""A uniform sample of the points of the bag being formed (reservoir sampling, Algorithm R).

While a bag forms, its learner is trained one point at a time and follows the path; when
the bag closes, :class:`iem.ensemble.IncrementalEnsemble` trains it once more on a uniform
sample of all the bag's points (their tandem samples), kept here, so that the frozen learner
serves the whole bag and not only its last stretch. The sample has a fixed size whatever
the bag's length: each new point replaces a random kept one with probability
``capacity / points seen``. Seeded, so it is reproducible.
"""

from __future__ import annotations

import numpy as np

from .learner import rng_state, set_rng_state


class Reservoir:
    """Up to ``capacity`` ``(X (K, n_in), Y (K, n_out))`` pairs, a uniform sample of those seen."""

    def __init__(self, capacity: int, seed) -> None:
        self.capacity = int(capacity)
        self.seen = 0
        self._rng = np.random.default_rng(seed)
        self._X: list[np.ndarray] = []
        self._Y: list[np.ndarray] = []

    def __len__(self) -> int:
        return len(self._X)

    def _targets(self, Y) -> np.ndarray:
        # the tandem simulators give the same family targets at every point: keep one copy
        if self._Y and (Y is self._Y[0] or np.array_equal(Y, self._Y[0])):
            return self._Y[0]
        return np.array(Y, dtype=float)

    def add(self, X, Y) -> None:
        self.seen += 1
        if len(self._X) < self.capacity:
            self._X.append(np.array(X, dtype=float))
            self._Y.append(self._targets(Y))
            return
        j = int(self._rng.integers(self.seen))
        if j < self.capacity:
            self._X[j] = np.array(X, dtype=float)
            self._Y[j] = self._targets(Y)

    def stacked(self) -> tuple[np.ndarray, np.ndarray]:
        """All kept samples stacked: ``(sum K, n_in)`` and ``(sum K, n_out)``."""
        return np.vstack(self._X), np.vstack(self._Y)

    def batch(self) -> int:
        """Samples per kept point (the mini-batch of one point)."""
        return self._X[0].shape[0] if self._X else 1

    def nbytes(self) -> int:
        return sum(x.nbytes for x in self._X) + sum(y.nbytes for y in {id(y): y for y in
                                                                       self._Y}.values())

    def to_state(self) -> dict:
        return {"capacity": self.capacity, "seen": self.seen, "rng": rng_state(self._rng),
                "X": [x.tobytes() for x in self._X], "Y": [y.tobytes() for y in self._Y],
                "shapes": [[list(x.shape), list(y.shape)] for x, y in
                           zip(self._X, self._Y, strict=True)]}

    @classmethod
    def from_state(cls, state: dict) -> Reservoir:
        r = cls(state["capacity"], 0)
        set_rng_state(r._rng, state["rng"])
        r.seen = int(state["seen"])
        for xb, yb, (xs, ys) in zip(state["X"], state["Y"], state["shapes"], strict=True):
            r._X.append(np.frombuffer(xb, dtype=float).reshape(xs).copy())
            r._Y.append(np.frombuffer(yb, dtype=float).reshape(ys).copy())
        return r
