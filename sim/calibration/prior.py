"""The calibration's settings and its prior: how the signals are treated, and what the fit
assumes before the data (the bodies within a few percent of the nominal ones, Gaz's friction,
no viscous or Stribeck excess, small offsets) and the bounds the friction stays inside."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from iem.errors import InvalidInputError

from ..friction import FRICTION_COLUMNS, GAZ_PHI, full_friction


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
        armature: fit each joint's armature (its drive's reflected rotor inertia, a torque
            ``armature * ddq`` on its own joint): a torque read from motor currents, or a
            simulator's applied torque, carries it; Franka's link-side torque sensors do not
            (fitted on the real Panda recording it comes out near zero and the held-out
            noise grows: hence off by default).
        armature_std: its prior standard deviation, kg·m² (centre 0).
        recorded_rate_hz: the joint states' rate, Hz (None: detected from each recording's
            time stamps, :func:`iem.signals.rate.detect_rate`). The other settings are in
            seconds and Hz, not samples, so they hold at any rate the offline chain accepts
            (a cut-off below 0.45 of it, equations at most at it).
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
    armature: bool = False
    armature_std: float = 0.2
    recorded_rate_hz: float | None = None


DEFAULT_SETTINGS = CalibrationSettings()
"""The settings every calibration function takes by default (frozen: shared safely)."""


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


def friction_prior(s: CalibrationSettings) -> tuple[np.ndarray, np.ndarray]:
    """The friction prior ``(centre (7, 9), standard deviation (7, 9))``
    (:data:`sim.friction.FRICTION_COLUMNS`): Gaz's sigmoid at Gaz's values (``friction_rel`` of
    each as deviation), no viscous friction (``viscous_std``), no Stribeck excess
    (``stribeck_std``) at :data:`sim.friction.STRIBECK_VS` (``stribeck_vs_std``)."""
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

ARMATURE_BOUNDS = np.array([[0.0, 2.0]])
"""Bounds of a fitted armature, kg·m²: a rotor's inertia is not negative."""
