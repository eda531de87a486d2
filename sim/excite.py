"""A short motion that determines a payload: optimal experiment design on the payload
regressor (``iem excite``).

A payload is ten numbers, and the torques it adds are linear in them, ``Y(q, dq, ddq) phi``
(:meth:`sim.robot.ArmModel.payload_regressor`). How well a motion determines them is its
information matrix ``I = sum_k S Y_k^T Y_k S`` over the motion's states, ``S`` the
parameters' scales (:data:`SCALES`: what a rated payload's parameters can be, so that a kilo
and a kilo-metre count alike): a motion whose ``I`` is well conditioned sees every
parameter, one whose ``I`` has a small eigenvalue leaves its direction to a prior. As
robot_payload_id does for the whole arm, :func:`excite_path` chooses a motion by maximising
``log det I`` (D-optimality: the volume of the parameters' confidence region shrinks most)
over the shape of a finite Fourier series per joint:

- ``q_j(t) = start_j + s_j f_j(t)``, ``f_j`` a series of :data:`HARMONICS` harmonics of
  the base frequency ``1 / seconds`` whose ``f``, ``f'`` and ``f''`` vanish at both ends: the
  motion starts and ends at rest at the start pose the user gives;
- each joint's scale ``s_j`` is the largest that keeps the motion inside the arm model's
  limits: its joint range less :data:`RANGE_MARGIN` of the room either side of the start,
  :data:`LIMIT_FRACTION` of its velocity and acceleration limits (so every shape tried is a
  feasible motion, and the optimiser searches shapes, not constraints);
- the shapes' free coefficients (the end conditions take three of each joint's ``2H``) are
  found by L-BFGS from :data:`RESTARTS` seeded random starts, ``I`` summed over the motion at
  :data:`DESIGN_RATE_HZ`.

The result is a :class:`sim.paths.Path` at 1 kHz (written by :func:`sim.path_csv.
save_path_csv`: what ``iem sim-controller --path``, ``iem train --excitation`` and a franky
program read) and a :class:`Design` that says what it determines: the condition number of
``I`` (its largest over its smallest singular value of ``Y S``, the figure ``iem calibrate``
checks for the arm) and the limits it keeps.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from iem.errors import PathError
from iem.types import vec7

from .joint_path import N_JOINTS, RATE_HZ, Path
from .paths import fourier_series
from .robot import arm_model

__all__ = ["DESIGN_RATE_HZ", "HARMONICS", "LIMIT_FRACTION", "RANGE_MARGIN", "RESTARTS",
           "SCALES", "Design", "condition_number", "excite_path", "information"]

HARMONICS = 4
"""Harmonics per joint of the motion's Fourier series."""
LIMIT_FRACTION = 0.75
"""Largest fraction of the velocity and acceleration limits the motion uses (the excitation
path's, :data:`sim.paths.LIMIT_FRACTION`)."""
RANGE_MARGIN = 0.1
"""Share of the room between the start pose and each joint limit the motion leaves free."""
RESTARTS = 4
"""Seeded random starting shapes of the optimiser."""
DESIGN_RATE_HZ = 20.0
"""States a second the information matrix is summed over while designing."""
SCALES = np.array([3.0, 0.3, 0.3, 0.3, 0.01, 0.01, 0.01, 0.01, 0.01, 0.01])
"""What each payload parameter can be (kg, kg·m, kg·m²; a rated 3 kg payload's, as
:data:`iem.physics.DEFAULT_PRIOR_STD`): the information matrix is of the parameters divided
by these, so that its condition number compares directions, not units."""


