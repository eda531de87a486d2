"""The last ``span`` seconds of a per-point vector, in one preallocated ring.

The safety gate watches the smoothed estimate over its stability window, one row a block
point. Stacking a window of small arrays into a new array at every decision (20 Hz) costs
hundreds of µs of one point in twenty, enough to set the latency's p99. :class:`TimeWindow`
writes each point's values into a row of a ring that doubles when full (never at steady
rate, after the first window), and hands the window out as at most two slices of it,
without copying.
"""

from __future__ import annotations

import numpy as np

__all__ = ["TimeWindow"]


class TimeWindow:
    """Rows ``(t, values)`` of the last ``span`` seconds (``t`` non-decreasing).

    Args:
        span: the window's length, s: a row older than ``t_last - span`` is dropped.
        width: values per row.
        capacity: rows allocated at first (doubled whenever the window outgrows them).
    """

    def __init__(self, span: float, width: int, capacity: int = 2048) -> None:
        self.span = float(span)
        self._t = np.empty(int(capacity))
        self._v = np.empty((int(capacity), int(width)))
        self._head = 0  # the oldest row
        self.n = 0
        """Rows in the window."""

    def clear(self) -> None:
        self._head = self.n = 0

    def push(self, t: float, values) -> None:
        """Add a row (``values`` is copied) and drop those older than ``t - span``."""
        cap = self._t.shape[0]
        if self.n == cap:
            self._grow()
            cap = self._t.shape[0]
        i = self._head + self.n
        if i >= cap:
            i -= cap
        self._t[i] = t
        self._v[i] = values
        self.n += 1
        self.expire(t)

    def expire(self, t: float) -> None:
        """Drop the rows older than ``t - span``."""
        limit = t - self.span
        cap = self._t.shape[0]
        t_rows, head, n = self._t, self._head, self.n
        while n and t_rows[head] < limit:
            head += 1
            if head == cap:
                head = 0
            n -= 1
        self._head, self.n = head, n

    def _grow(self) -> None:
        t, v = self.times(), self.values()
        cap = 2 * self._t.shape[0]
        self._t = np.empty(cap)
        self._v = np.empty((cap, self._v.shape[1]))
        self._t[:self.n] = t
        self._v[:self.n] = v
        self._head = 0

    def _parts(self, a: np.ndarray) -> list[np.ndarray]:
        end = self._head + self.n
        cap = a.shape[0]
        if end <= cap:
            return [a[self._head:end]]
        return [a[self._head:], a[:end - cap]]

    @property
    def first_t(self) -> float:
        return float(self._t[self._head])

    @property
    def last_t(self) -> float:
        i = self._head + self.n - 1
        return float(self._t[i - self._t.shape[0] if i >= self._t.shape[0] else i])

    def times(self) -> np.ndarray:
        """The rows' times, oldest first (a copy)."""
        return np.concatenate(self._parts(self._t))

    def values(self) -> np.ndarray:
        """The rows' values, oldest first (a copy)."""
        return np.concatenate(self._parts(self._v))

    def ptp(self, transform=None) -> np.ndarray:
        """Peak-to-peak per column over the window, of ``transform(rows)`` if given (e.g.
        the CoM from ``m`` and ``m c``), without stacking the ring's two parts."""
        lo = hi = None
        for part in self._parts(self._v):
            if transform is not None:
                part = transform(part)
            p_lo, p_hi = part.min(axis=0), part.max(axis=0)
            lo = p_lo if lo is None else np.minimum(lo, p_lo)
            hi = p_hi if hi is None else np.maximum(hi, p_hi)
        return hi - lo

    def column_max(self, j: int) -> float:
        """The largest value of column ``j`` over the window (-inf when empty)."""
        return max((float(part[:, j].max()) for part in self._parts(self._v) if len(part)),
                   default=-float("inf"))
