"""``iem run``: the plug-in service (:class:`deploy.service.loop.Service`) on the cell's link until
it is stopped (SIGTERM, SIGINT), ``--duration`` has passed, or it fails.

Whatever ends it, it ends the same way: the first failure, if any, with the errors that
followed it (``iem: error: ...``, or a JSON record, event ``fatal``, in JSON logging); then,
once it has estimated at least one point, the summary (:func:`deploy.service.report.
summary_lines` on stdout, as ``iem demo`` prints it, and event ``stopped`` in the log with
the summary's JSON); then the exit status (:func:`deploy.cli.exit_status`).
"""

from __future__ import annotations

import logging
import sys

from deploy.options import add_duration
from deploy.service.loop import Service

log = logging.getLogger("iem.service")

BUG = 1
"""Exit status of a failure that is not the project's (a bug: its traceback is logged), as
Python's own for an uncaught exception."""


def configure(parser) -> None:
    parser.add_argument("--config", required=True, metavar="FILE", help="cell.toml")
    add_duration(parser)


def run(args) -> int:
    import signal

    from deploy.config import load_config
    from deploy.service.logs import setup_logging

    config = load_config(args.config)
    setup_logging(config.log.level, config.log.format)
    service = Service(config)
    signal.signal(signal.SIGTERM, lambda *_: service.stop())
    signal.signal(signal.SIGINT, lambda *_: service.stop())
    try:
        try:
            service.configure()
            service.run(duration=args.duration)
        finally:
            service.shutdown()
    except Exception as exc:  # the service kept it; reported below
        service.failures.add("running", exc)
    return finish(service, config.log.format)


def finish(service: Service, fmt: str, out=None) -> int:
    """Report how ``service`` ended: its first failure and what followed it
    (:func:`deploy.service.logs.log_failure`), then its summary if it estimated a point; the exit
    status."""
    from deploy.cli import exit_status
    from deploy.service.logs import log_failure
    from deploy.service.report import summary_lines
    from iem.errors import IemError

    first = service.failures.first
    if first is not None:
        log_failure(first, service.failures.follow_ons, fmt)
    if service.tally is not None and service.tally.cycles > 0:
        summary = service.summary()
        log.info("stopped after %d block points", summary["cycles"],
                 extra={"event": "stopped", "summary": summary})
        out = sys.stdout if out is None else out
        print("\n".join(summary_lines(summary)), file=out, flush=True)
    if first is None:
        return 0
    return exit_status(first) if isinstance(first, IemError) else BUG
