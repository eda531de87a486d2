"""Calibrating the arm: its departure from the nominal model, from bare-arm traffic.

Model of the measured link-side torque of the bare arm (no payload)::

    tau_J = W(q, dq, ddq) theta + tau_f(dq; phi) + offset + noise

``W`` is Pinocchio's joint-torque regressor (``computeJointTorqueRegressor``, 7 x 70: ten
dynamic parameters per joint body), ``theta`` the bodies' parameters, ``tau_f`` the arm's
friction (:func:`sim.arm.friction_torque`: Gaz's Coulomb sigmoid, viscous and Stribeck
friction, per direction of motion; nine parameters per joint) and ``offset`` one constant
per torque sensor.

Steps (:func:`calibrate`):

1. **Signals.** The whole log is there, so the filtering is zero-phase: ``q``, ``dq`` and
   ``tau`` through the same 4th-order Butterworth forwards and backwards (``cutoff_hz``),
   ``ddq`` the central difference of the filtered ``dq`` on the recorded time stamps; then
   decimated to ``rate_hz`` (100 Hz), the first and last ``trim_s`` dropped. Traffic whose
   time steps jitter is first interpolated onto a uniform grid (:func:`prepare`).
2. **Base parameters.** Only combinations of ``theta`` act on the torques. Column-pivoted QR
   of the regressor at random states, with a relative tolerance (:data:`QR_TOL`), gives their
   number and a basis; the excitation's condition number is that of the recorded regressor on
   this basis (and on the Coulomb and viscous friction's and the offsets' columns; the
   Stribeck part, seen only near zero speed, is left to its prior where the motion does not
   show it), each column scaled by its prior standard deviation, so that it measures the
   motion, not the units.
3. **Refusal.** A joint that barely moves (range under :data:`MIN_RANGE`, or speed under
   :data:`MIN_SPEED` in either direction: friction needs both signs) or a condition number
   above :data:`MAX_CONDITION` is refused with :class:`CalibrationError`, naming the joints
   and the parameter directions the motion does not see.
4. **Fit: maximum a posteriori, by Levenberg-Marquardt.** A prior centred on the nominal
   model (``theta``: the bounds of a few-percent link error, :func:`link_prior_std`;
   friction, :func:`friction_prior`: Gaz's values with half their size as standard
   deviation, no viscous friction +- 0.2 N·m·s/rad, no Stribeck excess +- 0.2 N·m at
   0.1 +- 0.1 rad/s; offsets 0 +- 0.5 N·m) regularises the least squares, so the
   directions the motion does not excite stay nominal and the excited ones follow the data.
   Friction is non-linear in ``phi2, phi3`` and the Stribeck velocities: each iteration
   linearises it at the current parameters (:func:`sim.arm.friction_jacobian`) and solves
   the damped linear MAP problem for all unknowns at once (70 + 63 + 7); a step is taken
   only if it lowers the posterior's cost, the damping grows until one does (Nielsen's
   rule), and the friction stays inside :data:`FRICTION_BOUNDS` (:func:`_fit_map`). (The
   exact model is fitted, not a fixed-shape linearisation: Gaz's ``phi2`` differ by a
   factor of 3 between joints. Undamped Gauss-Newton on Gaz's sigmoid alone diverged on an
   arm with viscous friction and left a joint worse than the nominal model.)
5. **Physical consistency.** Each body's pseudo-inertia must be positive definite. The
   fit is moved to the consistent parameters nearest it in the metric of its own posterior
   precision (:func:`consistent_map`: the MAP under the pseudo-inertia LMIs, a small
   semidefinite program solved by Clarabel through cvxpy), so it moves mostly along the
   directions the data do not see and the torques barely change. Should the solver fail, a
   body still inconsistent is moved back toward its nominal values (a convex set holds both)
   just far enough (:func:`consistent`), which the report names.
6. **Never worse than nominal** (:func:`never_worse`). Per joint, the residual RMS of the
   result on the fitted signals is compared with the nominal model's; a joint that fits
   worse has its friction and offset refitted alone, and if the bodies are to blame the
   bodies stay nominal (the report's ``fallback_joints`` and warnings say so).
7. **Payload check.** A payload on the flange acts like extra mass on body 7: if the fit
   makes body 7 heavier than its prior allows (:data:`PAYLOAD_WARN_SIGMAS` standard
   deviations, at least :data:`PAYLOAD_WARN_KG`), the result carries a warning.

The result is a :class:`sim.arm.ArmParams` with a ``(7, 9)`` friction array whose
``report`` holds the per-joint residual RMS before (nominal model) and after, the condition
number, the number of base parameters, the iterations, the joints the guard changed and any
warnings.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin
from scipy.linalg import qr
from scipy.signal import butter, sosfiltfilt

from iem.errors import InvalidInputError

from .arm import (
    FRICTION_COLUMNS,
    GAZ_PHI,
    ArmParams,
    friction_jacobian,
    friction_torque,
    full_friction,
)
from .robot import PandaModel, nominal_link_params

PARAM_NAMES = ("m", "mcx", "mcy", "mcz", "Ixx", "Ixy", "Iyy", "Ixz", "Iyz", "Izz")
"""Pinocchio's dynamic-parameter order, per body."""
QR_TOL = 1e-8
"""Relative tolerance of the pivoted QR that finds the base parameters."""
MIN_RANGE = 0.3
"""Smallest range of motion per joint, rad."""
MIN_SPEED = 0.3
"""Smallest peak speed per joint in each direction, rad/s."""
MAX_CONDITION = 2000.0
"""Largest condition number of the prior-scaled excitation (base parameters, Coulomb and
viscous friction, offsets) that is accepted (the shipped calibration motion: about 1000; the
real recording's first 11 s 1270)."""
PAYLOAD_WARN_SIGMAS = 4.0
PAYLOAD_WARN_KG = 0.1
"""Body 7 heavier than nominal by more than this many prior standard deviations (and at
least this many kg) reads as a payload."""


