""":func:`identify`: a payload from a loaded and a bare recording, or a loaded one and a
calibrated arm (the steps of :mod:`sim.identify`)."""

from __future__ import annotations

import math

import numpy as np

from iem.errors import InvalidInputError
from iem.physics.consistency import is_consistent, project, pseudo_inertia
from iem.physics.posterior import DEFAULT_PRIOR_STD
from iem.signals.offline import Signals, prepare
from iem.signals.recording import as_recording
from iem.types import GROUPS, N_JOINTS

from .fit import (
    HUBER,
    RobustFit,
    arm_model,
    nominal_residual,
    residuals_and_regressor,
    robust_fit,
)
from .refusals import (
    EXCITATION_TOL,
    MIN_MASS,
    MIN_OVERLAP_S,
    PATH_TOL,
    IdentifyError,
    align,
    refuse_loaded_bare,
    refuse_unexcited,
)
from .result import Identification, payload_std

CUTOFF_HZ = 10.0
"""Default zero-phase low-pass cutoff, Hz."""
RATE_HZ = 100.0
"""Default rate of the equations after decimation, Hz."""
EDGE_S = 0.1
"""Default time trimmed at both ends of a recording after filtering, s."""
DATA_SHARE = 0.25
"""A parameter is determined by the data if its posterior std is below this share of its
prior std."""
LEAD_PRIOR_S = 0.002
"""Prior std of the torque's lead over the joint state it comes with, s (zero mean)."""


def identify(loaded, bare=None, arm=None, *, cutoff_hz: float = CUTOFF_HZ,
             rate_hz: float = RATE_HZ, edge_s: float = EDGE_S, path_tol: float = PATH_TOL,
             min_overlap_s: float = MIN_OVERLAP_S, huber: float = HUBER,
             prior_std=DEFAULT_PRIOR_STD, excitation_tol: dict | None = None,
             check_excitation: bool = True, min_mass: float = MIN_MASS,
             model=None, recorded_rate_hz: float | None = None) -> Identification:
    """Identify the payload from a loaded recording and a bare one (or an arm model).

    Args:
        loaded: the recording with the payload mounted (see
            :func:`iem.signals.recording.as_recording`).
        bare: a recording of the same motion without the payload, or None with ``arm``.
        arm: a calibrated arm model (``rnea(q, dq, ddq) -> tau``) or its file, for any motion;
            exactly one of ``bare`` and ``arm``.
        cutoff_hz: zero-phase low-pass cutoff, Hz.
        rate_hz: rate of the equations after decimation, Hz.
        edge_s: time trimmed at both ends of each gap-free piece after filtering, s.
        path_tol: largest joint difference between the loaded and bare motions, rad.
        min_overlap_s: shortest common stretch of the two recordings, s.
        huber: Huber threshold, robust-scale units.
        prior_std: the zero-mean prior's standard deviation per parameter (10, paper order).
        excitation_tol: 1-sigma tolerance per group (``mass``, ``com``, ``inertia``) each
            direction must be determined to; default :data:`EXCITATION_TOL`.
        check_excitation: refuse an unexciting motion (else report it in ``determined_by``).
        min_mass: smallest mass the loaded-minus-bare difference must carry, kg.
        model: the nominal arm (a :class:`sim.robot.ArmModel`); default a new one.
        recorded_rate_hz: the recordings' joint states a second, Hz (None: each one's
            detected from its time stamps, :func:`iem.signals.rate.detect_rate`).

    Raises:
        MismatchedLogsError, ExcitationError, BareLoadError (all :class:`IdentifyError`);
        InvalidInputError for malformed inputs.
    """
    prior_std, tol = _checked_arguments(bare, arm, prior_std, excitation_tol)
    if model is None:
        from sim.robot import ArmModel

        model = ArmModel()
    arm_rnea = None if arm is None else arm_model(arm)

    L = prepare(as_recording(loaded), cutoff_hz, rate_hz, edge_s, what="loaded recording",
                recorded_rate_hz=recorded_rate_hz)
    report: dict = {"cutoff_hz": cutoff_hz, "rate_hz": rate_hz,
                    "recorded_rate_hz": L.rate, "spikes_replaced": {"loaded": L.spikes},
                    "pieces": {"loaded": L.pieces}, "pieces_dropped": {"loaded": L.dropped}}
    if bare is not None:
        B = prepare(as_recording(bare), cutoff_hz, rate_hz, edge_s, what="bare recording",
                    recorded_rate_hz=recorded_rate_hz)
        report["spikes_replaced"]["bare"] = B.spikes
        report["pieces"]["bare"] = B.pieces
        report["pieces_dropped"]["bare"] = B.dropped
        r, Y, lead, at = _against_bare(model, L, B, path_tol, min_overlap_s, report)
    else:
        r, Y, lead, at = _against_arm(model, L, arm_rnea)
    reference = "bare" if bare is not None else "arm"
    report.update({"reference": reference, "samples": int(Y.shape[0]),
                   "equations": int(Y.shape[0] * N_JOINTS),
                   "residual_rms_before": np.sqrt(np.mean(r**2, axis=0)).tolist()})

    prior_prec = np.diag(np.concatenate((1.0 / prior_std**2, [1.0 / LEAD_PRIOR_S**2])))
    fit = _fit(np.concatenate((Y, lead[:, :, None]), axis=2), r, prior_prec, huber, report)
    if reference == "bare":
        refuse_loaded_bare(fit, min_mass, model, at, prior_prec, huber, report)
    if check_excitation:
        refuse_unexcited(fit.H_phi, tol)
    return _consistent_result(fit, prior_std, report)


