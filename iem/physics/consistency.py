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
  semidefinite programme solved by a primal-dual interior-point method (Mehrotra's
  predictor-corrector) until its dual certifies the result's distance within ``rtol`` of the
  optimum's, relative to the smaller of the result's own distance and that of the clipped
  point (``J``'s eigenvalues raised to ``eps``): about five Newton steps for a payload's
  parameters just outside the set.

Consistent inputs (``J(phi) >= eps E`` already) come back unchanged.
"""

from __future__ import annotations

import numpy as np

from ..errors import InvalidInputError
from .small_linalg import cholesky, cholesky_solve, eigh, eigvalsh, tri_inv

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
_BF_INV = np.linalg.pinv(_BF)  # phi = J.ravel() @ _BF_INV for a symmetric J (16x10)
_BF_INV.flags.writeable = False


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
        rtol: accuracy of the weighted projection: its result's distance
            ``f = 0.5 (x - phi)^T W (x - phi)`` exceeds the optimum's by at most ``rtol``
            times the smaller of ``f`` and the clipped point's distance ``dist0``
            (certified by the dual), so it lies within ``sqrt(2 rtol dist0)`` of the
            optimum in the ``W`` norm (the distance grows quadratically from the optimum).
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
    try:
        LW = cholesky(W)
    except np.linalg.LinAlgError:
        raise InvalidInputError("weight must be symmetric positive definite (a precision "
                                "matrix); its Cholesky factorisation failed") from None
    lam, vec = eigh(pseudo_inertia(phi))
    raise_ = np.maximum(lam, eps + max(1e-6 * scale, 10.0 * eps)) - lam
    d0 = ((vec * raise_) @ vec.T).ravel() @ _BF_INV  # the clipped point, less phi
    dist0 = 0.5 * d0 @ W @ d0
    if not dist0 > 0.0:
        return phi + d0
    return (yield from _interior_point(phi, W, LW, eps, rtol, max_newton, lam, vec,
                                       phi + d0, dist0))


def _interior_point(mu, W, LW, eps, rtol, max_newton, lam, vec, clipped, dist0):
    """``min f(x) = 0.5 (x - mu)^T W (x - mu)`` subject to ``S = J(x) - eps E >= 0``, by a
    primal-dual interior-point method (a generator: yields after each Newton step, returns
    the point). ``LW``: ``W``'s lower Cholesky factor; ``lam, vec``: the eigendecomposition
    of ``J(mu)``; ``clipped``: its eigenvalues raised to just above ``eps``, ``dist0`` its
    distance (the fallback should the start fail).

    The dual of the problem is ``max g(Z) = -0.5 a^T W^-1 a - <Z, J(mu) - eps E>`` over
    ``Z >= 0``, with ``a = J^*(Z) = _BF @ Z.ravel()`` (the adjoint of ``J``): any ``Z >= 0``
    bounds the optimum from below, so the method stops at the first iterate whose gap
    ``f(x) - g(Z)`` is at most ``rtol min(f(x), dist0)``: a certified bound on ``f(x)``
    above the optimum. Every iterate is strictly feasible (``S > 0``). The steps are
    Newton's on the perturbed optimality conditions ``W (x - mu) = J^*(Z)``,
    ``S Z = sigma nu E`` (``nu = <S, Z> / 4``) in the HKM symmetrisation, with Mehrotra's
    predictor and corrector (one 10x10 factorisation, two solves), each step cut to
    :data:`_STEP` of the way to the boundary.
    The start is ``J(mu)`` with its eigenvalues raised to :data:`_START` of its largest
    absolute one (well inside the set, where the first steps are long), and ``Z = t S^-1``
    with the ``t`` that best balances ``W (x - mu)`` (least squares in ``W^-1``)."""
    eye = eps * np.eye(4)
    scale = float(np.abs(lam).max())
    x = mu + ((vec * (np.maximum(lam, eps + _START * scale) - lam)) @ vec.T).ravel() @ _BF_INV
    Jmu = (mu @ _BF).reshape(4, 4) - eye
    S = (x @ _BF).reshape(4, 4) - eye
    try:
        Li = tri_inv(cholesky(S))
    except np.linalg.LinAlgError:
        return clipped  # the start is not definite (degenerate scales): the clipped point
    Si = Li.T @ Li
    d = x - mu
    Wd = W @ d
    b = _BF @ Si.ravel()  # J^*(S^-1); d @ b > 0: J(d) >= 0 (raised eigenvalues), S^-1 > 0
    t = max(float(d @ b) / float(b @ cholesky_solve(LW, b)), rtol * dist0)
    Z = t * Si
    steps = 0
    while steps < max_newton:
        a = _BF @ Z.ravel()
        f = 0.5 * d @ Wd
        gap = f + 0.5 * a @ cholesky_solve(LW, a) + Z.ravel() @ Jmu.ravel()
        if gap <= rtol * min(f, dist0):
            break
        try:
            LZi = tri_inv(cholesky(Z))
            SZ = (Si[:, None, :, None] * Z[None, :, None, :]).reshape(16, 16)
            LH = cholesky(W + _BF @ SZ @ _BF.T)
        except np.linalg.LinAlgError:
            return x  # feasible, if not quite optimal
        nu = S.ravel() @ Z.ravel() / 4.0
        # predictor (affine scaling): S Z -> 0
        dx = cholesky_solve(LH, -Wd)
        dS = (dx @ _BF).reshape(4, 4)
        T = Si @ dS @ Z
        dZ = -Z - 0.5 * (T + T.T)
        ap, ad = _step(Li, dS, 1.0), _step(LZi, dZ, 1.0)
        sigma = ((S + ap * dS).ravel() @ (Z + ad * dZ).ravel() / 4.0 / nu) ** 3
        # corrector: centring sigma nu and the predictor's second-order term
        T = Si @ dS @ dZ
        R = sigma * nu * Si - 0.5 * (T + T.T)
        dx = cholesky_solve(LH, _BF @ R.ravel() - Wd)
        dS = (dx @ _BF).reshape(4, 4)
        T = Si @ dS @ Z
        dZ = R - Z - 0.5 * (T + T.T)
        ap, ad = _step(Li, dS, _STEP), _step(LZi, dZ, _STEP)
        steps += 1
        yield
        for _ in range(30):  # rounding at the boundary: shorten until S stays definite
            x_new = x + ap * dx
            S_new = (x_new @ _BF).reshape(4, 4) - eye
            try:
                Li = tri_inv(cholesky(S_new))
                break
            except np.linalg.LinAlgError:
                ap *= 0.5
        else:
            return x
        x, S, Si = x_new, S_new, Li.T @ Li
        Z = Z + ad * dZ
        Z = 0.5 * (Z + Z.T)
        d = x - mu
        Wd = W @ d
    return x


_START = 1e-3
"""Where the interior-point method starts: ``J(mu)``'s eigenvalues raised to this fraction
of its largest absolute eigenvalue."""
_STEP = 0.98
"""Fraction of the way to the boundary of ``S >= 0`` (or ``Z >= 0``) a step goes at most."""


def _step(Li, D, fraction):
    """The step length (at most 1) along ``D`` from ``A = L L^T`` (``Li = L^-1``) that goes
    ``fraction`` of the way to the boundary of ``A + a D >= 0``."""
    low = float(eigvalsh(Li @ D @ Li.T)[0])
    return 1.0 if low >= -fraction else -fraction / low
