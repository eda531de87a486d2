"""A joint-state source over a recorded CAN log (python-can's readers).

``ReplaySource(path, profile, pace)`` reads a ``.blf``, ``.log``, ``.asc`` or ``.trc`` file
with ``can.LogReader`` and decodes it exactly as the live link does (same E2E checks,
reassembly and counters). ``pace="recorded"`` paces the frames with ``can.MessageSync`` as
they were recorded (gaps longer than ``skip`` s are shortened to it); ``pace="fast"`` reads
as fast as it can. Decoding depends only on the frames, so replaying a file twice gives
identical joint states, at either pace. ``read`` raises
:class:`~firmware_bridge.errors.EndOfStream` at the end of the file; iterating yields the
states until then. The ``timeout`` of ``read`` is not used: a replay has the recorded timing.
"""

from __future__ import annotations

from pathlib import Path as FsPath

import can

from iem.types import JointState

from .can_link import CanDecoder
from .errors import BridgeConfigError, EndOfStream, LogFileError
from .record import check_format

PACES = ("recorded", "fast")


class ReplaySource:
    """A :class:`~firmware_bridge.links.JointStateSource` over a CAN log file."""

    def __init__(self, path, profile: str = "fd", pace: str = "fast", skip: float = 60.0,
                 window: int = 16) -> None:
        if pace not in PACES:
            raise BridgeConfigError(f"unknown replay pace {pace!r}; valid are {', '.join(PACES)}")
        self.path = FsPath(path)
        suffix = check_format(self.path)
        if not self.path.is_file():
            raise LogFileError(f"{self.path}: no such log file")
        kwargs = {"relative_timestamp": False} if suffix == ".asc" else {}
        try:
            self._reader = can.LogReader(str(self.path), **kwargs)
        except Exception as exc:  # any parser failure is a bad file
            raise LogFileError(f"{self.path}: cannot read as {suffix}: {exc}") from exc
        messages = can.MessageSync(self._reader, timestamps=True, skip=skip) \
            if pace == "recorded" else self._reader
        self._it = iter(messages)
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

    def read(self, timeout: float | None = None) -> JointState:
        push = self.decoder.push
        while True:
            try:
                msg = next(self._it)
            except StopIteration:
                raise EndOfStream(f"{self.path}: end of log after {self.frames} frames; "
                                  f"{self.counters.summary()}") from None
            except Exception as exc:
                raise LogFileError(f"{self.path}: unreadable after {self.frames} frames: "
                                   f"{exc}") from exc
            self.frames += 1
            state = push(msg)
            if state is not None:
                return state

    def __iter__(self):
        while True:
            try:
                yield self.read()
            except EndOfStream:
                return

    def close(self) -> None:
        self._reader.stop()

    def __enter__(self) -> ReplaySource:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def open_replay(kind: str, channel: str, *, profile: str = "fd", silence_timeout: float = 0.1,
                pace: str = "recorded", skip: float = 60.0, window: int = 16) -> ReplaySource:
    """Opener for :func:`firmware_bridge.links.open_link`: ``channel`` is the log file
    (``silence_timeout`` is not used: a replay has the recorded timing and ends with
    ``EndOfStream``)."""
    return ReplaySource(channel, profile, pace, skip=skip, window=window)
