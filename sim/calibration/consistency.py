"""Step 5 of the calibration: physically consistent bodies, each pseudo-inertia positive
definite, nearest the fit in the metric of its posterior (a small semidefinite program), or
moved back toward the nominal bodies should the solver fail."""

from __future__ import annotations

import numpy as np


def pseudo_min_eig(p: np.ndarray) -> float:
    """Smallest eigenvalue of a body's pseudo-inertia (positive: physically consistent)."""
    m, h = p[0], p[1:4]
    ixx, ixy, iyy, ixz, iyz, izz = p[4:]
    inertia = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
    sigma = 0.5 * np.trace(inertia) * np.eye(3) - inertia
    pseudo = np.zeros((4, 4))
    pseudo[:3, :3] = sigma
    pseudo[:3, 3] = pseudo[3, :3] = h
    pseudo[3, 3] = m
    return float(np.linalg.eigvalsh(pseudo)[0])


def consistent_map(theta_map: np.ndarray, precision: np.ndarray, eps: float = 1e-6
                   ) -> np.ndarray | None:
    """The physically consistent body parameters nearest the unconstrained MAP ``theta_map``
    (70) in the metric of its posterior ``precision`` (70 x 70): the constrained MAP, since
    the torques are linear in the parameters. Each body's pseudo-inertia ``[[Σ, h], [h^T,
    m]]`` (``Σ = tr(I)/2 E - I``) is kept ``>= eps E``: a semidefinite program (cvxpy, solved
    by Clarabel). None if the solver fails."""
    import cvxpy as cp

    theta_map = np.asarray(theta_map, dtype=float).ravel()
    evals, evecs = np.linalg.eigh(0.5 * (precision + precision.T))
    root = evecs * np.sqrt(np.maximum(evals, 0.0))  # precision = root @ root.T
    x = cp.Variable(70)
    cons = []
    for j in range(7):
        p = x[10 * j:10 * j + 10]
        m, h = p[0], p[1:4]
        ixx, ixy, iyy, ixz, iyz, izz = (p[k] for k in range(4, 10))
        tr = 0.5 * (ixx + iyy + izz)
        pseudo = cp.bmat([[tr - ixx, -ixy, -ixz, h[0]],
                          [-ixy, tr - iyy, -iyz, h[1]],
                          [-ixz, -iyz, tr - izz, h[2]],
                          [h[0], h[1], h[2], m]])
        cons.append(0.5 * (pseudo + pseudo.T) >> eps * np.eye(4))
    problem = cp.Problem(cp.Minimize(cp.sum_squares(root.T @ (x - theta_map))), cons)
    try:
        problem.solve(solver=cp.CLARABEL)
    except cp.error.SolverError:
        return None
    if x.value is None or problem.status not in ("optimal", "optimal_inaccurate"):
        return None
    return np.asarray(x.value).reshape(7, 10)


def consistent(params: np.ndarray, nominal: np.ndarray, eps: float = 1e-7
               ) -> tuple[np.ndarray, list[int]]:
    """``params`` (7 x 10) with each body whose pseudo-inertia is not positive definite
    moved back toward ``nominal`` (halving the step along the segment, which stays in the convex set
    of consistent bodies) until it is; returns the bodies and the 1-based joints moved. The
    last resort, after :func:`consistent_map`: it changes the torques."""
    out = np.array(params, dtype=float).reshape(7, 10)
    moved = []
    for j in range(7):
        if pseudo_min_eig(out[j]) > eps:
            continue
        lo, hi = 0.0, 1.0  # fraction of the correction kept
        for _ in range(50):
            mid = 0.5 * (lo + hi)
            if pseudo_min_eig(nominal[j] + mid * (out[j] - nominal[j])) > eps:
                lo = mid
            else:
                hi = mid
        out[j] = nominal[j] + lo * (out[j] - nominal[j])
        moved.append(j + 1)
    return out, moved
