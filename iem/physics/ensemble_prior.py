"""The ensemble as IEM+phys's prior: how sure each bag's learner is, and what its estimates
since the last payload change say (:mod:`iem.physics.prior_summary` holds the statistics).

:class:`EnsemblePrior` keeps, beside the held :class:`iem.ensemble.IncrementalEnsemble`:

- the per-bag calibration (:class:`~iem.physics.prior_summary.BagCalibration`) with the slot
  generation it was measured for: a slot the ensemble reused for a new bag (its budget)
  forgets the retired bag's errors, so the new learner is not judged by them;
- the summary of the ensemble's estimates since the last change
  (:class:`~iem.physics.prior_summary.PriorSummary`), each with its bag and, out of distribution,
  the extra uncertainty of an input the learner was not trained for.

It gives the prior as ``(mu_p, C_p)`` before the model's own scale and floor:
:meth:`summarised` from the summary, :meth:`at` from one estimate at an input.
"""

from __future__ import annotations

import numpy as np

from ..ensemble.model import IncrementalEnsemble
from .prior_summary import BagCalibration, PriorSummary

__all__ = ["EnsemblePrior"]


class EnsemblePrior:
    """Calibration and summary of an ensemble's estimates (see the module docstring)."""

    def __init__(self, ensemble: IncrementalEnsemble) -> None:
        self.ensemble = ensemble
        self.calib = BagCalibration()
        self.calib_gen: list[int] = []  # the slot generation each calibration belongs to
        self.summary = PriorSummary()

    # -- calibration ---------------------------------------------------------------------
    def current(self, bag: int) -> None:
        """Forget ``bag``'s calibration if its slot now holds another bag."""
        gen = self.ensemble.slot_generation(bag)
        while len(self.calib_gen) <= bag:
            self.calib_gen.append(0)
        if self.calib_gen[bag] != gen:
            self.calib.forget(bag)
            self.calib_gen[bag] = gen

    def calibrate(self, bag: int, X, Y) -> None:
        """Add a bag's learner's errors on labelled samples to the bag's covariance."""
        self.current(bag)
        Y = np.asarray(Y, dtype=float)
        err = self.ensemble.learner(bag).predict_many(X) - Y
        self.calib.add(bag, err, Y)

    def calibrate_trained(self) -> None:
        """Add the errors of the points the ensemble has learnt since the last call (its
        :meth:`~iem.ensemble.IncrementalEnsemble.trained_errors`: the learner after each
        point, on the point's samples; measured in the learning worker, added here, in the
        caller's thread, so the covariances are only ever changed by it)."""
        for bag, gen, err, Y in self.ensemble.trained_errors():
            self.current(bag)
            if self.calib_gen[bag] == gen:  # the slot was not reused since
                self.calib.add(bag, err, Y)

    def ood_factor(self, est) -> float:
        """How much less sure an ensemble estimate is than its bag's calibration says:
        ``(score / threshold)²`` once its input lies beyond the bag's training distribution
        (:meth:`iem.ensemble.IncrementalEnsemble.ood_score`), else 1."""
        score = est.extra.get("ood_score", 0.0) if est.extra else 0.0
        return max(1.0, score / self.ensemble.ood_threshold) ** 2

    def bag_cov(self, bag: int) -> np.ndarray:
        """The bag's learner's error covariance (a weak default if never measured)."""
        self.current(bag)
        if self.calib.measured(bag):
            return self.calib.cov(bag)
        learner = self.ensemble.learner(bag)
        return np.diag(np.square((learner.hi - learner.lo) / 4.0))

    def noise_cov(self, bag: int, x: np.ndarray) -> np.ndarray:
        """Covariance of the learner's output from the sensor noise on its input ``x``."""
        learner = self.ensemble.learner(bag)
        if learner.input_noise is None:
            return np.zeros((10, 10))
        z = (x - learner.center) / learner.scale
        active = (learner.a @ z + learner.b) > 0.0
        a = learner.a * (learner.input_noise / learner.scale)
        a = a * (active * (learner.hi - learner.lo))[:, None]
        return a @ a.T

    # -- the summary ---------------------------------------------------------------------
    def add(self, est, x: np.ndarray) -> bool:
        """Summarise one ensemble estimate ``est`` made at input ``x``; False if it has no
        bag or is not finite (not summarised)."""
        if est.bag < 0 or not np.isfinite(est.phi).all():
            return False
        summary = self.summary
        if summary.n == 0:
            summary.noise0 = self.noise_cov(est.bag, x)
        factor = self.ood_factor(est)  # out of distribution: the physics governs
        summary.add(est.phi, est.bag,
                    None if factor == 1.0 else (factor - 1.0) * self.bag_cov(est.bag))
        return True

    def summarised(self) -> tuple[np.ndarray, np.ndarray]:
        """``(mu_p, C_p)`` of the estimates summarised since the last change (at least one)."""
        return self.summary.mean_cov(self.bag_cov, self.calib.widen)

    def at(self, x, flange) -> tuple[np.ndarray, np.ndarray] | None:
        """``(mu_p, C_p)`` of the ensemble's estimate at ``x`` alone: its bag's covariance
        (widened for its mass and out of distribution) plus its input noise; None if no bag
        gives a finite estimate."""
        est = self.ensemble.predict_raw(x, flange)
        if est.bag < 0 or not np.all(np.isfinite(est.phi)):
            return None
        mean = est.phi
        cov = (self.calib.widen(self.bag_cov(est.bag) * self.ood_factor(est), float(mean[0]))
               + self.noise_cov(est.bag, np.asarray(x, float)))
        return mean, cov

    def nbytes(self) -> int:
        return self.calib.nbytes() + self.summary._buf.nbytes + self.summary._sum_outer.nbytes
