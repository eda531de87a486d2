"""The old IEM (Taie et al. 2024), the paper's predecessor and a baseline here.

It has the same bags and learners as the proposed IEM after the excitation path, but no way
to add a learner: a point outside every bag updates the nearest bag's learner *in place*
with the point's tandem samples (the same SGD, ``iters`` steps per point) and that learner
makes the estimate. The bags themselves stay as trained.

An incremental learner's input standardisation is incremental too (as an online scaler in
front of an online regressor): the learner's input ``center`` follows the inputs it is
trained on, an exponential running mean with weight ``center_rate`` per point. Without
that, a learner met far outside its range extrapolates until its ReLU outputs die (zero
gradient) and it can never adapt. With it, the learner adapts to the new task and, being
the same learner, loses what it knew of the old one: the catastrophic forgetting the paper
reports.
"""

from __future__ import annotations

import numpy as np

from .base import Samples, resolve
from .ensemble import IncrementalEnsemble


class InPlaceEnsemble(IncrementalEnsemble):
    """The 2024 incremental ensemble: learners updated in place, never added.

    Same hyper-parameters as :class:`iem.ensemble.IncrementalEnsemble` (``warmup_iters``
    is used only for the very first bag of an untrained model), plus ``center_rate``: the
    weight of each new point's inputs in the learner's running input mean. It holds
    nothing out of distribution (``ood_hold_s`` 0 by default): the paper's baseline answers
    with the learner it updates.
    """

    name = "old_IEM"

    def __init__(self, *args, center_rate: float = 0.05, **kwargs) -> None:
        kwargs.setdefault("ood_hold_s", 0.0)
        super().__init__(*args, **kwargs)
        self.center_rate = float(center_rate)

    def params(self) -> dict:
        return {**super().params(), "center_rate": self.center_rate}

    def _learn_one(self, x, flange, samples: Samples) -> None:
        if not self._learners:  # nothing to update yet: start the first bag
            super()._learn_one(x, flange, samples)
            self._open, self._kept = -1, None  # no bag forms here: nothing to consolidate
            return None
        bag, nearest = self._router.route(np.asarray(x, dtype=float)[:7], flange)
        if bag >= 0:
            return None  # inside the trained range: estimate only
        X, Y = resolve(samples)
        learner = self._learners[nearest]
        learner.center += self.center_rate * (X.mean(axis=0) - learner.center)
        learner.learn(X, Y, self.iters)
        return None
