"""Structured logs: one JSON object per line (for journald and log shippers) or plain text.

Each record has ``ts`` (UTC ISO 8601), ``level``, ``logger``, ``msg`` and any extra fields
given with ``extra={...}`` (e.g. ``event``, ``reason``). The live status line is not a log
(see :mod:`deploy.service.status`); a record is never glued to it: the handler erases a status line
drawn in place on a terminal before it writes the record.

The failure that ends the service (:func:`log_failure`) is a record too in JSON logging
(event ``fatal``, with the errors that followed it), so a log shipper reads every line; in
text it is the ``iem: error: ...`` line every ``iem`` command ends an error with.
"""

from __future__ import annotations

import json
import logging
import sys
import traceback
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


def log_failure(first: BaseException, follow_ons=(), fmt: str = "json", stream=None) -> None:
    """Report the failure that ended the service, ``first``, and ``follow_ons``, the
    ``(stage, error)`` pairs that failed after it: one JSON record (level ``error``, event
    ``fatal``, ``error_type``, ``follow_on``: ``[{"while", "error"}]``) in JSON logging, else
    ``iem: error: <first>`` and one ``iem: and while <stage>: <error>`` line each on
    ``stream`` (default stderr). An error that is not the project's (a bug) keeps its
    traceback."""
    from iem.errors import IemError

    from .status import make_room

    bug = not isinstance(first, IemError)
    text = f"{type(first).__name__}: {first}" if bug else str(first)
    if fmt == "json":
        logging.getLogger("iem.service").error(
            text, exc_info=(type(first), first, first.__traceback__) if bug else None,
            extra={"event": "fatal", "error_type": type(first).__name__,
                   "follow_on": [{"while": stage, "error": str(exc)}
                                 for stage, exc in follow_ons]})
        return
    out = sys.stderr if stream is None else stream
    make_room()
    if bug:
        traceback.print_exception(first, file=out)
    print(f"iem: error: {text}", file=out)
    for stage, exc in follow_ons:
        print(f"iem: and while {stage}: {exc}", file=out)
    out.flush()
