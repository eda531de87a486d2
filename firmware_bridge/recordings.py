"""Joint-state recordings of any supported format, read as arrays or as a joint-state source.

Three formats (:data:`FORMATS`), told apart by :func:`detect_format` (a caller may name one):

- ``can``: a CAN log of this project's wire protocol (``.blf .log .asc .trc``, as ``iem
  record`` writes them), decoded by :class:`firmware_bridge.replay.ReplaySource` exactly as
  the live link decodes the bus (the link kind ``replay``). python-can's own CSV CAN log is
  recognised and refused: it keeps no CAN FD flag, so ``iem record`` does not write it.
- ``rosbag2``: ``ros2 bag record /franka/joint_states``: a bag directory holding
  ``metadata.yaml``, or one of its ``.db3`` (sqlite3) or ``.mcap`` files, whose topic (default
  ``/franka/joint_states``) carries ``sensor_msgs/msg/JointState``: the arm's joints by name,
  ``t`` from the header stamps (:mod:`firmware_bridge.rosbag2_reader`).
- ``csv``: a text file whose header names the columns ``t`` (s), ``q1..q7`` (rad),
  ``dq1..dq7`` (rad/s) and ``tau1..tau7`` (N·m, link side: libfranka's ``tau_J``), in any
  order; other columns are ignored. A libfranka ``RobotState`` logged that way.

:func:`read_recording` gives an :class:`iem.signals.recording.Recording` (``t (N,)``, ``q, dq, tau
(N, 7)``); :class:`RecordingSource` is a :class:`~firmware_bridge.links.JointStateSource` over
one (the link kind ``recording``, rosbag2 and CSV), delivering the recorded time stamps as they
are: nothing is resampled or filled, the estimator's gap rule (:mod:`iem.signals.gaps`) decides what
a gap is. :func:`open_recording` opens any of the three formats as a source.

A recording's rate is its own: :class:`RecordingSource` reports the rate its time stamps show
(:func:`iem.signals.rate.detect_rate`, the median step) or the one given, and
:func:`can_log_rate` reads it off a CAN log's first joint states.

A rosbag2 or CSV recording is read whole and checked before anything is delivered: a missing
joint or column, a time stamp that does not increase strictly, a non-finite value (a single
NaN refuses the whole file: a recording quietly shortened or patched would identify another
payload without saying so), an empty file, a topic not in the bag or one of another message
type is a :class:`~firmware_bridge.errors.LogFileError` naming the message or line, the joint
or column, and what is valid. It holds 22 float64 per joint state (176 bytes: 10 MB a minute
at 1 kHz).
"""

from __future__ import annotations

import csv
import io
import time
from pathlib import Path as FsPath

import numpy as np

from iem.signals.rate import detect_rate
from iem.signals.recording import Recording
from iem.types import N_JOINTS, JointState
from iem.user_files import open_regular

from .errors import BridgeConfigError, EndOfStream, LogFileError
from .links import LinkCounters, RecordedSource, open_link
from .reassembly import CYCLE_MOD
from .record import FORMATS as CAN_SUFFIXES
from .recording_checks import MIN_JOINT_STATES, checked_recording, refuse_nonfinite
from .ros2_link import DEFAULT_TOPIC
from .rosbag2_reader import BAG_SUFFIXES, read_rosbag2

FORMATS = ("can", "rosbag2", "csv")
"""The recording formats, as ``--format`` names them."""
CSV_COLUMNS = ("t", *(f"{s}{i}" for s in ("q", "dq", "tau") for i in range(1, N_JOINTS + 1)))
"""The columns a joint-state CSV must have (any order; others are ignored)."""
CAN_CSV_HEADER = ("timestamp", "arbitration_id")
"""How python-can's CSV CAN log starts its header."""
VALID = ("a CAN log (.blf, .log, .asc, .trc), a rosbag2 bag (its directory, a .db3 or a .mcap "
         "file) or a joint-state CSV (header t,q1..q7,dq1..dq7,tau1..tau7)")

# -- which format ------------------------------------------------------------------------------
def _header(path: FsPath) -> list[str] | None:
    """The first line of a text file as CSV field names, or None if it is not text."""
    try:
        with open(path, "rb") as f:
            head = f.read(65536)
    except OSError:
        return None
    try:
        line = head.split(b"\n", 1)[0].rstrip(b"\r").decode("utf-8-sig")
    except UnicodeDecodeError:
        return None
    return [name.strip() for name in line.split(",")]