class CalibrationError(InvalidInputError):
    """The traffic cannot calibrate the arm (too short, or it does not excite enough)."""


@dataclass(frozen=True)
class CalibrationSettings:
    """How :func:`calibrate` treats the signals.

    Attributes:
        cutoff_hz: zero-phase low-pass cut-off for q, dq, tau, Hz.
        rate_hz: rate the filtered signals are decimated to, Hz.
        trim_s: dropped at each end (the filter's edges), s.
        sigma_tau: torque noise the residual is weighted with, N·m.
        iterations: most Levenberg-Marquardt iterations.
        damping: the Levenberg-Marquardt damping it starts with (-).
        tolerance: the fit stops when an iteration lowers the cost (chi-square: twice the
            negative log posterior) by less than this (-).
        mass_rel, com_abs, inertia_rel: bounds of the link error the prior allows (-, m, -).
        friction_rel: prior standard deviation of Gaz's parameters, relative.
        viscous_std: prior standard deviation of the viscous coefficients, N·m·s/rad.
        stribeck_std: prior standard deviation of the Stribeck excess, N·m.
        stribeck_vs_std: prior standard deviation of the Stribeck velocities, rad/s.
        offset_std: prior standard deviation of the offsets, N·m.
    """

    cutoff_hz: float = 10.0
    rate_hz: float = 100.0
    trim_s: float = 0.5
    sigma_tau: float = 0.05
    iterations: int = 50
    damping: float = 1e-3
    tolerance: float = 0.05
    mass_rel: float = 0.05
    com_abs: float = 0.005
    inertia_rel: float = 0.10
    friction_rel: float = 0.5
    viscous_std: float = 0.2
    stribeck_std: float = 0.2
    stribeck_vs_std: float = 0.1
    offset_std: float = 0.5


