"""The arm's own noise: measured from residuals, carried by IEM+phys, offsets marginalised."""

import math

import numpy as np
import pytest

from iem.errors import InvalidInputError
from iem.physics.posterior import EquationWindow
from iem.physics.torque_noise import (
    MIN_OFFSET_STD,
    NOMINAL_ARM_NOISE,
    TorqueNoise,
    bias_std,
    measure,
)


def _ar1(n, rho, sigma, rng):
    e = np.empty((n, 7))
    e[0] = rng.normal(0, sigma, 7)
    w = rng.normal(0, sigma * math.sqrt(1 - rho * rho), (n, 7))
    for k in range(1, n):
        e[k] = rho * e[k - 1] + w[k]
    return e


def test_measure_finds_size_correlation_and_offset():
    rng = np.random.default_rng(0)
    rho = 0.8  # AR(1): sum of the autocorrelation over all lags (1 + rho) / (1 - rho) = 9
    e = _ar1(60_000, rho, 0.1, rng) + np.array([0.0, 0.05, 0, 0, 0, 0, 0])
    noise = measure(e, 100.0, filter_weight=1.0)
    assert np.allclose(noise.std[2:], 0.1, rtol=0.05)
    assert noise.std[1] == pytest.approx(math.hypot(0.1, 0.05), rel=0.05)
    assert np.allclose(noise.weight, 9.0, rtol=0.15)
    assert noise.offset_std[1] == pytest.approx(0.05, rel=0.2)  # the constant offset
    assert all(v >= MIN_OFFSET_STD for v in noise.offset_std)
    white = measure(rng.normal(0, 0.1, (20_000, 7)), 100.0, filter_weight=11.3)
    assert np.allclose(white.weight, 11.3)  # never below the filter's own


def test_torque_noise_round_trip_and_checks():
    d = NOMINAL_ARM_NOISE.to_dict()
    assert TorqueNoise.from_dict(d) == NOMINAL_ARM_NOISE
    with pytest.raises(InvalidInputError, match="weight must be >= 1"):
        TorqueNoise.from_dict({**d, "weight": [0.5] * 7})
    with pytest.raises(InvalidInputError, match="std must be 7"):
        TorqueNoise.from_dict({**d, "std": [0.1] * 6})
    with pytest.raises(InvalidInputError, match="not valid"):
        TorqueNoise.from_dict({"std": [0.1] * 7})


def test_window_marginalises_offsets_as_an_augmented_least_squares():
    """Independent truth: the 17-unknown problem [phi, o] solved whole, its phi block."""
    rng = np.random.default_rng(1)
    offset_var = rng.uniform(0.01, 0.2, 7) ** 2
    window = EquationWindow(offset_var)
    A = np.zeros((17, 17))
    b = np.zeros(17)
    for _ in range(200):
        Y = rng.normal(size=(7, 10))
        r = rng.normal(size=7)
        L = rng.normal(size=(7, 7)) * 0.1
        R = L @ L.T + np.eye(7) * 0.05
        window.add(Y, r, R, weight=3.0)
        Ya = np.hstack((Y, np.eye(7)))
        W = np.linalg.inv(3.0 * R)
        A += Ya.T @ W @ Ya
        b += Ya.T @ W @ r
    A[10:, 10:] += np.diag(1.0 / offset_var)
    cov = np.linalg.inv(A)
    info_phi = np.linalg.inv(cov[:10, :10])
    assert np.allclose(window.info, info_phi, rtol=1e-8, atol=1e-8)
    mean_phi = (cov @ b)[:10]
    assert np.allclose(np.linalg.solve(window.info, window.eta), mean_phi, rtol=1e-8,
                       atol=1e-10)
    state = window.to_state()
    other = EquationWindow(offset_var)
    other.set_state(state)
    assert np.allclose(other.info, window.info) and np.allclose(other.eta, window.eta)


def test_bias_is_the_spread_beyond_the_phantoms_own_variance():
    rng = np.random.default_rng(2)
    var = np.full((4000, 10), 0.01 ** 2)
    phantoms = rng.normal(0, 0.01, (4000, 10))  # noise alone: what 4000 cannot resolve
    assert np.all(bias_std(phantoms, var) < 0.003)
    biased = phantoms + rng.normal(0, 0.03, (4000, 10))
    assert np.allclose(bias_std(biased, var), 0.03, rtol=0.1)


