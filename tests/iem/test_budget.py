"""The bag budget's policy (:mod:`iem.ensemble.budget`): probation for the newest bags, promotion
when the motion comes back, the least-used permanent bag after a promotion, and its
persistence."""

from __future__ import annotations

import numpy as np
import pytest

from iem.ensemble import IncrementalEnsemble
from iem.ensemble.budget import BagBudget, default_probation
from iem.errors import InvalidInputError
from iem.persistence import dumps, loads

from .test_checks import DATA
from .test_ensemble_longrun import fitted, learn

SMALL = {"delta": 0.03, "rho": 0.02}  # a bag every few points of the synthetic path


def test_the_policy_step_by_step():
    budget = BagBudget(5, probation=2)
    for n, bag in enumerate(range(5), start=1):  # bags 0-2 permanent, 3-4 on probation
        budget.admit(bag, n)
    assert budget.on_probation == [3, 4] and not budget.full(4) and budget.full(5)
    counts = np.array([5, 1, 7, 9, 2])
    assert budget.victim(counts, open_bag=-1) == 3  # the oldest on probation
    budget.admit(3, 5)
    assert budget.on_probation == [4, 3]
    assert budget.victim(counts, open_bag=4) == 3  # never the open bag
    budget.admit(3, 5)
    budget.revisited(4)  # the motion came back to bag 4: promoted
    budget.revisited(0)  # a permanent bag: nothing to do
    assert budget.on_probation == [3] and budget.promoted == 1
    # four permanent bags against a share of three: the least-used permanent bag goes
    assert budget.victim(counts, open_bag=-1) == 1
    budget.admit(1, 5)
    assert budget.on_probation == [3, 1]
    assert budget.victim(counts, open_bag=-1) == 3
    assert budget.retired == 4


def test_without_probation_the_least_used_goes():
    budget = BagBudget(3, probation=0)
    for n, bag in enumerate(range(3), start=1):
        budget.admit(bag, n)
    assert budget.on_probation == []
    assert budget.victim(np.array([4, 2, 3]), open_bag=-1) == 1
    assert budget.victim(np.array([4, 2, 3]), open_bag=1) == 2


def test_bad_budgets_are_refused():
    assert default_probation(2000) == 200 and default_probation(5) == 1
    assert default_probation(2) == 0 and IncrementalEnsemble(budget_bags=2).budget.probation == 0
    with pytest.raises(InvalidInputError, match="budget_bags"):
        BagBudget(1)
    with pytest.raises(InvalidInputError, match="probation_bags must be between 0 and"):
        BagBudget(10, probation=9)
    with pytest.raises(InvalidInputError, match="probation_bags"):
        IncrementalEnsemble(budget_bags=10, probation_bags=-1)
    with pytest.raises(InvalidInputError, match="needs a budget_bags"):
        IncrementalEnsemble(probation_bags=3)


def run(revisit: bool):
    """The synthetic path: its first bags fill the permanent share, a stretch A forms bags on
    probation, (driven back over, if ``revisit``), then the rest of the path forms more new
    bags than the probation pool holds."""
    model = fitted(budget_bags=34, probation_bags=6, **SMALL)
    learn(model, DATA.train_points())
    first = model.n_bags
    stretch = DATA.further_points()[:30]
    learn(model, stretch)
    a = list(range(first, model.n_bags))
    assert model.budget.on_probation == a
    if revisit:
        learn(model, stretch[::-1])
    learn(model, DATA.further_points()[30:])
    return model, first, a


def test_a_stretch_passed_once_makes_way_and_what_was_known_stays():
    model, first, a = run(revisit=False)
    assert model.n_bags == 34 and model.retired > len(a) and model.budget.promoted == 0
    assert all(model.slot_generation(b) == 0 for b in range(first))  # the first bags stay
    assert all(model.slot_generation(b) > 0 for b in a)  # the stretch's went, oldest first


def test_a_stretch_the_motion_comes_back_to_is_kept():
    once, _, _ = run(revisit=False)
    model, first, a = run(revisit=True)
    promoted = [b for b in a if model.slot_generation(b) == 0]
    # every bag of the stretch but the one still open when the motion turned back
    assert len(promoted) == len(a) - 1 == model.budget.promoted
    # the permanent bags are back to their share: as many of the least-used first bags went
    went = [b for b in range(first) if model.slot_generation(b) > 0]
    assert len(went) == len(promoted)
    stretch = DATA.further_points()[:30]
    x, f = DATA.X[stretch], DATA.F[stretch]
    kept = np.isin(model.router.route_many(x[:, :7], f), promoted)
    assert kept.mean() > 0.5  # the stretch routes to its own bags again
    assert not np.isin(once.router.route_many(x[:, :7], f), a).any()


def test_the_probation_pool_persists_in_order():
    model, _, _ = run(revisit=True)
    loaded = loads(dumps(model))
    assert loaded.budget.on_probation == model.budget.on_probation
    assert (loaded.retired, loaded.budget.promoted) == (model.retired, model.budget.promoted)
    assert loaded.params()["probation_bags"] == 6 == loaded.clone().budget.probation
    state = model.to_state()
    for key in ("on_probation", "promoted"):
        state.pop(key)  # a file from before probation: every bag permanent
    old = IncrementalEnsemble.from_state(state)
    assert old.budget.on_probation == [] and old.retired == model.retired
    state["on_probation"] = [0, 0]
    with pytest.raises(InvalidInputError, match="on probation"):
        IncrementalEnsemble.from_state(state)