def link_prior_std(params: np.ndarray, s: CalibrationSettings) -> np.ndarray:
    """Prior standard deviation of each of the 70 body parameters (Pinocchio order): what a
    mass error of ``mass_rel``, a CoM error of ``com_abs`` and an inertia error of
    ``inertia_rel`` can change, with a floor for massless-looking entries."""
    out = np.empty((7, 10))
    for j, p in enumerate(np.asarray(params).reshape(7, 10)):
        m = p[0]
        c = p[1:4] / m
        inertia = pin.Inertia.FromDynamicParameters(p)
        i_c = inertia.inertia  # about the CoM
        out[j, 0] = s.mass_rel * m
        out[j, 1:4] = np.hypot(s.mass_rel * m * np.abs(c), m * s.com_abs)
        scale = (s.inertia_rel * np.abs(i_c).max() + s.mass_rel * m * c @ c
                 + 2.0 * m * np.linalg.norm(c) * s.com_abs)
        out[j, 4:] = scale
    return np.maximum(out, 1e-6).ravel()


def _pseudo_min_eig(p: np.ndarray) -> float:
    """Smallest eigenvalue of a body's pseudo-inertia (positive: physically consistent)."""
    m, h = p[0], p[1:4]
    ixx, ixy, iyy, ixz, iyz, izz = p[4:]
    inertia = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
    sigma = 0.5 * np.trace(inertia) * np.eye(3) - inertia
    pseudo = np.zeros((4, 4))
    pseudo[:3, :3] = sigma
    pseudo[:3, 3] = pseudo[3, :3] = h
    pseudo[3, 3] = m
    return float(np.linalg.eigvalsh(pseudo)[0])


def consistent_map(theta_map: np.ndarray, precision: np.ndarray, eps: float = 1e-6
                   ) -> np.ndarray | None:
    """The physically consistent body parameters nearest the unconstrained MAP ``theta_map``
    (70) in the metric of its posterior ``precision`` (70 x 70): the constrained MAP, since
    the torques are linear in the parameters. Each body's pseudo-inertia ``[[Σ, h], [h^T,
    m]]`` (``Σ = tr(I)/2 E - I``) is kept ``>= eps E``: a semidefinite program (cvxpy, solved
    by Clarabel). None if the solver fails."""
    import cvxpy as cp

    theta_map = np.asarray(theta_map, dtype=float).ravel()
    evals, evecs = np.linalg.eigh(0.5 * (precision + precision.T))
    root = evecs * np.sqrt(np.maximum(evals, 0.0))  # precision = root @ root.T
    x = cp.Variable(70)
    cons = []
    for j in range(7):
        p = x[10 * j:10 * j + 10]
        m, h = p[0], p[1:4]
        ixx, ixy, iyy, ixz, iyz, izz = (p[k] for k in range(4, 10))
        tr = 0.5 * (ixx + iyy + izz)
        pseudo = cp.bmat([[tr - ixx, -ixy, -ixz, h[0]],
                          [-ixy, tr - iyy, -iyz, h[1]],
                          [-ixz, -iyz, tr - izz, h[2]],
                          [h[0], h[1], h[2], m]])
        cons.append(0.5 * (pseudo + pseudo.T) >> eps * np.eye(4))
    problem = cp.Problem(cp.Minimize(cp.sum_squares(root.T @ (x - theta_map))), cons)
    try:
        problem.solve(solver=cp.CLARABEL)
    except cp.error.SolverError:
        return None
    if x.value is None or problem.status not in ("optimal", "optimal_inaccurate"):
        return None
    return np.asarray(x.value).reshape(7, 10)


def consistent(params: np.ndarray, nominal: np.ndarray, eps: float = 1e-7
               ) -> tuple[np.ndarray, list[int]]:
    """``params`` (7 x 10) with each body whose pseudo-inertia is not positive definite
    moved back toward ``nominal`` (bisection on the segment, which stays in the convex set
    of consistent bodies) until it is; returns the bodies and the 1-based joints moved. The
    last resort, after :func:`consistent_in_null_space`: it changes the torques."""
    out = np.array(params, dtype=float).reshape(7, 10)
    moved = []
    for j in range(7):
        if _pseudo_min_eig(out[j]) > eps:
            continue
        lo, hi = 0.0, 1.0  # fraction of the correction kept
        for _ in range(50):
            mid = 0.5 * (lo + hi)
            if _pseudo_min_eig(nominal[j] + mid * (out[j] - nominal[j])) > eps:
                lo = mid
            else:
                hi = mid
        out[j] = nominal[j] + lo * (out[j] - nominal[j])
        moved.append(j + 1)
    return out, moved