@dataclass(frozen=True)
class Design:
    """What a motion determines of a payload and the limits it keeps.

    Attributes:
        condition: condition number of the scaled payload regressor over the motion (-).
        log_det: ``log det`` of its information matrix (-; larger: the parameters' joint
            confidence region smaller).
        q_peak: the largest ``|q - start|`` per joint, rad; dq_peak, ddq_peak: the largest
            ``|dq|``, ``|ddq|`` per joint, rad/s and rad/s².
        q_room: how far each joint may go from the start either way within its limits,
            rad; dq_max, ddq_max: the arm model's velocity and acceleration limits.
    """

    condition: float
    log_det: float
    q_peak: tuple[float, ...]
    dq_peak: tuple[float, ...]
    ddq_peak: tuple[float, ...]
    q_room: tuple[float, ...]
    dq_max: tuple[float, ...]
    ddq_max: tuple[float, ...]


def information(model, q, dq, ddq) -> np.ndarray:
    """``sum_k S Y_k^T Y_k S`` over the states ``(q, dq, ddq)`` (``(N, 7)`` each) of
    ``model`` (:class:`sim.robot.ArmModel`), ``S = diag(SCALES)`` (10x10)."""
    Y = _regressors(model, q, dq, ddq)
    return Y.T @ Y


def condition_number(model, q, dq, ddq) -> float:
    """The condition number of the scaled payload regressor over the states (the square
    root of the information matrix's); inf where a direction is not seen at all."""
    s = np.linalg.svd(_regressors(model, q, dq, ddq), compute_uv=False)
    return float(s[0] / s[-1]) if s[-1] > 0.0 else math.inf


def _regressors(model, q, dq, ddq) -> np.ndarray:
    return np.vstack([model.payload_regressor(q[k], dq[k], ddq[k]) * SCALES
                      for k in range(q.shape[0])])


