"""Offline commissioning identification: a payload from a loaded and a bare recording.

``identify(loaded, bare)`` (or ``identify(loaded, arm=ARM)``) takes recorded joint states (the
arrays ``t, q, dq, tau`` at 1 kHz or any rate, in any form :func:`iem.recording.as_recording`
accepts) and returns an :class:`Identification`: the payload's ten parameters, physically
consistent, with their covariance, and which of them the data determine and which the prior.

Method (offline, so the filters may be non-causal):

1. **Signals** (:func:`iem.recording.filtered`). Each recording goes on a uniform time grid at
   its own median rate (interpolating over the time stamps it has, so lost cycles shift
   nothing); spikes (single corrupt samples, more than 6 robust standard deviations from a
   local quadratic fit) are replaced by that fit; ``q``, ``dq`` and ``tau`` go through a
   zero-phase Butterworth low-pass (order 4, ``cutoff_hz`` = 10 Hz: no lag, so every signal
   lines up with every other); ``ddq`` is the central difference of the filtered ``dq``; the
   result is taken every ``1/rate_hz`` s (100 Hz; the low-pass is the anti-alias filter),
   ``edge_s`` trimmed at both ends.
2. **Alignment.** The bare recording is moved in time onto the loaded one by the peak of the
   cross-correlation of their filtered joint velocities (sub-sample, parabolic), and sampled
   at the loaded recording's instants. The two must be the same motion: on the overlap (at
   least ``min_overlap_s``) no joint may differ by more than ``path_tol`` rad, else
   :class:`MismatchedLogsError`.
3. **Residual torques.** ``r = (tau_L - tau_nom(x_L)) - (tau_B - tau_nom(x_B))``, ``tau_nom``
   the nominal Panda's RNEA at each recording's own filtered state. What the nominal model
   gets wrong about the arm (links, friction, torque offsets) is nearly the same in both and
   cancels; the small difference between the two actual motions (the loaded arm tracks a few
   mrad differently) is accounted for by the model instead of being read as payload. With an
   arm file instead of a bare recording, ``r = tau_L - tau_arm(x_L)`` for any motion.
4. **Robust weighted least squares.** ``r = Y(x_L) phi + c lead + e`` with ``Y`` the flange
   body regressor of :class:`sim.robot.PandaModel`, and ``c`` the time derivative of the
   torques that enter ``r``: a torque sample may belong to a slightly later instant than the
   joint state it comes with (the project's plant reports the torque applied over the
   following 1 ms cycle, half a cycle ahead; a real sensor has its own delay), so that lead is
   estimated with the payload (prior 0 ± 2 ms) and marginalised out; it is reported as
   ``tau_lead_s``. Rows are weighted by the inverse variance of their joint's residual (a
   robust scale, 1.4826 MAD) times Huber weights (``huber`` = 1.345 scale units, iteratively
   reweighted), so that a disturbance longer than a spike (a touch, a cable pulling) pulls
   with bounded force.
5. **Prior.** A stated weak Gaussian prior: standard deviations of the Panda's rated payload
   (:data:`iem.least_squares.DEFAULT_PRIOR_STD`: 3 kg, 0.3 kg·m, 0.01 kg·m²); zero mean for
   the mass and the first moments, and for the inertia about the flange the inertia of a
   point mass at the CoM a first fit found (refit once from there): a body whose CoM is far
   from the flange has at least that inertia about it, so a zero mean would contradict it
   (a 2.8 kg tool 0.1 m off-axis on the unexciting 6 s task path was refused as "not a rigid
   body" with it). On an exciting motion the data determine every parameter thousands of
   times better and the prior moves nothing; it only keeps unexcited directions finite.
6. **Physical consistency.** The weighted least-squares cost is ``(phi - phi_hat)^T H (phi -
   phi_hat) + const``, ``H`` the posterior precision, so the constrained least squares under
   the pseudo-inertia LMI ``J(phi) >= eps E`` is exactly the weighted projection
   :func:`iem.consistency.project` (a log-barrier Newton method, checked against SLSQP in its
   tests): no separate convex-programming dependency.
7. **Uncertainty.** ``cov = H^-1`` (the lead marginalised out), ``std`` its diagonal's root,
   with the residual variance measured on the
   data and inflated by the residuals' own autocorrelation (filtered noise and model error are
   not white at 100 Hz: ``1 + 2 sum rho_k``). A parameter is *determined by the data* if its
   posterior std is below ``DATA_SHARE`` (a quarter) of its prior std, else *by the prior*.

Refusals (all :class:`IdentifyError`, so ``iem`` exits with status 2):

- :class:`MismatchedLogsError`: the two recordings are not the same motion (step 2).
- :class:`ExcitationError`: the motion does not determine each direction of the parameters to
  within ``excitation_tol`` (1 sigma; per group: mass 0.01 kg, first moments 0.002 kg·m,
  inertia 0.001 kg·m²), measured in the posterior covariance scaled by those tolerances; the
  message names the directions not excited and the parameters in them.
- :class:`BareLoadError`, the payload in the "bare" recording. The rule tests the loaded-minus-
  bare difference, not the bare recording against the nominal model alone (on a real arm the
  nominal model is off by 0.5-2 N·m, which a flange body can partly absorb):

  a. the difference carries no load: its mass is below ``min_mass`` (0.01 kg) or below 5
     standard deviations: the same load is in both recordings;
  b. the difference is not a rigid body: the unconstrained estimate lies more than
     ``BODY_SIGMAS`` (5) standard deviations (Mahalanobis, in ``H``) from the nearest
     consistent body, e.g. a negative mass or a negative inertia: the bare recording carries
     a load of its own that differs from the loaded one;
  c. the bare recording, against the nominal model, looks like a gross load at the flange:
     fitted alone it gives a consistent body of at least ``BARE_MASS`` (1 kg) that explains at
     least ``BARE_EXPLAINED`` (95 %) of the bare residual's power. Only a gross load, because
     a real arm's own model error looks partly like a flange body: on the simulated Panda,
     random link errors (mass ±5 %, CoM ±5 mm, inertia ±10 %) with friction and offsets read
     as 0.02-0.2 kg explaining 13-70 % of the residual, but every link 5 % heavier (2 N·m of
     residual, the top of a real Panda's 0.5-2 N·m) reads as 0.43-0.51 kg explaining 90 %,
     and 8 % heavier as 0.71 kg explaining 95 %. This rule catches a different, lighter tool
     left on the flange for the bare recording, which (a) and (b) cannot see when the
     difference of the two happens to be a rigid body. Its figures are always in the report
     (``bare_flange_mass_kg``, ``bare_flange_explained``).

The module is numpy-only at import (the ``iem`` core's rule); scipy and Pinocchio (through
:mod:`sim.robot`) are imported when :func:`identify` runs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .consistency import is_consistent, project, pseudo_inertia
from .errors import InvalidInputError
from .least_squares import DEFAULT_PRIOR_STD
from .recording import Recording, Signals, as_recording, filtered, lag, sample
from .types import GROUPS, N_JOINTS, PARAMS

__all__ = ["BareLoadError", "ExcitationError", "Identification", "IdentifyError",
           "MismatchedLogsError", "Recording", "as_recording", "identify"]

CUTOFF_HZ = 10.0
"""Default zero-phase low-pass cutoff, Hz."""
RATE_HZ = 100.0
"""Default rate of the equations after decimation, Hz."""
EDGE_S = 0.1
"""Default time trimmed at both ends of a recording after filtering, s."""
PATH_TOL = 0.02
"""Default largest joint difference between a loaded and a bare recording, rad."""
MIN_OVERLAP_S = 1.0
"""Default shortest common stretch of a loaded and a bare recording, s."""
HUBER = 1.345
"""Default Huber threshold in robust-scale units (95 % efficiency on Gaussian noise)."""
EXCITATION_TOL = {"mass": 0.01, "com": 0.002, "inertia": 0.001}
"""Default 1-sigma tolerance per group that every direction must be determined to (kg, kg·m,
kg·m²)."""
DATA_SHARE = 0.25
"""A parameter is determined by the data if its posterior std is below this share of its
prior std."""
MIN_MASS = 0.01
"""Smallest payload mass the difference of two recordings must show, kg."""
BODY_SIGMAS = 5.0
"""How far (standard deviations) the unconstrained estimate may lie from a rigid body."""
BARE_MASS = 1.0
"""A bare recording fitting a flange body of this mass (kg) or more is refused ..."""
BARE_EXPLAINED = 0.95
"""... if that body explains at least this share of its residual power."""
LEAD_PRIOR_S = 0.002
"""Prior std of the torque's lead over the joint state it comes with, s (zero mean)."""
IRLS_STEPS = 8
MAX_LAG_ACF = 30


