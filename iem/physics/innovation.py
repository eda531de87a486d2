"""IEM+phys's test of each equation against the posterior: the NIS and the change detector.

An equation ``r = Y phi + e``, ``e ~ N(0, R)`` (:mod:`iem.physics.regression`) has, under the
current posterior ``N(mean, P)``, the innovation ``nu = r - Y mean`` with covariance ``S = R + Y P
Y^T``. Its normalised square ``nu^T S^-1 nu`` per degree of freedom, averaged over the last
:data:`NIS_WINDOW` equations, is the NIS (about 1 while the data fit the model: the safety
gate's check). Once the window holds enough equations for the posterior to stand on its own,
the same innovation feeds the CUSUM of :class:`iem.physics.change.ChangeDetector`, beside the
innovation judged with the filtered equation's model error (:data:`MODEL_ERROR_GAIN`); the
detector adds the smaller of the two.
"""

from __future__ import annotations

import math

import numpy as np

from .change import ChangeDetector, chi_square

__all__ = ["MODEL_ERROR_GAIN", "NIS_WINDOW", "InnovationTest"]

MODEL_ERROR_GAIN = 3.0
"""The change detector's model error: the standard deviation of an equation's error per
joint is this times the second difference of the robot model's torque over the last three
equations (:attr:`iem.physics.regression.PayloadRegression.curvature`, 10 ms apart by default).

A 4 Hz low-pass does not commute with the arm's nonlinear dynamics: where the arm's torque
bends sharply (a fast start from rest), the filtered equations of a perfect arm miss by
0.1-0.3 N·m against a filtered noise of 0.01-0.02 N·m, and once the window holds many
equations that miss reaches a chi² as large as a payload change's. Of the kinematic measures
tried (the first and second differences of the model torque, the mass matrix times the
jerk, ``|ddq|``), the second difference predicts the miss best (correlation 0.61 with
``|nu|``). Kinematic only, so a payload change does not raise it. Judged by it alone, the
detector would raise false alarms of its own: with the sharp bends explained away, the level
stays low and the rest of the misfit counts. So the detector gets both statistics and adds
the smaller (:class:`iem.physics.change.ChangeDetector`): evidence only where both see it.
The gain of 3 keeps ``bench longrun``'s largest evidence on a fixed payload, where the arm
starts fast from rest, far under the detector's threshold (32 against 300; a gain of 1
gives 73, and 10 misses a 48 g change) and still detects 48 g within about 0.1 s and 275 g
within 30 ms. The NIS and the estimate's weights keep the noise alone."""
NIS_WINDOW = 50
"""Equations over which :attr:`InnovationTest.nis` is averaged (0.5 s by default)."""


class InnovationTest:
    """The NIS of the last :data:`NIS_WINDOW` equations and the change detector they feed.

    Args:
        drift, threshold: the detector's CUSUM (:class:`iem.physics.change.ChangeDetector`).
        dof: rows of an equation (the arm's joints).
        level: rescale the detector's statistic by its recent level (a model whose ``R`` is
            the sensor's alone: its misfit at speed is what the level follows); False: the
            raw ``chi2``, for a model whose ``R`` holds the arm's measured error, where a
            payload change stands a few times, not orders of magnitude, above the noise.
    """

    def __init__(self, drift: float, threshold: float, dof: int = 7,
                 level: bool = True) -> None:
        self.dof = int(dof)
        self.detector = (ChangeDetector(self.dof, drift, threshold) if level
                         else ChangeDetector(self.dof, drift, threshold, level_equations=0))
        self._ring = np.zeros(NIS_WINDOW)
        self.reset()

    def reset(self) -> None:
        """Forget the equations and the detector's evidence (a new payload)."""
        self.detector.reset()
        self.count = 0
        """Equations tested since the reset."""
        self.nis = math.nan
        """Mean normalised innovation squared per degree of freedom of the last
        :data:`NIS_WINDOW` equations (NaN before the first)."""
        self.last_nis = math.nan
        """The last equation's normalised innovation squared per degree of freedom."""

    def __call__(self, Y, r, R, mean, cov, detect: bool, curvature=None,
                 R_detect=None) -> bool:
        """Test one equation against the posterior ``N(mean, cov)``: its NIS always, the
        change detector only if ``detect``; True if the detector reports a change. A
        ``curvature`` (7, :attr:`iem.physics.regression.PayloadRegression.curvature`) gives the
        detector the innovation judged with the model error
        ``S + diag((MODEL_ERROR_GAIN * curvature)²)`` too. ``R_detect``: the equation's
        error as the detector judges it (None: ``R``), e.g. without the slow part that the
        caller carries as a state of its own and has taken out of ``r`` already."""
        nu = r - Y @ mean
        P = Y @ cov @ Y.T
        S = R + P
        S += S.T  # symmetric: 0.5 (S + S^T), with no temporaries
        S *= 0.5
        try:
            chi2 = chi_square(nu, S)
        except np.linalg.LinAlgError:
            return False
        self.last_nis = chi2 / self.dof
        self._ring[self.count % NIS_WINDOW] = self.last_nis
        self.count += 1
        self.nis = float(self._ring[:min(self.count, NIS_WINDOW)].mean())
        if not detect:
            return False
        if R_detect is not None:
            S = R_detect + P
            S += S.T
            S *= 0.5
            try:
                chi2 = chi_square(nu, S)
            except np.linalg.LinAlgError:
                return False
        chi2_model = None
        if curvature is not None:
            S.flat[::self.dof + 1] += np.square(MODEL_ERROR_GAIN * curvature)  # the diagonal
            try:
                chi2_model = chi_square(nu, S)
            except np.linalg.LinAlgError:
                chi2_model = None  # the plain statistic alone
        return self.detector(chi2, chi2_model)

    def nbytes(self) -> int:
        return self._ring.nbytes
