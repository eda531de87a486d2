"""What motion would settle an uncertain payload: the joint move that determines best what
the data lack (IEM+phys's ``extra["settle"]``).

While the equations since a change do not determine the mass or the CoM (their standard
deviation from the data alone is wider than the prior's: the estimate is the prior's guess,
and the safety gate holds it as ``uncertain``), the estimate says which parameter the data
lack most (the largest ratio of its data's standard deviation to its prior's) and which
move would determine it: for each joint and either way, a slow move of :data:`MOVE_RAD` from
the current pose (:data:`MOVE_POSES` gravity-only poses on the way, the equations of
:data:`MOVE_S` at the model's rate, each with the model's own equation error), whose
information ``sum Y^T R^-1 Y`` added to the posterior's precision shrinks that parameter's
standard deviation most. A move that would not halve it says so and names ``iem excite``,
which designs a motion for the whole payload.
"""

from __future__ import annotations

import numpy as np

from ..types import GROUPS
from .small_linalg import sym_inv

__all__ = ["LABELS", "MOVE_POSES", "MOVE_RAD", "MOVE_S", "advice"]

MOVE_RAD = 0.5
"""The joint move tried, rad."""
MOVE_POSES = 6
"""Poses on the way the move's equations are taken at."""
MOVE_S = 1.0
"""How long the move is taken to last, s (its equations at the model's rate)."""
ENOUGH = 0.5
"""A move that leaves the parameter's standard deviation above this share of what it is
now is not named: a slow move of one joint does not settle it."""
LABELS = ("the mass", "the CoM along x", "the CoM along y", "the CoM along z",
          "Ixx", "Ixy", "Ixz", "Iyy", "Iyz", "Izz")
"""What each parameter is called in the advice (the CoM in the flange frame)."""


def advice(gravity_regressor, q, cov, data_std, prior_std, equation_var, rate_hz: float,
           q_min=None, q_max=None) -> str | None:
    """The advice (see the module docstring), or None while the data determine the mass
    and the CoM.

    Args:
        gravity_regressor: ``q -> Y`` (7x10), the payload regressor at rest at ``q``.
        q: the current pose (7, rad).
        cov: the posterior's covariance (10x10).
        data_std, prior_std: the standard deviations of the data alone and of the prior
            (10 each; inf where the data see nothing).
        equation_var: the variance of one equation's error per joint (7, (N·m)²), as
            counted in the window (its correlation included).
        rate_hz: equations a second.
        q_min, q_max: the joint limits (7 each, rad; None: not checked).
    """
    lacking = [i for g in ("mass", "com") for i in GROUPS[g]
               if not data_std[i] <= prior_std[i]]
    if not lacking:
        return None
    ratio = {i: data_std[i] / max(prior_std[i], 1e-300) for i in lacking}
    worst = max(lacking, key=lambda i: ratio[i])
    q = np.asarray(q, dtype=float)
    precision = sym_inv(0.5 * (cov + cov.T))
    now = float(np.sqrt(max(cov[worst, worst], 0.0)))
    weight = 1.0 / np.asarray(equation_var, dtype=float)
    per_pose = MOVE_S * rate_hz / MOVE_POSES
    best = None
    for j in range(q.shape[0]):
        for sign in (1.0, -1.0):
            end = q[j] + sign * MOVE_RAD
            if q_min is not None and not q_min[j] <= end <= q_max[j]:
                continue
            info = np.zeros((10, 10))
            for step in np.linspace(0.0, 1.0, MOVE_POSES):
                pose = q.copy()
                pose[j] += sign * MOVE_RAD * step
                Y = gravity_regressor(pose)
                info += per_pose * (Y.T * weight) @ Y
            after = float(np.sqrt(max(sym_inv(precision + info)[worst, worst], 0.0)))
            if best is None or after < best[0]:
                best = (after, j, sign)
    what = f"{LABELS[worst]} undetermined"
    if best is None or best[0] > ENOUGH * now:
        return f"{what}: no slow move of one joint settles it; run 'iem excite' for a motion"
    _, j, sign = best
    return f"{what}: move joint {j + 1} by {sign * MOVE_RAD:+.1f} rad or more, slowly"
