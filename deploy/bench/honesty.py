"""The paper benchmark's checks that can fail.

- **Forgetting, by the weights.** An after/before MAE ratio of 1.00 can hide a learner that
  changed and happens to score alike. :func:`fingerprints` hashes every bag's learner (its
  weights, biases and input scaling); the benchmark takes them after the excitation path and
  compares them after the new task path and after a revisit: ``weights_identical`` is true
  only if not one bit of an excitation bag's learner changed. The old in-place IEM changes
  them, so the check can fail.
- **A path that revisits the excitation bags.** The new task path never enters an excitation
  bag, so "nothing is forgotten" there says nothing about learning inside old bags.
  :func:`revisit_path` plays the excitation path's first seconds backwards (the same poses,
  every velocity reversed), learning on; the excitation path is then scored again.
- **Hold-out payloads drawn at random.** The default test payloads were chosen near the
  family's centre. :func:`holdout_payloads` draws configurations at random (seeded) from
  those outside the 77 training payloads, any number of weights; the benchmark runs IEM and
  IEM+phys afresh on the new task path with each.
"""

from __future__ import annotations

import hashlib

import numpy as np

REVISIT_S = 6.0
"""Seconds of the excitation path played backwards by the revisit scenario."""
HOLDOUT_COUNT = 4
"""Hold-out payloads of a full run (2 in a quick run)."""


def _ensemble(model):
    return getattr(model, "ensemble_model", model)


def fingerprints(model) -> dict[int, str] | None:
    """SHA-256 of each bag's learner (``a``, ``b``, ``center``, ``scale``) by bag, or None
    for a model without bags of learners."""
    ens = _ensemble(model)
    if not hasattr(ens, "learner") or not getattr(ens, "n_bags", 0):
        return None
    out = {}
    for bag in range(ens.n_bags):
        learner = ens.learner(bag)
        h = hashlib.sha256()
        for name in ("a", "b", "center", "scale"):
            h.update(np.ascontiguousarray(getattr(learner, name), dtype=np.float64).tobytes())
        out[bag] = h.hexdigest()
    return out


def unchanged(before: dict[int, str] | None, model) -> bool | None:
    """True if every bag of ``before`` still has a bit-identical learner (None: no bags)."""
    if before is None:
        return None
    after = fingerprints(model) or {}
    return all(after.get(bag) == digest for bag, digest in before.items())


def revisit_path(excitation, seconds: float = REVISIT_S):
    """The first ``seconds`` of the excitation path played backwards."""
    from sim.paths import Path

    part = excitation.slice(0.0, seconds)
    return Path(f"{excitation.name} backwards", part.t, part.q[::-1], -part.dq[::-1],
                part.ddq[::-1])


def holdout_payloads(seed: int, count: int = HOLDOUT_COUNT) -> list:
    """``count`` configurations drawn at random (seed ``seed``) from the unique ones outside
    the training payloads, named ``holdout-<i>``."""
    from sim.family import candidate_payloads, training_payloads

    trained = {tuple(np.round(p.to_phi(), 12)) for p in training_payloads()}
    pool = [p for p in candidate_payloads() if tuple(np.round(p.to_phi(), 12)) not in trained]
    rng = np.random.default_rng(10_000 + seed)
    picks = rng.choice(len(pool), size=count, replace=False)
    return [pool[i].with_name(f"holdout-{k}") for k, i in enumerate(sorted(picks))]
