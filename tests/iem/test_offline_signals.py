"""The offline signal chain (iem.signals.offline) of ``iem calibrate`` and ``iem identify``:
a recording is split at its gaps, never interpolated across them; a piece too short is
dropped; a cut-off the recorded rate cannot carry is refused; the time stamps, not the sample
count, set the derivatives.

Independent truth: sines with known derivatives, and the pieces of a recording prepared one
by one."""

from __future__ import annotations

import numpy as np
import pytest

from iem.errors import InvalidInputError
from iem.signals.offline import MAX_GAP_S, covered, lag, prepare
from iem.signals.recording import Recording

W = 2 * np.pi * np.array([0.3, 0.5, 0.7, 0.4, 0.6, 0.8, 0.35])


def sines(t) -> Recording:
    """``q = sin(w t)`` per joint, ``dq`` its derivative, ``tau = q``."""
    t = np.asarray(t, dtype=float)
    q = np.sin(np.outer(t, W))
    return Recording(t, q, W * np.cos(np.outer(t, W)), q.copy())


def test_a_hole_splits_the_recording_into_pieces_prepared_apart():
    """Prepared whole, a recording with a 0.5 s hole gives what its two pieces give prepared
    one by one; no equation lies in the hole, and the derivatives stay true at its edges."""
    t = np.arange(8000) * 1e-3
    hole = (t >= 3.0) & (t < 3.5)
    whole = prepare(sines(t[~hole]), 10.0, 100.0, 0.1)
    first = prepare(sines(t[t < 3.0]), 10.0, 100.0, 0.1)
    second = prepare(sines(t[t >= 3.5]), 10.0, 100.0, 0.1)
    assert whole.pieces == 2 and whole.dropped == 0
    for name in ("t", "q", "dq", "ddq", "tau", "dtau"):
        np.testing.assert_allclose(getattr(whole, name),
                                   np.concatenate((getattr(first, name), getattr(second, name))),
                                   rtol=0, atol=1e-9, err_msg=name)
    assert not np.any((whole.t > 3.0 - 0.1) & (whole.t < 3.5 + 0.1))
    truth = -W**2 * np.sin(np.outer(whole.t, W))
    assert np.abs(whole.ddq - truth).max() < 0.01 * np.abs(truth).max()
    assert whole.duration == pytest.approx(first.duration + second.duration)
    assert not covered(whole, np.array([3.2])).any() and covered(whole, np.array([2.5])).all()


def test_a_gap_of_up_to_max_gap_s_is_interpolated_over():
    t = np.arange(6000) * 1e-3
    short_hole = (t >= 3.0) & (t < 3.0 + MAX_GAP_S - 0.002)
    sig = prepare(sines(t[~short_hole]), 10.0, 100.0, 0.1)
    assert sig.pieces == 1 and np.any((sig.t > 3.0) & (sig.t < 3.0 + MAX_GAP_S - 0.002))
    np.testing.assert_allclose(sig.q, np.sin(np.outer(sig.t, W)), atol=0.01)


def test_pieces_too_short_are_dropped_and_none_long_enough_is_refused():
    t = np.arange(6000) * 1e-3
    keep = (t < 0.3) | (t >= 0.5)  # a 0.3 s piece, then 5.5 s
    sig = prepare(sines(t[keep]), 10.0, 100.0, 0.1)
    assert sig.pieces == 1 and sig.dropped == 1 and sig.t[0] >= 0.5
    with pytest.raises(InvalidInputError, match=r"too short to filter at 10 Hz.*0\.299 s; "
                                                r"valid is at least 0\.60 s"):
        prepare(sines(t[:300]), 10.0, 100.0, 0.1)


def test_a_cutoff_the_recorded_rate_cannot_carry_is_refused_not_moved():
    t = np.arange(400) * 0.05  # 20 Hz
    with pytest.raises(InvalidInputError, match=r"recorded at 20\.0 Hz; valid is a cut-off "
                                                r"below 0\.45 of that \(9\.0 Hz, got 10 Hz\)"):
        prepare(sines(t), 10.0, 10.0, 0.1, what="recording")
    with pytest.raises(InvalidInputError, match=r"equation rate at most that \(got 100 Hz\)"):
        prepare(sines(t), 5.0, 100.0, 0.1)


def test_a_jittering_clock_is_resampled_a_steady_one_is_not():
    rng = np.random.default_rng(0)
    steps = rng.uniform(0.7e-3, 1.6e-3, 6000)
    t = np.concatenate(([0.0], np.cumsum(steps)))
    sig = prepare(sines(t), 10.0, 100.0, 0.1)
    truth = -W**2 * np.sin(np.outer(sig.t, W))
    assert np.abs(sig.ddq - truth).max() < 0.01 * np.abs(truth).max()
    steady = np.arange(6000) * 1e-3 + 1e-6 * rng.uniform(-1, 1, 6000)  # 0.2 % jitter
    kept = prepare(sines(steady), 10.0, 100.0, 0.1)
    assert np.all(np.isin(kept.fine_t, steady))  # its own samples, none interpolated


def test_lag_finds_the_shift_when_one_recording_has_a_hole():
    """One motion (random sines, no period within the recording) on two clocks 2 s apart,
    the second with a 0.5 s hole."""
    rng = np.random.default_rng(1)
    f, a = rng.uniform(0.2, 2.0, (12, 7)), rng.uniform(0.05, 0.2, (12, 7))
    t = np.arange(8000) * 1e-3
    q = np.einsum("kj,tkj->tj", a, np.sin(2 * np.pi * f[None] * t[:, None, None]))
    dq = np.einsum("kj,tkj->tj", a * 2 * np.pi * f,
                   np.cos(2 * np.pi * f[None] * t[:, None, None]))
    loaded = prepare(Recording(t, q, dq, q), 10.0, 100.0, 0.1)
    keep = (t < 4.0) | (t >= 4.5)
    bare = prepare(Recording(t[keep] - 2.0, q[keep], dq[keep], q[keep]), 10.0, 100.0, 0.1)
    assert bare.pieces == 2
    assert lag(loaded, bare) == pytest.approx(2.0, abs=1e-4)