# -- signals -------------------------------------------------------------------------------
JITTER_TOL = 0.01
"""Time steps that depart from their median by more than this fraction make
:func:`prepare` resample the traffic onto a uniform grid before it filters."""


def prepare(t, q, dq, tau, s: CalibrationSettings = CalibrationSettings()):
    """Zero-phase filtered, differentiated and decimated ``(t, q, dq, ddq, tau)``.

    The filter runs on a uniform grid: traffic whose time steps jitter (a logger's: by more
    than :data:`JITTER_TOL` of the median step) is first interpolated linearly onto the grid
    of its median step, so that the filter and the derivative see the time stamps, not the
    sample count (a real Panda log, filtered sample by sample, had ``ddq`` 12 % off and twice
    the residual on joints 1-3)."""
    t = np.asarray(t, dtype=float)
    q, dq, tau = (np.asarray(a, dtype=float) for a in (q, dq, tau))
    n = t.shape[0]
    if n < 10 or q.shape != (n, 7) or dq.shape != (n, 7) or tau.shape != (n, 7):
        raise CalibrationError(f"calibration needs (N, 7) q, dq, tau with N >= 10 samples, "
                               f"got t {t.shape}, q {q.shape}, dq {dq.shape}, tau {tau.shape}")
    dt = np.diff(t)
    if np.any(dt <= 0.0):
        raise CalibrationError("calibration needs strictly increasing time stamps")
    rate = 1.0 / float(np.median(dt))
    duration = float(t[-1] - t[0])
    if duration < 4.0 * s.trim_s + 2.0:
        raise CalibrationError(f"{duration:.2f} s of traffic is too short to calibrate; "
                               f"record at least {4.0 * s.trim_s + 2.0:.0f} s of the "
                               f"calibration motion (30 s: sim.paths.calibration_path)")
    if np.max(np.abs(dt * rate - 1.0)) > JITTER_TOL:
        grid = t[0] + np.arange(int(np.floor(duration * rate)) + 1) / rate
        q, dq, tau = (np.column_stack([np.interp(grid, t, a[:, j]) for j in range(7)])
                      for a in (q, dq, tau))
        t = grid
    sos = butter(4, min(s.cutoff_hz, 0.45 * rate), fs=rate, output="sos")
    qf, dqf, tauf = (sosfiltfilt(sos, a, axis=0) for a in (q, dq, tau))
    ddqf = np.gradient(dqf, t, axis=0)
    step = max(1, round(rate / s.rate_hz))
    keep = np.flatnonzero((t >= t[0] + s.trim_s) & (t <= t[-1] - s.trim_s))[::step]
    return t[keep], qf[keep], dqf[keep], ddqf[keep], tauf[keep]


# -- the problem ---------------------------------------------------------------------------
def _regressors(model: pin.Model, q, dq, ddq) -> np.ndarray:
    data = model.createData()
    out = np.empty((q.shape[0], 7, 70))
    for k in range(q.shape[0]):
        out[k] = pin.computeJointTorqueRegressor(model, data, q[k], dq[k], ddq[k])
    return out


def base_basis(model: pin.Model, samples: int = 300, seed: int = 0,
               null: bool = False) -> np.ndarray:
    """``(70, r)`` orthonormal basis of the parameter combinations that act on the torques
    (the base parameters), from a pivoted QR of the regressor at random states with relative
    tolerance :data:`QR_TOL`; ``r`` is their number. ``null``: the ``(70, 70 - r)`` basis
    of the combinations that act on no torque instead."""
    kin = PandaModel()
    rng = np.random.default_rng(seed)
    states = [kin.random_state(rng) for _ in range(samples)]
    W = _regressors(model, *(np.array(x) for x in zip(*states, strict=True))).reshape(-1, 70)
    _, R, _ = qr(W, mode="economic", pivoting=True)
    d = np.abs(np.diag(R))
    rank = int(np.sum(d > QR_TOL * d[0]))
    _, _, vt = np.linalg.svd(W, full_matrices=False)
    return vt[rank:].T if null else vt[:rank].T


