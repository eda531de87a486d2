"""Payload-change detection on the whitened torque residual (numpy; scipy's LAPACK via
small_linalg).

With the current estimate ``phi`` (covariance ``P``) the next regression equation
``r = Y phi + e`` (:mod:`iem.physics.regression`) has the innovation ``nu = r - Y phi`` with
covariance ``S = R + Y P Y^T``; while the payload stays, ``chi2 = nu^T S^-1 nu`` is chi-square with
``dof = 7`` degrees of freedom (mean 7). A new payload adds ``Y (phi_new - phi)`` to ``nu``:
0.275 kg more is about 1 N·m on the shoulder and elbow, against a filtered noise of about
0.01 N·m, so ``chi2`` jumps by orders of magnitude.

:class:`ChangeDetector` is a one-sided CUSUM on ``chi2`` rescaled by its recent level::

    z = chi2 * dof / max(dof, level)
    g <- max(0, g + z - dof - drift),   change when g > threshold
    level <- level + (min(chi2, LEVEL_CLIP * level) - level) / level_equations

(with a second statistic of the same equation, ``chi2_model``, rescaled by its own level, the
CUSUM adds ``min(z, z_model)``: see the end of this docstring)

``drift`` is the excess per equation that counts as evidence; ``threshold`` the evidence that
makes a change. The defaults (drift 21 = 3 dof, threshold 300) fire on the first one or two
equations after a switch between the test payloads (``chi2`` jumps to 10³-10⁴).

Why the level: a model is never exact. At speed the regression's filtered equations do not
fit the physics exactly (a real arm's friction and link errors do the same), so a fixed
payload gives stretches of tens of equations with ``chi2`` of 40-70, and, once the window
holds tens of thousands of equations and the posterior is sharp, misfits of ``chi2``
2,000-6,000 where the motion starts fast from rest: the size of a payload change's. A CUSUM
on the raw ``chi2`` counts them as evidence (``iem bench longrun`` raised tens of false
alarms in minutes). What tells them apart is the rise: a change's ``chi2`` grows 2-7 times
per equation while the 4 Hz filter lets the new torque through, a misfit's 1.1-1.5 times.
The level is a mean of ``chi2`` over the last :data:`LEVEL_EQUATIONS` equations (0.1 s at
100 equations per second); each equation moves it by at most a factor ``LEVEL_CLIP`` of
itself, so it can rise 30 % per equation: it follows a misfit's rise and stops counting it,
while a payload change outruns it and fires within two to four equations. The first
``level_equations`` equations after a reset only learn the level (a conflict there is the
prior's, not a new payload's). The caller resets the detector after a change. A level over
10 equations detects ``bench paper``'s payload change as fast as one over 30 and follows
misfits that one over 30 lets through.

Some misfits rise as steeply as a change: where the arm's torque bends sharply, the
filtered equations of a perfect arm miss by 0.1-0.3 N·m. So each equation is also judged
with a model error for it in its covariance (:data:`iem.physics.innovation.MODEL_ERROR_GAIN`: 3 x
the second difference of the robot model's torque over the last three equations), a second
statistic ``chi2_model <= chi2`` with a level of its own, and the CUSUM adds the smaller of
the two rescaled statistics. Why the smaller: with the sharp part of a misfit explained
away, ``chi2_model``'s level stays low and the rest of the misfit counts, so that statistic
alone raises false alarms of its own; a CUSUM is monotone in what it adds, so with the
smaller its evidence is never above that of a CUSUM of either statistic alone, and it fires
only where both would. A payload change raises both (the model error is kinematic): on a
perfect arm 48 g is detected within about 0.1 s and 275 g within 30 ms.
"""

from __future__ import annotations

import numpy as np

from ..errors import InvalidInputError
from .small_linalg import chi_square

__all__ = ["LEVEL_CLIP", "LEVEL_EQUATIONS", "ChangeDetector", "chi_square"]

LEVEL_EQUATIONS = 10
"""Equations over which the level of ``chi2`` is averaged (exponentially)."""
LEVEL_CLIP = 4.0
"""Largest ``chi2`` an equation adds to the level, as a multiple of the level."""

class ChangeDetector:
    """One-sided CUSUM on a chi-square statistic.

    Args:
        dof: degrees of freedom of the statistic (its mean while nothing changes).
        drift: excess over ``dof`` per step that does not count as evidence.
        threshold: accumulated evidence that signals a change.
        level_equations: equations of the level's mean (0: no level, the raw ``chi2``).
    """

    def __init__(self, dof: int = 7, drift: float = 21.0, threshold: float = 300.0,
                 level_equations: int = LEVEL_EQUATIONS) -> None:
        if not (drift >= 0.0 and threshold > 0.0 and dof > 0 and level_equations >= 0):
            raise InvalidInputError(f"need dof > 0, drift >= 0, threshold > 0 and "
                                    f"level_equations >= 0, got {dof}, {drift}, {threshold}, "
                                    f"{level_equations}")
        self.dof = int(dof)
        self.drift = float(drift)
        self.threshold = float(threshold)
        self.level_equations = int(level_equations)
        self.reset()

    def reset(self) -> None:
        self.g = 0.0
        self.last = 0.0
        self.level = float(self.dof)
        self.level_model = float(self.dof)
        self.n = 0

    def __call__(self, chi2: float, chi2_model: float | None = None) -> bool:
        """Add one statistic; True if the evidence now exceeds the threshold.

        ``chi2_model``: the same equation judged with its model error in the covariance
        (never above ``chi2``; None: not known, taken as ``chi2``). Each statistic is
        rescaled by its own level and the CUSUM adds the smaller, so it never holds more
        evidence than a CUSUM of either alone would."""
        self.last = float(chi2)
        if not np.isfinite(self.last):
            return False
        model = self.last if chi2_model is None else float(chi2_model)
        if not np.isfinite(model):
            model = self.last
        z, z_model = self.last, model
        if self.level_equations:
            z, self.level = self._rescaled(self.last, self.level)
            z_model, self.level_model = self._rescaled(model, self.level_model)
            self.n += 1
            if self.n <= self.level_equations:
                return False  # the first equations after a reset only learn the level
        self.g = max(0.0, self.g + min(z, z_model) - self.dof - self.drift)
        return self.g > self.threshold

    def _rescaled(self, chi2: float, level: float) -> tuple[float, float]:
        """``chi2`` rescaled by ``level``, and the level after this equation."""
        floor = max(float(self.dof), level)
        step = min(self.n + 1, self.level_equations)
        return (chi2 * self.dof / floor,
                level + (min(chi2, LEVEL_CLIP * floor) - level) / step)

    def to_state(self) -> dict:
        return {"g": self.g, "last": self.last, "level": self.level, "n": self.n,
                "level_model": self.level_model}

    def set_state(self, state: dict) -> None:
        self.g = float(state["g"])
        self.last = float(state["last"])
        # a state from before the level: nominal level, learnt already
        self.level = float(state.get("level", self.dof))
        self.n = int(state.get("n", self.level_equations))
        # a state from before the model error: its level is the plain one's
        self.level_model = float(state.get("level_model", self.level))
