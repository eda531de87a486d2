"""The equations of :func:`sim.identify.identify` and their robust weighted least squares
(step 4 of :mod:`sim.identify`): residual torques and the flange body regressor per sample,
and a Huber IRLS with per-joint scales, the residuals' autocorrelation and a Gaussian prior."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from iem.types import N_JOINTS

HUBER = 1.345
"""Default Huber threshold in robust-scale units (95 % efficiency on Gaussian noise)."""
IRLS_STEPS = 8
MAX_LAG_ACF = 30


# -- the equations -------------------------------------------------------------------------
def residuals_and_regressor(model, q, dq, ddq, tau) -> tuple[np.ndarray, np.ndarray]:
    """``(tau - tau_nom, Y)`` per sample: the residual against ``model``'s RNEA (n, 7) and its
    flange body regressor (n, 7, 10)."""
    n = q.shape[0]
    r = np.empty((n, N_JOINTS))
    Y = np.empty((n, N_JOINTS, 10))
    for i in range(n):
        tau_nom, Y[i] = model.rnea_and_regressor(q[i], dq[i], ddq[i])
        r[i] = tau[i] - tau_nom
    return r, Y


def nominal_residual(model, q, dq, ddq, tau) -> np.ndarray:
    """``tau - tau_nom`` per sample against ``model``'s RNEA (n, 7)."""
    return np.array([tau[i] - model.rnea(q[i], dq[i], ddq[i]) for i in range(q.shape[0])])


def arm_model(arm):
    """The calibrated arm model: an object with ``rnea(q, dq, ddq) -> tau`` (N·m, friction
    and offsets included), a :class:`sim.arm.ArmParams`, or the path of an arm file
    (``sim.arm.load_arm``, ``iem calibrate``'s)."""
    if hasattr(arm, "rnea"):
        return arm
    from sim.arm import load_arm
    from sim.robot import ArmModel

    params = arm if not isinstance(arm, str | bytes) and hasattr(arm, "link_params") \
        else load_arm(arm)
    return ArmModel(arm=params)  # rnea: the arm's links, friction and offsets


# -- the robust fit ------------------------------------------------------------------------
def mad_scale(e: np.ndarray) -> np.ndarray:
    """Per-joint robust scale of residuals (n, 7), floored to stay positive."""
    med = np.median(e, axis=0)
    s = 1.4826 * np.median(np.abs(e - med), axis=0)
    floor = 1e-6 + 1e-3 * np.sqrt(np.mean(e**2))
    return np.maximum(s, floor)


def acf_inflation(u: np.ndarray) -> float:
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
class RobustFit:
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


def robust_fit(Y: np.ndarray, r: np.ndarray, prior_prec: np.ndarray, huber: float,
               prior_mean: np.ndarray | None = None) -> RobustFit:
    """Huber IRLS of ``r = Y phi`` with per-joint scales and the Gaussian prior (mean
    ``prior_mean``, zero if None)."""
    pm = np.zeros(prior_prec.shape[0]) if prior_mean is None else prior_mean
    pull = prior_prec @ pm
    n = r.shape[0]
    p = Y.shape[2]
    A = Y.reshape(-1, p)
    b = r.reshape(-1)
    w_h = np.ones((n, N_JOINTS))
    scale = mad_scale(r)
    sigma2, inflation = 1.0, 1.0
    phi = np.zeros(p)
    for _ in range(IRLS_STEPS):
        w = (w_h / scale**2).reshape(-1)
        Aw = A * w[:, None]
        H_data = (A.T @ Aw) / (sigma2 * inflation)
        H = H_data + prior_prec
        phi_new = np.linalg.solve(H, (Aw.T @ b) / (sigma2 * inflation) + pull)
        e = r - (Y @ phi_new)
        scale = mad_scale(e)
        u = e / scale
        w_h = np.minimum(1.0, huber / np.maximum(np.abs(u), 1e-12))
        sigma2 = float(np.sum(w_h * u**2) / max(1, n * N_JOINTS - p))
        inflation = acf_inflation(u)
        converged = np.allclose(phi_new, phi, rtol=1e-9, atol=1e-12)
        phi = phi_new
        if converged:
            break
    w = (w_h / scale**2).reshape(-1)
    H = (A.T @ (A * w[:, None])) / (sigma2 * inflation) + prior_prec
    theta = np.linalg.solve(H, ((A * w[:, None]).T @ b) / (sigma2 * inflation) + pull)
    return RobustFit(theta=theta, H=H, scale=scale, sigma2=sigma2, inflation=inflation,
                     weights=w_h, residual=r - Y @ theta)
