"""What a model file holds of an :class:`~iem.ensemble.IncrementalEnsemble`, and the model
rebuilt from it.

The state (plain data, :mod:`iem.persistence` packs it): ``params`` (the hyper-parameters as
given, the ``learner`` among them), ``router`` (the bags' means and counts), ``learners`` (one
per bag), ``open`` (the bag being formed, -1: none), ``kept`` (what it keeps for its refit:
its reservoir of samples, or its statistics with the ``expected`` learner, or None),
``out`` (the output scaling ``[lo, hi]`` new bags' learners start from, or None before the
first), ``gen`` (each slot's generation) and the budget's bookkeeping
(:meth:`iem.ensemble.budget.BagBudget.to_state`; ``retired`` 0 without a budget). Older
layouts are brought to this one by :mod:`iem.migrations` before :func:`restore_ensemble`
reads it.
"""

from __future__ import annotations

from ..errors import InvalidInputError
from .expected import BagStatistics
from .learner import N_OUT, saved_numbers
from .reservoir import Reservoir
from .router import BagRouter

__all__ = ["ensemble_state", "restore_ensemble"]


def ensemble_state(model) -> dict:
    """The state of ``model`` (its pending training already landed)."""
    return {"params": model.params(), "router": model._router.to_state(),
            "learners": [lr.to_state() for lr in model._learners], "open": model._open,
            "kept": None if model._kept is None else model._kept.to_state(),
            "out": None if model._out is None else [v.tolist() for v in model._out],
            "gen": list(model._gen),
            **(model._budget.to_state() if model._budget is not None else {"retired": 0})}


def restore_ensemble(model, state: dict):
    """``model``, fresh from ``state["params"]``, with the rest of ``state`` loaded.

    Raises:
        InvalidInputError: the parts of the state do not fit together.
    """
    model._router = BagRouter.from_state(state["router"])
    model._learners = [model._learner_cls.from_state(s) for s in state["learners"]]
    if len(model._learners) != len(model._router):
        raise InvalidInputError(f"model state has {len(model._router)} bags but "
                                f"{len(model._learners)} learners")
    model._gen = [int(g) for g in state.get("gen", [0] * len(model._learners))]
    if len(model._gen) != len(model._learners):
        raise InvalidInputError(f"model state has {len(model._learners)} bags but "
                                f"{len(model._gen)} slot generations")
    if model._budget is not None:
        model._budget.load_state(state, len(model._learners))
    model._open = int(state["open"])
    if not -1 <= model._open < len(model._learners):
        raise InvalidInputError(f"model state's open bag {model._open} is not one of its "
                                f"{len(model._learners)} bags (or -1)")
    kept = state["kept"]
    keeper = BagStatistics if model._learner_cls.keeps_statistics else Reservoir
    model._kept = None if kept is None else keeper.from_state(kept)
    if model._open >= 0:  # the jobs train their own copy; the published one stays
        model._training = model._learners[model._open].copy()
    out = state["out"]  # the output scaling (lo, hi) new bags' learners start from
    if out is not None:
        lo, hi = out
        out = (saved_numbers(lo, (N_OUT,), "model state's out[0]"),
               saved_numbers(hi, (N_OUT,), "model state's out[1]"))
    model._out = out
    return model