class IdentifyError(InvalidInputError):
    """Recordings from which no payload can honestly be identified."""


class MismatchedLogsError(IdentifyError):
    """The loaded and bare recordings are not the same motion."""


class ExcitationError(IdentifyError):
    """The motion does not determine the payload's parameters."""


class BareLoadError(IdentifyError):
    """The "bare" recording carries a load."""


# -- result ------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Identification:
    """What :func:`identify` found.

    Attributes:
        phi: the payload, paper order ``[m, mrx, mry, mrz, Ixx, Ixy, Ixz, Iyy, Iyz, Izz]``
            (kg, kg·m, kg·m², inertia about the flange origin), physically consistent.
        std: one standard deviation per parameter of ``phi``, same units.
        cov: the posterior covariance of ``phi`` (10x10; ``std`` is the root of its diagonal),
            e.g. to start an online estimator from this result as its prior.
        phi_unconstrained: the robust least-squares estimate before the consistency
            projection.
        prior_std: the prior's standard deviation per parameter (zero mean).
        determined_by: ``"data"`` or ``"prior"`` per parameter (see ``DATA_SHARE``).
        payload_std: std of the payload in the TOML's terms: ``mass`` (kg), ``com`` (m, 3),
            ``inertia`` (kg·m² about the CoM, 6), by first-order propagation from ``std``.
        report: figures of the run (samples, lag, path difference, residual RMS per joint
            before and after, noise inflation, outliers, min eigenvalue of the pseudo-inertia).
    """

    phi: np.ndarray
    std: np.ndarray
    cov: np.ndarray
    phi_unconstrained: np.ndarray
    prior_std: np.ndarray
    determined_by: tuple[str, ...]
    payload_std: dict
    report: dict = field(default_factory=dict, compare=False)

    def payload(self, name: str = "identified"):
        """The result as a :class:`sim.payload.Payload` (mass, CoM, inertia about the CoM)."""
        from sim.payload import Payload

        return Payload.from_phi(self.phi, name=name)

    def summary(self, name: str = "identified") -> dict:
        """The JSON summary: ``payload {mass, com, inertia}`` and ``std {mass, com,
        inertia}`` in the payload file's units, plus phi, its std and the report."""
        p = self.payload(name)
        return {
            "payload": {"name": p.name, "mass": p.mass, "com": list(p.com),
                        "inertia": list(p.inertia)},
            "std": {"mass": self.payload_std["mass"], "com": list(self.payload_std["com"]),
                    "inertia": list(self.payload_std["inertia"])},
            "units": {"mass": "kg", "com": "m, flange frame",
                      "inertia": "kg·m² about the CoM, [Ixx, Ixy, Ixz, Iyy, Iyz, Izz]"},
            "phi": dict(zip(PARAMS, self.phi.tolist(), strict=True)),
            "phi_std": dict(zip(PARAMS, self.std.tolist(), strict=True)),
            "determined_by": dict(zip(PARAMS, self.determined_by, strict=True)),
            "prior": {"mean": 0.0, "std": dict(zip(PARAMS, self.prior_std.tolist(),
                                                   strict=True))},
            "report": self.report,
        }




