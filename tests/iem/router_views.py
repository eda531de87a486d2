"""What the tests read of a :class:`iem.ensemble.router.BagRouter` beyond what the product
reads: the joint-space means of its bags, from its saved state."""

from __future__ import annotations

import numpy as np


def q_means(router) -> np.ndarray:
    """Joint-space mean of every bag of ``router``, ``(n, 7)`` rad."""
    return np.asarray(router.to_state()["means"], dtype=float).reshape(-1, 10)[:, :7]
