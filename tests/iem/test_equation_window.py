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


def test_the_arms_considered_parameters_move_the_estimate_as_their_covariance_says():
    """What the arm's uncertainty adds to the estimate (``Posterior.arm_cov``) against an
    independent computation: the posterior mean of windows whose equations carry the arm's
    torque for each unit parameter ``A e_i`` (offsets marginalised alike) moves by column
    ``i`` of ``J``, and ``arm_cov = J J^T``."""
    from iem.physics.posterior import combine

    rng = np.random.default_rng(5)
    offset_var = rng.uniform(0.01, 0.2, 7) ** 2
    k = 4
    mu, C = rng.normal(size=10), np.diag(rng.uniform(0.1, 1.0, 10))
    eqs = []
    for _ in range(25):  # data that agree with the prior: it is not inflated
        Y, _, R = _equation(rng)
        eqs.append((Y, Y @ mu + rng.normal(size=7) * 0.01, R, rng.normal(size=(7, k)) * 0.05))

    def posterior(shift=None):
        window = EquationWindow(offset_var)
        for Y, r, R, A in eqs:
            window.add(Y, r if shift is None else r + A @ shift, R, weight=3.0, A=A)
        return combine(mu, C, window)

    base = posterior()
    assert base.inflation == 1.0
    J = np.column_stack([posterior(np.eye(k)[i]).mean - base.mean for i in range(k)])
    np.testing.assert_allclose(base.arm_cov, J @ J.T, rtol=1e-6, atol=1e-12)
    assert np.all(np.diag(base.arm_cov) > 0.0)
    # a window without them adds nothing; its state keeps them for the next refresh
    plain = EquationWindow(offset_var)
    for Y, r, R, _ in eqs:
        plain.add(Y, r, R, weight=3.0)
    assert not combine(mu, C, plain).arm_cov.any()
    window = EquationWindow(offset_var)
    for Y, r, R, A in eqs:
        window.add(Y, r, R, weight=3.0, A=A)
    back = EquationWindow(offset_var)
    back.set_state(window.to_state())
    np.testing.assert_array_equal(back.arm_sensitivity(), window.arm_sensitivity())
