"""Linear algebra on the small matrices of the cycle (7x7, 10x10), straight through LAPACK.

``numpy.linalg`` spends 5-10 µs per call on checks and dispatch around a factorisation that
takes under 1 µs at these sizes (10x10 symmetric inverse: 12.9 µs with ``cholesky`` and
``solve``, 2.9 µs here; a 7x7 chi-square: 7.6 µs against 1.9 µs; measured on this machine).
The cycle makes several of them per equation and per posterior refresh, so they are called
here through SciPy's LAPACK wrappers (``dpotrf``, ``dtrtri``, ``dtrtrs``, ``dgesv``), the
same routines numpy's functions call. Failures raise :class:`numpy.linalg.LinAlgError`, as
numpy's would, so callers keep their ``except`` clauses.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import lapack

__all__ = ["chi_square", "cholesky", "solve", "sym_inv"]

_potrf, _trtri, _trtrs, _gesv = lapack.dpotrf, lapack.dtrtri, lapack.dtrtrs, lapack.dgesv


def cholesky(A: np.ndarray) -> np.ndarray:
    """The lower Cholesky factor of the symmetric positive-definite ``A`` (its lower
    triangle is read); ``LinAlgError`` if it is not positive definite."""
    L, info = _potrf(A, lower=1, clean=1)
    if info != 0:
        raise np.linalg.LinAlgError(f"matrix is not positive definite (LAPACK dpotrf info "
                                    f"{info})")
    return L


def sym_inv(A: np.ndarray) -> np.ndarray:
    """Inverse of a symmetric positive-definite matrix, via its Cholesky factor: ``L^-T
    L^-1``, symmetric by construction."""
    Li, info = _trtri(cholesky(A), lower=1)
    if info != 0:
        raise np.linalg.LinAlgError(f"singular Cholesky factor (LAPACK dtrtri info {info})")
    return Li.T @ Li


def chi_square(nu: np.ndarray, S: np.ndarray) -> float:
    """``nu^T S^-1 nu`` for symmetric positive-definite ``S``, via its Cholesky factor."""
    w, info = _trtrs(cholesky(S), nu, lower=1)
    if info != 0:
        raise np.linalg.LinAlgError(f"singular Cholesky factor (LAPACK dtrtrs info {info})")
    return float(w @ w)


def solve(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``A^-1 b`` for a square ``A`` (LU with partial pivoting, as ``numpy.linalg.solve``);
    ``LinAlgError`` if ``A`` is singular."""
    _, _, x, info = _gesv(A, b)
    if info != 0:
        raise np.linalg.LinAlgError(f"singular matrix (LAPACK dgesv info {info})")
    return x
