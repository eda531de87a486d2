"""The change detector's level: a sustained misfit raises no alarm, a jump still fires."""

from __future__ import annotations

import numpy as np
import pytest

from iem.errors import InvalidInputError
from iem.physics.change import LEVEL_EQUATIONS, ChangeDetector


def feed(det, values) -> list[int]:
    return [i for i, v in enumerate(values) if det(float(v))]


def test_a_sustained_misfit_is_no_change_but_the_raw_cusum_fires_on_it():
    rng = np.random.default_rng(0)
    quiet = rng.chisquare(7, 200)
    misfit = np.concatenate([quiet, np.linspace(12, 70, 15), 60 + 10 * rng.random(300), quiet])
    assert feed(ChangeDetector(), misfit) == []
    assert feed(ChangeDetector(level_equations=0), misfit) != []  # what it was before


@pytest.mark.parametrize("misfit", [7.0, 60.0])
def test_a_payload_jump_fires_within_two_equations_whatever_the_level(misfit):
    det = ChangeDetector()
    assert feed(det, np.full(200, misfit)) == []
    assert feed(det, [3000.0, 3000.0, 3000.0])[0] <= 1


def test_the_first_equations_after_a_reset_only_learn_the_level():
    det = ChangeDetector()
    assert feed(det, np.full(LEVEL_EQUATIONS, 1e4)) == []
    assert det.g == 0.0 and det.level > 7.0
    det.reset()
    assert det.level == 7.0 and det.n == 0


def test_state_round_trip_and_old_states():
    det = ChangeDetector()
    feed(det, np.linspace(5, 50, 80))
    twin = ChangeDetector()
    twin.set_state(det.to_state())
    assert feed(det, [40.0, 400.0, 4000.0]) == feed(twin, [40.0, 400.0, 4000.0])
    old = ChangeDetector()
    old.set_state({"g": 3.0, "last": 9.0})  # saved before the level existed
    assert old.g == 3.0 and old.level == 7.0 and old.n == LEVEL_EQUATIONS
    with pytest.raises(InvalidInputError, match="level_equations"):
        ChangeDetector(level_equations=-1)


# Recorded chi² (iem bench longrun seed 0 at 445.7 s, the window 44,540 equations long, and
# iem bench paper seed 0 across its payload change), each after a quiet stretch.
MOTION_ONSET = [11, 27, 50, 65, 77, 87, 90, 87, 90, 129, 200, 275, 363, 473, 557, 613, 689,
                753, 761, 731, 643, 482, 347, 290, 288, 350, 488, 674, 910, 1180, 1435, 1676,
                1870, 1949, 1964, 1942, 1815, 1606, 1360, 1081, 835, 673, 576, 527, 533]
PAYLOAD_CHANGE = [25, 181, 691, 1703, 3224, 5150, 7339, 9557, 11239, 13304, 15153]


def test_a_misfit_rising_with_the_motion_is_no_change_but_a_new_payload_is():
    rng = np.random.default_rng(3)
    quiet = list(rng.chisquare(7, 100))
    assert feed(ChangeDetector(), quiet + MOTION_ONSET + quiet) == []
    fired = feed(ChangeDetector(), quiet + PAYLOAD_CHANGE)
    assert fired and fired[0] - len(quiet) <= 3
    # the 30-equation level this replaced counted the misfit's rise as evidence
    assert feed(ChangeDetector(level_equations=30), quiet + MOTION_ONSET + quiet) != []


def test_with_a_model_error_statistic_the_evidence_is_the_smaller_cusums():
    """Two statistics per equation: each rescaled by its own level, the CUSUM adds the
    smaller, so its evidence never exceeds a CUSUM of either alone (checked step by step
    against two plain detectors), and it fires only where both would."""
    rng = np.random.default_rng(5)
    quiet = rng.chisquare(7, 100)
    # a sharp misfit the model error explains (the plain statistic alone fires on it), then
    # a misfit rising with the motion that the plain level absorbs, of which the model error
    # leaves 200 for a few equations (the model-error statistic alone, its level low, fires)
    sharp = [3, 13, 33, 62, 106, 162, 193, 400, 960, 5779, 6326]
    left = rng.chisquare(7, len(MOTION_ONSET))
    left[10:15] = 200.0
    plain = np.concatenate([quiet, sharp, quiet, MOTION_ONSET, quiet])
    model = np.minimum(plain, np.concatenate([quiet, rng.chisquare(7, len(sharp)), quiet,
                                              left, quiet]))  # never above the plain one
    both, a, b = ChangeDetector(), ChangeDetector(), ChangeDetector()
    assert feed(ChangeDetector(), plain) != [] and feed(ChangeDetector(), model) != []
    for c, cm in zip(plain, model, strict=True):
        assert not both(float(c), float(cm))
        a(float(c)), b(float(cm))
        assert both.g <= min(a.g, b.g) + 1e-9
    # a new payload raises both: it fires
    assert feed_two(ChangeDetector(), list(quiet) + PAYLOAD_CHANGE,
                    list(quiet) + [v / 2 for v in PAYLOAD_CHANGE])[0] - len(quiet) <= 3
    # None or NaN for the second: the plain detector's arithmetic
    one, two = ChangeDetector(), ChangeDetector()
    for c in plain:
        assert one(float(c)) == two(float(c), None)
        assert one.g == two.g and one.level == two.level == two.level_model
    twin = ChangeDetector()
    twin.set_state(both.to_state())
    assert twin.level_model == both.level_model


def feed_two(det, values, model) -> list[int]:
    pairs = zip(values, model, strict=True)
    return [i for i, (v, m) in enumerate(pairs) if det(float(v), float(m))]
