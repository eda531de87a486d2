"""The arm's joint friction: Gaz et al.'s Coulomb sigmoid (IEEE RA-L 2019, identified on a
Panda's ``tau_J``), plus viscous and Stribeck friction, each with its own coefficients for
either direction of motion (:func:`friction_torque`), and its Jacobian for the calibration.

A ``(7, 3)`` friction array is Gaz's model alone, a ``(7, 9)`` one the full model
(:data:`FRICTION_COLUMNS`); :class:`sim.arm.ArmParams` holds one per arm.
"""

from __future__ import annotations

import numpy as np

GAZ_PHI = np.array([
    [0.546, 0.872, 0.641, 1.279, 0.839, 0.303, 0.565],  # phi1, N·m
    [5.12, 9.07, 10.14, 5.59, 8.35, 17.13, 10.34],  # phi2, s/rad
    [0.0395, 0.0259, -0.0461, 0.0362, 0.0262, -0.0210, 0.0036],  # phi3, rad/s
]).T
"""Gaz et al.'s friction parameters, ``(7, 3)``: ``phi1`` (N·m), ``phi2`` (s/rad),
``phi3`` (rad/s) per joint."""
GAZ_PHI.flags.writeable = False


def _sigmoid(x):
    return 0.5 * (1.0 + np.tanh(0.5 * x))  # 1 / (1 + exp(-x)), without overflow


def gaz_friction(dq, phi) -> np.ndarray:
    """Friction torque of Gaz's model, N·m, at joint velocities ``dq`` (``(..., 7)``, rad/s),
    with ``phi`` ``(7, 3)`` = ``[phi1, phi2, phi3]`` per joint; zero at ``dq = 0``."""
    phi = np.asarray(phi, dtype=float)
    p1, p2, p3 = phi[:, 0], phi[:, 1], phi[:, 2]
    return p1 * (_sigmoid(p2 * (np.asarray(dq, dtype=float) + p3)) - _sigmoid(p2 * p3))


def gaz_friction_jacobian(dq, phi) -> np.ndarray:
    """``d tau_f / d phi`` at ``dq`` ``(N, 7)``: ``(N, 7, 3)`` (phi1, phi2, phi3 columns)."""
    phi = np.asarray(phi, dtype=float)
    p1, p2, p3 = phi[:, 0], phi[:, 1], phi[:, 2]
    dq = np.asarray(dq, dtype=float)
    s = _sigmoid(p2 * (dq + p3))
    s0 = _sigmoid(p2 * p3)
    ds, ds0 = s * (1.0 - s), s0 * (1.0 - s0)
    out = np.empty((*dq.shape, 3))
    out[..., 0] = s - s0
    out[..., 1] = p1 * (ds * (dq + p3) - ds0 * p3)
    out[..., 2] = p1 * p2 * (ds - ds0)
    return out


FRICTION_COLUMNS = ("phi1", "phi2", "phi3", "fv_pos", "fv_neg", "fs_pos", "fs_neg",
                    "vs_pos", "vs_neg")
"""The columns of a full friction array ``(7, 9)``, per joint: Gaz's ``phi1`` (N·m), ``phi2``
(s/rad), ``phi3`` (rad/s); the viscous coefficients for ``dq > 0`` and ``dq < 0``
(N·m·s/rad); the Stribeck excess for ``dq > 0`` and ``dq < 0`` (N·m) and its velocities
(rad/s, > 0). A ``(7, 3)`` array is Gaz's model alone (the first three)."""
GAZ_COLUMNS = 3
"""The columns of Gaz's model, the first of a full array."""
STRIBECK_VS = 0.1
"""Stribeck velocity of a friction array that has none (a Gaz array made full), rad/s."""


def _beyond_gaz(dq, friction: np.ndarray):
    """``dq`` as an array, the columns ``fv_pos, fv_neg, fs_pos, fs_neg, vs_pos, vs_neg`` of
    a full friction array, and the direction switch ``w = σ(phi2 dq)``: what the viscous and
    Stribeck terms and their Jacobian share."""
    dq = np.asarray(dq, dtype=float)
    cols = tuple(friction[:, c] for c in (3, 4, 5, 6, 7, 8))
    return dq, cols, _sigmoid(friction[:, 1] * dq)