def detect_format(path) -> str:
    """The format of the recording at ``path``: ``"can"``, ``"rosbag2"`` or ``"csv"``.

    A directory holding ``metadata.yaml`` or a ``.db3``/``.mcap`` file is a rosbag2; a CAN log
    suffix is a CAN log; a text file whose header has the joint-state columns is a CSV, whatever
    its suffix; a ``.csv`` file with another header is a CSV too (reading it names the missing
    columns). LogFileError for python-can's CSV CAN log, a directory that is no bag, a missing
    path without a known suffix, and anything else, naming the valid formats.
    """
    path = FsPath(path)
    suffix = path.suffix.lower()
    if path.is_dir():
        if (path / "metadata.yaml").is_file():
            return "rosbag2"
        raise LogFileError(f"{path}: a directory without metadata.yaml is not a rosbag2 bag; "
                           f"valid recordings are {VALID}")
    if suffix in BAG_SUFFIXES:
        return "rosbag2"
    if suffix in CAN_SUFFIXES:
        return "can"
    if path.is_file():
        header = _header(path)
        if header is not None and set(CSV_COLUMNS) <= set(header):
            return "csv"
        if header is not None and tuple(header[:2]) == CAN_CSV_HEADER:
            raise LogFileError(f"{path}: a python-can CSV CAN log; it keeps no CAN FD flag, so "
                               "iem reads CAN logs as .blf, .log, .asc or .trc (iem record "
                               "writes them)")
    elif not path.exists() and suffix != ".csv":
        what = f"unknown log format {suffix!r}" if suffix else "no such file or directory"
        raise LogFileError(f"{path}: {what}; valid recordings are {VALID}")
    if suffix == ".csv":
        return "csv"
    raise LogFileError(f"{path}: unknown log format {suffix or '(no suffix)'!r}; valid "
                       f"recordings are {VALID}")


def recording_format(path, format: str | None = None) -> str:
    """``format`` if it is one of :data:`FORMATS` (LogFileError naming them if not); None:
    :func:`detect_format`."""
    if format is None:
        return detect_format(path)
    if format not in FORMATS:
        raise LogFileError(f"unknown recording format {format!r}; valid are "
                           f"{', '.join(FORMATS)}")
    return format


# -- readers -----------------------------------------------------------------------------------
def read_csv(path) -> Recording:
    """A joint-state CSV (see the module docstring) as arrays; LogFileError naming the line and
    column of anything wrong."""
    path = FsPath(path)
    if not path.exists():
        raise LogFileError(f"{path}: no such file")
    try:
        with io.TextIOWrapper(open_regular(path, "recording", LogFileError),
                              encoding="utf-8-sig", newline="") as f:
            rows = list(csv.reader(f))
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise LogFileError(f"{path}: cannot read as a joint-state CSV: {exc}") from exc
    if not rows:
        raise LogFileError(f"{path}: empty; a joint-state CSV starts with the header "
                           f"{','.join(CSV_COLUMNS)} (any order)")
    header = [name.strip() for name in rows[0]]
    missing = [c for c in CSV_COLUMNS if c not in header]
    if missing:
        raise LogFileError(f"{path}: a joint-state CSV needs the columns t (s), q1..q7 (rad), "
                           "dq1..dq7 (rad/s) and tau1..tau7 (N·m), in any order, other "
                           f"columns ignored; missing: {', '.join(missing)}")
    twice = sorted({c for c in CSV_COLUMNS if header.count(c) > 1})
    if twice:
        raise LogFileError(f"{path}: the column(s) {', '.join(twice)} appear more than once in "
                           "the header; each may appear once")
    columns = [header.index(c) for c in CSV_COLUMNS]
    lines = [(i + 1, row) for i, row in enumerate(rows) if i and any(x.strip() for x in row)]
    for line, row in lines:
        if len(row) != len(header):
            raise LogFileError(f"{path}: line {line} has {len(row)} fields, the header "
                               f"{len(header)}")
    try:
        values = np.array([[row[c] for c in columns] for _, row in lines], dtype=float)
    except ValueError:
        for line, row in lines:
            for name, c in zip(CSV_COLUMNS, columns, strict=True):
                try:
                    float(row[c])
                except ValueError:
                    raise LogFileError(f"{path}: line {line}, column {name}: {row[c]!r} is not "
                                       "a number") from None
        raise
    values = values.reshape(-1, len(CSV_COLUMNS))

    def what(k: int) -> str:
        return f"line {lines[k][0]}"

    def column(name: str, j: int) -> str:
        return f"column {CSV_COLUMNS[j]}"

    refuse_nonfinite(path, {"all": values}, what, column)
    n = N_JOINTS
    t = np.ascontiguousarray(values[:, 0])
    q, dq, tau = (np.ascontiguousarray(values[:, 1 + i * n:1 + (i + 1) * n]) for i in range(3))
    return checked_recording(path, t, q, dq, tau, what)


