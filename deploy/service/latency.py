"""The service's cycle latencies, kept in bounded memory.

A cell runs the plug-in for days: a list of every cycle's latency grew by about 32 bytes a
cycle, 2.7 GB a day at 1 kHz. :class:`LatencyWindow` keeps the last ``capacity`` latencies in
one preallocated array (a ring: pages are touched only as it fills), and its percentiles are
those of the cycles it holds, exact over any run shorter than the window.
"""

from __future__ import annotations

import numpy as np

from iem.errors import InvalidInputError

CAPACITY = 1_000_000
"""Latencies kept: the last 1,000,000 cycles (about 17 minutes at 1 kHz, 8 MB)."""


class LatencyWindow:
    """The last ``capacity`` latencies (s; NaN for a cycle without an arrival time)."""

    def __init__(self, capacity: int = CAPACITY) -> None:
        if int(capacity) < 1:
            raise InvalidInputError(f"a latency window holds at least 1 cycle, got {capacity}")
        self._buf = np.empty(int(capacity))
        self.count = 0
        """Latencies added since the start (the window holds the last ``capacity``)."""

    def add(self, latency_s: float) -> None:
        self._buf[self.count % self._buf.size] = latency_s
        self.count += 1

    def values(self) -> np.ndarray:
        """The latencies held, finite ones only (a copy, in no particular order)."""
        held = self._buf[:min(self.count, self._buf.size)]
        return held[np.isfinite(held)].copy()

    def percentiles_us(self, *qs: float) -> list[float | None]:
        """The ``qs`` percentiles of the held latencies in µs (None when there are none)."""
        v = self.values()
        if not v.size:
            return [None for _ in qs]
        return [float(x) for x in np.percentile(v * 1e6, qs)]