class _Shapes:
    """The Fourier series' free coefficients and the motion they make (see the module
    docstring): ``x`` holds, per joint, the sine coefficients in the null space of ``sum k
    a_k = 0`` and the cosine ones in that of ``sum b_k = sum k² b_k = 0``."""

    def __init__(self, model, start: np.ndarray, seconds: float, harmonics: int) -> None:
        k = np.arange(1, harmonics + 1, dtype=float)
        self.na = _null(k[None, :])  # (H, H-1)
        self.nb = _null(np.vstack((np.ones(harmonics), k * k)))  # (H, H-2)
        self.size = N_JOINTS * (self.na.shape[1] + self.nb.shape[1])
        self.omega = 2.0 * math.pi / seconds
        self.start = start
        self.room = (1.0 - RANGE_MARGIN) * np.minimum(start - model.q_min, model.q_max - start)
        self.dq_cap = LIMIT_FRACTION * model.dq_max
        self.ddq_cap = LIMIT_FRACTION * model.ddq_max
        self.t_check = np.arange(round(seconds * 200.0) + 1) / 200.0  # the caps' grid
        self.t_design = np.arange(round(seconds * DESIGN_RATE_HZ) + 1) / DESIGN_RATE_HZ

    def coefficients(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        ka, kb = self.na.shape[1], self.nb.shape[1]
        x = x.reshape(N_JOINTS, ka + kb)
        return self.na @ x[:, :ka].T, self.nb @ x[:, ka:].T  # (H, 7) each

    def motion(self, x: np.ndarray, t: np.ndarray, exact: bool = False):
        """``(q, dq, ddq)`` of the shape ``x`` scaled into the limits, at times ``t``; the
        peaks are taken on a 200 Hz grid while designing, on ``t`` itself if ``exact``."""
        a, b = self.coefficients(x)
        f, df, ddf = fourier_series(a, b, self.omega, t if exact else self.t_check)
        with np.errstate(divide="ignore", invalid="ignore"):
            scale = np.nan_to_num(np.minimum.reduce([
                self.room / np.abs(f).max(axis=0),
                self.dq_cap / np.abs(df).max(axis=0),
                self.ddq_cap / np.abs(ddf).max(axis=0)]), nan=0.0, posinf=0.0)
        f, df, ddf = fourier_series(a * scale, b * scale, self.omega, t)
        return self.start + f, df, ddf


def _null(C: np.ndarray) -> np.ndarray:
    """An orthonormal basis of the null space of ``C`` (columns)."""
    _, s, vt = np.linalg.svd(C)
    return vt[int(np.sum(s > 1e-12 * s[0])):].T


def excite_path(seconds: float, start=None, *, model=None, harmonics: int = HARMONICS,
                restarts: int = RESTARTS, iterations: int = 60, seed: int = 0,
                name: str = "excite") -> tuple[Path, Design]:
    """A motion of ``seconds`` from and back to ``start`` (rad; None: the arm model's home)
    that determines a payload (see the module docstring), and its :class:`Design`.

    Raises:
        PathError: ``seconds`` not in [2, 120], ``start`` not 7 finite values strictly
            inside the joint limits, or ``harmonics``, ``restarts`` or ``iterations`` out of
            range (each names what is valid).
    """
    from scipy.optimize import minimize

    m = arm_model() if model is None else model
    seconds = float(seconds)
    if not (math.isfinite(seconds) and 2.0 <= seconds <= 120.0):
        raise PathError(f"excite: seconds must be from 2 to 120 s, got {seconds}")
    if int(harmonics) != harmonics or not 3 <= harmonics <= 10:
        raise PathError(f"excite: harmonics must be an integer from 3 to 10, got {harmonics}")
    if int(restarts) != restarts or restarts < 1 or int(iterations) != iterations \
            or iterations < 0:
        raise PathError(f"excite: restarts must be >= 1 and iterations >= 0, got {restarts}, "
                        f"{iterations}")
    q0 = np.array(m.description.home if start is None else
                  vec7("start", start, PathError, finite=True), dtype=float)
    inside = (q0 > m.q_min) & (q0 < m.q_max)
    if not inside.all():
        j = int(np.flatnonzero(~inside)[0])
        raise PathError(f"excite: the start pose's joint {j + 1} is {q0[j]:.4g} rad, outside "
                        f"or on its limits; valid is strictly between {m.q_min[j]:.4g} and "
                        f"{m.q_max[j]:.4g} rad")
    shapes = _Shapes(m, q0, seconds, int(harmonics))
    t = shapes.t_design

    def cost(x: np.ndarray) -> float:
        info = information(m, *shapes.motion(x, t))
        sign, logdet = np.linalg.slogdet(info + 1e-12 * np.eye(10))
        return -logdet if sign > 0 else 1e6

    rng = np.random.default_rng(seed)
    best = None
    for _ in range(int(restarts)):
        x0 = rng.standard_normal(shapes.size)
        res = minimize(cost, x0, method="L-BFGS-B",
                       options={"maxiter": int(iterations), "eps": 1e-4})
        x = res.x if res.fun <= cost(x0) else x0
        value = min(res.fun, cost(x0))
        if best is None or value < best[0]:
            best = (value, x)
    grid = np.arange(round(seconds * RATE_HZ) + 1) / RATE_HZ
    q, dq, ddq = shapes.motion(best[1], grid, exact=True)
    dq[[0, -1]] = 0.0  # the series is at rest at its ends: no round-off left there
    ddq[[0, -1]] = 0.0
    q[[0, -1]] = q0
    path = Path(name=name, t=grid, q=q, dq=dq, ddq=ddq).check_limits(m)
    qd, dqd, ddqd = shapes.motion(best[1], t)
    design = Design(
        condition=condition_number(m, qd, dqd, ddqd), log_det=float(-best[0]),
        q_peak=tuple(np.abs(q - q0).max(axis=0).tolist()),
        dq_peak=tuple(np.abs(dq).max(axis=0).tolist()),
        ddq_peak=tuple(np.abs(ddq).max(axis=0).tolist()),
        q_room=tuple((shapes.room / (1.0 - RANGE_MARGIN)).tolist()),
        dq_max=tuple(m.dq_max.tolist()), ddq_max=tuple(m.ddq_max.tolist()))
    return path, design
