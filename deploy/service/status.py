"""The live status line: estimate, bags, rate, writes and faults.

It is not a log, and how it is written depends on where it goes:

- on a terminal it is one line redrawn in place (a carriage return, then the text padded
  over the previous one) every ``status_period_s``; a log record written meanwhile first
  erases it (:func:`make_room`, called by the handler of :mod:`deploy.service.logs`), so a warning
  is never glued to it, and the next redraw brings it back;
- off a terminal (a pipe, a file, ``make demo | tee log``) it never writes a carriage
  return: a plain line ``status: ...`` every ``status_plain_period_s`` (0: none), and a
  forced message (e.g. "controller silent") once when it changes.

With ``status_line = "auto"`` it shows only on a terminal (under systemd the journal gets the
structured logs and the ``STATUS=`` line instead); ``"on"`` shows it anywhere, as above.
"""

from __future__ import annotations

import sys
import threading
import time
import weakref

_drawn: weakref.WeakSet[StatusLine] = weakref.WeakSet()
"""Status lines with text drawn in place on a terminal, not yet erased."""


def isatty(stream) -> bool:
    """True if ``stream`` is a terminal (a stream without ``isatty`` is not)."""
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError, OSError):  # no isatty, or a closed stream
        return False


def make_room() -> None:
    """Erase every status line drawn in place: something else is about to be written."""
    for line in list(_drawn):
        line.clear()


class StatusLine:
    """The status line on ``stream`` (default stderr).

    Args:
        enabled: show it at all.
        stream: where it goes; a terminal gets the redrawn line, anything else plain lines.
        period_s: how often the line is redrawn on a terminal, s.
        plain_period_s: off a terminal, a plain line every this many s (0: none).
    """

    def __init__(self, enabled: bool, stream=None, period_s: float = 0.25,
                 plain_period_s: float = 10.0) -> None:
        self.stream = sys.stderr if stream is None else stream
        self.tty = isatty(self.stream)
        self.enabled = enabled and (self.tty or plain_period_s > 0)
        self.period_s = period_s
        self.plain_period_s = plain_period_s
        self._next = 0.0
        self._width = 0
        self._last_plain = ""
        self._lock = threading.Lock()

    @classmethod
    def from_config(cls, log_config, stream=None) -> StatusLine:
        """Per ``[log] status_line`` (``auto``: only on a terminal; ``on``; ``off``),
        ``status_period_s`` and ``status_plain_period_s``."""
        stream = sys.stderr if stream is None else stream
        mode = log_config.status_line
        enabled = mode == "on" or (mode == "auto" and isatty(stream))
        return cls(enabled, stream, log_config.status_period_s,
                   getattr(log_config, "status_plain_period_s", 10.0))

    @property
    def interval_s(self) -> float:
        """Seconds between two lines: the redraw period on a terminal, else the plain one."""
        return self.period_s if self.tty else self.plain_period_s

    def due(self, now: float) -> bool:
        return self.enabled and now >= self._next

    def show(self, text: str, force: bool = False, now: float | None = None) -> None:
        """Show ``text`` if the line is due (``force``: at once; off a terminal, a forced
        text is written once, not again while it stays the same)."""
        if not self.enabled:
            return
        now = time.monotonic() if now is None else now
        with self._lock:
            if self.tty:
                if not force and now < self._next:
                    return
                pad = max(0, self._width - len(text))
                self.stream.write("\r" + text + " " * pad)
                self._width = len(text)
                _drawn.add(self)
            else:
                if force:
                    if text == self._last_plain:
                        return
                elif now < self._next:
                    return
                self.stream.write("status: " + text + "\n")
                self._last_plain = text
            self._next = now + self.interval_s
            self.stream.flush()

    def clear(self) -> None:
        """Erase the line drawn in place (nothing to do off a terminal: lines are whole)."""
        with self._lock:
            if self.enabled and self.tty and self._width:
                self.stream.write("\r" + " " * self._width + "\r")
                self.stream.flush()
                self._width = 0
            _drawn.discard(self)
