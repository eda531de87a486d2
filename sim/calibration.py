"""Calibrating the arm: its departure from the nominal model, from bare-arm traffic.

Model of the measured link-side torque of the bare arm (no payload)::

    tau_J = W(q, dq, ddq) theta + tau_f(dq; phi) + offset + noise

``W`` is Pinocchio's joint-torque regressor (``computeJointTorqueRegressor``, 7 x 70: ten
dynamic parameters per joint body), ``theta`` the bodies' parameters, ``tau_f`` Gaz's
friction (:func:`sim.arm.gaz_friction`) and ``offset`` one constant per torque sensor.

Steps (:func:`calibrate`):

1. **Signals.** The whole log is there, so the filtering is zero-phase: ``q``, ``dq`` and
   ``tau`` through the same 4th-order Butterworth forwards and backwards (``cutoff_hz``),
   ``ddq`` the central difference of the filtered ``dq`` on the recorded time stamps; then
   decimated to ``rate_hz`` (100 Hz), the first and last ``trim_s`` dropped.
2. **Base parameters.** Only combinations of ``theta`` act on the torques. Column-pivoted QR
   of the regressor at random states, with a relative tolerance (:data:`QR_TOL`), gives their
   number and a basis; the excitation's condition number is that of the recorded regressor on
   this basis (and on the friction and offset columns), each column scaled by its prior
   standard deviation, so that it measures the motion, not the units.
3. **Refusal.** A joint that barely moves (range under :data:`MIN_RANGE`, or speed under
   :data:`MIN_SPEED` in either direction: friction needs both signs) or a condition number
   above :data:`MAX_CONDITION` is refused with :class:`CalibrationError`, naming the joints
   and the parameter directions the motion does not see.
4. **Fit: maximum a posteriori, by Gauss-Newton.** A prior centred on the nominal model
   (``theta``: the bounds of a few-percent link error, :func:`link_prior_std`; friction: Gaz's
   values with half their size as standard deviation; offsets 0 +- 0.5 N·m) regularises the
   least squares, so the directions the motion does not excite stay nominal and the excited
   ones follow the data. Friction is non-linear in ``phi2, phi3``: each iteration linearises
   it at the current ``phi`` (:func:`sim.arm.gaz_friction_jacobian`) and solves the linear
   MAP problem for all unknowns at once (70 + 21 + 7), until the step is negligible. (The
   exact sigmoid is fitted, not a fixed-shape linearisation: Gaz's ``phi2`` differ by a
   factor of 3 between joints and the simulated arm scales them by up to 30 %.)
5. **Physical consistency.** Each body's pseudo-inertia must be positive definite. The
   fit is moved to the consistent parameters nearest it in the metric of its own posterior
   precision (:func:`consistent_map`: the MAP under the pseudo-inertia LMIs, a small
   semidefinite program solved by Clarabel through cvxpy), so it moves mostly along the
   directions the data do not see and the torques barely change. Should the solver fail, a
   body still inconsistent is moved back toward its nominal values (a convex set holds both)
   just far enough (:func:`consistent`), which the report names.
6. **Payload check.** A payload on the flange acts like extra mass on body 7: if the fit
   makes body 7 heavier than its prior allows (:data:`PAYLOAD_WARN_SIGMAS` standard
   deviations, at least :data:`PAYLOAD_WARN_KG`), the result carries a warning.

The result is a :class:`sim.arm.ArmParams` whose ``report`` holds the per-joint residual RMS
before (nominal model) and after, the condition number, the number of base parameters and
any warnings.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin
from scipy.linalg import qr
from scipy.signal import butter, sosfiltfilt

from iem.errors import InvalidInputError

from .arm import GAZ_PHI, ArmParams, gaz_friction, gaz_friction_jacobian
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
"""Largest condition number of the prior-scaled excitation (base parameters, friction,
offsets) that is accepted (the shipped calibration motion: about 700; another seed of it
630)."""
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
        iterations: most Gauss-Newton iterations.
        mass_rel, com_abs, inertia_rel: bounds of the link error the prior allows (-, m, -).
        friction_rel: prior standard deviation of Gaz's parameters, relative.
        offset_std: prior standard deviation of the offsets, N·m.
    """

    cutoff_hz: float = 10.0
    rate_hz: float = 100.0
    trim_s: float = 0.5
    sigma_tau: float = 0.05
    iterations: int = 20
    mass_rel: float = 0.05
    com_abs: float = 0.005
    inertia_rel: float = 0.10
    friction_rel: float = 0.5
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
def prepare(t, q, dq, tau, s: CalibrationSettings = CalibrationSettings()):
    """Zero-phase filtered, differentiated and decimated ``(t, q, dq, ddq, tau)``."""
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


def _direction_names(v: np.ndarray, top: int = 3) -> str:
    order = np.argsort(-np.abs(v))[:top]
    return " + ".join(f"{v[i]:+.2f} body{i // 10 + 1}.{PARAM_NAMES[i % 10]}" for i in order)


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