def _read_can(path, profile: str) -> Recording:
    from .replay import ReplaySource

    with ReplaySource(path, profile, pace="fast") as source:
        states = list(source)
    if not states:
        raise LogFileError(f"{path}: no complete joint-state cycle of the {profile} profile in "
                           f"it ({source.counters.summary()})")
    return Recording.from_states(states)


def read_recording(path, format: str | None = None, *, topic: str = DEFAULT_TOPIC,
                   profile: str = "fd", joints: tuple[str, ...] | None = None) -> Recording:
    """The joint states of a recording of any format as arrays (``format`` None: detected;
    ``topic``: rosbag2's JointState topic; ``profile``: a CAN log's wire profile;
    ``joints``: the arm model's joint names a rosbag2 bag must carry, None: fr3's or
    panda's)."""
    fmt = recording_format(path, format)
    if fmt == "can":
        return _read_can(path, profile)
    return read_rosbag2(path, topic, joints) if fmt == "rosbag2" else read_csv(path)


# -- the source --------------------------------------------------------------------------------
class RecordingSource(RecordedSource):
    """A :class:`~firmware_bridge.links.JointStateSource` over a :class:`Recording`.

    ``read`` returns the recorded joint states in order, with their time stamps as recorded
    and ``cycle`` the joint state's index in the recording; :class:`EndOfStream` at the end;
    the ``timeout`` of ``read`` is not used. ``pace="fast"`` returns them as fast as they are
    asked for (``iem replay``); ``pace="recorded"`` waits until each is due at the recorded
    pace (gaps longer than ``skip`` s shortened to it), as python-can's ``MessageSync`` paces
    a CAN log for ``iem run``, whose reader thread drops the oldest states once the estimator
    is 0.5 s behind (:mod:`deploy.service.reader`). ``counters``: ``received`` and
    ``delivered`` count joint states; ``lost`` counts the cycles at ``rate_hz`` that the time stamps
    skip (as the ``ros2`` link counts them), ``silences`` the gaps longer than
    ``silence_timeout`` (what a live link would have reported there). Nothing is dropped:
    the file was checked whole. ``truncated`` and ``bad_lines`` are those of a CAN log's
    source, always False and 0 here. ``rate_hz``: the recording's joint states a second, as
    given or else detected from its time stamps (:func:`iem.signals.rate.detect_rate`).
    """

    last_frame_time = 0.0  # a recording has no receive time on this PC
    truncated = False
    bad_lines = 0

    def __init__(self, recording: Recording, name: str = "recording",
                 silence_timeout: float = 0.1, pace: str = "fast", skip: float = 60.0,
                 rate_hz: float | None = None) -> None:
        from .replay import PACES

        if pace not in PACES:
            raise BridgeConfigError(f"unknown replay pace {pace!r}; valid are {', '.join(PACES)}")
        self.recording = recording
        self.name = name
        self.rate_hz = detect_rate(recording.t) if rate_hz is None else float(rate_hz)
        self.rate_detected = rate_hz is None
        self.silence_timeout = float(silence_timeout)
        self.counters = LinkCounters()
        self._k = 0
        self._paced, self._skip = pace == "recorded", float(skip)
        self._start: float | None = None  # perf_counter of the first joint state (paced)
        self._skipped = 0.0  # recorded seconds of gaps skipped (paced)

    def read(self, timeout: float | None = None) -> JointState:
        r, k, c = self.recording, self._k, self.counters
        if k >= len(r):
            raise EndOfStream(f"{self.name}: end of the recording after {k} joint states")
        t = float(r.t[k])
        if k:
            dt = t - float(r.t[k - 1])
            c.lost += max(round(dt * self.rate_hz) - 1, 0)
            if dt > self.silence_timeout:
                c.silences += 1
            if self._paced:
                self._skipped += max(dt - self._skip, 0.0)
                wait = self._start + (t - float(r.t[0]) - self._skipped) - time.perf_counter()
                if wait > 1e-4:
                    time.sleep(wait)
        elif self._paced:
            self._start = time.perf_counter()
        self._k = k + 1
        c.received += 1
        c.delivered += 1
        return JointState(t=t, q=r.q[k], dq=r.dq[k], tau_J=r.tau[k], cycle=k % CYCLE_MOD)

    def read_many(self, n: int, T: np.ndarray, X: np.ndarray, cycles: np.ndarray) -> int | None:
        """The next ``n`` joint states at most, at once, into ``T`` (time stamps), ``X``
        (``[q, dq, tau_J]`` rows) and ``cycles``: what :meth:`read` gives one by one, and the
        same counters. Returns how many (0: the end, where :meth:`read` raises
        :class:`~firmware_bridge.errors.EndOfStream`), or None at the recorded pace (that
        waits state by state: use :meth:`read`)."""
        if self._paced:
            return None
        r, k, c = self.recording, self._k, self.counters
        m = max(min(int(n), len(r) - k), 0)
        if not m:
            return 0
        end = k + m
        T[:m] = r.t[k:end]
        X[:m, :7], X[:m, 7:14], X[:m, 14:] = r.q[k:end], r.dq[k:end], r.tau[k:end]
        cycles[:m] = np.arange(k, end) % CYCLE_MOD
        first = max(k, 1)  # the first state with one before it
        if end > first:
            dt = r.t[first:end] - r.t[first - 1:end - 1]
            c.lost += int(np.maximum(np.rint(dt * self.rate_hz) - 1.0, 0.0).sum())
            c.silences += int(np.count_nonzero(dt > self.silence_timeout))
        self._k = end
        c.received += m
        c.delivered += m
        return m



