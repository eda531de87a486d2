"""The compiled kernels (iem.kernels, opt-in with IEM_KERNELS=numba) against the NumPy
code they stand in for, which is the default.

Every test here runs with the kernels on (the ``compiled`` fixture); :func:`numpy_path`
switches back to the NumPy code for a reference inside a test.
"""

from __future__ import annotations

import contextlib
import copy
import math

import numpy as np
import pytest

from iem import kernels
from iem.errors import InvalidInputError
from iem.learner import WeakLearner, velocity_precision
from iem.router import BagRouter

pytest.importorskip("numba", reason="the compiled kernels need numba (the dev extra has it)")


@pytest.fixture(autouse=True)
def compiled():
    before = kernels.active
    kernels.set_active(True)
    yield
    kernels.set_active(before)


@contextlib.contextmanager
def numpy_path():
    kernels.set_active(False)
    try:
        yield
    finally:
        kernels.set_active(True)


def _learner(rng, precision: bool) -> WeakLearner:
    lo = rng.normal(size=10)
    learner = WeakLearner(lo, lo + rng.uniform(0.5, 2.0, 10), rng.normal(size=21),
                          rng.uniform(0.1, 3.0, 21))
    learner.a = rng.normal(size=(10, 21))
    learner.b = rng.normal(0.3, 0.5, 10)
    if precision:
        learner.dq_precision = velocity_precision(rng.normal(size=(50, 7)) * 2.0,
                                                  np.full(7, 0.01))
    return learner


def _scaled(learner, x):
    return (x - learner.center) * (1.0 / learner.scale)  # the learner scales so


@pytest.mark.parametrize("precision", [True, False])
def test_the_learners_kernel_is_its_numpy(precision):
    rng = np.random.default_rng(11)
    for _ in range(20):
        learner = _learner(rng, precision)
        for scale in (0.1, 1.0, 30.0):  # inside and far outside the training inputs
            x = learner.center + rng.normal(size=21) * learner.scale * scale
            phi, score, vscore = learner.estimate(x, velocity=True)
            with numpy_path():
                ref_phi, ref_score, ref_vscore = learner.estimate(x, velocity=True)
            np.testing.assert_allclose(phi, ref_phi, rtol=1e-12, atol=1e-12)
            np.testing.assert_allclose(phi, learner.predict_many(x[None])[0], rtol=1e-12,
                                       atol=1e-12)
            assert phi.tobytes() == learner.predict_one(x).tobytes()
            assert score == ref_score == float(np.abs(_scaled(learner, x)).max())  # no sums
            assert vscore == pytest.approx(ref_vscore, rel=1e-12, abs=1e-15)
            assert ref_vscore == learner.velocity_score(x) if precision else ref_vscore == 0.0
            assert learner.estimate(x, velocity=False)[2] == 0.0
    assert (phi >= learner.lo).all()  # the ReLU floors at lo


def test_the_learners_kernel_takes_any_layout_and_a_nan_input_scores_nan():
    learner = _learner(np.random.default_rng(2), precision=True)
    learner.a = np.asfortranarray(learner.a)  # e.g. weights mapped back from a transpose
    x = np.concatenate([learner.center, np.zeros(5)])[:21].copy()
    np.testing.assert_allclose(learner.estimate(x, True)[0], learner.predict_many(x[None])[0],
                               rtol=1e-12)
    x[3] = math.nan
    _, score, _ = learner.estimate(x, True)
    assert math.isnan(score)
    assert math.isnan(float(np.abs(_scaled(learner, x)).max()))  # as NumPy says
    with pytest.raises(TypeError):  # a wrong dtype is refused, not reinterpreted
        learner.estimate(np.zeros(21, dtype=np.float32), True)
    with pytest.raises(InvalidInputError, match="21 values"):  # never read past its end
        learner.estimate(np.zeros(20), True)


def test_route_join_when_the_nearest_bag_is_out_of_reach_in_cartesian_space():
    """The nearest bag in joint space fails the flange sphere; a farther one holds the
    point: that one is joined, the nearest is still reported (Algorithm 1's two spheres)."""
    router = BagRouter()
    q = np.zeros(7)
    router.new_bag(q + 0.01, np.array([0.5, 0.0, 0.0]))  # nearest, its flange 0.5 m away
    router.new_bag(q + 0.1, np.zeros(3))  # within both spheres
    router.new_bag(q + 0.2, np.zeros(3))  # within both, farther
    split = copy.deepcopy(router)
    bag, nearest = split.route(q, np.zeros(3))
    split.join(bag, q, np.zeros(3))
    assert (bag, nearest) == (1, 0)
    assert router.route_join(q, np.zeros(3)) == (1, 0)
    assert router.q_means.tobytes() == split.q_means.tobytes()
    assert router.counts.tolist() == [1, 2, 1]
    # nothing holds it: no bag moves, the nearest is reported
    far = np.full(7, 2.0)
    assert router.route_join(far, np.zeros(3)) == (-1, 2)
    assert router.counts.tolist() == [1, 2, 1]
    with pytest.raises(InvalidInputError, match=r"q \(7\) and flange \(3\)"):
        router.route_join(np.zeros(6), np.zeros(3))


