"""``iem record``: write the traffic of a CAN bus to a log file with python-can's writers.

Formats by suffix: ``.blf`` (Vector binary), ``.log`` (Linux can-utils), ``.asc`` (Vector
ASCII) and ``.trc`` (PEAK). All four round-trip classic frames exactly (the ``.asc`` reader
needs ``relative_timestamp=False`` to return the recorded times, which
:mod:`firmware_bridge.replay` passes). python-can 4.6.1's ``.trc`` writer cannot log CAN FD
frames (it drops them with "Logging CAN FD is not implemented"), so recording the ``fd``
profile to ``.trc`` is refused up front, and an FD frame arriving in a ``.trc`` recording
stops it with an error rather than losing frames silently. The ``.db`` (SQLite) writer is
not offered: it loses frames.
"""

from __future__ import annotations

import signal
import sys
import threading
import time
from pathlib import Path as FsPath

import can

from .errors import LinkError, LogFileError
from .protocol import PROFILES

FORMATS = {".blf": "Vector BLF", ".log": "can-utils log", ".asc": "Vector ASC",
           ".trc": "PEAK TRC"}
"""Suffix -> format of the logs ``iem record`` writes and the replay source reads."""


def check_format(path, fd: bool = False) -> str:
    suffix = FsPath(path).suffix.lower()
    if suffix not in FORMATS:
        raise LogFileError(f"{path}: unknown log format {suffix or '(no suffix)'!r}; valid are "
                           f"{', '.join(FORMATS)}")
    if fd and suffix == ".trc":
        raise LogFileError(f"{path}: python-can 4.6.1's .trc writer cannot log CAN FD frames "
                           "and the fd profile sends them; use .blf, .log or .asc, or the "
                           "classic profile")
    return suffix


def record(bus: can.BusABC, out, *, duration: float | None = None,
           stop: threading.Event | None = None, max_frames: int | None = None) -> int:
    """Write every frame received on ``bus`` to ``out`` until ``stop``, ``duration`` s or
    ``max_frames``; return the number of frames written."""
    suffix = check_format(out)
    try:
        writer = can.Logger(str(out))
    except OSError as exc:
        raise LogFileError(f"{out}: cannot write: {exc.strerror or exc}") from exc
    end = None if duration is None else time.perf_counter() + duration
    n = 0
    try:
        while (stop is None or not stop.is_set()) and (max_frames is None or n < max_frames):
            if end is not None and time.perf_counter() >= end:
                break
            try:
                msg = bus.recv(0.05)
            except can.CanError as exc:
                raise LinkError(f"recording {bus.channel_info}: receiving failed: {exc}") from exc
            if msg is None:
                continue
            if msg.is_fd and suffix == ".trc":
                raise LogFileError(f"{out}: a CAN FD frame (ID 0x{msg.arbitration_id:X}) "
                                   "arrived; python-can 4.6.1's .trc writer cannot log it. "
                                   f"{n} frames written; record to .blf, .log or .asc")
            writer.on_message_received(msg)
            n += 1
    finally:
        writer.stop()
    return n


def configure(parser) -> None:
    from .links import LINKS, bus_kinds

    parser.add_argument("--interface", required=True, choices=bus_kinds(),
                        help="the bus kind: " + "; ".join(f"{k}: {LINKS[k].help}"
                                                          for k in bus_kinds()))
    parser.add_argument("--channel", required=True, help="bus channel, device or URL")
    parser.add_argument("--out", required=True, metavar="FILE",
                        help=f"log file: {', '.join(FORMATS)}")
    parser.add_argument("--profile", default="fd", choices=PROFILES,
                        help="wire profile: opens the bus in FD mode for fd (default fd)")
    parser.add_argument("--duration", type=float, help="stop after this many s (default: "
                        "until interrupted)")


def run(args) -> int:
    from .can_link import open_bus

    check_format(args.out, fd=args.profile == "fd")
    stop = threading.Event()

    def _stop(signum, frame):
        stop.set()

    signal.signal(signal.SIGTERM, _stop)
    signal.signal(signal.SIGINT, _stop)
    bus = open_bus(args.interface, args.channel, args.profile)
    try:
        print(f"recording {args.interface} {args.channel!r} to {args.out}", file=sys.stderr,
              flush=True)
        n = record(bus, args.out, duration=args.duration, stop=stop)
    finally:
        bus.shutdown()
    print(f"{n} frames written to {args.out}")
    return 0
