"""Step 8 of the calibration: how sure it is of the arm it found, as a posterior covariance.

The fit (:func:`.fit.fit_map`) is a maximum a posteriori under a prior centred on the nominal
arm; its uncertainty is the inverse of the posterior's precision at the result, for the
bodies' parameters and the friction (:data:`POSTERIOR_PARAMS` of them: ``theta`` (70), then
the friction per joint, 9 columns each) with the offsets marginalised (an estimator carries
its own offsets, :class:`iem.physics.posterior.EquationWindow`)::

    P = sum_j J_j^T J_j / (s_j² c_j) + diag(1 / prior_sd²),    Sigma = (P^-1)[:133, :133]

``J_j`` the Jacobian of joint ``j``'s torque (the joint torque regressor, the friction's
Jacobian at the result, the offset), ``s_j`` the RMS of the fit's residual on joint ``j``
and ``c_j`` how many of its samples count as one independent sample (the sum of its
autocorrelation over :data:`MAX_LAG_S`, at least 1): the residual the fit leaves is what
the data's noise is, so the posterior is as sure as that residual allows, no surer. In
directions the motion does not excite it is the prior's: an estimator that carries it
(:mod:`iem.physics`) sees the arm's uncertainty in every direction, along its own poses.
"""

from __future__ import annotations

import numpy as np

from ..friction import FRICTION_COLUMNS, friction_jacobian, friction_torque

POSTERIOR_PARAMS = 70 + 7 * len(FRICTION_COLUMNS)
"""Parameters the posterior covariance covers: the bodies' 70, the friction's 63."""
MAX_LAG_S = 0.5
"""The longest lag of the residual's autocorrelation summed into ``c_j``, s."""


def effective_share(e: np.ndarray, rate_hz: float) -> float:
    """How many consecutive samples of ``e`` count as one independent sample: ``1 + 2 sum
    rho(k)`` over lags up to :data:`MAX_LAG_S` with a triangular taper, at least 1."""
    x = np.asarray(e, dtype=float) - float(np.mean(e))
    n = x.shape[0]
    var = float(x @ x) / n
    lags = min(n - 1, round(MAX_LAG_S * rate_hz))
    if var <= 0.0 or lags < 1:
        return 1.0
    acf = np.array([float(x[:n - k] @ x[k:]) / n / var for k in range(1, lags + 1)])
    taper = 1.0 - np.arange(1, lags + 1) / (lags + 1)
    return max(1.0, 1.0 + 2.0 * float(np.sum(acf * taper)))


def posterior_covariance(W, dq, tau, params, friction, offset, sd_theta, sd_phi, sd_off,
                         rate_hz: float) -> np.ndarray:
    """The calibration's posterior covariance of ``[theta, friction]``
    (:data:`POSTERIOR_PARAMS` square; see the module docstring) at the calibrated arm
    ``params`` (7x10), ``friction`` (7x9), ``offset`` (7), on the fitted signals ``W (N, 7,
    70)``, ``dq``, ``tau`` (``(N, 7)``) at ``rate_hz``, under the fit's prior standard
    deviations ``sd_theta`` (70), ``sd_phi`` (7x9) and ``sd_off`` (7)."""
    friction = np.asarray(friction, dtype=float)
    k = friction.shape[1]
    theta = np.asarray(params, dtype=float).ravel()
    e = tau - W @ theta - friction_torque(dq, friction) - offset
    jac = friction_jacobian(dq, friction)  # (N, 7, 9)
    sd = np.concatenate((sd_theta, np.asarray(sd_phi, dtype=float).ravel(), sd_off))
    n_all = 70 + 7 * k + 7
    precision = np.diag(1.0 / np.square(sd))
    for j in range(7):
        w = 1.0 / (float(np.mean(e[:, j] ** 2)) * effective_share(e[:, j], rate_hz))
        cols = np.zeros((W.shape[0], n_all))
        cols[:, :70] = W[:, j, :]
        cols[:, 70 + k * j:70 + k * (j + 1)] = jac[:, j, :]
        cols[:, 70 + 7 * k + j] = 1.0
        precision += w * (cols.T @ cols)
    cov = np.linalg.inv(0.5 * (precision + precision.T))
    out = cov[:70 + 7 * k, :70 + 7 * k]
    return 0.5 * (out + out.T)
