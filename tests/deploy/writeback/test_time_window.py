"""The gate's stability window (a ring) against a plain list of the rows in the window."""

import numpy as np
import pytest

from deploy.writeback.time_window import TimeWindow


@pytest.mark.parametrize("capacity", [1, 3, 64])
def test_the_ring_holds_exactly_the_rows_of_the_last_span(capacity):
    """Random steps (repeats included), pushes and bare expiries, across wrap-arounds and
    growth: the ring's rows, times and peak-to-peak equal a brute-force list's."""
    rng = np.random.default_rng(capacity)
    span = 0.05
    ring = TimeWindow(span, 3, capacity=capacity)
    rows: list[tuple[float, np.ndarray]] = []
    t = 0.0
    for _ in range(3000):
        t += float(rng.choice([0.0, 0.001, 0.002, 0.03]))
        v = rng.normal(size=3)
        if rng.random() < 0.9:
            ring.push(t, v)
            rows.append((t, v.copy()))
            v[:] = 99.0  # the ring copied it
        else:
            ring.expire(t)
        rows = [(tr, vr) for tr, vr in rows if not tr < t - span]
        assert ring.n == len(rows)
        if rows:
            want = np.array([vr for _, vr in rows])
            assert np.array_equal(ring.times(), np.array([tr for tr, _ in rows]))
            assert np.array_equal(ring.values(), want)
            assert np.array_equal(ring.ptp(), np.ptp(want, axis=0))
            assert np.allclose(ring.ptp(lambda a: 2.0 * a), 2.0 * np.ptp(want, axis=0))
            assert ring.first_t == rows[0][0] and ring.last_t == rows[-1][0]
    ring.clear()
    assert ring.n == 0
