"""Steps 4 and 6 of the calibration: the maximum a posteriori of the bodies, the friction and
the offsets (and, where asked, each joint's armature) by Levenberg-Marquardt
(:func:`fit_map`), and the guard that leaves no joint fitting worse than the nominal model
(:func:`never_worse`)."""

from __future__ import annotations

import numpy as np

from ..friction import friction_jacobian, friction_torque
from .prior import ARMATURE_BOUNDS, FRICTION_BOUNDS, CalibrationSettings


class _MapProblem:
    """The posterior's cost of :func:`fit_map` in prior-scaled unknowns: ``theta`` (70), then
    per joint its friction (``k``) and its joint-local linear terms: the offset, and the
    armature where ``ddq`` is given (its torque ``armature * ddq``); its residual and its
    damped normal equations."""

    def __init__(self, W, dq, tau, theta0, phi0, sd_theta, sd_phi, sd_off,
                 s: CalibrationSettings, ddq=None, sd_arm=None) -> None:
        self.W, self.dq, self.tau = W, dq, tau
        self.sd_phi = sd_phi
        self.n, self.k = dq.shape[0], phi0.shape[1]
        self.w = 1.0 / s.sigma_tau
        k = self.k
        columns, sds = [np.ones_like(dq)], [sd_off]
        if ddq is not None:
            columns.append(ddq)
            sds.append(sd_arm)
        self.L = np.stack(columns, axis=-1)  # (N, 7, c): the local terms' columns
        self.sd_loc = np.column_stack(sds)  # (7, c)
        self.c = c = self.L.shape[-1]
        self.sd = np.concatenate((sd_theta, np.column_stack((sd_phi, self.sd_loc)).ravel()))
        self.x0 = np.concatenate((theta0, np.column_stack((phi0, np.zeros((7, c)))).ravel()))
        bounds = np.vstack((FRICTION_BOUNDS[:k], [[-np.inf, np.inf]], ARMATURE_BOUNDS[:c - 1]))
        self.lo = np.concatenate((np.full(70, -np.inf), np.tile(bounds[:, 0], 7)))
        self.hi = np.concatenate((np.full(70, np.inf), np.tile(bounds[:, 1], 7)))
        self.A = (W * (sd_theta * self.w)).transpose(1, 2, 0)  # (7, 70, N), constant
        self.AtA = np.einsum("jan,jbn->ab", self.A, self.A)

    def split(self, x):
        """``(theta, friction, local terms (7, c))`` of ``x``."""
        joint = x[70:].reshape(7, self.k + self.c)
        return x[:70], joint[:, :self.k], joint[:, self.k:]

    def residual(self, x):
        theta, phi, local = self.split(x)
        return (self.tau - self.W @ theta - friction_torque(self.dq, phi)
                - np.einsum("njc,jc->nj", self.L, local))

    def cost(self, x, r):
        return float(self.w * self.w * np.sum(r * r) + np.sum(((x - self.x0) / self.sd) ** 2))

    def normal_equations(self, x, r):
        """``(lhs, rhs)`` of the Gauss-Newton step at ``x`` (friction linearised there), the
        prior's identity included."""
        n, k, w, A = self.n, self.k, self.w, self.A
        m = k + self.c
        _, phi, _ = self.split(x)
        G = np.empty((n, 7, m))
        G[..., :k] = friction_jacobian(self.dq, phi) * self.sd_phi
        G[..., k:] = self.L * self.sd_loc
        G = (G * w).transpose(1, 0, 2)  # (7, N, m)
        lhs = np.zeros((70 + 7 * m, 70 + 7 * m))
        lhs[:70, :70] = self.AtA
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
                              (G.transpose(0, 2, 1) @ wr)[..., 0].ravel()))
        return lhs, rhs - (x - self.x0) / self.sd