# -- the method --------------------------------------------------------------------------------
def _align(loaded: Signals, bare: Signals, path_tol: float, min_overlap_s: float):
    shift = lag(loaded, bare)
    t_bare = bare.fine_t + shift
    keep = (loaded.t >= t_bare[0]) & (loaded.t <= t_bare[-1])
    overlap = float(loaded.t[keep][-1] - loaded.t[keep][0]) if keep.sum() > 1 else 0.0
    if overlap < min_overlap_s:
        raise MismatchedLogsError(
            f"the loaded and bare recordings share {overlap:.2f} s of motion at their best "
            f"alignment (bare shifted by {shift:+.3f} s); they must be recordings of the same "
            f"motion overlapping at least {min_overlap_s:g} s")
    at = sample(bare, loaded.t[keep] - shift)
    diff = np.abs(loaded.q[keep] - at["q"])
    worst = np.unravel_index(int(np.argmax(diff)), diff.shape)
    if diff[worst] > path_tol:
        raise MismatchedLogsError(
            f"the loaded and bare recordings are not the same motion: joint {worst[1] + 1} "
            f"differs by {diff[worst]:.4f} rad at t = {loaded.t[keep][worst[0]]:.2f} s of the "
            f"loaded recording (bare shifted by {shift:+.3f} s, RMS difference "
            f"{np.sqrt(np.mean(diff**2)):.4f} rad); valid is the same path within "
            f"{path_tol:g} rad, or an arm file (--arm) for a different motion")
    return keep, at, {"lag_s": shift, "overlap_s": overlap, "path_diff_max_rad": float(diff.max()),
                      "path_diff_rms_rad": float(np.sqrt(np.mean(diff**2)))}


