"""Keeping up with the controller: whether the service learns from the next block point.

Behind the controller by more than ``max_lag`` s (a slow learning step), the service still
estimates every point but skips the learning steps until it is current again (below half of
``max_lag``: a hysteresis), so estimates and writes stay fresh. The points estimated without
learning are counted (``unlearnt``) and each episode is logged once.
"""

from __future__ import annotations

import logging

__all__ = ["LearningPace"]

log = logging.getLogger("iem.service")


class LearningPace:
    """Whether the service is behind the controller (see the module docstring)."""

    def __init__(self) -> None:
        self.behind = False
        self.unlearnt = 0
        """Block points estimated without learning so far."""

    def observe(self, lag: float, max_lag: float) -> bool:
        """A block point read ``lag`` s after its last frame arrived: True if the service
        fell behind or became current again with it (:attr:`behind` says which)."""
        behind = lag > (max_lag / 2.0 if self.behind else max_lag)  # hysteresis
        if behind:
            self.unlearnt += 1
        if behind == self.behind:
            return False
        self.behind = behind
        if behind:
            log.warning("behind the controller by %.0f ms: estimating without learning "
                        "until current", lag * 1e3, extra={"event": "behind",
                                                           "lag_ms": lag * 1e3})
        else:
            log.info("current again (%d points estimated without learning so far)",
                     self.unlearnt, extra={"event": "current", "unlearnt": self.unlearnt})
        return True