def open_recording_link(kind: str, channel: str, *, profile: str = "fd",
                        silence_timeout: float = 0.1, format: str | None = None,
                        topic: str = DEFAULT_TOPIC, pace: str = "recorded",
                        skip: float = 60.0, rate_hz: float | None = None,
                        joints: tuple[str, ...] | None = None) -> RecordingSource:
    """Opener for :func:`firmware_bridge.links.open_link` (kind ``recording``): ``channel`` is
    a rosbag2 bag or a joint-state CSV (``format`` None: detected), read whole and checked
    now; ``topic``: the bag's JointState topic; ``pace``, ``skip``: see
    :class:`RecordingSource` (recorded pace by default, as the ``replay`` kind's);
    ``rate_hz``: the recording's rate (None: detected); ``joints``: the arm model's joint
    names a bag must carry (None: fr3's or panda's); ``profile`` is a CAN notion and not
    used."""
    fmt = recording_format(channel, format)
    if fmt == "can":
        raise LogFileError(f"{channel}: a CAN log; open it as the link kind 'replay'")
    recording = read_recording(channel, fmt, topic=topic, joints=joints)
    what = f"{fmt} recording {channel}" + (f" ({topic})" if fmt == "rosbag2" else "")
    return RecordingSource(recording, what, silence_timeout, pace, skip, rate_hz)


def recording_link(path, format: str | None = None, topic: str = DEFAULT_TOPIC,
                   joints: tuple[str, ...] | None = None) -> tuple[str, str, dict]:
    """``(format, link kind, opener options)`` that open the recording at ``path`` with
    :func:`firmware_bridge.links.open_link`: ``replay`` (as fast as it decodes) for a CAN log,
    ``recording`` for the others (``format`` None: detected)."""
    fmt = recording_format(path, format)
    if fmt == "can":
        return fmt, "replay", {"pace": "fast"}
    options = {"format": fmt, "topic": topic, "pace": "fast"}
    return fmt, "recording", options if joints is None else {**options, "joints": joints}


def open_recording(path, format: str | None = None, *, topic: str = DEFAULT_TOPIC,
                   profile: str = "fd", joints: tuple[str, ...] | None = None):
    """A joint-state source over the recording at ``path`` of any format (``format`` None:
    detected): a :class:`~firmware_bridge.replay.ReplaySource` for a CAN log (``profile``: its
    wire profile), a :class:`RecordingSource` for a rosbag2 bag (``topic``) or a CSV."""
    _, kind, options = recording_link(path, format, topic, joints)
    return open_link(kind, str(path), profile=profile, **options)


RATE_PEEK = 2000
"""Joint states of a CAN log :func:`can_log_rate` reads its rate from."""


def can_log_rate(path, profile: str = "fd", states: int = RATE_PEEK) -> float:
    """The rate of a CAN log's joint states (:func:`iem.signals.rate.detect_rate` over its
    first ``states``), without decoding the rest; LogFileError if it holds fewer than two
    complete cycles of ``profile``."""
    from .replay import ReplaySource

    with ReplaySource(path, profile, pace="fast", quiet=True) as source:  # a peek: the
        t = []  # replay itself reports what the file holds
        for state in source:
            t.append(state.t)
            if len(t) >= states:
                break
    if len(t) < MIN_JOINT_STATES:
        raise LogFileError(f"{path}: {len(t)} complete joint-state cycle(s) of the {profile} "
                           f"profile ({source.counters.summary()}); a recording needs at "
                           f"least {MIN_JOINT_STATES}")
    return detect_rate(t)
