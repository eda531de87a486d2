"""The arm's joint friction: Gaz et al.'s Coulomb sigmoid (IEEE RA-L 2019, identified on a
Panda's ``tau_J``), plus viscous and Stribeck friction, each with its own coefficients for
either direction of motion (:func:`friction_torque`), and its Jacobian for the calibration;
:class:`FrictionPoints` gives both at one velocity at a time, as an estimator asks them.

A ``(7, 3)`` friction array is Gaz's model alone, a ``(7, 9)`` one the full model
(:data:`FRICTION_COLUMNS`); :class:`sim.arm.ArmParams` holds one per arm.
"""

from __future__ import annotations

from typing import ClassVar

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


class FrictionPoints:
    """One arm's friction at single velocities ``dq`` (7,), fast: the torque of
    :func:`friction_torque`, the same values to the bit, and the Jacobian of
    :func:`friction_jacobian`, the same to rounding (its ``phi2`` column sums its terms in
    another grouping).

    The friction array's columns and ``σ(phi2 phi3)`` are taken once, and the terms the
    torque and the Jacobian share (the sigmoids and the Stribeck exponentials) are kept for
    the last :data:`KEEP` velocities asked: an estimator asks each of a block point's
    velocities several times (its tandem simulators, its samples driven backwards, its
    equation's torque and that torque's sensitivity). Whatever thread asks, the values are
    the same; a kept entry only spares the work.

    Args:
        friction: ``(7, 3)`` or ``(7, 9)`` (:data:`FRICTION_COLUMNS`).
    """

    KEEP = 8
    """Velocities whose terms are kept."""
    _SHARED: ClassVar[dict[bytes, FrictionPoints]] = {}
    _SHARED_MAX: ClassVar[int] = 64

    @classmethod
    def of(cls, friction) -> FrictionPoints:
        """The one instance for this friction array's values in this process: copies of an
        arm (a model's tandem simulators, its equations, its samples driven backwards) then
        share the velocities' terms."""
        f = np.asarray(friction, dtype=float)
        key = f.shape[1].to_bytes(1, "little") + f.tobytes()
        points = cls._SHARED.get(key)
        if points is None:
            if len(cls._SHARED) >= cls._SHARED_MAX:
                cls._SHARED = {}
            points = cls._SHARED[key] = cls(f)
        return points

    def __init__(self, friction) -> None:
        f = np.asarray(friction, dtype=float)
        cols = [np.ascontiguousarray(f[:, c]) for c in range(f.shape[1])]
        self.full = f.shape[1] == len(FRICTION_COLUMNS)
        self.p1, self.p2, self.p3 = cols[:GAZ_COLUMNS]
        self.s0 = _sigmoid(self.p2 * self.p3)
        self.ds0 = self.s0 * (1.0 - self.s0)
        if self.full:
            self.fvp, self.fvn, self.fsp, self.fsn, self.vsp, self.vsn = cols[GAZ_COLUMNS:]
        self._kept: dict[bytes, tuple] = {}

    def _terms(self, dq: np.ndarray) -> tuple:
        """``(torque, s, w, ep, en)`` at ``dq`` (7,): the friction torque (read-only) and the
        terms the Jacobian shares with it (``w, ep, en`` None for Gaz's model alone). A
        velocity not kept is evaluated with its opposite, in one pass over both (elementwise:
        each row's numbers are its own), and both are kept: samples driven backwards ask
        the opposite of the velocity their simulators asked."""
        key = dq.tobytes()
        terms = self._kept.get(key)
        if terms is not None:
            return terms
        both = np.empty((2, 7))
        both[0] = dq
        np.negative(dq, out=both[1])
        dq = both
        s = _sigmoid(self.p2 * (dq + self.p3))
        tau = self.p1 * (s - self.s0)
        w = ep = en = None
        if self.full:  # friction_torque's arithmetic, term by term
            w = _sigmoid(self.p2 * dq)
            ep, en = np.exp(-(dq / self.vsp) ** 2), np.exp(-(dq / self.vsn) ** 2)
            stribeck = (2.0 * w - 1.0) * (self.fsp * w * ep + self.fsn * (1.0 - w) * en)
            tau = tau + dq * (self.fvp * w + self.fvn * (1.0 - w)) + stribeck
        tau.flags.writeable = False
        if len(self._kept) >= self.KEEP:
            self._kept = {}  # (rebound, not cleared: another thread may be reading it)
        rows = [(tau[i], s[i]) + ((None,) * 3 if w is None else (w[i], ep[i], en[i]))
                for i in (1, 0)]
        self._kept[both[1].tobytes()] = rows[0]
        self._kept[key] = terms = rows[1]
        return terms

    def torque(self, dq) -> np.ndarray:
        """:func:`friction_torque` at ``dq`` (7,), N·m (read-only)."""
        return self._terms(_velocity(dq))[0]

    def jacobian(self, dq) -> np.ndarray:
        """:func:`friction_jacobian` at ``dq`` (7,) of a full friction array: (7, 9), a new
        array."""
        if not self.full:
            raise ValueError("FrictionPoints.jacobian needs a full (7, 9) friction array")
        dq = _velocity(dq)
        _, s, w, ep, en = self._terms(dq)
        p1, p2, p3, fsp, fsn = self.p1, self.p2, self.p3, self.fsp, self.fsn
        ds = s * (1.0 - s)
        dw = w * (1.0 - w) * dq
        sw = 2.0 * w - 1.0
        out = np.empty((7, len(FRICTION_COLUMNS)))
        out[:, 0] = s - self.s0
        stribeck = 2.0 * (fsp * w * ep + fsn * (1.0 - w) * en) + sw * (fsp * ep - fsn * en)
        out[:, 1] = (p1 * (ds * (dq + p3) - self.ds0 * p3)
                     + dw * (dq * (self.fvp - self.fvn) + stribeck))
        out[:, 2] = p1 * p2 * (ds - self.ds0)
        out[:, 3] = dq * w
        out[:, 4] = dq * (1.0 - w)
        out[:, 5] = sw * w * ep
        out[:, 6] = sw * (1.0 - w) * en
        out[:, 7] = out[:, 5] * fsp * 2.0 * dq ** 2 / self.vsp ** 3
        out[:, 8] = out[:, 6] * fsn * 2.0 * dq ** 2 / self.vsn ** 3
        return out


def _velocity(dq) -> np.ndarray:
    dq = np.asarray(dq, dtype=float)
    if dq.shape != (7,):
        raise ValueError(f"FrictionPoints takes one velocity (7,), got shape {dq.shape}")
    return dq
