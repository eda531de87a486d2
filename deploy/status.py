"""The live status line on a terminal: estimate, bags, rate, writes and faults, redrawn in
place every ``status_period_s``. It is not a log: with ``status_line = "auto"`` it shows only
when the stream is a terminal (under systemd the journal gets the structured logs instead).
"""

from __future__ import annotations

import sys


class StatusLine:
    def __init__(self, enabled: bool, stream=None, period_s: float = 0.25) -> None:
        self.enabled = enabled
        self.stream = sys.stderr if stream is None else stream
        self.period_s = period_s
        self._next = 0.0
        self._width = 0

    @classmethod
    def from_config(cls, log_config, stream=None) -> StatusLine:
        stream = sys.stderr if stream is None else stream
        mode = log_config.status_line
        enabled = mode == "on" or (mode == "auto" and getattr(stream, "isatty", lambda: False)())
        return cls(enabled, stream, log_config.status_period_s)

    def due(self, now: float) -> bool:
        return self.enabled and now >= self._next

    def show(self, text: str, force: bool = False, now: float | None = None) -> None:
        if not self.enabled:
            return
        import time

        now = time.monotonic() if now is None else now
        if not force and now < self._next:
            return
        self._next = now + self.period_s
        pad = max(0, self._width - len(text))
        self.stream.write("\r" + text + " " * pad)
        self.stream.flush()
        self._width = len(text)

    def clear(self) -> None:
        if self.enabled and self._width:
            self.stream.write("\r" + " " * self._width + "\r")
            self.stream.flush()
            self._width = 0
