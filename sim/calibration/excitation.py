"""Steps 2-3 of the calibration: the base parameters (the combinations of the bodies'
parameters that act on the torques) and whether the motion excites them, the friction and the
offsets enough; a motion that does not is refused, naming the joints and directions."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
from scipy.linalg import qr

from ..friction import FRICTION_COLUMNS, friction_jacobian
from ..robot import ArmModel
from .prior import CalibrationError

PARAM_NAMES = ("m", "mcx", "mcy", "mcz", "Ixx", "Ixy", "Iyy", "Ixz", "Iyz", "Izz")
"""Pinocchio's dynamic-parameter order, per body."""
QR_TOL = 1e-4
"""Relative tolerance of the pivoted QR that finds the base parameters. A combination seen
10⁴ times less than the strongest is none: a URDF's angles rounded to 4 decimals (1.5708
for π/2, as xacro output gives them) tilt a vertical joint axis by 7e-6 rad and make the
mass moments of the body it moves show at about 4e-6, where no motion excites them; the
true base parameters of the arms here are above 0.04."""
MIN_RANGE = 0.3
"""Smallest range of motion per joint, rad."""
MIN_SPEED = 0.3
"""Smallest peak speed per joint in each direction, rad/s."""
MAX_CONDITION = 2000.0
"""Largest condition number of the prior-scaled excitation (base parameters, Coulomb and
viscous friction, offsets) that is accepted (the shipped calibration motion: about 1000; the
real recording's first 11 s 1270)."""
NEGLIGIBLE_SHARE = 0.01
"""A direction whose change by its prior's standard deviation moves the joint torques by less
than this share of the torque noise (RMS over the motion) is left to its prior and does not
count against :data:`MAX_CONDITION`: no motion within the arm's limits would show it (a light
wrist's inertia, about 1e-4 N·m on the Kinova Gen3's last body)."""


def regressors(model: pin.Model, q, dq, ddq) -> np.ndarray:
    data = model.createData()
    out = np.empty((q.shape[0], 7, 70))
    for k in range(q.shape[0]):
        out[k] = pin.computeJointTorqueRegressor(model, data, q[k], dq[k], ddq[k])
    return out


def base_basis(model: pin.Model, samples: int = 300, seed: int = 0,
               null: bool = False, kinematics=None) -> np.ndarray:
    """``(70, r)`` orthonormal basis of the parameter combinations that act on the torques
    (the base parameters), from a pivoted QR of the regressor at random states with relative
    tolerance :data:`QR_TOL`; ``r`` is their number. ``null``: the ``(70, 70 - r)`` basis
    of the combinations that act on no torque instead. The states are drawn within the
    limits of ``kinematics`` (an :class:`sim.robot.ArmModel`; None: the default arm model's)."""
    kin = ArmModel() if kinematics is None else kinematics
    rng = np.random.default_rng(seed)
    states = [kin.random_state(rng) for _ in range(samples)]
    W = regressors(model, *(np.array(x) for x in zip(*states, strict=True))).reshape(-1, 70)
    _, R, _ = qr(W, mode="economic", pivoting=True)
    d = np.abs(np.diag(R))
    rank = int(np.sum(d > QR_TOL * d[0]))
    _, _, vt = np.linalg.svd(W, full_matrices=False)
    return vt[rank:].T if null else vt[:rank].T


def check_excitation(q, dq, columns: np.ndarray, names: list[str],
                     to_named: np.ndarray, negligible_nm: float = 0.0) -> float:
    """The condition number of the prior-scaled ``columns`` (``(rows, k)``, N·m per prior
    standard deviation); raises :class:`CalibrationError` naming the joints that barely move
    and the directions the motion does not see (``to_named`` maps a direction of the columns
    to the ``names``), but for directions whose RMS torque is below ``negligible_nm``
    (:data:`NEGLIGIBLE_SHARE`)."""
    problems = []
    span = np.ptp(q, axis=0)
    for j in range(7):
        up, down = float(dq[:, j].max()), float(-dq[:, j].min())
        if span[j] < MIN_RANGE or min(up, down) < MIN_SPEED:
            problems.append(f"joint {j + 1} (range {span[j]:.3f} rad, speed +{up:.3f}/"
                            f"-{down:.3f} rad/s; needs >= {MIN_RANGE} rad and "
                            f">= {MIN_SPEED} rad/s both ways)")
    _, sv, vt = np.linalg.svd(columns, full_matrices=False)
    cond = float(sv[0] / sv[-1]) if sv[-1] > 0 else float("inf")
    weak = []
    if cond > MAX_CONDITION:
        seen = sv / np.sqrt(columns.shape[0]) >= negligible_nm  # RMS torque, N·m
        for i in np.flatnonzero((sv < sv[0] / MAX_CONDITION) & seen)[::-1][:4]:
            v = to_named @ vt[i]
            v /= np.abs(v).max()
            order = np.argsort(-np.abs(v))[:3]
            weak.append(" + ".join(f"{v[k]:+.2f} {names[k]}" for k in order))
    if problems or weak:
        parts = []
        if problems:
            parts.append("joints that do not move enough: " + "; ".join(problems))
        if weak:
            parts.append(f"condition number {cond:.3g} > {MAX_CONDITION:g}; directions not "
                         "excited: " + "; ".join(weak))
        raise CalibrationError("the traffic does not excite the arm enough to calibrate it: "
                               + ". ".join(parts) + ". Record the calibration motion "
                               "(sim.paths.calibration_path) on the bare arm")
    return cond


def excitation_condition(W, q, dq, basis, sd_theta, phi0, sd_phi, sd_off,
                         sigma_tau: float = 0.0) -> float:
    """:func:`check_excitation` of the traffic's regressor ``W`` ``(N, 7, 70)``: the base
    directions (prior-scaled, ``basis`` of :func:`base_basis`), Gaz's and the viscous
    friction at the prior's centre ``phi0``, the offsets (the Stribeck part, seen only near
    zero speed, is left to its prior where the motion does not show it); a direction that
    moves the torques by less than :data:`NEGLIGIBLE_SHARE` of ``sigma_tau`` is left to its
    prior."""
    n = W.shape[0]
    Wf = W.reshape(-1, 70)
    checked = [0, 1, 2, 3, 4]
    jac0 = friction_jacobian(dq, phi0)  # (N, 7, 9)
    fcols = np.zeros((n, 7, 7 * len(checked)))
    for j in range(7):
        fcols[:, j, len(checked) * j:len(checked) * (j + 1)] = (jac0[:, j, checked]
                                                                * sd_phi[j, checked])
    scaled_basis = np.linalg.qr(basis / sd_theta[:, None])[0]  # base directions, scaled
    scaled_base = (Wf * sd_theta) @ scaled_basis
    cols = np.hstack((scaled_base, fcols.reshape(-1, 7 * len(checked)),
                      np.tile(np.eye(7), (n, 1)) * sd_off))
    names = ([f"body{i // 10 + 1}.{PARAM_NAMES[i % 10]}" for i in range(70)]
             + [f"joint{j + 1}.{FRICTION_COLUMNS[c]}" for j in range(7) for c in checked]
             + [f"joint{j + 1}.offset" for j in range(7)])
    r = basis.shape[1]
    m = 7 * len(checked) + 7
    to_named = np.zeros((70 + m, r + m))
    to_named[:70, :r] = scaled_basis
    to_named[70:, r:] = np.eye(m)
    return check_excitation(q, dq, cols, names, to_named, NEGLIGIBLE_SHARE * sigma_tau)