def _residuals_and_regressor(model, q, dq, ddq, tau) -> tuple[np.ndarray, np.ndarray]:
    n = q.shape[0]
    r = np.empty((n, N_JOINTS))
    Y = np.empty((n, N_JOINTS, 10))
    for i in range(n):
        tau_nom, Y[i] = model.rnea_and_regressor(q[i], dq[i], ddq[i])
        r[i] = tau[i] - tau_nom
    return r, Y


def _nominal_residual(model, q, dq, ddq, tau) -> np.ndarray:
    return np.array([tau[i] - model.rnea(q[i], dq[i], ddq[i]) for i in range(q.shape[0])])


def _mad_scale(e: np.ndarray) -> np.ndarray:
    """Per-joint robust scale of residuals (n, 7), floored to stay positive."""
    med = np.median(e, axis=0)
    s = 1.4826 * np.median(np.abs(e - med), axis=0)
    floor = 1e-6 + 1e-3 * np.sqrt(np.mean(e**2))
    return np.maximum(s, floor)


def _acf_inflation(u: np.ndarray) -> float:
    """``1 + 2 sum_k rho_k`` of standardized residuals (n, 7), averaged over joints, summed
    until the first non-positive lag (the effective-sample-size correction), >= 1."""
    n = u.shape[0]
    total = 0.0
    for j in range(u.shape[1]):
        x = u[:, j] - u[:, j].mean()
        var = float(x @ x)
        if var <= 0.0:
            continue
        acc = 0.0
        for k in range(1, min(MAX_LAG_ACF, n - 1) + 1):
            rho = float(x[:-k] @ x[k:]) / var
            if rho <= 0.0:
                break
            acc += rho
        total += 1.0 + 2.0 * acc
    return max(1.0, total / u.shape[1])


@dataclass
class _Fit:
    """A robust fit of ``r = [Y, c] [phi; lead]`` and the payload's marginal posterior."""

    theta: np.ndarray  # phi (10), then the torque lead (s)
    H: np.ndarray  # posterior precision of theta (data + prior)
    scale: np.ndarray  # per-joint residual scale, N·m
    sigma2: float
    inflation: float
    weights: np.ndarray  # Huber weights (n, 7)
    residual: np.ndarray  # (n, 7) at theta

    def __post_init__(self) -> None:
        self.cov_theta = np.linalg.inv(self.H)
        self.phi = self.theta[:10]
        self.cov = self.cov_theta[:10, :10]
        self.std = np.sqrt(np.diag(self.cov))
        self.H_phi = np.linalg.inv(self.cov)  # the lead marginalised out (Schur complement)