def test_unresolved_bias_counts_at_the_measurement_resolution():
    """Phantoms that show no bias still leave one as large as their count can resolve: the
    standard error of mean(phi²), sqrt(2 / n) var, not zero."""
    var = np.full((8, 10), 0.01 ** 2)
    floor = bias_std(np.zeros((8, 10)), var)
    assert np.allclose(floor, 0.01 * (2.0 / 8) ** 0.25)
    assert np.all(bias_std(np.zeros((800, 10)), var[:1].repeat(800, 0)) < 0.5 * floor)


def _augmented_mean(eqs, offset_var, mu_p, c_p):
    """Independent truth: the 17-unknown least squares [phi, o] with the prior, its phi."""
    A = np.zeros((17, 17))
    b = np.zeros(17)
    for Y, r, R in eqs:
        Ya = np.hstack((Y, np.eye(7)))
        W = np.linalg.inv(3.0 * R)
        A += Ya.T @ W @ Ya
        b += Ya.T @ W @ r
    A[10:, 10:] += np.diag(1.0 / offset_var)
    A[:10, :10] += np.linalg.inv(c_p)
    b[:10] += np.linalg.solve(c_p, mu_p)
    return np.linalg.solve(A, b)[:10]


def test_considered_gain_error_is_what_a_gain_does_to_the_estimate():
    """A torque-sensor gain error per joint, r = (I + diag(g)) Y phi + o + e: the posterior's
    gain_var is the variance of the estimate's shift that such gains cause, found here by
    refitting with each joint's gain perturbed (the augmented least squares); it grows with
    the payload's torque, as the square of it."""
    from iem.physics.posterior import combine

    rng = np.random.default_rng(3)
    offset_var = rng.uniform(0.01, 0.2, 7) ** 2
    gain_var = rng.uniform(0.005, 0.02, 7) ** 2
    phi = np.array([2.7, 0.11, -0.08, 0.22, 0.028, 0.003, -0.008, 0.031, 0.006, 0.012])
    mu_p, c_p = np.zeros(10), np.diag(np.full(10, 10.0))

    def window_of(payload):  # the same motion and noise for any payload
        rng = np.random.default_rng(4)
        window = EquationWindow(offset_var, gain_var)
        eqs = []
        for _ in range(300):
            Y = rng.normal(size=(7, 10))
            L = rng.normal(size=(7, 7)) * 0.1
            R = L @ L.T + np.eye(7) * 0.05
            r = Y @ payload + rng.normal(size=7) * 0.02
            window.add(Y, r, R, weight=3.0)
            eqs.append((Y, r, R))
        return window, eqs

    window, eqs = window_of(phi)
    post = combine(mu_p, c_p, window)
    assert post.inflation == 1.0
    base = _augmented_mean(eqs, offset_var, mu_p, c_p)
    assert np.allclose(base, post.mean, rtol=1e-7, atol=1e-9)
    J = np.empty((10, 7))
    for j in range(7):  # a unit gain error on joint j, of the torque the estimate explains
        shifted = [(Y, r + np.eye(7)[j] * (Y @ post.mean)[j], R) for Y, r, R in eqs]
        J[:, j] = _augmented_mean(shifted, offset_var, mu_p, c_p) - base
    assert np.allclose(post.gain_var, np.square(J) @ gain_var, rtol=1e-6, atol=1e-14)
    assert np.all(post.gain_var > 0.0)
    light, _ = window_of(0.25 * phi)
    ratio = combine(mu_p, c_p, light).gain_var / post.gain_var
    assert np.allclose(ratio, 1.0 / 16.0, rtol=0.2)  # a quarter of the load
    state = window.to_state()
    restored = EquationWindow(offset_var, gain_var)
    restored.set_state(state)
    assert np.allclose(combine(mu_p, c_p, restored).gain_var, post.gain_var)
    restored.set_state({k: v for k, v in state.items() if k != "gains"})
    assert restored.empty  # no gain sums: the window starts again
    assert not np.any(combine(mu_p, c_p, EquationWindow(offset_var)).gain_var)