def friction_torque(dq, friction) -> np.ndarray:
    """Joint friction torque, N·m, at joint velocities ``dq`` (``(..., 7)``, rad/s): the one
    friction model of the arm (:meth:`ArmParams.joint_torque`). With ``w = σ(phi2 dq)``
    (``σ`` the logistic function: the direction switch, smooth through zero)::

        tau_f = phi1 (σ(phi2 (dq + phi3)) - σ(phi2 phi3))              Coulomb (Gaz)
              + dq (fv_pos w + fv_neg (1 - w))                            viscous
              + (2w - 1) (fs_pos w exp(-(dq/vs_pos)²)
                          + fs_neg (1 - w) exp(-(dq/vs_neg)²))            Stribeck

    zero at ``dq = 0`` and continuous with all its derivatives. ``friction`` is ``(7, 9)``
    (:data:`FRICTION_COLUMNS`) or ``(7, 3)``: Gaz's sigmoid alone, computed as
    :func:`gaz_friction` does (the same torques to the bit)."""
    friction = np.asarray(friction, dtype=float)
    tau = gaz_friction(dq, friction)
    if friction.shape[1] == GAZ_COLUMNS:
        return tau
    dq, (fvp, fvn, fsp, fsn, vsp, vsn), w = _beyond_gaz(dq, friction)
    stribeck = (2.0 * w - 1.0) * (fsp * w * np.exp(-(dq / vsp) ** 2)
                                  + fsn * (1.0 - w) * np.exp(-(dq / vsn) ** 2))
    return tau + dq * (fvp * w + fvn * (1.0 - w)) + stribeck


def friction_jacobian(dq, friction) -> np.ndarray:
    """``d tau_f / d friction`` at ``dq`` ``(N, 7)``: ``(N, 7, K)`` for ``friction``
    ``(7, K)``, ``K`` 3 or 9 (the columns of :func:`friction_torque`)."""
    friction = np.asarray(friction, dtype=float)
    gaz = gaz_friction_jacobian(dq, friction)
    if friction.shape[1] == GAZ_COLUMNS:
        return gaz
    dq, (fvp, fvn, fsp, fsn, vsp, vsn), w = _beyond_gaz(dq, friction)
    dw = w * (1.0 - w) * dq  # d w / d phi2
    sw = 2.0 * w - 1.0
    ep, en = np.exp(-(dq / vsp) ** 2), np.exp(-(dq / vsn) ** 2)
    out = np.empty((*dq.shape, len(FRICTION_COLUMNS)))
    out[..., :GAZ_COLUMNS] = gaz
    out[..., 1] += dw * (dq * (fvp - fvn) + 2.0 * (fsp * w * ep + fsn * (1.0 - w) * en)
                         + sw * (fsp * ep - fsn * en))
    out[..., 3] = dq * w
    out[..., 4] = dq * (1.0 - w)
    out[..., 5] = sw * w * ep
    out[..., 6] = sw * (1.0 - w) * en
    out[..., 7] = out[..., 5] * fsp * 2.0 * dq ** 2 / vsp ** 3
    out[..., 8] = out[..., 6] * fsn * 2.0 * dq ** 2 / vsn ** 3
    return out


def full_friction(friction) -> np.ndarray:
    """``friction`` as a full ``(7, 9)`` array (a ``(7, 3)`` Gaz array: no viscous and no
    Stribeck part; their velocities :data:`STRIBECK_VS`): the same torques."""
    friction = np.asarray(friction, dtype=float)
    if friction.shape[1] == len(FRICTION_COLUMNS):
        return friction.copy()
    out = np.zeros((friction.shape[0], len(FRICTION_COLUMNS)))
    out[:, :GAZ_COLUMNS] = friction
    out[:, 7:9] = STRIBECK_VS
    return out
