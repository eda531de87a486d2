"""The regression's block averaging (IEM+phys's equations at 100 Hz from 1 kHz samples) and
the honest count of correlated equations."""

from __future__ import annotations

import numpy as np
import pytest

from iem.physics.regression import PayloadRegression, correlation_weight
from iem.signals.filters import LowPass2
from iem.signals.gaps import RESTART

from .test_gaps import FAKE


def test_block_means_through_the_slow_filter_give_the_equations():
    """Independent truth: numpy's block means fed to a low-pass designed at the block rate."""
    rng = np.random.default_rng(3)
    n, m = 3000, 10
    X = rng.normal(size=(n, 21)).cumsum(axis=0) * 0.01
    reg = PayloadRegression(FAKE, cutoff_hz=4.0, every=1, settle=0, decimate=m)
    got = [reg(x, steps=RESTART if k == 0 else 1) for k, x in enumerate(X)]
    means = X.reshape(-1, m, 21).mean(axis=1)
    lp = LowPass2(4.0, 100.0, channels=21)
    filtered = np.array([lp(v) for v in means])
    eqs = [(k, e) for k, e in enumerate(got) if e is not None]
    assert len(eqs) == n // m - 1  # one per block after the first
    for k, (Y, r, _) in eqs:
        b = (k + 1) // m - 1  # the block this sample completed
        mid = 0.5 * (filtered[b] + filtered[b - 1])  # the instant ddq belongs to
        q, dq = mid[:7], mid[7:14]
        ddq = (filtered[b, 7:14] - filtered[b - 1, 7:14]) * 100.0
        np.testing.assert_allclose(Y[:, 0], ddq, atol=1e-9)
        np.testing.assert_allclose(Y[:, 2], q, atol=1e-12)
        np.testing.assert_allclose(r, mid[14:] - (2 * ddq + dq), atol=1e-9)


def test_noise_model_at_the_block_rate_matches_a_simulation():
    """The filtered torque noise's variance (``r_tau``) and the correlation weight agree with
    white noise pushed through the regression."""
    rng = np.random.default_rng(4)
    reg = PayloadRegression(FAKE, sigma_tau=0.05, cutoff_hz=4.0, every=1, settle=-1,
                            decimate=10)
    noise = []
    for k in range(200_000):
        x = np.zeros(21)
        x[14:] = rng.normal(0.0, 0.05, 7)
        eq = reg(x, steps=RESTART if k == 0 else 1)
        if eq is not None:
            noise.append(eq[1].copy())
    e = np.array(noise)
    assert np.var(e) == pytest.approx(reg.r_tau, rel=0.1)
    # the variance of block averages of N equations ~ weight * r_tau / N
    N = 400
    means = e[: len(e) // N * N].reshape(-1, N, 7).mean(axis=1)
    ratio = np.var(means) * N / reg.r_tau
    assert 0.6 * reg.correlation_weight < ratio < 1.5 * reg.correlation_weight
    assert correlation_weight(4.0, 100.0, 1) > 10.0


def test_bridged_gaps_in_the_blocks():
    """Lost samples inside blocks are interpolated: the equations of a stream with 5 % lost
    equal those of the whole stream to the interpolation's accuracy."""
    t = np.arange(4000) * 1e-3
    w = 2 * np.pi * 0.5

    def x_at(tk):
        q, dq = np.sin(w * tk) * np.ones(7), w * np.cos(w * tk) * np.ones(7)
        ddq = -w * w * np.sin(w * tk) * np.ones(7)
        return np.concatenate((q, dq, 2 * ddq + dq + 0.3 * q))

    whole = PayloadRegression(FAKE, cutoff_hz=4.0, every=1, settle=-1, decimate=10)
    ref = {k: e for k, tk in enumerate(t) if (e := whole(x_at(tk))) is not None}
    keep = np.random.default_rng(5).random(t.size) > 0.05
    keep[:3] = True
    broken = PayloadRegression(FAKE, cutoff_hz=4.0, every=1, settle=-1, decimate=10)
    last, same = None, 0
    for k in np.flatnonzero(keep):
        e = broken(x_at(t[k]), steps=RESTART if last is None else k - last)
        last = k
        if e is not None and k in ref:
            np.testing.assert_allclose(e[1], ref[k][1], atol=1e-3)
            same += 1
    assert same > 0.8 * len(ref)