def calibrate_segments(parts, settings: CalibrationSettings = CalibrationSettings(),
                       source: str = "traffic") -> ArmParams:
    """:func:`calibrate` on several recordings ``[(t, q, dq, tau), ...]``, each filtered on
    its own (several logs, or one log split at its gaps by :func:`segments`)."""
    s = settings
    if not parts:
        raise CalibrationError("no traffic to calibrate from (no segment of at least 3 s)")
    prepared = [prepare(*part, s) for part in parts]
    np.concatenate([p[0] for p in prepared])
    q, dq, ddq, tau = (np.concatenate([p[i] for p in prepared]) for i in range(1, 5))
    duration = float(sum(p[0][-1] - p[0][0] for p in prepared))
    nominal_model = PandaModel().model
    theta0 = nominal_link_params().ravel()
    W = _regressors(nominal_model, q, dq, ddq)  # (N, 7, 70)
    n = W.shape[0]
    Wf = W.reshape(-1, 70)
    y = tau.reshape(-1)
    basis = base_basis(nominal_model)
    sd_theta = link_prior_std(theta0, s)
    sd_phi = (s.friction_rel * np.abs(GAZ_PHI)).ravel()
    sd_off = np.full(7, s.offset_std)

    def friction_columns(phi):
        jac = gaz_friction_jacobian(dq, phi)  # (N, 7, 3)
        cols = np.zeros((n, 7, 21))
        for j in range(7):
            cols[:, j, 3 * j:3 * j + 3] = jac[:, j, :]
        return cols.reshape(-1, 21)

    offset_cols = np.tile(np.eye(7), (n, 1))
    # excitation: base directions (prior-scaled), friction at Gaz's values, offsets
    scaled_basis = np.linalg.qr(basis / sd_theta[:, None])[0]  # base directions, scaled
    scaled_base = (Wf * sd_theta) @ scaled_basis
    cols = np.hstack((scaled_base, friction_columns(GAZ_PHI) * sd_phi, offset_cols * sd_off))
    names = ([f"body{i // 10 + 1}.{PARAM_NAMES[i % 10]}" for i in range(70)]
             + [f"joint{j + 1}.phi{c + 1}" for j in range(7) for c in range(3)]
             + [f"joint{j + 1}.offset" for j in range(7)])
    r = basis.shape[1]
    to_named = np.zeros((98, r + 28))
    to_named[:70, :r] = scaled_basis
    to_named[70:, r:] = np.eye(28)
    cond = check_excitation(q, dq, cols, names, to_named)

    # MAP by Gauss-Newton in prior-scaled unknowns z = x / sd
    sd = np.concatenate((sd_theta, sd_phi, sd_off))
    theta, phi, off = theta0.copy(), np.array(GAZ_PHI, dtype=float), np.zeros(7)
    w = 1.0 / s.sigma_tau
    for _ in range(s.iterations):
        fric = gaz_friction(dq, phi).reshape(-1)
        r = y - Wf @ theta - fric - np.tile(off, n)
        A = np.hstack((Wf, friction_columns(phi), offset_cols)) * sd * w
        x = np.concatenate((theta - theta0, (phi - GAZ_PHI).ravel(), off)) / sd
        # minimise |w r - A dz|² + |x + dz|²
        lhs = A.T @ A + np.eye(A.shape[1])
        dz = np.linalg.solve(lhs, A.T @ (w * r) - x)
        step = dz * sd
        theta += step[:70]
        phi = phi + step[70:91].reshape(7, 3)
        phi[:, 1] = np.maximum(phi[:, 1], 0.1)  # a sigmoid's slope stays positive
        off += step[91:]
        if np.max(np.abs(dz)) < 1e-6:
            break
    # the constrained MAP, in the metric of the posterior of theta (friction, offsets fixed)
    A_theta = Wf * w
    fixed = consistent_map(theta, A_theta.T @ A_theta + np.diag(1.0 / sd_theta ** 2))
    params, moved = consistent(theta if fixed is None else fixed, theta0.reshape(7, 10))
    before = tau - (W @ theta0)
    after = tau - (W @ params.ravel()) - gaz_friction(dq, phi) - off
    warnings = []
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
        "rms_before": np.sqrt(np.mean(before ** 2, axis=0)).tolist(),
        "rms_after": np.sqrt(np.mean(after ** 2, axis=0)).tolist(),
        "consistency": "lmi" if fixed is not None else "shrink toward nominal",
        "consistency_moved_bodies": moved,
        "warnings": warnings,
        "settings": {k: getattr(s, k) for k in s.__dataclass_fields__},
    }
    return ArmParams(params, phi, off, report)


def residual_rms(arm: ArmParams | None, t, q, dq, tau,
                 settings: CalibrationSettings = CalibrationSettings()) -> np.ndarray:
    """Per-joint RMS of ``tau - model`` (N·m) on traffic prepared as :func:`calibrate` does,
    for ``arm`` (None: the nominal model): how well an arm model explains held-out motion."""
    t, q, dq, ddq, tau = prepare(t, q, dq, tau, settings)
    model = PandaModel(arm=arm)
    pred = np.array([model.rnea(q[k], dq[k], ddq[k]) for k in range(q.shape[0])])
    return np.sqrt(np.mean((tau - pred) ** 2, axis=0))
