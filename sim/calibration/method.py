""":func:`calibrate`: the arm identified from bare-arm traffic, the steps of
:mod:`sim.calibration` in order, and how well an arm explains held-out traffic."""

from __future__ import annotations

import numpy as np

from ..arm import ArmParams
from ..end_effector import end_effector_of
from ..friction import friction_torque
from ..robot import ArmModel, nominal_link_params
from .consistency import consistent, consistent_map
from .excitation import (
    MAX_CONDITION,
    NEGLIGIBLE_SHARE,
    base_basis,
    excitation_condition,
    regressors,
)
from .fit import fit_map, joint_rms, never_worse
from .posterior import posterior_covariance
from .prior import (
    DEFAULT_SETTINGS,
    CalibrationError,
    CalibrationSettings,
    friction_prior,
    link_prior_std,
)
from .signals import calibration_signals

PAYLOAD_WARN_SIGMAS = 4.0
PAYLOAD_WARN_KG = 0.1
"""Body 7 heavier than nominal by more than this many prior standard deviations (and at
least this many kg) reads as a payload."""


def calibrate(t, q, dq, tau, settings: CalibrationSettings = DEFAULT_SETTINGS,
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


def calibrate_segments(parts, settings: CalibrationSettings = DEFAULT_SETTINGS,
                       source: str = "traffic", end_effector=None,
                       refuse: bool = True, description=None,
                       posterior: bool = True) -> ArmParams:
    """:func:`calibrate` on several recordings ``[(t, q, dq, tau), ...]``, each filtered on
    its own and split at its gaps (:func:`.signals.calibration_signals`).
    ``end_effector`` (a spec or :class:`sim.end_effector.EndEffector`; None: the arm
    model's default) is the prior's body 7 and the nominal model the result is compared with, on the
    arm model ``description`` (:mod:`sim.description`; None: the default).
    ``refuse=False`` fits too little excitation instead of refusing it (the prior holds the
    directions it lacks): the cross-validation's folds (:mod:`sim.calibration_noise`), which
    need no ``posterior`` either (:mod:`.posterior`: the result's covariance, step 8)."""
    s = settings
    if not parts:
        raise CalibrationError("no traffic to calibrate from (no segment of at least 3 s)")
    prepared = calibration_signals(parts, s)
    q, dq, ddq, tau = (np.concatenate([getattr(p, k) for p in prepared])
                       for k in ("q", "dq", "ddq", "tau"))
    kinematics = ArmModel(description=description)
    nominal_model = kinematics.model
    ee = end_effector_of(end_effector, kinematics.description)  # the prior's centre
    theta0 = nominal_link_params(ee, kinematics.description).ravel()
    W = regressors(nominal_model, q, dq, ddq)  # (N, 7, 70)
    basis = base_basis(nominal_model, kinematics=kinematics)
    sd_theta = link_prior_std(theta0, s)
    phi0, sd_phi = friction_prior(s)
    sd_off = np.full(7, s.offset_std)
    try:
        cond = excitation_condition(W, q, dq, basis, sd_theta, phi0, sd_phi, sd_off,
                                    s.sigma_tau)
    except CalibrationError:
        if refuse:
            raise
        cond = float("inf")  # a cross-validation fold: the prior holds what it lacks

    theta, phi, off, armature, iterations = fit_map(
        W, dq, tau, theta0, phi0, sd_theta, sd_phi, sd_off, s,
        *((ddq, np.full(7, s.armature_std)) if s.armature else ()))
    tau = tau - armature * ddq  # known from here on: what the bodies and friction leave
    # the constrained MAP, in the metric of the posterior of theta (friction, offsets fixed)
    w = 1.0 / s.sigma_tau
    A_theta = W.reshape(-1, 70) * w
    fixed = consistent_map(theta, A_theta.T @ A_theta + np.diag(1.0 / sd_theta ** 2))
    params, moved = consistent(theta if fixed is None else fixed, theta0.reshape(7, 10))
    params, phi, off, warnings, fallback = never_worse(W, dq, tau, theta0, params, phi, off)
    warnings += _payload_warning(params, theta0, sd_theta)
    cov = (posterior_covariance(W, dq, tau, params, phi, off, sd_theta, sd_phi, sd_off,
                                s.rate_hz) if posterior else None)
    if MAX_CONDITION < cond < float("inf"):  # accepted: only negligible directions are weak
        warnings.append(f"condition number {cond:.0f} above {MAX_CONDITION:g} only in "
                        f"directions that move the torques by less than "
                        f"{NEGLIGIBLE_SHARE:.0%} of the torque noise: left to the prior")
    report = {
        "source": source,
        "samples": int(W.shape[0]),
        "duration_s": float(sum(p.duration for p in prepared)),
        "segments": sum(p.pieces for p in prepared),
        "segments_dropped": sum(p.dropped for p in prepared),
        "base_parameters": int(basis.shape[1]),
        "condition_number": cond,
        "iterations": iterations,
        "rms_before": joint_rms(tau + armature * ddq - (W @ theta0)).tolist(),
        "rms_after": joint_rms(tau - (W @ params.ravel()) - friction_torque(dq, phi)
                               - off).tolist(),
        "consistency": "lmi" if fixed is not None else "shrink toward nominal",
        "consistency_moved_bodies": moved,
        "fallback_joints": fallback,
        "warnings": warnings,
        "settings": {k: getattr(s, k) for k in s.__dataclass_fields__},
    }
    return ArmParams(params, phi, off, report, end_effector=ee.label,
                     description=kinematics.description, posterior=cov, armature=armature)


def _payload_warning(params: np.ndarray, theta0: np.ndarray, sd_theta: np.ndarray) -> list:
    """Step 7: a warning if body 7 reads heavier than its prior allows (a payload)."""
    d_m7 = params[6, 0] - theta0[60]
    if d_m7 > max(PAYLOAD_WARN_SIGMAS * sd_theta[60], PAYLOAD_WARN_KG):
        return [f"body 7 reads {d_m7:.3f} kg heavier than nominal (its prior allows "
                f"about {sd_theta[60]:.3f} kg): the residual looks like a payload is "
                "mounted; calibrate on the bare arm"]
    return []


def residual_rms(arm: ArmParams | None, t, q, dq, tau,
                 settings: CalibrationSettings = DEFAULT_SETTINGS) -> np.ndarray:
    """Per-joint RMS of ``tau - model`` (N·m) on traffic prepared as :func:`calibrate` does,
    for ``arm`` (None: the nominal model): how well an arm model explains held-out motion."""
    (p,) = calibration_signals([(t, q, dq, tau)], settings)
    model = ArmModel(arm=arm)
    pred = np.array([model.rnea(p.q[k], p.dq[k], p.ddq[k]) for k in range(p.q.shape[0])])
    return np.sqrt(np.mean((p.tau - pred) ** 2, axis=0))
