"""The equation window's factors made once per state (iem.physics.posterior.EquationWindow):
read between additions, they follow every one (independent truth: the sums kept here and
solved with numpy), and the small LAPACK helpers they use agree with numpy."""

from __future__ import annotations

import numpy as np

from iem.physics.posterior import EquationWindow
from iem.physics.small_linalg import cholesky, cholesky_inverse, cholesky_solve


def _equation(rng):
    Y = rng.normal(size=(7, 10))
    L = rng.normal(size=(7, 7)) * 0.1
    return Y, rng.normal(size=7), L @ L.T + np.eye(7) * 0.05


def test_offsets_and_eigendecomposition_follow_every_added_equation():
    rng = np.random.default_rng(3)
    offset_var = rng.uniform(0.01, 0.2, 7) ** 2
    window = EquationWindow(offset_var, gain_var=np.full(7, 1e-4))
    W_sum, Wr_sum, WY_sum = np.zeros((7, 7)), np.zeros(7), np.zeros((7, 10))
    phi = rng.normal(size=10)
    for k in range(30):
        Y, r, R = _equation(rng)
        window.add(Y, r, R, weight=2.0)
        W = np.linalg.inv(2.0 * R)
        W_sum += W
        Wr_sum += W @ r
        WY_sum += W @ Y
        # the offsets' posterior mean given phi: (sum W + P_o)^-1 (sum W r - sum W Y phi)
        A = W_sum + np.diag(1.0 / offset_var)
        want = np.linalg.solve(A, Wr_sum - WY_sum @ phi)
        np.testing.assert_allclose(window.offsets(phi), want, rtol=1e-9, atol=1e-12)
        if k % 3 == 0:  # read the marginalised info (made from the same factor) in between
            d, U = window.info_eigh()
            np.testing.assert_allclose(d, np.linalg.eigvalsh(window.info), rtol=1e-9,
                                       atol=1e-9 * d.max())
            np.testing.assert_allclose(U @ np.diag(d) @ U.T, window.info, rtol=1e-9,
                                       atol=1e-9 * d.max())
    window.clear()
    assert window.offsets(phi) is not None and np.allclose(window.offsets(phi), 0.0)


def test_the_cholesky_helpers_agree_with_numpy():
    rng = np.random.default_rng(4)
    M = rng.normal(size=(7, 7))
    A = M @ M.T + 7 * np.eye(7)
    b = rng.normal(size=7)
    L = cholesky(A)
    np.testing.assert_allclose(cholesky_solve(L, b), np.linalg.solve(A, b), rtol=1e-12)
    np.testing.assert_allclose(cholesky_inverse(L), np.linalg.inv(A), rtol=1e-10,
                               atol=1e-14)