def check_excitation(q, dq, columns: np.ndarray, names: list[str],
                     to_named: np.ndarray) -> float:
    """The condition number of the prior-scaled ``columns`` (``(rows, k)``); raises
    :class:`CalibrationError` naming the joints that barely move and the directions the
    motion does not see (``to_named`` maps a direction of the columns to the ``names``)."""
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
        for i in np.flatnonzero(sv < sv[0] / MAX_CONDITION)[::-1][:4]:
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


MAX_GAP_S = 0.05
"""A longer gap between two time stamps splits the traffic into segments filtered apart."""


def segments(t, q, dq, tau, min_s: float = 3.0) -> list[tuple]:
    """``(t, q, dq, tau)`` split where the time stamps jump by more than :data:`MAX_GAP_S`
    (lost cycles, a restart); segments shorter than ``min_s`` are dropped."""
    t = np.asarray(t, dtype=float)
    cuts = np.flatnonzero(np.diff(t) > MAX_GAP_S) + 1
    out = []
    for a, b in zip(np.r_[0, cuts], np.r_[cuts, t.shape[0]], strict=True):
        if b - a >= 10 and t[b - 1] - t[a] >= min_s:
            out.append((t[a:b], *(np.asarray(x)[a:b] for x in (q, dq, tau))))
    return out


def calibrate(t, q, dq, tau, settings: CalibrationSettings = CalibrationSettings(),
              source: str = "traffic") -> ArmParams:
    """The arm identified from bare-arm joint states (see the module docstring).

    Args:
        t: time stamps, s ``(N,)``; q, dq, tau: measured ``(N, 7)`` (rad, rad/s, N·m).
        settings: the filtering and the prior.
        source: what the traffic was (recorded in the report).

    Raises:
        CalibrationError: too little traffic, or it does not excite the arm enough.
    """
    return calibrate_segments([(t, q, dq, tau)], settings, source)


def friction_prior(s: CalibrationSettings) -> tuple[np.ndarray, np.ndarray]:
    """The friction prior ``(centre (7, 9), standard deviation (7, 9))``
    (:data:`sim.arm.FRICTION_COLUMNS`): Gaz's sigmoid at Gaz's values (``friction_rel`` of
    each as deviation), no viscous friction (``viscous_std``), no Stribeck excess
    (``stribeck_std``) at :data:`sim.arm.STRIBECK_VS` (``stribeck_vs_std``)."""
    centre = full_friction(GAZ_PHI)
    sd = np.empty((7, len(FRICTION_COLUMNS)))
    sd[:, :3] = s.friction_rel * np.abs(GAZ_PHI)
    sd[:, 3:5] = s.viscous_std
    sd[:, 5:7] = s.stribeck_std
    sd[:, 7:9] = s.stribeck_vs_std
    return centre, sd


FRICTION_BOUNDS = np.array([
    [0.0, 5.0],  # phi1, N·m
    [1.0, 200.0],  # phi2, s/rad
    [-0.2, 0.2],  # phi3, rad/s
    [0.0, 2.0], [0.0, 2.0],  # viscous, N·m·s/rad
    [-2.0, 3.0], [-2.0, 3.0],  # Stribeck excess, N·m
    [0.01, 1.0], [0.01, 1.0],  # Stribeck velocities, rad/s
])
"""Bounds of the fitted friction, per column: the fit stays where the model means what it
says (a sigmoid that rises with speed, dissipative viscous friction, a Stribeck velocity
inside the motion's speeds)."""


