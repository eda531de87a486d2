"""IEM+phys's bag calibration: the mass-bin error table that widens a heavy payload's prior."""

import numpy as np
import pytest

from iem.physics.prior_summary import MASS_BINS, MIN_BIN_SAMPLES, SCALE_RANGE, BagCalibration


def _labelled(rng, masses, err_std):
    """Samples of the given true masses whose errors have standard deviation ``err_std``
    (10 parameters) per sample."""
    truth = np.zeros((masses.size, 10))
    truth[:, 0] = masses
    return truth, rng.normal(0.0, 1.0, (masses.size, 10)) * err_std[:, None]


def test_scale_is_the_bins_rms_over_the_pooled_one_and_never_shrinks():
    rng = np.random.default_rng(0)
    cal = BagCalibration()
    light = rng.uniform(0.1, 0.45, 2000)  # first bin: errors 1
    heavy = rng.uniform(2.6, 3.0, 2000)  # last bin: errors 3
    for bag, masses, s in ((0, light, 1.0), (1, heavy, 3.0)):
        truth, err = _labelled(rng, masses, np.full(masses.size, s))
        cal.add(bag, err, truth)
    pooled = np.sqrt((1.0 + 9.0) / 2.0)  # equal counts
    assert cal.scale(2.8) == pytest.approx(np.full(10, 3.0 / pooled), rel=0.05)
    # the light bin erred less than the pooled samples: its factor stays at the floor
    np.testing.assert_array_equal(cal.scale(0.3), np.full(10, SCALE_RANGE[0]))
    assert cal.scale(1.2) is None  # an empty bin
    assert cal.scale(float("nan")) is None
    # the per-bag covariances are the pooled ones, unchanged by the table
    assert np.sqrt(cal.cov(1)[0, 0]) == pytest.approx(3.0, rel=0.05)


def test_a_bin_needs_enough_samples_and_the_table_survives_its_state():
    rng = np.random.default_rng(1)
    cal = BagCalibration()
    truth, err = _labelled(rng, np.full(MIN_BIN_SAMPLES - 1, 2.8), np.full(MIN_BIN_SAMPLES - 1,
                                                                            5.0))
    cal.add(0, err, truth)
    truth2, err2 = _labelled(rng, np.full(400, 1.7), np.full(400, 1.0))
    cal.add(0, err2, truth2)
    assert cal.scale(2.8) is None
    assert np.searchsorted(MASS_BINS, 2.8, side="right") == len(MASS_BINS)
    cal.add(0, *reversed(_labelled(rng, np.full(1, 2.9), np.full(1, 5.0))))
    got = cal.scale(2.8)
    assert got is not None and np.all(got > 2.0)
    again = BagCalibration()
    again.set_state(cal.to_state())
    np.testing.assert_array_equal(again.scale(2.8), got)
    old = cal.to_state()
    del old["calib_bins"]  # a model file from before the table
    again.set_state(old)
    assert again.scale(2.8) is None


def test_errors_without_truth_leave_the_table_alone():
    cal = BagCalibration()
    cal.add(0, np.ones((500, 10)))
    assert cal.measured(0) and cal.scale(1.0) is None
