"""Structured logs: one JSON object per line (for journald and log shippers) or plain text.

Each record has ``ts`` (UTC ISO 8601), ``level``, ``logger``, ``msg`` and any extra fields
given with ``extra={...}`` (e.g. ``event``, ``reason``). The live status line is not a log
(see :mod:`deploy.service.status`); a record is never glued to it: the handler erases a status line
drawn in place on a terminal before it writes the record.
"""

from __future__ import annotations

import json
import logging
import sys
from datetime import UTC, datetime

_STANDARD = set(vars(logging.LogRecord("", 0, "", 0, "", None, None))) | {"message", "asctime"}


class JsonFormatter(logging.Formatter):
    def format(self, record: logging.LogRecord) -> str:
        out = {"ts": datetime.fromtimestamp(record.created, UTC).isoformat(timespec="milliseconds"),
               "level": record.levelname.lower(), "logger": record.name,
               "msg": record.getMessage()}
        for key, value in vars(record).items():
            if key not in _STANDARD and not key.startswith("_"):
                out[key] = value
        if record.exc_info:
            out["exc"] = self.formatException(record.exc_info)
        return json.dumps(out, default=str)


class StatusAwareHandler(logging.StreamHandler):
    """A stream handler that first erases any status line drawn in place on a terminal."""

    def emit(self, record: logging.LogRecord) -> None:
        from .status import make_room

        make_room()
        super().emit(record)


def setup_logging(level: str = "info", fmt: str = "json", stream=None) -> None:
    """Route the ``iem`` loggers to ``stream`` (default stderr) in the chosen format."""
    handler = StatusAwareHandler(sys.stderr if stream is None else stream)
    handler.setFormatter(JsonFormatter() if fmt == "json" else logging.Formatter(
        "%(asctime)s %(levelname)-7s %(name)s: %(message)s"))
    root = logging.getLogger("iem")
    root.handlers[:] = [handler]
    root.setLevel(level.upper())
    root.propagate = False
