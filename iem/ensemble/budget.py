"""The bag budget: which slot a new bag takes once the ensemble holds ``budget_bags`` bags.

The policy keeps what the model knows and lets a new region prove itself first:

- **Permanent bags** are the first ``budget_bags - probation_bags`` bags the model formed, and
  any bag promoted since. They are never retired for a new bag that has not earned a place.
- **The probation pool** holds the bags formed after that, at most ``probation_bags`` of them,
  oldest first. At the budget a new bag takes the slot of the oldest bag on probation (never
  the open one) and joins the pool itself. So a region the motion passes once is learnt and
  estimated while the path is in it (the open bag learns at every point) and kept for the
  next ``probation_bags`` new bags; then it is forgotten.
- **Promotion.** A bag on probation that a point joins after it closed (the motion came back)
  becomes permanent. The permanent bags are then one too many, so the next new bag takes the
  slot of the least-used permanent bag (fewest points joined; the lowest index of equals).

Why: with a budget something must be forgotten once the motion has covered more than the
budget. Retiring the least-used bag outright (the policy with ``probation_bags=0``)
forgets old knowledge as fast as new: on a motion that never
repeats, every bag is used about as much, so the model ends up holding a random sample of
the regions it saw and loses most of any one stretch (62 of the first minute's 93 bags on a
ten-minute motion with a 300-bag budget; docs/decisions.md). A robot cell repeats its tasks: what it
comes back to is promoted and kept, what it passed once makes way first, and what it has
learnt is not traded for regions it never returns to. What is lost: a region passed once,
after the budget, more than ``probation_bags`` new bags ago, and the least-used permanent
bag per promotion. A later visit there routes to the nearest remaining bag (flagged out of
distribution when far) or forms a bag again, which learns from its first point.
"""

from __future__ import annotations

import numpy as np

from ..errors import InvalidInputError

DEFAULT_BUDGET_BAGS = 2000
"""The bag budget of a model the plug-in trains (``deploy.model.training.DEPLOY_ENSEMBLE``) and of
``iem bench longrun`` (``--budget``)."""

PROBATION_SHARE = 0.1
"""Default probation pool, a share of the budget (200 of 2,000 bags: at the 77 new bags a
minute of ``iem bench longrun``'s never-repeating motion, about 2.5 minutes of new ground
before a region passed once is forgotten; a task's cycle is shorter)."""


def default_probation(budget_bags: int) -> int:
    """The probation pool for a budget when none is given (none for a budget of 2)."""
    return min(budget_bags - 2, max(1, round(PROBATION_SHARE * budget_bags)))


class BagBudget:
    """The budget's bookkeeping: which slots are on probation, which slot a new bag takes.

    Args:
        bags: the budget, bags (>= 2).
        probation: the probation pool, bags (0 to ``bags - 2``; None: 10 % of ``bags``).
    """

    def __init__(self, bags: int, probation: int | None = None) -> None:
        self.bags = int(bags)
        if self.bags < 2:
            raise InvalidInputError(f"budget_bags must be None or >= 2, got {bags}")
        self.probation = default_probation(self.bags) if probation is None else int(probation)
        if not 0 <= self.probation <= self.bags - 2:
            raise InvalidInputError(f"probation_bags must be between 0 and budget_bags - 2 = "
                                    f"{self.bags - 2}, got {probation}")
        self._pool: dict[int, None] = {}  # slots on probation, oldest first
        self.retired = 0
        """Bags retired to stay within the budget."""
        self.promoted = 0
        """Bags promoted from probation (a point joined them after they closed)."""

    @property
    def on_probation(self) -> list[int]:
        """The slots on probation, oldest first."""
        return list(self._pool)

    def full(self, n_bags: int) -> bool:
        """A new bag must take another's slot."""
        return n_bags >= self.bags

    def victim(self, counts: np.ndarray, open_bag: int) -> int:
        """The slot a new bag takes (``counts``: points joined per bag; ``open_bag``: never
        it) and forget it: the oldest bag on probation, or the least-used permanent bag
        when the permanent bags are more than their share (after a promotion)."""
        n = len(counts)
        waiting = [b for b in self._pool if b != open_bag]
        if waiting and n - len(self._pool) <= self.bags - self.probation:
            bag = waiting[0]
        else:
            c = np.array(counts, dtype=float)  # a copy: the permanent bags' counts
            c[list(self._pool)] = np.inf
            if open_bag >= 0:
                c[open_bag] = np.inf
            bag = int(np.argmin(c))
            if not np.isfinite(c[bag]):  # only the open bag is permanent
                bag = waiting[0]
        self._pool.pop(bag, None)
        self.retired += 1
        return bag

    def admit(self, bag: int, n_bags: int) -> None:
        """A new bag in slot ``bag`` (``n_bags`` bags now, itself included): on probation
        once the permanent share is taken."""
        if n_bags - len(self._pool) > self.bags - self.probation:
            self._pool[bag] = None

    def revisited(self, bag: int) -> None:
        """A point joined closed bag ``bag``: promoted if it was on probation."""
        if self._pool.pop(bag, False) is None:
            self.promoted += 1

    def to_state(self) -> dict:
        return {"on_probation": list(self._pool),
                "retired": self.retired, "promoted": self.promoted}

    def load_state(self, state: dict, n_bags: int) -> None:
        """What :meth:`to_state` gave; a file from before probation has none (every bag is
        then permanent)."""
        pool = [int(b) for b in state.get("on_probation", [])]
        if any(not 0 <= b < n_bags for b in pool) or len(set(pool)) != len(pool):
            raise InvalidInputError(f"model state's bags on probation {pool} are not distinct "
                                    f"bags of its {n_bags}")
        self._pool = dict.fromkeys(pool)
        self.retired = int(state.get("retired", 0))
        self.promoted = int(state.get("promoted", 0))
