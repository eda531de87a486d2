"""The simulated controller's reference: a path played forward, backward, forward again (both
ends are at rest, so the turns are smooth), or once and then held at rest at its end."""

from __future__ import annotations

import numpy as np


class PathPlayer:
    """Reference ``(q, dq, ddq)`` at controller cycle ``k``: the path forward, backward, ...

    With ``once`` the path is played once and then its last sample held at rest.
    """

    def __init__(self, path, once: bool = False) -> None:
        self.path = path
        self.once = once
        self.n = len(path)
        self._zeros = np.zeros(path.q.shape[1])

    def at(self, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        p, n = self.path, self.n
        if n == 1:
            return p.q[0], self._zeros, self._zeros
        if self.once:
            if k >= n - 1:
                return p.q[-1], self._zeros, self._zeros
            return p.q[k], p.dq[k], p.ddq[k]
        period = 2 * (n - 1)
        i = k % period
        if i < n - 1:
            return p.q[i], p.dq[i], p.ddq[i]
        j = period - i  # backward: q(T - t), dq -> -dq, ddq unchanged
        return p.q[j], -p.dq[j], p.ddq[j]

    def holding(self, k: int) -> bool:
        return self.once and k >= self.n - 1
