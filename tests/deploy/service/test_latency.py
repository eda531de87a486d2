"""The service's latency window: bounded memory, exact percentiles within the window."""

import numpy as np
import pytest

from deploy.service.latency import LatencyWindow
from iem.errors import InvalidInputError


def test_percentiles_are_numpys_over_the_cycles_held():
    rng = np.random.default_rng(0)
    lat = rng.exponential(3e-4, 5000)
    w = LatencyWindow(10_000)
    for v in lat:
        w.add(float(v))
    w.add(float("nan"))  # a cycle without an arrival time
    got = w.percentiles_us(50, 99)
    assert got == pytest.approx(list(np.percentile(lat * 1e6, [50, 99])), rel=1e-12)
    assert w.count == 5001


def test_the_window_keeps_the_last_cycles_only():
    w = LatencyWindow(100)
    for v in range(1000):
        w.add(float(v))
    held = np.sort(w.values())
    np.testing.assert_array_equal(held, np.arange(900, 1000, dtype=float))
    assert w._buf.size == 100  # memory stays what it was made with


def test_empty_and_bad_windows():
    assert LatencyWindow(5).percentiles_us(50, 99) == [None, None]
    with pytest.raises(InvalidInputError, match="at least 1"):
        LatencyWindow(0)
