"""A joint-state source over a recorded CAN log.

``ReplaySource(path, profile, pace)`` reads a ``.blf`` file with
:class:`firmware_bridge.blf_reader.BlfReader` (python-can's format, read within bounds), a
``.log``, ``.asc`` or ``.trc`` file with ``can.LogReader``, and decodes it exactly as the
live link does (same E2E checks, reassembly and counters). ``pace="recorded"`` paces the
frames with ``can.MessageSync`` as they were recorded (gaps longer than ``skip`` s are
shortened to it); ``pace="fast"`` reads as fast as it can. Decoding depends only on the
frames, so replaying a file twice gives identical joint states, at either pace. ``read``
raises :class:`~firmware_bridge.errors.EndOfStream` at the end of the file; iterating yields
the states until then. The ``timeout`` of ``read`` is not used: a replay has the recorded
timing. Where the recording holds ``silence_timeout`` s (recorded time) without a complete
cycle, the source does what the live link did there: it counts a silence and accepts a
controller restart after it, so a restart in the log never makes the rest of the file stale.

A damaged log loses only what is damaged:

- a bad line in a text log (``.log``, ``.asc``, ``.trc``) that python-can's reader cannot
  parse is skipped and counted in ``counters.malformed`` (and ``bad_lines``); reading goes on
  with the same reader at the next line;
- a truncated log (a ``.blf`` shorter than its header says, or holding fewer objects than
  it declares, or that stops inside a container; a text log whose last line has no end)
  replays what it holds and sets ``truncated``;
- a ``.blf`` damaged after some frames (a container that does not inflate or breaks a
  bound of :mod:`firmware_bridge.blf_reader`) replays the frames before the damage and sets
  ``truncated``; ``damage`` says where and why. Damage before the first frame is a
  :class:`~firmware_bridge.errors.LogFileError` saying so.

Both are logged (``iem.bridge``) when the end is reached (unless ``quiet``: a peek at the
start, as :func:`firmware_bridge.recordings.can_log_rate` takes), and ``iem replay`` reports
them.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path as FsPath

import can

from iem.types import JointState
from iem.user_files import open_regular

from .blf_reader import BlfError, BlfReader
from .can_link import CanDecoder
from .errors import BridgeConfigError, EndOfStream, LogFileError
from .links import RecordedSource
from .record import check_format

PACES = ("recorded", "fast")
TEXT_FORMATS = (".log", ".asc", ".trc")
MAX_BAD_LINES_IN_A_ROW = 1000
"""A text log with more unparsable lines than this in a row is not a log of this kind."""

log = logging.getLogger("iem.bridge")


class ReplaySource(RecordedSource):
    """A :class:`~firmware_bridge.links.JointStateSource` over a CAN log file."""

    def __init__(self, path, profile: str = "fd", pace: str = "fast", skip: float = 60.0,
                 window: int = 16, silence_timeout: float = 0.1, quiet: bool = False) -> None:
        if pace not in PACES:
            raise BridgeConfigError(f"unknown replay pace {pace!r}; valid are {', '.join(PACES)}")
        self.path = FsPath(path)
        suffix = check_format(self.path)
        if not self.path.exists():
            raise LogFileError(f"{self.path}: no such log file")
        open_regular(self.path, "log file", LogFileError).close()  # not a FIFO: never waits
        kwargs = {"relative_timestamp": False} if suffix == ".asc" else {}
        try:
            self._reader = (BlfReader(self.path) if suffix == ".blf"
                            else can.LogReader(str(self.path), **kwargs))
        except BlfError as exc:
            raise LogFileError(f"{self.path}: {exc}") from exc
        except Exception as exc:  # any parser failure is a bad file
            raise LogFileError(f"{self.path}: cannot read as {suffix}: {exc}") from exc
        self._suffix = suffix
        self._pace, self._skip = pace, skip
        self._it = self._messages()
        self.truncated = False
        self.damage = ""
        """Where and why a ``.blf`` stopped before its end ("" if it did not)."""
        self.quiet = quiet
        self.bad_lines = 0
        self.last_bad_line = ""
        self._bad_in_a_row = 0
        self._ended = False
        self.silence_timeout = float(silence_timeout)
        self._delivered_at: float | None = None  # recorded time of the last cycle delivered
        self._silent = False
        self.decoder = CanDecoder(profile, window=window)
        self.profile = self.decoder.profile  # the wire profile (its sample rate, for one)
        self.counters = self.decoder.counters
        self.name = f"replay of {self.path}"
        self.rate_hz = float(self.profile.joint_state.rate_hz)
        self.last_frame_time = 0.0  # a log has no receive time on this PC
        self.frames = 0

    @property
    def last_heartbeat(self):
        return self.decoder.last_heartbeat

    def _messages(self):
        """A new iteration of the same reader (it goes on where the last one stopped)."""
        if self._pace == "recorded":
            return iter(can.MessageSync(self._reader, timestamps=True, skip=self._skip))
        return iter(self._reader)

    def _bad_line(self, exc: Exception) -> None:
        """python-can's text reader raised on a line: count it, go on at the next line."""
        self.bad_lines += 1
        self.counters.malformed += 1
        self.last_bad_line = f"{type(exc).__name__}: {exc}"
        self._bad_in_a_row += 1
        if self._bad_in_a_row > MAX_BAD_LINES_IN_A_ROW:
            raise LogFileError(f"{self.path}: {self._bad_in_a_row} lines in a row python-can "
                               f"cannot read as {self._suffix} (last: {self.last_bad_line}); "
                               "is it a log of this format?") from exc
        if hasattr(self._reader, "_extract_header"):  # .asc, .trc: the header is read
            self._reader._extract_header = lambda: None  # once; go on with the frames
        self._it = self._messages()

    def _check_complete(self) -> None:
        """At the end of the file: did it hold everything it should?"""
        try:
            size = os.path.getsize(self.path)
            if self._suffix == ".blf":
                r = self._reader
                declared = getattr(r, "file_size", 0)
                objects = getattr(r, "object_count", 0)
                if (declared and size < declared) or (objects and self.frames < objects):
                    self.truncated = True
            elif size:
                with open(self.path, "rb") as f:
                    f.seek(-1, os.SEEK_END)
                    self.truncated = self.truncated or f.read(1) != b"\n"
        except OSError:
            pass

    def _end(self) -> EndOfStream:
        if not self._ended:
            self._ended = True
            self._check_complete()
            if self.damage and not self.quiet:
                log.warning("%s is damaged (%s): replayed the %d frames before it", self.path,
                            self.damage, self.frames, extra={"event": "log_truncated"})
            elif self.truncated and not self.quiet:
                log.warning("%s is truncated: replayed the %d frames it holds",
                            self.path, self.frames, extra={"event": "log_truncated"})
            if self.bad_lines and not self.quiet:
                log.warning("%s: skipped %d lines python-can could not read (last: %s)",
                            self.path, self.bad_lines, self.last_bad_line,
                            extra={"event": "log_bad_lines"})
        what = " (truncated)" if self.truncated else ""
        return EndOfStream(f"{self.path}: end of log{what} after {self.frames} frames; "
                           f"{self.counters.summary()}")

    def read(self, timeout: float | None = None) -> JointState:
        push = self.decoder.push
        while True:
            try:
                msg = next(self._it)
            except StopIteration:
                raise self._end() from None
            except BlfError as exc:  # a damaged container: what came before stands
                if not self.frames:
                    raise LogFileError(f"{self.path}: {exc}") from exc
                self.truncated = True
                self.damage = str(exc)
                raise self._end() from exc
            except Exception as exc:  # python-can's parsers raise ValueError, IndexError ...
                if self._suffix not in TEXT_FORMATS:
                    raise LogFileError(f"{self.path}: unreadable after {self.frames} frames: "
                                       f"{exc}") from exc
                self._bad_line(exc)
                continue
            self._bad_in_a_row = 0
            self.frames += 1
            self._silence_check(msg.timestamp)
            state = push(msg)
            if state is not None:
                self._delivered_at = msg.timestamp
                self._silent = False
                return state

    def _silence_check(self, stamp: float) -> None:
        """What the live link did at this point of the recording: no complete cycle for
        ``silence_timeout`` s of recorded time is a silence, after which a controller restart
        (a counter that went backwards) is accepted. Counted in ``silences``, not raised."""
        last = self._delivered_at
        if last is not None and not self._silent and stamp - last > self.silence_timeout:
            self._silent = True
            self.counters.silences += 1
            self.decoder.resync()

    def close(self) -> None:
        self._reader.stop()


def open_replay(kind: str, channel: str, *, profile: str = "fd", silence_timeout: float = 0.1,
                pace: str = "recorded", skip: float = 60.0, window: int = 16) -> ReplaySource:
    """Opener for :func:`firmware_bridge.links.open_link`: ``channel`` is the log file
    (``silence_timeout``: recorded seconds without a complete cycle that count as a silence,
    as on the live link)."""
    return ReplaySource(channel, profile, pace, skip=skip, window=window,
                        silence_timeout=silence_timeout)