def _robust_fit(Y: np.ndarray, r: np.ndarray, prior_prec: np.ndarray, huber: float,
                prior_mean: np.ndarray | None = None) -> _Fit:
    """Huber IRLS of ``r = Y phi`` with per-joint scales and the Gaussian prior (mean
    ``prior_mean``, zero if None)."""
    pm = np.zeros(prior_prec.shape[0]) if prior_mean is None else prior_mean
    pull = prior_prec @ pm
    n = r.shape[0]
    p = Y.shape[2]
    A = Y.reshape(-1, p)
    b = r.reshape(-1)
    w_h = np.ones((n, N_JOINTS))
    scale = _mad_scale(r)
    sigma2, inflation = 1.0, 1.0
    phi = np.zeros(p)
    for _ in range(IRLS_STEPS):
        w = (w_h / scale**2).reshape(-1)
        Aw = A * w[:, None]
        H_data = (A.T @ Aw) / (sigma2 * inflation)
        H = H_data + prior_prec
        phi_new = np.linalg.solve(H, (Aw.T @ b) / (sigma2 * inflation) + pull)
        e = r - (Y @ phi_new)
        scale = _mad_scale(e)
        u = e / scale
        w_h = np.minimum(1.0, huber / np.maximum(np.abs(u), 1e-12))
        sigma2 = float(np.sum(w_h * u**2) / max(1, n * N_JOINTS - p))
        inflation = _acf_inflation(u)
        converged = np.allclose(phi_new, phi, rtol=1e-9, atol=1e-12)
        phi = phi_new
        if converged:
            break
    w = (w_h / scale**2).reshape(-1)
    H = (A.T @ (A * w[:, None])) / (sigma2 * inflation) + prior_prec
    theta = np.linalg.solve(H, ((A * w[:, None]).T @ b) / (sigma2 * inflation) + pull)
    return _Fit(theta=theta, H=H, scale=scale, sigma2=sigma2, inflation=inflation,
                weights=w_h, residual=r - Y @ theta)


def _point_mass_inertia(m_h: np.ndarray) -> np.ndarray | None:
    """``[Ixx, Ixy, Ixz, Iyy, Iyz, Izz]`` about the flange of a point mass ``m`` at ``h / m``
    (``m_h = [m, h]``), or None if the mass is not positive."""
    m, h = float(m_h[0]), np.asarray(m_h[1:4], dtype=float)
    if not m > 0.0:
        return None
    inertia = (h @ h * np.eye(3) - np.outer(h, h)) / m
    return inertia[np.triu_indices(3)]


def _payload_terms(phi: np.ndarray) -> np.ndarray:
    """``[m, com (3), inertia about the CoM (6)]`` of ``phi``."""
    m = phi[0]
    c = phi[1:4] / m
    xx, xy, xz, yy, yz, zz = phi[4:]
    I_o = np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]])
    I_c = I_o - m * (float(c @ c) * np.eye(3) - np.outer(c, c))
    return np.concatenate(([m], c, I_c[[0, 0, 0, 1, 1, 2], [0, 1, 2, 1, 2, 2]]))


def _payload_std(phi: np.ndarray, cov: np.ndarray) -> dict:
    """First-order propagation of ``cov`` (phi) to mass, CoM and inertia about the CoM."""
    jac = np.empty((10, 10))
    for k in range(10):
        h = 1e-7 * max(1.0, abs(phi[k]))
        step = np.zeros(10)
        step[k] = h
        jac[:, k] = (_payload_terms(phi + step) - _payload_terms(phi - step)) / (2.0 * h)
    std = np.sqrt(np.maximum(np.diag(jac @ cov @ jac.T), 0.0))
    return {"mass": float(std[0]), "com": std[1:4].tolist(), "inertia": std[4:].tolist()}


