"""The change detector's level: a sustained misfit raises no alarm, a jump still fires."""

from __future__ import annotations

import numpy as np
import pytest

from iem.change import LEVEL_EQUATIONS, ChangeDetector
from iem.errors import InvalidInputError


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
