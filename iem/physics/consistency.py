"""Physical consistency of payload parameters, and the projection onto it (numpy; scipy's
LAPACK via small_linalg).

A rigid body's parameters ``phi = [m, h, I]`` (paper order: ``h = m r`` in kg·m, ``I`` the
inertia about the flange origin in kg·m², see :mod:`iem.types`) are physically consistent iff
its 4x4 *pseudo-inertia* (Wensing, Kim and Slotine 2017)::

    J(phi) = [[Sigma, h], [h^T, m]],   Sigma = 0.5 tr(I) E - I

is positive definite: ``J = integral of [x; 1][x; 1]^T dm`` over the body, so ``J > 0`` is mass
``m > 0``, a positive-definite inertia about the CoM and the strict triangle inequality of its
principal moments, all at once (the CoM-frame second moment ``Sigma_c = Sigma - h h^T / m`` is
the Schur complement, and ``I_c = tr(Sigma_c) E - Sigma_c``). ``J`` is linear in ``phi``, a
bijection between the ten parameters and the symmetric 4x4 matrices; Pinocchio calls it
``PseudoInertia`` (its ``LogCholeskyParameters`` parametrise exactly the ``J > 0``).

:func:`project` returns the consistent parameters nearest to ``phi`` in a given metric ``W``
(10x10, positive definite), with ``J(phi) >= eps E`` (``eps`` = :data:`EPS`, far below any real
body: a gram at a millimetre):

- no metric: the nearest in the Frobenius norm of ``J``, which is clipping ``J``'s eigenvalues
  at ``eps`` (exact);
- a metric, e.g. an estimate's posterior precision so that the least certain parameters move
  the most: ``min (x - phi)^T W (x - phi)`` subject to ``J(x) - eps E >= 0``, a small convex
  semidefinite programme solved by a log-barrier Newton method from the clipped point
  (duality gap below ``rtol`` of the clipped point's distance).

Consistent inputs (``J(phi) >= eps E`` already) come back unchanged.
"""

from __future__ import annotations

import numpy as np

from ..errors import InvalidInputError
from .small_linalg import cholesky, cholesky_inverse, solve

EPS = 1e-9
"""Smallest eigenvalue a projected pseudo-inertia gets (kg, kg·m²)."""

# J = sum_i phi_i B[i]: the basis of the linear map (paper order of phi)
_B = np.zeros((10, 4, 4))
_B[0, 3, 3] = 1.0
for _i in range(3):
    _B[1 + _i, _i, 3] = _B[1 + _i, 3, _i] = 1.0
# I entries in paper order: Ixx, Ixy, Ixz, Iyy, Iyz, Izz
_I_INDEX = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))
for _k, (_r, _c) in enumerate(_I_INDEX):
    unit = np.zeros((3, 3))
    unit[_r, _c] = unit[_c, _r] = 1.0
    _B[4 + _k, :3, :3] = 0.5 * np.trace(unit) * np.eye(3) - unit
_B.flags.writeable = False
_BF = _B.reshape(10, 16)  # J.ravel() = phi @ _BF


def _check(phi) -> np.ndarray:
    phi = np.asarray(phi, dtype=float)
    if phi.shape[-1:] != (10,):
        raise InvalidInputError(f"phi must have 10 values [m, mrx, mry, mrz, Ixx, Ixy, Ixz, "
                                f"Iyy, Iyz, Izz], got shape {phi.shape}")
    return phi


def pseudo_inertia(phi) -> np.ndarray:
    """``J(phi)`` (4x4, or ``(..., 4, 4)`` for ``(..., 10)`` inputs)."""
    return np.einsum("...i,ijk->...jk", _check(phi), _B)


def from_pseudo_inertia(J) -> np.ndarray:
    """The inverse of :func:`pseudo_inertia`: ``phi`` (paper order) of a symmetric 4x4 ``J``."""
    J = np.asarray(J, dtype=float)
    if J.shape[-2:] != (4, 4):
        raise InvalidInputError(f"J must be 4x4, got shape {J.shape}")
    J = 0.5 * (J + np.swapaxes(J, -1, -2))
    sigma = J[..., :3, :3]
    inertia = np.trace(sigma, axis1=-2, axis2=-1)[..., None, None] * np.eye(3) - sigma
    six = np.stack([inertia[..., r, c] for r, c in _I_INDEX], axis=-1)
    return np.concatenate((J[..., 3:, 3], J[..., :3, 3], six), axis=-1)


def min_eigenvalue(phi) -> np.ndarray | float:
    """Smallest eigenvalue of ``J(phi)``: > 0 iff ``phi`` is physically consistent."""
    lam = np.linalg.eigvalsh(pseudo_inertia(phi))[..., 0]
    return float(lam) if np.ndim(lam) == 0 else lam


