"""``iem run``: the plug-in service (:class:`deploy.service.loop.Service`) on the cell's link until
it is stopped (SIGTERM, SIGINT) or ``--duration`` has passed; the summary is logged at the end
(event ``stopped``) and one line of it printed."""

from __future__ import annotations

import logging
import sys

from deploy.options import add_duration
from deploy.service.loop import Service

log = logging.getLogger("iem.service")


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
        service.open()
        summary = service.run(duration=args.duration)
    finally:
        service.close()
    log.info("stopped: %s", summary, extra={"event": "stopped"})
    print(f"iem run: {summary['cycles']} block points, {summary['bags']} bags, writes "
          f"{summary['writes']}", file=sys.stderr)
    return 0