def _checked_arguments(bare, arm, prior_std, excitation_tol) -> tuple[np.ndarray, dict]:
    """``(prior_std, tol)`` as arrays and dicts, or InvalidInputError."""
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
    return prior_std, tol


def _against_bare(model, L: Signals, B: Signals, path_tol: float, min_overlap_s: float,
                  report: dict):
    """``(r, Y, lead, at)`` of step 3 with a bare recording: the loaded residual minus the
    bare one (each against the nominal model at its own state), the loaded regressor, the
    torques' time derivative, and the bare signals at the loaded instants."""
    keep, at, info = align(L, B, path_tol, min_overlap_s)
    report.update(info)
    q, dq, ddq, tau = L.q[keep], L.dq[keep], L.ddq[keep], L.tau[keep]
    r_loaded, Y = residuals_and_regressor(model, q, dq, ddq, tau)
    r_bare = nominal_residual(model, at["q"], at["dq"], at["ddq"], at["tau"])
    return r_loaded - r_bare, Y, L.dtau[keep] - at["dtau"], at


def _against_arm(model, L: Signals, arm_rnea):
    """``(r, Y, lead, None)`` of step 3 with a calibrated arm: the loaded torques minus the
    arm's, the regressor and the torques' time derivative. An arm model that gives its own
    regressor (a :class:`sim.robot.ArmModel`) gives it as its sensors read a payload's
    torque (its measured gain, :attr:`sim.arm.ArmParams.gain`); else the nominal one."""
    q, dq, ddq, tau = L.q, L.dq, L.ddq, L.tau
    if hasattr(arm_rnea, "rnea_and_regressor"):
        r, Y = residuals_and_regressor(arm_rnea, q, dq, ddq, tau)
        return r, Y, L.dtau, None
    _, Y = residuals_and_regressor(model, q, dq, ddq, tau)
    r = tau - np.array([arm_rnea.rnea(q[i], dq[i], ddq[i]) for i in range(q.shape[0])])
    return r, Y, L.dtau, None


def _fit(A: np.ndarray, r: np.ndarray, prior_prec: np.ndarray, huber: float,
         report: dict) -> RobustFit:
    """Steps 4-5: the robust fit, refit once with the inertia's prior at the point mass the
    first fit found; its figures go to ``report``."""
    fit = robust_fit(A, r, prior_prec, huber)
    # the inertia's prior: a point mass at the CoM the data found (the parallel-axis part of
    # the inertia about the flange, which a body with that CoM has at least), not zero, which
    # no body with a CoM far from the flange can have; refit once from there
    point = _point_mass_inertia(fit.theta[:4])
    if point is not None:
        fit = robust_fit(A, r, prior_prec, huber,
                         np.concatenate((np.zeros(4), point, [0.0])))
        report["inertia_prior_mean"] = point.tolist()
    report.update({
        "tau_lead_s": float(fit.theta[10]),
        "tau_lead_std_s": float(np.sqrt(fit.cov_theta[10, 10])),
        "residual_rms_after": np.sqrt(np.mean(fit.residual**2, axis=0)).tolist(),
        "residual_scale": fit.scale.tolist(),
        "noise_inflation": fit.inflation,
        "sigma2": fit.sigma2,
        "downweighted_share": float(np.mean(fit.weights < 1.0)),
    })
    return fit


def _point_mass_inertia(m_h: np.ndarray) -> np.ndarray | None:
    """``[Ixx, Ixy, Ixz, Iyy, Iyz, Izz]`` about the flange of a point mass ``m`` at ``h / m``
    (``m_h = [m, h]``), or None if the mass is not positive."""
    m, h = float(m_h[0]), np.asarray(m_h[1:4], dtype=float)
    if not m > 0.0:
        return None
    inertia = (h @ h * np.eye(3) - np.outer(h, h)) / m
    return inertia[np.triu_indices(3)]


def _consistent_result(fit: RobustFit, prior_std: np.ndarray, report: dict) -> Identification:
    """Steps 6-7: the estimate projected onto the consistent bodies, and its uncertainty."""
    std = fit.std
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
                          payload_std=payload_std(phi, fit.cov), report=report)
