"""Filters, smoothing and metrics against independent computations."""

import math

import numpy as np
import pytest
from scipy import signal

from iem.errors import InvalidInputError
from iem.metrics import convergence_s, mae, mae_groups, moving_average
from iem.signals.filters import LowPass2, StateFilter, butterworth2
from iem.signals.smoothing import ExponentialSmoother
from iem.types import PARAMS


@pytest.mark.parametrize("cutoff", [5.0, 20.0, 50.0, 200.0])
def test_butterworth_design_equals_scipy(cutoff):
    b, a = butterworth2(cutoff, 1000.0)
    sb, sa = signal.butter(2, cutoff / 500.0)
    np.testing.assert_allclose(b, sb, rtol=1e-12)
    np.testing.assert_allclose(a, sa, rtol=1e-12)


def test_lowpass_equals_lfilter_from_steady_state():
    rng = np.random.default_rng(0)
    x = rng.normal(size=(500, 3)) + 2.0
    lp = LowPass2(30.0, 1000.0, channels=3)
    ours = np.array([lp(row) for row in x])
    b, a = butterworth2(30.0, 1000.0)
    zi = signal.lfilter_zi(b, a)[:, None] * x[0]
    ref, _ = signal.lfilter(b, a, x, axis=0, zi=zi)
    np.testing.assert_allclose(ours, ref, atol=1e-12)


def test_state_filter_differentiates_a_slow_sine():
    f = StateFilter()  # 25 Hz at the 100 Hz of block points
    t = np.arange(400) / 100.0
    w = 2 * math.pi * 0.5
    for k, tk in enumerate(t):
        _, _, ddq = f(np.full(7, math.sin(w * tk)), np.full(7, w * math.cos(w * tk)))
        if k > 20:  # after the filter's lag (~7 ms) and the difference's (5 ms) it is right
            assert abs(ddq[0] + w * w * math.sin(w * (tk - 0.012))) < 0.01


def test_bad_cutoff_is_an_error():
    with pytest.raises(InvalidInputError, match="Nyquist"):
        butterworth2(600.0, 1000.0)


def test_exponential_smoother_is_causal_and_documented():
    s = ExponentialSmoother(tau_s=0.2, dt=1e-3)
    alpha = 1 - math.exp(-0.005)
    assert s.alpha == pytest.approx(alpha)
    rng = np.random.default_rng(0)
    x = rng.normal(size=(1000, 2))
    out = s.run(x)
    # the documented rule, step by step: the plain mean of the first 1/alpha estimates,
    # then the exponential average
    ref = np.empty_like(x)
    acc = x[0].copy()
    ref[0] = acc
    for n in range(2, len(x) + 1):
        acc = acc + max(1.0 / n, alpha) * (x[n - 1] - acc)
        ref[n - 1] = acc
    np.testing.assert_allclose(out, ref, atol=1e-15)
    np.testing.assert_allclose(out[150], x[:151].mean(axis=0), atol=1e-12)  # still the mean
    # causal: changing a later sample never changes an earlier output
    y = x.copy()
    y[500:] += 10.0
    np.testing.assert_array_equal(ExponentialSmoother(dt=1e-3).run(y)[:500], out[:500])
    # after the start, a step is 1 - exp(-t / tau) through after t
    steady = ExponentialSmoother(tau_s=0.2)  # at the 100 Hz of block points
    steady.run(np.zeros((100, 1)))
    step = steady.run(np.ones((61, 1)))
    assert step[60, 0] == pytest.approx(1 - math.exp(-0.61 / 0.2), rel=1e-2)


def test_smoother_skips_nan_and_restarts():
    s = ExponentialSmoother()
    s(np.array([np.nan]))
    assert s(np.array([2.0]))[0] == 2.0
    assert s(np.array([np.nan]))[0] == 2.0


def test_mae_and_groups():
    truth = np.arange(10.0)
    est = np.tile(truth, (4, 1))
    est[:, 0] += 0.1
    est[:, 1:4] += np.array([0.3, -0.3, 0.6])
    est[:, 4:] += 0.06
    per = mae(est, truth)
    assert list(per) == list(PARAMS)
    g = mae_groups(est, truth)
    assert g["mass"] == pytest.approx(0.1)
    assert g["com"] == pytest.approx(0.4)
    assert g["inertia"] == pytest.approx(0.06)


def test_moving_average_is_trailing():
    x = np.arange(10.0)[:, None]
    ma = moving_average(x, 3)
    np.testing.assert_allclose(ma[:, 0], [0, 0.5, 1, 2, 3, 4, 5, 6, 7, 8])


def test_convergence_time_is_the_last_exit_from_the_band():
    t = np.arange(3000) * 1e-3
    truth = np.zeros(10)
    est = np.zeros((3000, 10))
    est[:1000, 0] = 1.0        # mass wrong for 1 s
    est[1500:1510, 0] = 10.0   # a 10 ms spike at 1.5 s: its 100 ms average is 1.0, too far
    est[:, 4:] = 1e-3          # inertia always within 0.0014
    est[:, 1:4] = 1.0          # com never converges
    conv = convergence_s(t, est, truth)
    assert conv["inertia"] == 0.0
    assert conv["com"] is None
    assert conv["mass"] == pytest.approx(1.609, abs=2e-3)