def _fit_map(W, dq, tau, theta0, phi0, sd_theta, sd_phi, sd_off, s: CalibrationSettings):
    """The MAP of ``(theta, friction, offsets)`` on the signals ``W (N, 7, 70)``, ``dq``,
    ``tau`` (``(N, 7)``), by Levenberg-Marquardt in prior-scaled unknowns inside
    :data:`FRICTION_BOUNDS`: a step is taken only if it lowers the posterior's cost, the
    damping grows until it does. Returns ``(theta, friction, offsets, iterations)``."""
    n, k = dq.shape[0], phi0.shape[1]
    w = 1.0 / s.sigma_tau
    # unknowns: theta (70), then per joint its friction (k) and offset, prior-scaled
    sd = np.concatenate((sd_theta, np.column_stack((sd_phi, sd_off)).ravel()))
    x0 = np.concatenate((theta0, np.column_stack((phi0, np.zeros(7))).ravel()))
    bounds = np.vstack((FRICTION_BOUNDS[:k], [[-np.inf, np.inf]]))
    lo = np.concatenate((np.full(70, -np.inf), np.tile(bounds[:, 0], 7)))
    hi = np.concatenate((np.full(70, np.inf), np.tile(bounds[:, 1], 7)))
    A = (W * (sd_theta * w)).transpose(1, 2, 0)  # (7, 70, N), constant
    AtA = np.einsum("jan,jbn->ab", A, A)

    def split(x):
        joint = x[70:].reshape(7, k + 1)
        return x[:70], joint[:, :k], joint[:, k]

    def residual(x):
        theta, phi, off = split(x)
        return tau - W @ theta - friction_torque(dq, phi) - off

    def cost(x, r):
        return float(w * w * np.sum(r * r) + np.sum(((x - x0) / sd) ** 2))

    x = x0.copy()
    r = residual(x)
    c = cost(x, r)
    lam, nu = s.damping, 2.0
    m = k + 1
    it = 0
    for it in range(1, s.iterations + 1):  # noqa: B007
        _, phi, _ = split(x)
        G = np.empty((n, 7, m))
        G[..., :k] = friction_jacobian(dq, phi) * sd_phi
        G[..., k] = sd_off
        G = (G * w).transpose(1, 0, 2)  # (7, N, m)
        lhs = np.zeros((70 + 7 * m, 70 + 7 * m))
        lhs[:70, :70] = AtA
        AtG = A @ G  # (7, 70, m)
        GtG = G.transpose(0, 2, 1) @ G  # (7, m, m)
        for j in range(7):
            b = slice(70 + m * j, 70 + m * (j + 1))
            lhs[:70, b] = AtG[j]
            lhs[b, :70] = AtG[j].T
            lhs[b, b] = GtG[j]
        lhs[np.diag_indices_from(lhs)] += 1.0
        wr = (w * r).T[:, :, None]  # (7, N, 1)
        rhs = np.concatenate(((A @ wr).sum(axis=0)[:, 0],
                              (G.transpose(0, 2, 1) @ wr)[..., 0].ravel())) - (x - x0) / sd
        diag = np.diag(lhs).copy()
        while True:  # damp until the step lowers the cost (Nielsen's update of the damping)
            step = np.linalg.solve(lhs + lam * np.diag(diag), rhs)
            x_new = np.clip(x + step * sd, lo, hi)
            r_new = residual(x_new)
            c_new = cost(x_new, r_new)
            gain = (c - c_new) / max(step @ (lam * diag * step + rhs), 1e-300)
            if c_new < c or lam > 1e10:
                break
            lam *= nu
            nu *= 2.0
        if c_new >= c:
            break  # no step lowers the cost: a minimum (up to the bounds)
        small = c - c_new < s.tolerance
        x, r, c = x_new, r_new, c_new
        lam *= max(1.0 / 3.0, 1.0 - (2.0 * gain - 1.0) ** 3)
        nu = 2.0
        if small:
            break
    theta, phi, off = split(x)
    return theta.copy(), phi.copy(), off.copy(), it


