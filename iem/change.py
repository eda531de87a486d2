"""Payload-change detection on the whitened torque residual (numpy only).

With the current estimate ``phi`` (covariance ``P``) the next regression equation
``r = Y phi + e`` (:mod:`iem.regression`) has the innovation ``nu = r - Y phi`` with covariance
``S = R + Y P Y^T``; while the payload stays, ``chi2 = nu^T S^-1 nu`` is chi-square with
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

Why the level: a model is never exact. Over a long random motion at 90 % of the velocity and
acceleration limits, a fixed payload gives stretches of tens of equations with ``chi2`` of
40-70 (the regression's filtered equations do not fit the physics exactly at speed; a real
arm's friction and link errors do the same): a CUSUM on the raw ``chi2`` read them as
evidence and raised 26 false alarms in 3 minutes (``iem bench longrun``, seed 0). Once the
window holds tens of thousands of equations the posterior is so sharp that the same misfit
reaches ``chi2`` of 2,000-6,000 where the motion starts fast from rest (seed 0, 445.8 s: 27,
50, 65, ..., 129, 200, 275, ..., 1,964 over 30 equations), the size of a payload change's.
What tells them apart is the rise: a change's ``chi2`` grows 2-7 times per equation while
the 4 Hz filter lets the new torque through (25, 181, 691, 1,703, 3,224, ...), the misfit's
1.1-1.5 times once it stands out of the noise (twice at its very start, at 11-50). The level
is a mean of ``chi2`` over the last :data:`LEVEL_EQUATIONS` equations (0.1 s at 100
equations per second): each equation moves it by at most a factor ``LEVEL_CLIP`` of itself,
so it can rise 30 % per equation, which follows a misfit's rise and stops counting it, while
a payload change outruns it and fires within two to four equations. The first
``level_equations`` equations after a reset only learn the level (a conflict there is the
prior's, not a new payload's). The caller resets the detector after a change.

The level's length was chosen on seed 0's 10-minute ``bench longrun`` (its chi² stream with
the detector off) and the seed-0 payload change of ``bench paper``: 30 equations raised one
false alarm there (the 445.8 s stretch) and detected the change after 39 ms; 10 equations
raise none (the CUSUM's largest evidence 59 against the threshold of 300) and still detect
it after 39 ms. Seeds 1-2 of both are the report.

The level follows a misfit that rises at most 30 % per equation; a 60-minute run (seed 1)
still met one that rose faster (3, 13, 33, 62, 106, ... at 1,838 s, up to 6,326), as steeply
as a change: the regression's own error where the arm's torque bends sharply (the filtered
equations of a perfect arm miss by 0.1-0.3 N·m there). So each equation is also judged with
a model error for it in its covariance (:data:`iem.innovation.MODEL_ERROR_GAIN`: 3 x the second
difference of the robot model's torque over the last three equations), a second statistic
``chi2_model <= chi2`` with a level of its own. Judged by that statistic alone (commit
b89d90c), the detector lost that alarm but raised 3 false alarms in seed 0's 10 minutes, 2
in seed 1's first 270 s and 2 in seed 2's hour: with the sharp part explained away, its
level stayed low and the rest of the misfit counted. So the CUSUM adds the smaller of the
two rescaled statistics: a CUSUM is monotone in what it adds, so its evidence is never above
that of a CUSUM of either statistic alone, and it fires only where both would (a payload
change raises both: the model error is kinematic). On the 1,830-1,900 s stretch of seed 1
(the tuning data), the largest evidence on the fixed payload is 32 (294 with the plain
statistic alone, threshold 300); 48 g injected there is detected after 90 ms (70 ms with the
plain statistic), 275 g after 30 ms (30).
"""

from __future__ import annotations

import numpy as np

from .errors import InvalidInputError
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
