"""What :func:`sim.identify.identify` refuses, and why: its errors, the alignment of a bare
recording on the loaded one (step 2), and the rules on the fit (the motion's excitation, a
load in the bare recording: rules (a)-(c) of :mod:`sim.identify`)."""

from __future__ import annotations

import math

import numpy as np

from iem.errors import InvalidInputError
from iem.physics.consistency import is_consistent, project
from iem.signals.offline import Signals, lag, piece_of, sample
from iem.types import GROUPS, PARAMS

from .fit import RobustFit, residuals_and_regressor, robust_fit

PATH_TOL = 0.02
"""Default largest joint difference between a loaded and a bare recording, rad."""
MIN_OVERLAP_S = 1.0
"""Default shortest common stretch of a loaded and a bare recording, s."""
EXCITATION_TOL = {"mass": 0.01, "com": 0.002, "inertia": 0.001}
"""Default 1-sigma tolerance per group that every direction must be determined to (kg, kg·m,
kg·m²)."""
MIN_MASS = 0.01
"""Smallest payload mass the difference of two recordings must show, kg."""
BODY_SIGMAS = 5.0
"""How far (standard deviations) the unconstrained estimate may lie from a rigid body."""
BARE_MASS = 1.0
"""A bare recording fitting a flange body of this mass (kg) or more is refused ..."""
BARE_EXPLAINED = 0.95
"""... if that body explains at least this share of its residual power."""


class IdentifyError(InvalidInputError):
    """Recordings from which no payload can honestly be identified."""


class MismatchedLogsError(IdentifyError):
    """The loaded and bare recordings are not the same motion."""


class ExcitationError(IdentifyError):
    """The motion does not determine the payload's parameters."""


class BareLoadError(IdentifyError):
    """The "bare" recording carries a load."""


# -- step 2: the bare recording on the loaded one --------------------------------------------
def align(loaded: Signals, bare: Signals, path_tol: float, min_overlap_s: float):
    """``(keep, at, info)``: the loaded samples the bare recording overlaps, the bare
    recording's signals at those instants, and the figures of the alignment; or
    :class:`MismatchedLogsError`."""
    shift = lag(loaded, bare)
    # inside a piece of each (no gap of either); the overlap sums the stretches that are
    piece = np.stack((piece_of(loaded, loaded.t), piece_of(bare, loaded.t - shift)))
    keep = piece[1] >= 0
    joined = keep[1:] & keep[:-1] & np.all(piece[:, 1:] == piece[:, :-1], axis=0)
    overlap = float(np.diff(loaded.t)[joined].sum())
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


# -- the motion's excitation ---------------------------------------------------------------
def _group_of(k: int) -> str:
    return next(g for g, idx in GROUPS.items() if k in idx)


def refuse_unexcited(H: np.ndarray, tol: dict) -> None:
    """:class:`ExcitationError` unless the precision ``H`` of the payload determines every
    direction to within ``tol`` (1 sigma per group), naming the weak directions."""
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


# -- a load in the bare recording: rules (a)-(c) -------------------------------------------
def refuse_loaded_bare(fit: RobustFit, min_mass: float, model, at: dict, prior_prec,
                       huber: float, report: dict) -> None:
    """The rules (a)-(c) of :mod:`sim.identify` on the loaded-minus-bare ``fit``; (c) adds
    its figures to ``report``."""
    _check_difference(fit, min_mass)
    _check_bare_alone(model, at, prior_prec, huber, report)


def _check_difference(fit: RobustFit, min_mass: float) -> None:
    """(a) the difference carries a load, (b) a rigid body."""
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


def _check_bare_alone(model, at: dict, prior_prec, huber: float, report: dict) -> None:
    """(c) the bare recording alone against the nominal model: no gross flange load."""
    r_b, Y_b = residuals_and_regressor(model, at["q"], at["dq"], at["ddq"], at["tau"])
    Y_b = np.concatenate((Y_b, at["dtau"][:, :, None]), axis=2)
    fb = robust_fit(Y_b, r_b, prior_prec, huber)
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