def _joint_rms(res: np.ndarray) -> np.ndarray:
    return np.sqrt(np.mean(res ** 2, axis=0))


def _local_refit(res: np.ndarray, jac: np.ndarray) -> np.ndarray:
    """One joint's friction amplitudes (``phi1``, viscous, Stribeck: the model is linear in
    them; the Jacobian ``jac`` ``(N, 9)`` at the current non-linear parameters gives their
    columns) and offset, fitted by bounded least squares to its residual ``res`` ``(N,)``
    of the bodies alone: ``(6,)``. Zero friction and offset are within the bounds, so the
    result never fits worse than none."""
    from scipy.optimize import lsq_linear

    amp = list(AMPLITUDES)
    cols = np.column_stack((jac[:, amp], np.ones_like(res)))
    lo = np.r_[FRICTION_BOUNDS[amp, 0], -np.inf]
    hi = np.r_[FRICTION_BOUNDS[amp, 1], np.inf]
    return lsq_linear(cols, res, bounds=(lo, hi)).x


AMPLITUDES = (0, 3, 4, 5, 6)
"""The friction columns the torque is linear in: ``phi1``, viscous, Stribeck excess."""


def calibrate_segments(parts, settings: CalibrationSettings = CalibrationSettings(),
                       source: str = "traffic", end_effector=None,
                       refuse: bool = True) -> ArmParams:
    """:func:`calibrate` on several recordings ``[(t, q, dq, tau), ...]``, each filtered on
    its own (several logs, or one log split at its gaps by :func:`segments`).
    ``end_effector`` (a spec or :class:`sim.end_effector.EndEffector`; None: the Franka
    Hand) is the prior's body 7 and the nominal model the result is compared with.
    ``refuse=False`` fits too little excitation instead of refusing it (the prior holds the
    directions it lacks): the cross-validation's folds (:mod:`sim.calibration_noise`)."""
    s = settings
    if not parts:
        raise CalibrationError("no traffic to calibrate from (no segment of at least 3 s)")
    prepared = [prepare(*part, s) for part in parts]
    q, dq, ddq, tau = (np.concatenate([p[i] for p in prepared]) for i in range(1, 5))
    duration = float(sum(p[0][-1] - p[0][0] for p in prepared))
    nominal_model = PandaModel().model
    from .end_effector import EndEffector
    from .end_effector import end_effector as resolve_end_effector

    # the prior's centre: the declared end effector
    ee = end_effector if isinstance(end_effector, EndEffector) else resolve_end_effector(
        end_effector)
    theta0 = nominal_link_params(ee).ravel()
    W = _regressors(nominal_model, q, dq, ddq)  # (N, 7, 70)
    n = W.shape[0]
    Wf = W.reshape(-1, 70)
    basis = base_basis(nominal_model)
    sd_theta = link_prior_std(theta0, s)
    phi0, sd_phi = friction_prior(s)
    sd_off = np.full(7, s.offset_std)

    # excitation: base directions (prior-scaled), Gaz's and the viscous friction at the
    # prior's centre, offsets (the Stribeck part, seen only near zero speed, is left to
    # its prior where the motion does not show it)
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
    try:
        cond = check_excitation(q, dq, cols, names, to_named)
    except CalibrationError:
        if refuse:
            raise
        cond = float("inf")  # a cross-validation fold: the prior holds what it lacks

    theta, phi, off, iterations = _fit_map(W, dq, tau, theta0, phi0, sd_theta, sd_phi,
                                           sd_off, s)
    # the constrained MAP, in the metric of the posterior of theta (friction, offsets fixed)
    w = 1.0 / s.sigma_tau
    A_theta = Wf * w
    fixed = consistent_map(theta, A_theta.T @ A_theta + np.diag(1.0 / sd_theta ** 2))
    params, moved = consistent(theta if fixed is None else fixed, theta0.reshape(7, 10))
    params, phi, off, warnings, fallback = never_worse(W, dq, tau, theta0, params, phi, off)
    before = tau - (W @ theta0)
    after = tau - (W @ params.ravel()) - friction_torque(dq, phi) - off
    d_m7 = params[6, 0] - theta0[60]
    if d_m7 > max(PAYLOAD_WARN_SIGMAS * sd_theta[60], PAYLOAD_WARN_KG):
        warnings.append(f"body 7 reads {d_m7:.3f} kg heavier than nominal (its prior allows "
                        f"about {sd_theta[60]:.3f} kg): the residual looks like a payload is "
                        "mounted; calibrate on the bare arm")
    report = {
        "source": source,
        "samples": int(n),
        "duration_s": duration,
        "segments": len(prepared),
        "base_parameters": int(basis.shape[1]),
        "condition_number": cond,
        "iterations": iterations,
        "rms_before": _joint_rms(before).tolist(),
        "rms_after": _joint_rms(after).tolist(),
        "consistency": "lmi" if fixed is not None else "shrink toward nominal",
        "consistency_moved_bodies": moved,
        "fallback_joints": fallback,
        "warnings": warnings,
        "settings": {k: getattr(s, k) for k in s.__dataclass_fields__},
    }
    return ArmParams(params, phi, off, report, end_effector=ee.label)


