"""When a write helps: the joint-torque error a load leaves, bounded along the recent motion.

The controller uses the load it holds in its model: gravity compensation, the collision
thresholds. A load that differs from the payload by ``d`` (paper order) leaves the joint
torques ``Y(q, dq) d`` unexplained, ``Y`` the payload regressor. The gate judges a write by
that error at the poses the arm passed through recently (:class:`RecentMotion`), never by the
width of a band alone:

- the load in force ``L`` certainly errs by at least ``hold = max(|Y (L - phi)| - s)`` over
  the poses and joints, ``phi`` the estimate and ``s`` the 2-sigma of the joint torque its
  uncertainty leaves: ``2 sqrt(y C y^T)`` per joint (row ``y`` of ``Y``) with the estimate's
  covariance ``C``; without one, ``|Y| b`` with ``b`` the 2-sigma band per parameter, the
  worst the band can do without knowing its correlations;
- a write of the candidate ``W`` (the estimate, or the empty load) errs by at most ``write =
  max(|Y (W - phi)| + s)``.

The write helps when ``hold >= min_torque_error_nm`` (the load in force lies outside the
estimate's band by a torque worth correcting) and ``write <= write_margin * hold`` (the
write's worst case is at most that share of the least error the load in force has). With
the default margin 1 the write is sure to be better than the load in force, in the worst case
the estimate's band allows. ``docs/decisions.md`` gives the defaults and their sources.

Without poses (no motion seen yet, or a gate without an arm model) the bound is the gravity
torque at the arm's reach ``reach_m``: ``g (reach |dm| + |d(m r)|)`` per group of
parameters, the largest a load's error can produce at any pose.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable

import numpy as np

G = 9.81
"""Standard gravity, m/s²."""

POSE_PERIOD_S = 0.1
"""One pose kept every this many seconds of the recent motion."""
MOTION_S = 2.0
"""The recent motion the bound looks along, s."""

Regressor = Callable[[np.ndarray, np.ndarray], np.ndarray]
"""``(q, dq) -> Y`` (n_joints x 10): the payload regressor at a pose, ``ddq = 0``."""


class RecentMotion:
    """The payload regressor at the poses of the last :data:`MOTION_S` seconds, one every
    :data:`POSE_PERIOD_S` (each computed once, when its pose arrives).

    Args:
        regressor: the arm model's payload regressor (None: the reach bound only).
    """

    def __init__(self, regressor: Regressor | None = None) -> None:
        self.regressor = regressor
        self._poses: deque[tuple[float, np.ndarray]] = deque()
        self._stack: np.ndarray | None = None

    def observe(self, t: float, q, dq) -> None:
        """A block point's pose at gate time ``t``."""
        if self.regressor is None or (self._poses and t - self._poses[-1][0] < POSE_PERIOD_S):
            return
        try:
            q = np.asarray(q, dtype=float)
            dq = np.asarray(dq, dtype=float)
        except (TypeError, ValueError):
            return  # not a pose: no bound from it
        if not (q.ndim == 1 and q.shape == dq.shape and q.size and np.isfinite(q).all()
                and np.isfinite(dq).all()):
            return
        y = np.asarray(self.regressor(q, dq), dtype=float)
        if y.ndim != 2 or y.shape[1] != 10 or not np.isfinite(y).all() or (
                self._poses and y.shape != self._poses[-1][1].shape):
            return
        self._poses.append((t, y))
        while self._poses and self._poses[0][0] < t - MOTION_S:
            self._poses.popleft()
        self._stack = None

    @property
    def stack(self) -> np.ndarray | None:
        """``(poses, n_joints, 10)``, or None before the first pose."""
        if self._stack is None and self._poses:
            self._stack = np.stack([y for _, y in self._poses])
        return self._stack


def torque_errors(motion: RecentMotion, in_force: np.ndarray, candidate: np.ndarray,
                  phi: np.ndarray, band: np.ndarray, reach_m: float,
                  cov: np.ndarray | None = None) -> tuple[float, float]:
    """``(hold, write)``, N·m: the least joint-torque error the load in force has and the
    most a write of ``candidate`` may have, given the estimate ``phi`` with 2-sigma ``band``
    (all paper order; the empty load is zeros). With the estimate's covariance ``cov`` the
    band's torque at each joint and pose is its own 2-sigma, ``2 sqrt(y cov y^T)``; without,
    ``|Y| band``, the worst case of unknown correlations."""
    Y = motion.stack
    d_hold = in_force - phi
    d_write = candidate - phi
    if Y is None:
        return _reach_bound(d_hold, band, reach_m, -1.0), _reach_bound(d_write, band, reach_m,
                                                                         1.0)
    if cov is None:
        spread = np.abs(Y) @ band
    else:  # the torque's own variance per joint and pose: diag(Y cov Y^T)
        spread = 2.0 * np.sqrt(np.maximum(np.einsum("pjk,kl,pjl->pj", Y, cov, Y), 0.0))
    hold = float((np.abs(Y @ d_hold) - spread).max())
    write = float((np.abs(Y @ d_write) + spread).max())
    return hold, write


def _reach_bound(d: np.ndarray, band: np.ndarray, reach_m: float, sign: float) -> float:
    """The gravity torque of the parameter error ``d`` at the reach, with the band taken
    off (``sign`` -1) or added (+1)."""
    mass = abs(d[0]) + sign * band[0]
    first = np.abs(d[1:4]).sum() + sign * band[1:4].sum()
    return G * (reach_m * mass + first) if math.isfinite(mass) else math.inf
