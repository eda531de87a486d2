"""What a model file holds of an IEM+phys (:class:`~iem.physics.PhysicsInformedEnsemble`),
and the model rebuilt from it.

The state (plain data, :mod:`iem.persistence` packs it): ``params`` (the hyper-parameters as
given); ``ensemble`` (the held IEM's state, :mod:`iem.ensemble.state`); the bags'
calibration (:class:`~iem.physics.prior_summary.BagCalibration`) with ``calib_gen``, the
slot generation each was measured for; ``regression`` (its filter and block); the window of
equations (:class:`~iem.physics.posterior.EquationWindow`) and the prior summary since the
last change; ``detector`` (the change detector's CUSUM); ``changed``, ``holdoff`` and
``changes``; ``post`` (the cached posterior, or None) and ``data_shown``; when the cached
posterior is refreshed next (``stale``, ``since_refresh``: :mod:`iem.physics.scheduler`)
and what it does not determine (``undetermined``); ``initial`` (a known payload started
from, ``[phi, cov]``, or None); ``candidate`` (the posterior before the last alarm while
the data have not chosen between them, :class:`~iem.physics.candidate.Candidate`, or
None). Older layouts are brought to this one by :mod:`iem.migrations` before
:func:`restore_physics` reads it.
"""

from __future__ import annotations

import copy

import numpy as np

from ..ensemble.model import IncrementalEnsemble
from ..errors import InvalidInputError
from .candidate import Candidate
from .ensemble_prior import EnsemblePrior
from .posterior import Posterior

__all__ = ["physics_state", "restore_physics"]


def physics_state(model) -> dict:
    """The state of ``model`` (its ensemble's pending training lands first)."""
    prior, schedule = model.ensemble_prior, model._schedule
    return {"params": model.params(), "ensemble": model._ens.to_state(),
            **prior.calib.to_state(), "calib_gen": list(prior.calib_gen),
            "regression": model._reg.to_state(),
            **model._window.to_state(), **prior.summary.to_state(),
            "detector": model._innovation.detector.to_state(), "changed": model._changed,
            "post": None if model._post is None else model._post.to_state(),
            "data_shown": model._data_shown,
            "holdoff": model._holdoff, "changes": model.changes,
            # when the cached posterior is refreshed next, and what it does not determine
            "stale": schedule.stale, "since_refresh": schedule.since_refresh,
            "undetermined": list(model._undetermined),
            "initial": _payload_state(model._initial),
            # the posterior before the last alarm, while the data have not yet chosen
            "candidate": _candidate_state(model._candidate)}


def _payload_state(payload) -> list | None:
    """A known payload ``(phi, cov)`` as ``[phi, cov]`` lists (None: None)."""
    return None if payload is None else [payload[0].tolist(), payload[1].tolist()]


def _payload(value) -> tuple[np.ndarray, np.ndarray] | None:
    """:func:`_payload_state`'s value as ``(phi (10,), cov (10, 10))`` (None: None)."""
    if value is None:
        return None
    return (np.array(value[0], dtype=float).reshape(10),
            np.array(value[1], dtype=float).reshape(10, 10))


def _candidate_state(cand: Candidate | None) -> dict | None:
    """The candidate's window, its posterior at the alarm, the prior summary and known
    payload before it, and what the data have said since (None: none)."""
    if cand is None:
        return None
    return {"window": cand.window.to_state(), "post": cand.post.to_state(),
            "summary": cand.summary.to_state(), "initial": _payload_state(cand.initial),
            "decide_n": cand.decide_n, "evidence": cand.evidence, "compared": cand.compared,
            "samples": cand.samples}


def _candidate(model, state: dict) -> Candidate:
    """:func:`_candidate_state`'s candidate for ``model``, in a window and a summary of its
    own kinds."""
    window = model._window.fresh()
    window.set_state(state["window"])
    summary = copy.deepcopy(model.ensemble_prior.summary)
    summary.set_state(state["summary"])
    cand = Candidate(window, Posterior.from_state(state["post"], model.eps), summary,
                     _payload(state["initial"]), int(state["decide_n"]), model._weight)
    cand.evidence = float(state["evidence"])
    cand.compared = int(state["compared"])
    cand.samples = int(state["samples"])
    return cand


def restore_physics(model, state: dict):
    """``model``, fresh from ``state["params"]``, with the rest of ``state`` loaded.

    Raises:
        InvalidInputError: the parts of the state do not fit together.
    """
    model._ens = IncrementalEnsemble.from_state(state["ensemble"])
    model._ens.report_errors = True
    prior = model.ensemble_prior = EnsemblePrior(model._ens)
    prior.calib.set_state(state)
    prior.calib_gen = [int(g) for g in state.get("calib_gen", [])]
    if len(prior.calib) > model.n_bags:
        raise InvalidInputError(f"model state has {len(prior.calib)} bag covariances "
                                f"for {model.n_bags} bags")
    model._reg.set_state(state["regression"])
    model._window.set_state(state)
    prior.summary.set_state(state)
    model._innovation.detector.set_state(state["detector"])
    model._changed = bool(state["changed"])
    if state["post"] is not None:
        model._post = Posterior.from_state(state["post"], model.eps, model._window.m)
    model._data_shown = bool(state.get("data_shown", model._window.m > 0))
    model._holdoff = int(state["holdoff"])
    model.changes = int(state["changes"])
    model._schedule.stale = bool(state["stale"])
    model._schedule.since_refresh = int(state["since_refresh"])
    model._undetermined = tuple(str(g) for g in state["undetermined"])
    initial = _payload(state.get("initial"))  # files from before start_from have none
    if initial is not None:
        model._initial = initial
    candidate = state.get("candidate")  # files from before it kept none
    if candidate is not None:
        model._candidate = _candidate(model, candidate)
    return model