def _group_of(k: int) -> str:
    return next(g for g, idx in GROUPS.items() if k in idx)


def _check_excitation(H: np.ndarray, tol: dict) -> None:
    scale = np.array([tol[_group_of(k)] for k in range(10)])
    A = scale[:, None] * H * scale[None, :]  # precision in tolerance units
    lam, vec = np.linalg.eigh(A)
    weak = [(lam[i], vec[:, i]) for i in range(10) if lam[i] < 1.0]
    if not weak:
        return
    parts = []
    for lam_i, v in weak:
        v = v / np.abs(v).max()
        terms = " ".join(f"{v[k]:+.2f} {PARAMS[k]}" for k in np.argsort(-np.abs(v))
                         if abs(v[k]) >= 0.2)
        parts.append(f"[{terms}] to {1.0 / math.sqrt(lam_i):.2g} tolerances")
    names = sorted({PARAMS[k] for _, v in weak for k in range(10) if abs(v[k]) >= 0.2 *
                    np.abs(v).max()}, key=PARAMS.index)
    raise ExcitationError(
        f"the motion does not excite the payload enough: {len(weak)} direction(s) of the "
        f"parameters are determined only to (1 sigma) {'; '.join(parts)}; parameters not "
        f"excited: {', '.join(names)}. Valid is every direction within the tolerances "
        f"(mass {tol['mass']:g} kg, first moments {tol['com']:g} kg·m, inertia "
        f"{tol['inertia']:g} kg·m²): record a longer motion that moves every joint, the "
        f"wrist joints through large rotations and accelerations")


def _load_arm(arm):
    """The calibrated arm model: an object with ``rnea(q, dq, ddq) -> tau`` (N·m, friction
    and offsets included), a :class:`sim.arm.ArmParams`, or the path of an arm file
    (``sim.arm.load_arm``, ``iem calibrate``'s)."""
    if hasattr(arm, "rnea"):
        return arm
    from sim.arm import load_arm
    from sim.robot import PandaModel

    params = arm if not isinstance(arm, str | bytes) and hasattr(arm, "link_params") \
        else load_arm(arm)
    return PandaModel(arm=params)  # rnea: the arm's links, friction and offsets