def never_worse(W, dq, tau, theta0, params, phi, off):
    """The calibrated ``(params, friction, offsets)``, changed where they fit a joint worse
    than the nominal model (bodies ``theta0``, no friction, no offsets) on the fitted
    signals ``W (N, 7, 70)``, ``dq``, ``tau`` (``(N, 7)``), and the warnings that says so.

    A joint's friction and offset are its own: where a joint fits worse, they are refitted
    by bounded least squares on that joint alone (:func:`_local_refit`). Where the bodies
    are to blame (still worse), the bodies go back to nominal, each joint's friction and
    offset refitted on them, which fits no joint worse than the nominal model."""
    theta0 = np.asarray(theta0, dtype=float).ravel()
    nominal_rms = _joint_rms(tau - W @ theta0)
    phi = np.array(phi, dtype=float)
    off = np.array(off, dtype=float)

    def refit(bodies, joints):
        res = tau - W @ bodies.ravel()
        jac = friction_jacobian(dq, phi)
        for j in joints:
            coef = _local_refit(res[:, j], jac[:, j, :])
            phi[j, list(AMPLITUDES)] = coef[:5]
            off[j] = coef[5]
        return _joint_rms(res - friction_torque(dq, phi) - off)

    rms = _joint_rms(tau - W @ params.ravel() - friction_torque(dq, phi) - off)
    worse = np.flatnonzero(rms > nominal_rms)
    warnings = []
    first = rms
    if worse.size:
        rms = refit(params, worse)
        warnings += [f"joint {j + 1}: the calibrated model fitted {first[j]:.4f} N·m RMS, "
                     f"the nominal model {nominal_rms[j]:.4f}: its friction and offset were "
                     f"refitted alone ({rms[j]:.4f})" for j in worse]
    still = np.flatnonzero(rms > nominal_rms)
    if still.size:
        params = theta0.reshape(7, 10).copy()
        refit(params, range(7))
        warnings.append(f"joints {', '.join(str(j + 1) for j in still)} still fitted worse "
                        "than the nominal model: the bodies kept nominal, the friction and "
                        "offsets refitted on them")
    return params, phi, off, warnings, [int(j) + 1 for j in worse]


def residual_rms(arm: ArmParams | None, t, q, dq, tau,
                 settings: CalibrationSettings = CalibrationSettings()) -> np.ndarray:
    """Per-joint RMS of ``tau - model`` (N·m) on traffic prepared as :func:`calibrate` does,
    for ``arm`` (None: the nominal model): how well an arm model explains held-out motion."""
    t, q, dq, ddq, tau = prepare(t, q, dq, tau, settings)
    model = PandaModel(arm=arm)
    pred = np.array([model.rnea(q[k], dq[k], ddq[k]) for k in range(q.shape[0])])
    return np.sqrt(np.mean((tau - pred) ** 2, axis=0))
