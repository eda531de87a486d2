"""The old IEM (Taie et al. 2024), the paper's predecessor and a baseline here.

It has the same bags and learners as the proposed IEM after the excitation path, but no way
to add a learner: a point outside every bag updates the nearest bag's learner *in place*
with the point's tandem samples (the same SGD, ``iters`` steps per point) and that learner
makes the estimate. The bags themselves stay as trained.

What the paper says of it: its learners are "incremental neural networks" (section 2); it
"succeeded in adapting the model with the new path data" (5.2), then forgot: "merely
adjusting the weights of the original weak learners" (section 6) raised its excitation-path
MAE to 0.037 kg, 0.025 kg·m and 0.0022 kg·m² (5.3). It describes no input standardisation,
so ``update`` (default ``"frozen"``) keeps each learner's as it was trained (``center`` and
``scale`` never change) and adjusts the weights ``a, b`` only, by Algorithm 2's SGD (the
learner's own step, ``lr`` and input noise), with one departure: an output whose ReLU is
off on *every* sample of the point (``a x + b <= 0`` for all 77) has a zero gradient, so
Algorithm 2 could never move it; there the step takes the gradient of ``a x + b`` itself,
pushing it back up to its target. On the paper benchmark's new task path the standardised
inputs have norms of 22-38 (a median of 4.3 on the excitation path) and the learners as trained
have a median of 7-8 of their 10 outputs so dead at a point (the mass's at 64-92 % of the
points): with Algorithm 2's gradient alone (``update="strict"``) the old IEM stays at a mass
MAE of 0.8-1.1 kg there, against the paper's "succeeded in adapting". Where an output is
alive on some sample, the step is Algorithm 2's.

``update="running_centre"``: the learner's input ``center`` also follows the inputs it is
trained on, an exponential running mean with weight ``center_rate`` per point (an online
scaler in front of an online regressor), then the learner's own SGD. It adapts too, but
moves the standardisation to the new path, so the old path's inputs are mis-scaled
afterwards: on the paper benchmark its excitation-path MAE after the new path is 4-45 times
the paper's old IEM's (after/before 19-122). It is kept to show that.
"""

from __future__ import annotations

import numpy as np

from ..base import Samples, resolve
from ..ensemble.learner import N_IN, WeakLearner
from ..ensemble.model import IncrementalEnsemble
from ..errors import InvalidInputError

FROZEN, STRICT, RUNNING_CENTRE = "frozen", "strict", "running_centre"
UPDATES = (FROZEN, STRICT, RUNNING_CENTRE)
"""The in-place updates: standardisation frozen (dead outputs revived), standardisation
frozen with Algorithm 2's gradient alone, and the running input centre."""


def frozen_update(learner: WeakLearner, X, Y, iters: int) -> None:
    """``iters`` of the learner's normalised SGD steps on ``(X, Y)``, in place on ``a, b``
    only (its ``center`` and ``scale`` stay): :meth:`WeakLearner.learn`'s steps, input noise
    and step size, except that an output whose ReLU is off on every sample gets the gradient
    of its pre-activation (Algorithm 2's is zero there). NumPy only."""
    x0 = (np.asarray(X, dtype=float) - learner.center) * learner._inv_scale
    t = (np.asarray(Y, dtype=float) - learner.lo) / learner._span
    n = x0.shape[0]
    if x0.shape != (n, N_IN) or t.shape != (n, learner.lo.size):
        raise InvalidInputError(f"the update needs X (N, {N_IN}) and Y (N, "
                                f"{learner.lo.size}), got {x0.shape} and {t.shape}")
    iters = int(iters)
    norm2 = float(np.einsum("ij,ij->", x0, x0)) / n
    x = x0
    noise_scaled = learner._noise_scaled
    if noise_scaled is not None and iters > 0:  # the same draw as WeakLearner.learn's
        noise = learner._rng.standard_normal((n, N_IN))
        noise *= noise_scaled
        x = x0 + noise
        norm2 += float(noise_scaled @ noise_scaled)
    step = 2.0 * learner.lr / ((norm2 + 1.0) * n)
    a, b = learner.a, learner.b
    for _ in range(iters):
        z = x @ a.T
        z += b
        active = z > 0.0
        dead = ~active.any(axis=0)  # outputs off on every sample: no gradient through ReLU
        z -= t  # where active, ReLU(z) - t; where dead, the pre-activation's residual
        z *= active | dead
        a -= step * (z.T @ x)
        b -= step * z.sum(axis=0)


class InPlaceEnsemble(IncrementalEnsemble):
    """The 2024 incremental ensemble: learners updated in place, never added.

    Same hyper-parameters as :class:`iem.ensemble.IncrementalEnsemble` (``warmup_iters``
    is used only for the very first bag of an untrained model), plus ``update``, one of
    :data:`UPDATES` (see the module docstring), and ``center_rate``: with
    ``update="running_centre"``, the weight of each new point's inputs in the learner's
    running input mean (unused otherwise). It holds nothing out of distribution
    (``ood_hold_s`` 0 by default): the paper's baseline answers with the learner it updates.
    """

    name = "old_IEM"

    def __init__(self, *args, update: str = FROZEN, center_rate: float = 0.05,
                 **kwargs) -> None:
        if update not in UPDATES:
            raise InvalidInputError(f"update={update!r}: choose one of {', '.join(UPDATES)}")
        kwargs.setdefault("ood_hold_s", 0.0)
        super().__init__(*args, **kwargs)
        self.update = update
        self.center_rate = float(center_rate)

    def params(self) -> dict:
        return {**super().params(), "update": self.update, "center_rate": self.center_rate}

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
        if self.update == FROZEN:
            frozen_update(learner, X, Y, self.iters)
            return None
        if self.update == RUNNING_CENTRE:
            learner.center += self.center_rate * (X.mean(axis=0) - learner.center)
        learner.learn(X, Y, self.iters)
        return None