def _damped_step(p: _MapProblem, x, c: float, lhs, rhs, lam: float, nu: float):
    """Damp until the step lowers the cost (Nielsen's update of the damping), or the damping
    is past all use: ``(x, r, cost, gain, lam, nu)`` of the step."""
    diag = np.diag(lhs).copy()
    while True:
        step = np.linalg.solve(lhs + lam * np.diag(diag), rhs)
        x_new = np.clip(x + step * p.sd, p.lo, p.hi)
        r_new = p.residual(x_new)
        c_new = p.cost(x_new, r_new)
        gain = (c - c_new) / max(step @ (lam * diag * step + rhs), 1e-300)
        if c_new < c or lam > 1e10:
            return x_new, r_new, c_new, gain, lam, nu
        lam *= nu
        nu *= 2.0


def fit_map(W, dq, tau, theta0, phi0, sd_theta, sd_phi, sd_off, s: CalibrationSettings,
            ddq=None, sd_arm=None):
    """The MAP of ``(theta, friction, offsets)`` on the signals ``W (N, 7, 70)``, ``dq``,
    ``tau`` (``(N, 7)``), and of each joint's armature (prior ``0 +- sd_arm``) where its
    acceleration ``ddq`` is given, by Levenberg-Marquardt in prior-scaled unknowns inside
    :data:`~sim.calibration.prior.FRICTION_BOUNDS` and
    :data:`~sim.calibration.prior.ARMATURE_BOUNDS`: a step is taken only if it lowers the
    posterior's cost, the damping grows until it does. Returns ``(theta, friction, offsets,
    armature (zeros where not fitted), iterations)``."""
    p = _MapProblem(W, dq, tau, theta0, phi0, sd_theta, sd_phi, sd_off, s, ddq, sd_arm)
    x = p.x0.copy()
    r = p.residual(x)
    c = p.cost(x, r)
    lam, nu = s.damping, 2.0
    it = 0
    for it in range(1, s.iterations + 1):  # noqa: B007
        lhs, rhs = p.normal_equations(x, r)
        x_new, r_new, c_new, gain, lam, nu = _damped_step(p, x, c, lhs, rhs, lam, nu)
        if c_new >= c:
            break  # no step lowers the cost: a minimum (up to the bounds)
        small = c - c_new < s.tolerance
        x, r, c = x_new, r_new, c_new
        lam *= max(1.0 / 3.0, 1.0 - (2.0 * gain - 1.0) ** 3)
        nu = 2.0
        if small:
            break
    theta, phi, local = p.split(x)
    armature = local[:, 1].copy() if p.c > 1 else np.zeros(7)
    return theta.copy(), phi.copy(), local[:, 0].copy(), armature, it


AMPLITUDES = (0, 3, 4, 5, 6)
"""The friction columns the torque is linear in: ``phi1``, viscous, Stribeck excess."""


def joint_rms(res: np.ndarray) -> np.ndarray:
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


def never_worse(W, dq, tau, theta0, params, phi, off):
    """The calibrated ``(params, friction, offsets)``, changed where they fit a joint worse
    than the nominal model (bodies ``theta0``, no friction, no offsets) on the fitted
    signals ``W (N, 7, 70)``, ``dq``, ``tau`` (``(N, 7)``), and the warnings that says so.

    A joint's friction and offset are its own: where a joint fits worse, they are refitted
    by bounded least squares on that joint alone (:func:`_local_refit`). Where the bodies
    are to blame (still worse), the bodies go back to nominal, each joint's friction and
    offset refitted on them, which fits no joint worse than the nominal model."""
    theta0 = np.asarray(theta0, dtype=float).ravel()
    nominal_rms = joint_rms(tau - W @ theta0)
    phi = np.array(phi, dtype=float)
    off = np.array(off, dtype=float)

    def refit(bodies, joints):
        res = tau - W @ bodies.ravel()
        jac = friction_jacobian(dq, phi)
        for j in joints:
            coef = _local_refit(res[:, j], jac[:, j, :])
            phi[j, list(AMPLITUDES)] = coef[:5]
            off[j] = coef[5]
        return joint_rms(res - friction_torque(dq, phi) - off)

    rms = joint_rms(tau - W @ params.ravel() - friction_torque(dq, phi) - off)
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
