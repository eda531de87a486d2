"""The weak learners by name: how the ensemble's learners are trained (its ``learner``).

- ``sgd``: the paper's Algorithm 2, stochastic gradient descent with Gaussian input noise
  (:class:`~iem.ensemble.learner.WeakLearner`); the open bag keeps a reservoir of its points
  and its learner is refitted on it by SGD when it closes.
- ``expected``: the same steps and refit in expectation over that noise, computed exactly
  (:class:`~iem.ensemble.expected.ExpectedLearner`): a point's steps and a bag's refit are
  22 x 22 products and one 22 x 22 solve; the open bag keeps its sufficient statistics.

Both give learners of the same form and file; the ensemble's ``learner`` (a hyper-parameter,
in its model file) says which trains them.
"""

from __future__ import annotations

from ..errors import InvalidInputError
from .expected import ExpectedLearner
from .learner import WeakLearner

__all__ = ["DEFAULT_LEARNER", "FAST_LEARNER", "LEARNERS", "learner_class"]

LEARNERS: dict[str, type[WeakLearner]] = {"sgd": WeakLearner, "expected": ExpectedLearner}
"""Learner name -> class."""

DEFAULT_LEARNER = "sgd"
"""The paper's, :class:`~iem.ensemble.IncrementalEnsemble`'s default."""

FAST_LEARNER = "expected"
"""The one that costs microseconds."""


def learner_class(name: str) -> type[WeakLearner]:
    """The class of learner ``name`` (a key of :data:`LEARNERS`).

    Raises:
        InvalidInputError: it is not one of them.
    """
    if not isinstance(name, str) or name not in LEARNERS:
        raise InvalidInputError(f"learner {name!r} is not valid; valid learners are "
                                f"{', '.join(LEARNERS)}")
    return LEARNERS[name]
