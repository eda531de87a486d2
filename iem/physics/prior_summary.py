"""IEM+phys's prior: what the ensemble's estimates since the last payload change say.

- :class:`BagCalibration` (learnt with the model, kept forever): per bag, the covariance of
  its learner's error measured on labelled samples (the tandem samples of the training
  payloads at the bag's points: learner output minus the true phi). A learner sees 7 torques
  and outputs 10 parameters, so at one instant 3 directions (mostly inertia) are guessed from
  the family; that spread is what this covariance measures.
  Its errors grow with the payload: on the deploy family, the RMS com error of payloads of
  2.5-3 kg is three times that of 1.5-2 kg ones, the inertia's 2.6 times. So the calibration
  also keeps, pooled over all bags, the mean squared error per parameter in bins of the
  training payload's true mass (:data:`MASS_BINS`); :meth:`BagCalibration.scale` gives, for
  the estimated mass, the factor on each parameter's standard deviation relative to the
  pooled error (never below 1), so a heavy tool's prior is as unsure as the learners are for
  heavy tools.
- :class:`PriorSummary` (per payload, restarted at a change): the running mean ``mu_p`` of
  the ensemble's estimates, how many of them each bag made, and their scatter. The prior's
  covariance is the mean of the estimating bags' error covariances plus the mean's own noise:
  the scatter of the estimates divided by their number, shrunk toward the sensor noise's
  share while there are few (:data:`NOISE_PSEUDO_COUNT` pseudo-samples).

The summary costs one row copy and one counter per sample: estimates are gathered in a block
and folded into the sums (mean, outer products) once per :data:`BLOCK` samples.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from ..errors import InvalidInputError

NOISE_PSEUDO_COUNT = 10
"""Weight, in samples, of the input-noise covariance against the sample covariance of the
ensemble's estimates in the prior's noise term."""
BLOCK = 64
"""Estimates gathered before they are folded into the sums."""
MASS_BINS = (0.5, 1.0, 1.5, 2.0, 2.5)
"""Edges (kg) between the mass bins of the calibration's error table: 0-0.5, ..., 2.5 and
above (the families' payloads reach 3 kg)."""
MIN_BIN_SAMPLES = 100
"""Labelled samples a mass bin needs before its error ratio is used (else the factor is 1)."""
SCALE_RANGE = (1.0, 4.0)
"""Bounds of :meth:`BagCalibration.scale`'s factors on a standard deviation. Never below
the pooled calibration: a bin's payloads erring less than the pooled ones says nothing of an
off-family tool of that mass (a 0.4 kg tool's com prior shrunk by the light bin's 0.65 was
2σ-covered 0.70-0.77 of the time on ``bench realistic`` seeds 0-1)."""


class BagCalibration:
    """Per bag, the error covariance of its learner on labelled samples."""

    def __init__(self) -> None:
        self._sum: list[np.ndarray] = []  # per bag: sum of e e^T
        self._n: list[int] = []
        self._cov: dict[int, np.ndarray] = {}  # cache of sum / n
        self._bin_sq = np.zeros((len(MASS_BINS) + 1, 10))  # all bags: sum of e² per mass bin
        self._bin_n = np.zeros(len(MASS_BINS) + 1, dtype=np.int64)

    def __len__(self) -> int:
        return len(self._sum)

    def grow(self, n_bags: int) -> None:
        while len(self._sum) < n_bags:
            self._sum.append(np.zeros((10, 10)))
            self._n.append(0)

    def add(self, bag: int, errors: np.ndarray, truth: np.ndarray | None = None) -> None:
        """Add a bag's learner's errors ``(K, 10)`` on labelled samples whose true
        parameters are ``truth`` ``(K, 10)`` (their masses feed the mass-bin table)."""
        self.grow(bag + 1)
        self._sum[bag] += errors.T @ errors
        self._n[bag] += errors.shape[0]
        self._cov.pop(bag, None)
        if truth is not None:
            mass = np.asarray(truth, dtype=float)[:, 0]
            if mass.shape[0] != errors.shape[0]:
                raise InvalidInputError(f"errors {errors.shape} and truth "
                                        f"{np.shape(truth)} differ in samples")
            k = np.searchsorted(MASS_BINS, mass, side="right")
            np.add.at(self._bin_sq, k, np.square(errors))
            self._bin_n += np.bincount(k, minlength=self._bin_n.size)

    def scale(self, mass: float) -> np.ndarray | None:
        """Per parameter, the factor on a calibrated standard deviation for a payload of
        ``mass`` kg: ``sqrt`` of its mass bin's mean squared error over the pooled one,
        within :data:`SCALE_RANGE`; None while the bin holds fewer than
        :data:`MIN_BIN_SAMPLES` samples (or ``mass`` is not finite)."""
        if not math.isfinite(mass):
            return None
        k = int(np.searchsorted(MASS_BINS, mass, side="right"))
        n_all = int(self._bin_n.sum())
        if self._bin_n[k] < MIN_BIN_SAMPLES:
            return None
        pooled = self._bin_sq.sum(axis=0) / n_all
        ratio = (self._bin_sq[k] / self._bin_n[k]) / np.maximum(pooled, 1e-300)
        return np.clip(np.sqrt(ratio), *SCALE_RANGE)

    def widen(self, cov: np.ndarray, mass: float) -> np.ndarray:
        """``cov`` (a learner error covariance) with its standard deviations scaled by
        :meth:`scale` for a payload of ``mass`` kg (``cov`` itself when there is no factor)."""
        d = self.scale(mass)
        return cov if d is None else d[:, None] * cov * d[None, :]

    def measured(self, bag: int) -> bool:
        return bag < len(self._n) and self._n[bag] > 0

    def forget(self, bag: int) -> None:
        """Drop what was measured of ``bag`` (its slot now holds another bag)."""
        if bag < len(self._sum):
            self._sum[bag][:] = 0.0
            self._n[bag] = 0
            self._cov.pop(bag, None)

    def cov(self, bag: int) -> np.ndarray:
        """The bag's error covariance (only if :meth:`measured`)."""
        cov = self._cov.get(bag)
        if cov is None:
            cov = self._cov[bag] = self._sum[bag] / self._n[bag]
        return cov

    def nbytes(self) -> int:
        return (sum(c.nbytes + 8 for c in self._sum) + self._bin_sq.nbytes
                + self._bin_n.nbytes)

    def to_state(self) -> dict:
        return {"calib": [c.tolist() for c in self._sum], "calib_n": list(self._n),
                "calib_bins": {"sq": self._bin_sq.tolist(), "n": self._bin_n.tolist()}}

    def set_state(self, state: dict) -> None:
        self._sum = [np.array(c, dtype=float).reshape(10, 10) for c in state["calib"]]
        self._n = [int(n) for n in state["calib_n"]]
        self._cov = {}
        bins = state.get("calib_bins")  # files from before the table: factors stay 1
        self._bin_sq = np.zeros((len(MASS_BINS) + 1, 10))
        self._bin_n = np.zeros(len(MASS_BINS) + 1, dtype=np.int64)
        if bins is not None:
            self._bin_sq[:] = np.array(bins["sq"], dtype=float).reshape(self._bin_sq.shape)
            self._bin_n[:] = np.array(bins["n"], dtype=np.int64).reshape(self._bin_n.shape)


class PriorSummary:
    """The ensemble's estimates since the last payload change, summarised."""

    def __init__(self) -> None:
        self._buf = np.empty((BLOCK, 10))
        self.clear()

    def clear(self) -> None:
        self.n = 0
        """Estimates summarised."""
        self.noise0 = np.zeros((10, 10))
        """Covariance of the first estimate from the sensor noise on its input."""
        self._k = 0
        self._sum_phi = np.zeros(10)
        self._sum_outer = np.zeros((10, 10))
        self._counts: dict[int, int] = {}
        self._sum_c_base = np.zeros((10, 10))  # from a state saved before bag counts

    def add(self, phi: np.ndarray, bag: int, extra_cov: np.ndarray | None = None) -> None:
        """One estimate ``phi`` made by ``bag``'s learner; ``extra_cov`` is added to its
        error covariance (an estimate the learner was not trained for is less sure)."""
        if extra_cov is not None:
            self._sum_c_base += extra_cov
        self._buf[self._k] = phi
        self._k += 1
        if self._k == BLOCK:
            self._fold()
        self._counts[bag] = self._counts.get(bag, 0) + 1
        self.n += 1

    def _fold(self) -> None:
        if self._k:
            block = self._buf[:self._k]
            self._sum_phi += block.sum(axis=0)
            self._sum_outer += block.T @ block
            self._k = 0

    def mean_cov(self, bag_cov: Callable[[int], np.ndarray],
                 widen: Callable[[np.ndarray, float], np.ndarray] | None = None,
                 ) -> tuple[np.ndarray, np.ndarray]:
        """``(mu_p, C_p)``; ``bag_cov(bag)`` gives a bag's learner's error covariance and
        ``widen(cov, mass)`` scales the summed covariance for the mean's mass
        (:meth:`BagCalibration.widen`)."""
        self._fold()
        n = self.n
        mean = self._sum_phi / n
        scatter = self._sum_outer - n * np.outer(mean, mean)
        k = NOISE_PSEUDO_COUNT
        noise = (k * self.noise0 + scatter) / (k + n - 1)
        sum_c = self._sum_c_base.copy()
        for bag, count in self._counts.items():
            sum_c += count * bag_cov(bag)
        if widen is not None:
            sum_c = widen(sum_c, float(mean[0]))
        return mean, sum_c / n + noise / n

    def to_state(self) -> dict:
        self._fold()
        return {"n": self.n, "sum_phi": self._sum_phi.tolist(),
                "sum_outer": self._sum_outer.tolist(), "noise0": self.noise0.tolist(),
                "bag_counts": [[int(b), int(c)] for b, c in self._counts.items()],
                "sum_c_base": self._sum_c_base.tolist()}

    def set_state(self, state: dict) -> None:
        self.clear()
        self.n = int(state["n"])
        self._sum_phi = np.array(state["sum_phi"], dtype=float).reshape(10)
        self._sum_outer = np.array(state["sum_outer"], dtype=float).reshape(10, 10)
        self.noise0 = np.array(state["noise0"], dtype=float).reshape(10, 10)
        if "bag_counts" in state:
            self._counts = {int(b): int(c) for b, c in state["bag_counts"]}
            self._sum_c_base = np.array(state["sum_c_base"], dtype=float).reshape(10, 10)
        else:  # a file from before the per-bag counts: its sum of covariances as it was
            self._sum_c_base = np.array(state["sum_c"], dtype=float).reshape(10, 10)
