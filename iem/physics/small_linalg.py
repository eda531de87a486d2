"""Linear algebra on the small matrices of the cycle (7x7, 10x10), straight through LAPACK.

``numpy.linalg`` spends 5-10 µs per call on checks and dispatch around a factorisation that
takes under 1 µs at these sizes (10x10 symmetric inverse: 12.9 µs with ``cholesky`` and
``solve``, 2.9 µs here; a 7x7 chi-square: 7.6 µs against 1.9 µs; measured on this machine).
The cycle makes several of them per equation and per posterior refresh, so they are called
here through SciPy's LAPACK wrappers (``dpotrf``, ``dpotrs``, ``dtrtri``, ``dtrtrs``,
``dgesv``), the same routines numpy's functions call (SciPy is imported at the first call:
this module imports only numpy). Failures raise :class:`numpy.linalg.LinAlgError`, as
numpy's would, so callers keep their ``except`` clauses.
"""

from __future__ import annotations

import numpy as np

__all__ = ["chi_square", "cholesky", "cholesky_inverse", "cholesky_solve", "eigh", "eigvalsh",
           "solve", "sym_inv", "tri_inv"]


_LAPACK = None


def _lapack():
    """SciPy's LAPACK wrappers, imported at the first call (this module imports only numpy
    itself)."""
    global _LAPACK
    if _LAPACK is None:
        from scipy.linalg import lapack

        _LAPACK = lapack
    return _LAPACK


def cholesky(A: np.ndarray) -> np.ndarray:
    """The lower Cholesky factor of the symmetric positive-definite ``A`` (its lower
    triangle is read); ``LinAlgError`` if it is not positive definite."""
    L, info = _lapack().dpotrf(A, lower=1, clean=1)
    if info != 0:
        raise np.linalg.LinAlgError(f"matrix is not positive definite (LAPACK dpotrf info "
                                    f"{info})")
    return L


def sym_inv(A: np.ndarray) -> np.ndarray:
    """Inverse of a symmetric positive-definite matrix, via its Cholesky factor: ``L^-T
    L^-1``, symmetric by construction."""
    return cholesky_inverse(cholesky(A))


def cholesky_inverse(L: np.ndarray) -> np.ndarray:
    """``A^-1 = L^-T L^-1`` from the lower Cholesky factor ``L`` of ``A`` (:func:`cholesky`):
    :func:`sym_inv` of a matrix whose factor is already made."""
    Li = tri_inv(L)
    return Li.T @ Li


def tri_inv(L: np.ndarray) -> np.ndarray:
    """``L^-1`` of a lower-triangular ``L`` (a Cholesky factor; LAPACK ``dtrtri``), lower
    triangular; ``LinAlgError`` if it is singular."""
    Li, info = _lapack().dtrtri(L, lower=1)
    if info != 0:
        raise np.linalg.LinAlgError(f"singular Cholesky factor (LAPACK dtrtri info {info})")
    return Li


def cholesky_solve(L: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``A^-1 b`` from the lower Cholesky factor ``L`` of ``A`` (:func:`cholesky`; LAPACK
    ``dpotrs``)."""
    x, info = _lapack().dpotrs(L, b, lower=1)
    if info != 0:
        raise np.linalg.LinAlgError(f"invalid argument (LAPACK dpotrs info {info})")
    return x


def chi_square(nu: np.ndarray, S: np.ndarray) -> float:
    """``nu^T S^-1 nu`` for symmetric positive-definite ``S``, via its Cholesky factor."""
    w, info = _lapack().dtrtrs(cholesky(S), nu, lower=1)
    if info != 0:
        raise np.linalg.LinAlgError(f"singular Cholesky factor (LAPACK dtrtrs info {info})")
    return float(w @ w)


def solve(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``A^-1 b`` for a square ``A`` (LU with partial pivoting, as ``numpy.linalg.solve``);
    ``LinAlgError`` if ``A`` is singular."""
    _, _, x, info = _lapack().dgesv(A, b)
    if info != 0:
        raise np.linalg.LinAlgError(f"singular matrix (LAPACK dgesv info {info})")
    return x


def eigh(A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvalues (ascending) and eigenvectors (columns) of the symmetric ``A`` (its lower
    triangle is read), as ``numpy.linalg.eigh`` (LAPACK ``dsyevd``)."""
    w, v, info = _lapack().dsyevd(A, compute_v=1, lower=1)
    if info != 0:
        raise np.linalg.LinAlgError(f"eigenvalues did not converge (LAPACK dsyevd info "
                                    f"{info})")
    return w, v


def eigvalsh(A: np.ndarray) -> np.ndarray:
    """Eigenvalues (ascending) of the symmetric ``A`` (its lower triangle is read), as
    ``numpy.linalg.eigvalsh`` (LAPACK ``dsyevd`` without vectors)."""
    w, _, info = _lapack().dsyevd(A, compute_v=0, lower=1)
    if info != 0:
        raise np.linalg.LinAlgError(f"eigenvalues did not converge (LAPACK dsyevd info "
                                    f"{info})")
    return w