def identify(loaded, bare=None, arm=None, *, cutoff_hz: float = CUTOFF_HZ,
             rate_hz: float = RATE_HZ, edge_s: float = EDGE_S, path_tol: float = PATH_TOL,
             min_overlap_s: float = MIN_OVERLAP_S, huber: float = HUBER,
             prior_std=DEFAULT_PRIOR_STD, excitation_tol: dict | None = None,
             check_excitation: bool = True, min_mass: float = MIN_MASS,
             model=None) -> Identification:
    """Identify the payload from a loaded recording and a bare one (or an arm model).

    Args:
        loaded: the recording with the payload mounted (see :func:`as_recording`).
        bare: a recording of the same motion without the payload, or None with ``arm``.
        arm: a calibrated arm model (``rnea(q, dq, ddq) -> tau``) or its file, for any motion;
            exactly one of ``bare`` and ``arm``.
        cutoff_hz: zero-phase low-pass cutoff, Hz.
        rate_hz: rate of the equations after decimation, Hz.
        edge_s: time trimmed at both ends after filtering, s.
        path_tol: largest joint difference between the loaded and bare motions, rad.
        min_overlap_s: shortest common stretch of the two recordings, s.
        huber: Huber threshold, robust-scale units.
        prior_std: the zero-mean prior's standard deviation per parameter (10, paper order).
        excitation_tol: 1-sigma tolerance per group (``mass``, ``com``, ``inertia``) each
            direction must be determined to; default :data:`EXCITATION_TOL`.
        check_excitation: refuse an unexciting motion (else report it in ``determined_by``).
        min_mass: smallest mass the loaded-minus-bare difference must carry, kg.
        model: the nominal arm (a :class:`sim.robot.PandaModel`); default a new one.

    Raises:
        MismatchedLogsError, ExcitationError, BareLoadError (all :class:`IdentifyError`);
        InvalidInputError for malformed inputs.
    """
    if (bare is None) == (arm is None):
        raise InvalidInputError("identify needs exactly one of a bare recording (bare) and an "
                                "arm model (arm)")
    prior_std = np.asarray(prior_std, dtype=float).reshape(-1)
    if prior_std.shape != (10,) or not np.all(prior_std > 0.0):
        raise InvalidInputError(f"prior_std must be 10 positive values, got {prior_std}")
    tol = dict(EXCITATION_TOL if excitation_tol is None else excitation_tol)
    if set(tol) != set(GROUPS) or not all(v > 0 for v in tol.values()):
        raise InvalidInputError(f"excitation_tol must give positive mass, com and inertia, "
                                f"got {tol}")
    if model is None:
        from sim.robot import PandaModel

        model = PandaModel()
    arm_model = None if arm is None else _load_arm(arm)

    L = filtered(as_recording(loaded), cutoff_hz, rate_hz, edge_s, "loaded recording")
    report: dict = {"cutoff_hz": cutoff_hz, "rate_hz": rate_hz,
                    "recorded_rate_hz": L.rate, "spikes_replaced": {"loaded": L.spikes}}
    if bare is not None:
        B = filtered(as_recording(bare), cutoff_hz, rate_hz, edge_s, "bare recording")
        report["spikes_replaced"]["bare"] = B.spikes
        keep, at, info = _align(L, B, path_tol, min_overlap_s)
        report.update(info)
        q, dq, ddq, tau = L.q[keep], L.dq[keep], L.ddq[keep], L.tau[keep]
        r_loaded, Y = _residuals_and_regressor(model, q, dq, ddq, tau)
        r_bare = _nominal_residual(model, at["q"], at["dq"], at["ddq"], at["tau"])
        r = r_loaded - r_bare
        lead = L.dtau[keep] - at["dtau"]
        reference = "bare"
    else:
        q, dq, ddq, tau = L.q, L.dq, L.ddq, L.tau
        _, Y = _residuals_and_regressor(model, q, dq, ddq, tau)
        r = tau - np.array([arm_model.rnea(q[i], dq[i], ddq[i]) for i in range(q.shape[0])])
        lead = L.dtau
        reference = "arm"
    report.update({"reference": reference, "samples": int(q.shape[0]),
                   "equations": int(q.shape[0] * N_JOINTS),
                   "residual_rms_before": np.sqrt(np.mean(r**2, axis=0)).tolist()})

    prior_prec = np.diag(np.concatenate((1.0 / prior_std**2, [1.0 / LEAD_PRIOR_S**2])))
    A = np.concatenate((Y, lead[:, :, None]), axis=2)
    fit = _robust_fit(A, r, prior_prec, huber)
    # the inertia's prior: a point mass at the CoM the data found (the parallel-axis part of
    # the inertia about the flange, which a body with that CoM has at least), not zero, which
    # no body with a CoM far from the flange can have; refit once from there
    point = _point_mass_inertia(fit.theta[:4])
    if point is not None:
        fit = _robust_fit(A, r, prior_prec, huber,
                          np.concatenate((np.zeros(4), point, [0.0])))
        report["inertia_prior_mean"] = point.tolist()
    std = fit.std
    report.update({
        "tau_lead_s": float(fit.theta[10]),
        "tau_lead_std_s": float(np.sqrt(fit.cov_theta[10, 10])),
        "residual_rms_after": np.sqrt(np.mean(fit.residual**2, axis=0)).tolist(),
        "residual_scale": fit.scale.tolist(),
        "noise_inflation": fit.inflation,
        "sigma2": fit.sigma2,
        "downweighted_share": float(np.mean(fit.weights < 1.0)),
    })

    if reference == "bare":
        _check_bare(fit, min_mass, model, at, prior_prec, huber, report)
    if check_excitation:
        _check_excitation(fit.H_phi, tol)

    phi = project(fit.phi, weight=fit.H_phi) if not is_consistent(fit.phi, 1e-9) else fit.phi
    d2 = float((phi - fit.phi) @ fit.H_phi @ (phi - fit.phi))
    if not is_consistent(phi):
        raise IdentifyError(f"no physically consistent payload near the estimate "
                            f"{np.round(fit.phi, 6).tolist()} (paper order)")
    report.update({"projection_sigmas": math.sqrt(d2),
                   "pseudo_inertia_min_eig": float(np.linalg.eigvalsh(
                       pseudo_inertia(phi))[0])})
    determined = tuple("data" if std[k] < DATA_SHARE * prior_std[k] else "prior"
                       for k in range(10))
    return Identification(phi=phi, std=std, cov=fit.cov, phi_unconstrained=fit.phi,
                          prior_std=prior_std, determined_by=determined,
                          payload_std=_payload_std(phi, fit.cov), report=report)