@pytest.mark.parametrize("inactive", [False, True])
def test_the_sgd_kernel_is_the_numpy_steps(inactive):
    """The same weights as the NumPy steps (the products are the same BLAS calls), with
    every ReLU active and with some inactive (no gradient through those)."""
    rng = np.random.default_rng(5)
    learner = _learner(rng, precision=False)
    X = learner.center + rng.normal(size=(77, 21)) * learner.scale
    Y = learner.lo + rng.uniform(0.2, 0.8, (77, 10)) * (learner.hi - learner.lo)
    if inactive:
        learner.b[:4] = -30.0  # these outputs' ReLUs stay off for most samples
    a0, b0 = learner.a.copy(), learner.b.copy()
    ref = copy.deepcopy(learner)
    with numpy_path():  # WeakLearner.learn's own NumPy steps
        ref_loss = ref.learn(X, Y, 5)
    ref_a, ref_b = ref.a, ref.b
    loss = learner.learn(X, Y, 5)
    np.testing.assert_allclose(learner.a, ref_a, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(learner.b, ref_b, rtol=1e-12, atol=1e-14)
    assert loss == pytest.approx(ref_loss, rel=1e-12)
    assert not np.allclose(learner.a, a0)  # it learnt
    if inactive:
        z = (X - learner.center) / learner.scale @ a0.T + b0
        assert (z[:, :4] <= 0).mean() > 0.9
    assert math.isnan(learner.learn(X, Y, 0))  # no step: nothing changes, no loss
    # and WeakLearner.learn's own NumPy steps, with its input noise drawn alike
    noisy = [_learner(np.random.default_rng(5), precision=False) for _ in range(2)]
    for one in noisy:
        one.input_noise = np.full(21, 0.05)
        one._refresh()
    loss = noisy[0].learn(X, Y, 5)
    with numpy_path():
        ref_loss = noisy[1].learn(X, Y, 5)
    assert noisy[0].a.tobytes() == noisy[1].a.tobytes()
    assert noisy[0].b.tobytes() == noisy[1].b.tobytes()
    assert loss == pytest.approx(ref_loss, rel=1e-12)


def test_the_mass_bin_table_adds_as_numpy():
    """The calibration's mass-bin table: the same sums and counts as searchsorted and
    np.add.at, masses on the edges, beyond them and NaN included."""
    from iem.prior_summary import MASS_BINS, BagCalibration

    rng = np.random.default_rng(9)
    calib = BagCalibration()
    sq = np.zeros((len(MASS_BINS) + 1, 10))
    n = np.zeros(len(MASS_BINS) + 1, dtype=np.int64)
    for _ in range(5):
        truth = rng.uniform(0.0, 3.2, (77, 10))
        truth[:7, 0] = [*MASS_BINS[:3], 0.0, 3.0, math.nan, 2.5]
        errors = rng.normal(size=(77, 10))
        calib.add(1, errors, truth)
        k = np.searchsorted(MASS_BINS, truth[:, 0], side="right")
        np.add.at(sq, k, np.square(errors))
        n += np.bincount(k, minlength=n.size)
    assert calib._bin_sq.tobytes() == sq.tobytes()
    assert calib._bin_n.tolist() == n.tolist()


def test_the_kernels_take_read_only_inputs():
    """The tandem simulators' samples and a joint state's arrays are read-only: the kernels
    read them as they are (a compiled signature for writable arrays alone refused them)."""
    from iem.prior_summary import BagCalibration

    rng = np.random.default_rng(3)
    learner = _learner(rng, precision=True)

    def frozen(a):
        a = np.array(a)
        a.flags.writeable = False
        return a

    X = frozen(learner.center + rng.normal(size=(77, 21)) * learner.scale)
    Y = frozen(learner.lo + rng.uniform(0.2, 0.8, (77, 10)) * (learner.hi - learner.lo))
    before = learner.predict_one(X[0])
    assert math.isfinite(learner.learn(X, Y, 2))
    assert not np.array_equal(learner.predict_one(X[0]), before)
    assert np.isfinite(learner.estimate(X[0], True)[0]).all()
    BagCalibration().add(0, frozen(rng.normal(size=(77, 10))), Y)
    router = BagRouter()
    router.new_bag(np.zeros(7), np.zeros(3))
    assert router.route_join(frozen(np.full(7, 0.01)), frozen(np.zeros(3))) == (0, 0)


def test_the_filter_and_smoothing_kernels_are_their_numpy():
    """LowPass2's step against ``s[0] = x; m @ s`` (tests/iem/test_signals.py holds the
    filter to scipy's design and lfilter); the smoothing's step to the bit, a non-finite
    estimate leaving the average as it was."""
    from iem.filters import LowPass2
    from iem.smoothing import ExponentialSmoother

    rng = np.random.default_rng(8)
    lp = LowPass2(30.0, 1000.0, channels=21)
    lp(rng.normal(size=21))
    for _ in range(50):
        x = rng.normal(size=21)
        s = lp._s.copy()
        s[0] = x
        out = lp._m @ s
        np.testing.assert_allclose(lp(x), out[0], rtol=1e-13, atol=1e-15)
        np.testing.assert_allclose(lp._s[1:], out[1:], rtol=1e-13, atol=1e-15)
    with pytest.raises(InvalidInputError, match="21 channels"):
        lp(np.zeros(7))

    smoother = ExponentialSmoother(tau_s=0.2)
    ref = smoother(x[:10]).copy()
    for n in range(2, 40):
        y = rng.normal(size=10)
        alpha = smoother.alpha if n % 3 else 1.0 - (1.0 - smoother.alpha) ** 3
        ref += max(1.0 / n, alpha) * (y - ref)
        assert smoother(y, 1 if n % 3 else 3).tobytes() == ref.tobytes()
    y[4] = math.inf
    assert smoother(y).tobytes() == ref.tobytes()
    with pytest.raises(InvalidInputError, match="averages 10 values"):
        smoother(np.zeros(9))


def test_without_a_writable_cache_the_kernels_compile_with_a_warning():
    """A hardened unit has a read-only install and no home: numba then finds no place for
    its cache. The kernels still compile (uncached) and compute; the warning says what to
    set. (A locator list that never applies stands for it: numba reads it at import.)"""
    import os
    import subprocess
    import sys

    code = ("import logging, numpy as np; logging.basicConfig(level=logging.WARNING); "
            "from iem import kernels; kernels.load(); "
            "r = np.zeros((2, 10)); c = np.ones(2, dtype=np.int64); "
            "print(kernels.route_join_small(r, c, 2, np.zeros(7), np.zeros(3), 1.0, 1.0))")
    env = {**os.environ, "NUMBA_CACHE_LOCATOR_CLASSES": "IPythonCacheLocator"}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env=env, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "(0, 0)"
    assert "numba cannot cache the compiled kernels" in out.stderr
    assert "NUMBA_CACHE_DIR" in out.stderr


def test_route_join_of_a_nan_point_decides_as_numpy():
    """A NaN point (never from a link, whose decoders refuse it) joins nothing and names
    the nearest bag as NumPy's argmin does (the first NaN distance): no bag moves."""
    router = BagRouter()
    for i in range(3):
        router.new_bag(np.full(7, 0.1 * i), np.zeros(3))
    q = np.full(7, 0.1)
    q[2] = math.nan
    split = copy.deepcopy(router)
    assert router.route_join(q, np.zeros(3)) == split.route(q, np.zeros(3)) == (-1, 0)
    assert router.q_means.tobytes() == split.q_means.tobytes()
    assert router.counts.tolist() == [1, 1, 1]
    q[2] = math.inf  # every distance infinite: the first bag, as argmin
    assert router.route_join(q, np.zeros(3)) == split.route(q, np.zeros(3)) == (-1, 0)


@pytest.mark.parametrize("n_bags", [12, 60])
def test_route_join_kernel_decides_as_numpy_on_bag_boundaries(n_bags):
    """The algorithms test's boundary points (tests/iem/test_algorithms.py), the kernel's
    route_join against the NumPy one: the same bags, means and counts, to the bit."""
    from tests.iem.test_algorithms import _boundary_points, _crowded_router

    fused = _crowded_router(n_bags)
    ref = copy.deepcopy(fused)
    rng = np.random.default_rng(4)
    points = list(_boundary_points(ref, 10, rng))
    points += [(ref.q_means[i % len(ref)] + rng.normal(0, 0.2, 7), np.zeros(3))
               for i in range(200)]
    outcomes = set()
    for q, f in points:
        got = fused.route_join(q, f)
        with numpy_path():
            want = ref.route_join(q, f)
        assert got == want
        outcomes.add(got[0] >= 0)
    assert outcomes == {True, False}
    assert fused.q_means.tobytes() == ref.q_means.tobytes()
    assert fused.flange_means.tobytes() == ref.flange_means.tobytes()
    assert fused.counts.tolist() == ref.counts.tolist()


def test_the_choice_is_an_environment_variable_with_a_clear_error():
    import os
    import subprocess
    import sys

    code = "from iem import kernels; print(kernels.active)"
    for value, want in (("", "False"), ("numpy", "False"), ("NumBa", "True")):
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                             env={**os.environ, "IEM_KERNELS": value}, timeout=60)
        assert out.returncode == 0 and out.stdout.strip() == want, out.stderr
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env={**os.environ, "IEM_KERNELS": "fortran"}, timeout=60)
    assert out.returncode != 0
    assert "IEM_KERNELS='fortran'" in out.stderr and "numpy, numba" in out.stderr
