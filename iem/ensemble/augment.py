"""Training beyond the path: the samples a bag's learner trains on besides its own.

Both are off by default (the paper's rule) and apply where a bag's learner is trained on a
batch of kept samples: the initial bags' fit and the refit when a bag closes
(:class:`iem.ensemble.IncrementalEnsemble`).

Each is a spec of :data:`iem.factories.FACTORIES` (nothing else is accepted, nothing else
imported):

- ``coverage``: ``"module:function"`` of a factory of ``f(q, phi (K, 10), rng) -> X (K,
  21)``, the training family's samples at pose ``q`` with another velocity and acceleration
  (``"sim.coverage:other_velocities"``): each kept point adds ``draws`` such states, so the
  learner covers motions through its poses other than those that formed it (it also costs
  the closed bags their fit to their own motion: docs/decisions.md, "Training beyond the
  path").
- ``reversal``: ``"module:function[@ARG]"`` of a factory of ``f(X (N, 21)) -> X (N, 21)``,
  the samples of the same motion driven backwards (``"sim.coverage:reversed_velocities"``,
  ``...@arm:CRC32`` on a calibrated arm, given at run time; exact for rigid-body torques,
  :mod:`sim.coverage`):
  every sample, covered ones included, is added driven backwards, so a pose met again the
  other way reads as it did the first.

The factories are code, not data: a copy shares the reversal (immutable), and a pickle holds
only the specs and builds them again (in a process the arm it references was given to).
"""

from __future__ import annotations

import numpy as np

from ..factories import build, parse

__all__ = ["TrainingAugment"]


class TrainingAugment:
    """The coverage and reversal of one ensemble's training batches.

    Args:
        coverage: the coverage factory's spec, or None (checked now, built when first
            needed).
        draws: other states per kept point (coverage).
        reversal: the reversal factory's spec, or None (built now: a bad spec or an arm not
            given fails here, not at the first refit).

    Raises:
        InvalidInputError: a spec is not one of :data:`iem.factories.FACTORIES`, or the arm
            the reversal references was not given.
    """

    def __init__(self, coverage: str | None = None, draws: int = 1,
                 reversal: str | None = None) -> None:
        if coverage is not None:
            parse(coverage, "coverage")
        self.coverage = coverage
        self.draws = int(draws)
        self.reversal = reversal
        self.reverse = None if reversal is None else build(reversal, "reversal")
        self._cover = None  # the coverage sampler, built when first needed

    def __call__(self, X: np.ndarray, Y: np.ndarray, batch: int, seed) -> tuple:
        """``(X, Y)`` plus, if ``coverage``, ``draws`` other states at each point's pose
        (``batch`` samples per point, in order); then, if ``reversal``, all of those driven
        backwards (:meth:`reversed`)."""
        if self.coverage is None or self.draws <= 0:
            return self.reversed(X, Y)
        if self._cover is None:
            self._cover = build(self.coverage, "coverage")
        rng = np.random.default_rng(seed)
        n = X.shape[0]
        # filled in place, not stacked from a list: a bag's samples are tens of MB, and a
        # list of per-point arrays beside its stacked copy doubled the peak (and the heap
        # it leaves behind)
        X_out = np.empty((n * (1 + self.draws), X.shape[1]))
        Y_out = np.empty((X_out.shape[0], Y.shape[1]))
        X_out[:n], Y_out[:n] = X, Y
        r = n
        for s in range(0, n, batch):
            q, phi = X[s, :7], Y[s:s + batch]
            for _ in range(self.draws):
                x = self._cover(q, phi, rng)
                X_out[r:r + len(x)], Y_out[r:r + len(x)] = x, phi
                r += len(x)
        return self.reversed(X_out[:r], Y_out[:r])

    def beyond(self, X: np.ndarray, Y: np.ndarray, batch: int, seed):
        """Only what :meth:`__call__` adds to ``(X, Y)`` (the same rows, in its order), or
        None if nothing: without coverage, the samples driven backwards alone (no copy of
        ``(X, Y)`` made)."""
        if self.coverage is None or self.draws <= 0:
            return None if self.reverse is None else (self.reverse(X), Y)
        X_all, Y_all = self(X, Y, batch, seed)
        n = X.shape[0]
        return X_all[n:], Y_all[n:]

    def reversed(self, X: np.ndarray, Y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(X, Y)`` and, if ``reversal``, the same samples driven backwards."""
        if self.reverse is None:
            return X, Y
        return np.concatenate((X, self.reverse(X))), np.concatenate((Y, Y))

    def __deepcopy__(self, memo):
        new = type(self).__new__(type(self))  # not copy.copy: that would go through the
        new.__dict__.update(self.__dict__)  # pickle state and build the reversal again
        new._cover = None  # the specs are strings; the reversal is shared
        memo[id(self)] = new
        return new

    def __getstate__(self) -> dict:
        return {"coverage": self.coverage, "draws": self.draws, "reversal": self.reversal}

    def __setstate__(self, state: dict) -> None:
        self.__init__(state["coverage"], state["draws"], state["reversal"])
