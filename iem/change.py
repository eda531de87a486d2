"""Payload-change detection on the whitened torque residual (numpy only).

With the current estimate ``phi`` (covariance ``P``) the next regression equation
``r = Y phi + e`` (:mod:`iem.regression`) has the innovation ``nu = r - Y phi`` with covariance
``S = R + Y P Y^T``; while the payload stays, ``chi2 = nu^T S^-1 nu`` is chi-square with
``dof = 7`` degrees of freedom (mean 7). A new payload adds ``Y (phi_new - phi)`` to ``nu``:
0.275 kg more is about 1 N·m on the shoulder and elbow, against a filtered noise of about
0.01 N·m, so ``chi2`` jumps by orders of magnitude.

:class:`ChangeDetector` is a one-sided CUSUM on ``chi2``::

    g <- max(0, g + chi2 - dof - drift),   change when g > threshold

``drift`` is the excess per equation that counts as evidence; ``threshold`` the evidence that
makes a change. The defaults (drift 21 = 3 dof, threshold 300) leave a wide margin over what a
fixed payload gives along the excitation and task paths with the default sensor model
(``chi2`` rarely above 30, so ``g`` stays at or near 0), and still fire on the first one or two
equations after a switch between the test payloads. The caller resets the detector after a
change.
"""

from __future__ import annotations

import numpy as np

from .errors import InvalidInputError


def chi_square(nu, S) -> float:
    """``nu^T S^-1 nu`` (via a Cholesky factor of ``S``)."""
    L = np.linalg.cholesky(S)
    w = np.linalg.solve(L, nu)
    return float(w @ w)


class ChangeDetector:
    """One-sided CUSUM on a chi-square statistic.

    Args:
        dof: degrees of freedom of the statistic (its mean while nothing changes).
        drift: excess over ``dof`` per step that does not count as evidence.
        threshold: accumulated evidence that signals a change.
    """

    def __init__(self, dof: int = 7, drift: float = 21.0, threshold: float = 300.0) -> None:
        if not (drift >= 0.0 and threshold > 0.0 and dof > 0):
            raise InvalidInputError(f"need dof > 0, drift >= 0 and threshold > 0, got "
                                    f"{dof}, {drift}, {threshold}")
        self.dof = int(dof)
        self.drift = float(drift)
        self.threshold = float(threshold)
        self.reset()

    def reset(self) -> None:
        self.g = 0.0
        self.last = 0.0

    def __call__(self, chi2: float) -> bool:
        """Add one statistic; True if the evidence now exceeds the threshold."""
        self.last = float(chi2)
        if not np.isfinite(self.last):
            return False
        self.g = max(0.0, self.g + self.last - self.dof - self.drift)
        return self.g > self.threshold

    def to_state(self) -> dict:
        return {"g": self.g, "last": self.last}

    def set_state(self, state: dict) -> None:
        self.g = float(state["g"])
        self.last = float(state["last"])