def is_consistent(phi, eps: float = 0.0) -> bool:
    """True if ``J(phi) > eps E`` (finite values only)."""
    phi = _check(phi)
    return bool(np.all(np.isfinite(phi)) and min_eigenvalue(phi) > eps)


def _clip(phi: np.ndarray, floor: float) -> np.ndarray:
    lam, vec = np.linalg.eigh(pseudo_inertia(phi))
    return from_pseudo_inertia((vec * np.maximum(lam, floor)) @ vec.T)


def project(phi, weight=None, eps: float = EPS, rtol: float = 1e-6,
            max_newton: int = 200) -> np.ndarray:
    """The consistent parameters nearest to ``phi`` (see the module docstring).

    Args:
        phi: parameters, paper order (10).
        weight: the metric ``W`` (10x10 symmetric positive definite), or None for the
            Frobenius norm of ``J``.
        eps: smallest eigenvalue of the result's ``J``.
        rtol: accuracy of the weighted projection, relative to the clipped point's distance.
        max_newton: bound on the Newton steps of the weighted projection.

    Returns:
        A new array; ``phi`` itself (copied) if already consistent; NaN in, NaN out.
    """
    steps = project_steps(phi, weight, eps, rtol, max_newton)
    while True:
        try:
            next(steps)
        except StopIteration as done:
            return done.value


def project_steps(phi, weight=None, eps: float = EPS, rtol: float = 1e-6,
                  max_newton: int = 200):
    """:func:`project` one Newton step at a time: a generator that yields (None) after each
    step of the weighted projection and returns the result (``StopIteration.value``), the
    very same arithmetic. A caller with a time budget (the online cycle) spreads the
    projection over several calls; a consistent ``phi`` finishes without a yield."""
    phi = _check(phi).reshape(10).copy()
    if not np.all(np.isfinite(phi)):
        return phi
    if min_eigenvalue(phi) >= eps:
        return phi
    scale = max(float(np.abs(np.linalg.eigvalsh(pseudo_inertia(phi))).max()), eps)
    if weight is None:
        return _clip(phi, eps + 1e-12 * scale)
    W = np.asarray(weight, dtype=float)
    if W.shape != (10, 10):
        raise InvalidInputError(f"weight must be 10x10, got shape {W.shape}")
    W = 0.5 * (W + W.T)
    return (yield from _barrier(phi, W, eps, rtol, max_newton,
                                _clip(phi, eps + max(1e-6 * scale, 10.0 * eps))))


def _barrier(mu, W, eps, rtol, max_newton, x):
    """``min 0.5 (x - mu)^T W (x - mu) - t log det(J(x) - eps E)`` for t -> 0 (a generator:
    yields after each Newton step, returns the point). The Cholesky factor of the slack at
    the point the line search accepts is the one the next Newton step inverts (one
    factorisation per point)."""
    eye = eps * np.eye(4)

    def factor(x):  # the slack's lower Cholesky factor, None where it is not positive definite
        try:
            return cholesky((x @ _BF).reshape(4, 4) - eye)
        except np.linalg.LinAlgError:
            return None

    def cost(x, t, L):
        d = x - mu
        return 0.5 * d @ W @ d - 2.0 * t * np.log(L.diagonal()).sum()

    d0 = x - mu
    dist0 = 0.5 * d0 @ W @ d0
    if not dist0 > 0.0:
        return x
    t = dist0 / 4.0
    steps = 0
    L = factor(x)
    while steps < max_newton:
        f_x = None  # cost(x, t), kept from the line search that accepted x
        for _ in range(50):  # Newton on the barrier problem for this t
            if L is None:
                return x
            try:
                K = cholesky_inverse(L)  # x is feasible: the slack is positive definite
            except np.linalg.LinAlgError:
                return x
            grad = W @ (x - mu) - t * (_BF @ K.ravel())
            KK = (K[:, None, :, None] * K[None, :, None, :]).reshape(16, 16)
            hess = W + t * (_BF @ KK @ _BF.T)
            try:
                step = solve(hess, -grad)
            except np.linalg.LinAlgError:
                return x  # feasible, if not quite optimal
            dec = float(-grad @ step)  # Newton decrement squared
            steps += 1
            yield
            if dec <= rtol * dist0 or steps >= max_newton:
                break
            f0, a = (cost(x, t, L) if f_x is None else f_x), 1.0
            while a > 1e-10:
                trial = x + a * step
                L_trial = factor(trial)
                f_x = np.inf if L_trial is None else cost(trial, t, L_trial)
                if f_x <= f0 - 0.25 * a * dec:
                    break
                a *= 0.5
            if a <= 1e-10:
                break
            x, L = trial, L_trial  # the point f_x was computed at, and its factor
        if 4.0 * t <= rtol * dist0:
            break
        t *= 0.05
    return x