def _check_bare(fit: _Fit, min_mass: float, model, at: dict, prior_prec, huber: float,
                report: dict) -> None:
    """The rules (a)-(c) of the module docstring."""
    m, s_m = float(fit.phi[0]), float(fit.std[0])
    if m < -5.0 * s_m:
        raise BareLoadError(
            f"the bare recording carries more load than the loaded one (the difference is "
            f"{m:+.4f} ± {s_m:.4f} kg): are the two files swapped, or is a load mounted in "
            f"the bare recording? Valid is a bare recording without any payload")
    if m < max(min_mass, 5.0 * s_m):
        raise BareLoadError(
            f"the loaded recording carries no more load than the bare one (the difference "
            f"is {m:+.4f} ± {s_m:.4f} kg): is the payload mounted in the bare recording too, "
            f"or missing in the loaded one? Valid is a bare recording without the payload and "
            f"a difference of at least {min_mass:g} kg")
    if not is_consistent(fit.phi, 1e-9):
        near = project(fit.phi, weight=fit.H_phi)
        d = math.sqrt(max(0.0, float((near - fit.phi) @ fit.H_phi @ (near - fit.phi))))
        if d > BODY_SIGMAS:
            p = fit.phi
            raise BareLoadError(
                f"loaded minus bare is not a rigid body: the estimate (m {p[0]:.4f} kg, "
                f"m·r {np.round(p[1:4], 4).tolist()} kg·m, inertia about the flange "
                f"{np.round(p[4:], 5).tolist()} kg·m²) lies {d:.1f} standard deviations from "
                f"the nearest consistent body (valid: within {BODY_SIGMAS:g}); the bare "
                f"recording carries a load of its own, different from the loaded one")
    # (c) the bare recording alone against the nominal model
    r_b, Y_b = _residuals_and_regressor(model, at["q"], at["dq"], at["ddq"], at["tau"])
    Y_b = np.concatenate((Y_b, at["dtau"][:, :, None]), axis=2)
    fb = _robust_fit(Y_b, r_b, prior_prec, huber)
    phi_b = project(fb.phi, weight=fb.H_phi)
    power = float(np.sum(r_b**2))
    left = float(np.sum((r_b - Y_b @ np.append(phi_b, fb.theta[10])) ** 2))
    explained = 1.0 - left / power if power > 0.0 else 0.0
    report.update({"bare_flange_mass_kg": float(phi_b[0]), "bare_flange_explained": explained})
    if phi_b[0] >= BARE_MASS and explained >= BARE_EXPLAINED:
        raise BareLoadError(
            f"the bare recording looks loaded: against the nominal arm model its torques fit a "
            f"body on the flange of {phi_b[0]:.3f} kg that explains {100 * explained:.0f} % of "
            f"its residual (valid: below {BARE_MASS:g} kg or below "
            f"{100 * BARE_EXPLAINED:.0f} %); record the bare motion with the payload removed")
