"""pylibfranka in a process of its own: a ``Robot`` whose calls never hold this process's lock.

pylibfranka's ``Robot.read_once`` blocks until the robot's next state (a millisecond at
1 kHz) without releasing Python's global interpreter lock. A thread that reads every state
holds the lock most of the time, and every other thread of its process runs at a fraction of
its speed: against franky-sim's FR3, a pure-Python loop ran at 0.46 of its speed beside a
thread calling ``read_once`` (1.05 beside a thread sleeping a millisecond a loop). When the
states stop (a lost network), that thread holds the lock for libfranka's whole receive
timeout (1 s): nothing else in the process runs, not even the code that would notice.

:class:`RobotProcess` keeps the ``Robot`` in a child process (``python -m
firmware_bridge.franka_process ADDRESS``) and offers the calls the ``franka`` link makes,
with pylibfranka's signatures and exception classes:

- ``read_once()``: the child reads every state and writes it to a pipe; the parent's read
  of the pipe releases the lock while it waits. A state carries what the link reads
  (:class:`ProcessState`: ``time``, ``q``, ``dq``, ``tau_J``, ``m_load``, ``F_x_Cload``,
  ``I_load``), as the doubles pylibfranka gave, so values are the same as in-process.
- ``set_load(mass, F_x_Cload, I_load)``: run by the child's command thread; it returns or
  raises what the child's ``set_load`` returned or raised. The child hands the lock between
  its threads every :data:`CHILD_SWITCH_INTERVAL_S`: at Python's default (5 ms) the reader,
  back in ``read_once`` within microseconds of each state, kept the command thread waiting
  for the lock 130-200 ms at the median and up to 1.5 s (franky-sim, 40 calls), so a load
  sent while the arm moved could land after the motion, and the link's 2 s bound on
  ``set_load`` was sometimes reached; at 0.5 ms the same calls took 3.1 ms (max 5.1), about
  franky-sim's own 0.8 ms plus the pipes.
- Errors cross as pylibfranka's class name and message and are raised in the parent as that
  class of the given ``api`` module. After a ``NetworkException`` from ``read_once`` (no
  state within libfranka's timeout) the child's robot is unusable, as in-process: the child
  ends and every later call raises ``NetworkException``; the link connects anew with a new
  process. A child that ended for any other reason reads the same way.
- ``close()`` ends the child (it also ends on its own when its input closes: the parent
  died).

The child imports only the standard library and pylibfranka.
"""

from __future__ import annotations

import contextlib
import os
import queue
import struct
import subprocess
import sys
import threading
import time

RETRY_AFTER_ERROR_S = 0.1
"""Pause of the reader after ``read_once`` raised, s."""
CONNECT_TIMEOUT_S = 30.0
"""Longest wait for the child to connect to the robot (or fail to), s."""
CLOSE_TIMEOUT_S = 2.0
"""How long ``close`` waits for the child to end before it is terminated, s."""
CHILD_SWITCH_INTERVAL_S = 0.0005
"""The child's ``sys.setswitchinterval``, s: well under the robot's 1 ms cycle, so the
command thread gets the lock from the reader between two states."""

_HEADER = struct.Struct("<cI")  # kind, body length
_STATE = struct.Struct("<35d")  # t, q[7], dq[7], tau_J[7], m_load, F_x_Cload[3], I_load[9]
_LOAD = struct.Struct("<I13d")  # sequence, mass, F_x_Cload[3], I_load[9]
_SEQ = struct.Struct("<I")

CONNECTED, CONNECT_FAILED, STATE, READ_ERROR, OUTCOME = b"C", b"X", b"S", b"E", b"A"
"""Child -> parent: connected; the connection failed (error); a state; ``read_once``
raised (error); a ``set_load``'s outcome (sequence, error or empty)."""
SET_LOAD, QUIT = b"L", b"Q"
"""Parent -> child: ``set_load`` (sequence, mass, CoM, inertia); end."""


def pack_state(t: float, q, dq, tau_J, m_load: float, F_x_Cload, I_load) -> bytes:
    """A state's body on a pipe: its time and the flat sequences ``q``, ``dq``, ``tau_J``
    (7 each), ``F_x_Cload`` (3) and ``I_load`` (9, column-major), the 35 doubles
    :class:`ProcessState` reads back."""
    return _STATE.pack(t, *q, *dq, *tau_J, m_load, *F_x_Cload, *I_load)


def _error_body(exc: BaseException) -> bytes:
    return f"{type(exc).__name__}\0{exc}".encode("utf-8", "replace")


def _read_exact(stream, n: int) -> bytes | None:
    """``n`` bytes of ``stream``, or None at its end."""
    chunks, left = [], n
    while left:
        chunk = stream.read(left)
        if not chunk:
            return None
        chunks.append(chunk)
        left -= len(chunk)
    return b"".join(chunks)


def _read_frame(stream) -> tuple[bytes, bytes] | None:
    head = _read_exact(stream, _HEADER.size)
    if head is None:
        return None
    kind, n = _HEADER.unpack(head)
    body = _read_exact(stream, n) if n else b""
    return None if body is None else (kind, body)


class Duration:
    """The state's time, as pylibfranka's ``Duration`` answers it (``to_sec()``)."""

    __slots__ = ("_s",)

    def __init__(self, seconds: float) -> None:
        self._s = seconds

    def to_sec(self) -> float:
        return self._s


class ProcessState:
    """The fields of pylibfranka's ``RobotState`` the ``franka`` link reads, as the child read
    them."""

    __slots__ = ("F_x_Cload", "I_load", "dq", "m_load", "q", "tau_J", "time")

    def __init__(self, values: tuple[float, ...]) -> None:
        self.time = Duration(values[0])
        self.q = list(values[1:8])
        self.dq = list(values[8:15])
        self.tau_J = list(values[15:22])
        self.m_load = values[22]
        self.F_x_Cload = list(values[23:26])
        self.I_load = list(values[26:35])


class RobotProcess:
    """A ``pylibfranka.Robot`` at ``address`` in a child process (see the module docstring).

    Args:
        address: the robot's IP address.
        api: the pylibfranka module (its exception classes are raised here).
        realtime: ``RealtimeConfig.kEnforce`` (else ``kIgnore``: reading states needs no
            real-time kernel).
        connect_timeout: longest wait for the connection, s.

    Raises:
        what ``pylibfranka.Robot(address, ...)`` raised in the child (as ``api``'s class of
        that name), or ``api.NetworkException`` when the child neither connected nor failed
        within ``connect_timeout``.
    """

    def __init__(self, address: str, api, *, realtime: bool = False,
                 connect_timeout: float = CONNECT_TIMEOUT_S) -> None:
        self.api = api
        self.address = address
        root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join(p for p in (root, env.get("PYTHONPATH")) if p)
        cmd = [sys.executable, "-m", "firmware_bridge.franka_process", address]
        if realtime:
            cmd.append("--realtime")
        self._proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                      bufsize=0, env=env)
        self.pid = self._proc.pid
        self._write_lock = threading.Lock()
        self._items: queue.Queue = queue.Queue()  # states and read errors, in order
        self._outcomes: dict[int, list] = {}  # seq -> [Event, error or None]
        self._outcomes_lock = threading.Lock()
        self._seq = 0
        self._ended: BaseException | None = None
        self._connected = threading.Event()
        self._connect_error: BaseException | None = None
        self._demux = threading.Thread(target=self._read_child, name="franka-process",
                                       daemon=True)
        self._demux.start()
        if not self._connected.wait(connect_timeout):
            self.close()
            raise api.NetworkException(f"the robot process for {address!r} neither connected "
                                       f"nor failed within {connect_timeout:g} s")
        if self._connect_error is not None:
            self.close()
            raise self._connect_error

    # -- the child's output ----------------------------------------------------------------
    def _error(self, body: bytes) -> BaseException:
        name, _, message = body.decode("utf-8", "replace").partition("\0")
        cls = getattr(self.api, name, None)
        if isinstance(cls, type) and issubclass(cls, Exception):
            return cls(message)
        return RuntimeError(f"{name}: {message}")

    def _read_child(self) -> None:
        stream = self._proc.stdout
        while True:
            frame = _read_frame(stream)
            if frame is None:
                break
            kind, body = frame
            if kind == STATE:
                self._items.put(ProcessState(_STATE.unpack(body)))
            elif kind == READ_ERROR:
                self._items.put(self._error(body))
            elif kind == OUTCOME:
                (seq,) = _SEQ.unpack_from(body)
                rest = body[_SEQ.size:]
                with self._outcomes_lock:
                    waiting = self._outcomes.get(seq)
                if waiting is not None:
                    waiting[1] = self._error(rest) if rest else None
                    waiting[0].set()
            elif kind == CONNECTED:
                self._connected.set()
            elif kind == CONNECT_FAILED:
                self._connect_error = self._error(body)
                self._connected.set()
        code = self._proc.wait()
        ended = self.api.NetworkException(f"the robot process for {self.address!r} ended "
                                          f"(exit code {code})")
        self._ended = ended
        self._connected.set()
        self._items.put(ended)
        with self._outcomes_lock:
            for waiting in self._outcomes.values():
                if not waiting[0].is_set():
                    waiting[1] = ended
                    waiting[0].set()

    # -- the robot's calls -----------------------------------------------------------------
    def read_once(self) -> ProcessState:
        """The robot's next state (blocks until it comes, as pylibfranka's does)."""
        item = self._items.get() if self._ended is None else self._ended_item()
        if isinstance(item, BaseException):
            raise item
        return item

    def _ended_item(self):
        try:
            return self._items.get_nowait()
        except queue.Empty:
            return self._ended

    def set_load(self, load_mass: float, F_x_Cload, load_inertia) -> None:
        """The robot's ``set_load`` (returns when the robot answered; raises its error)."""
        com, inertia = [float(v) for v in F_x_Cload], [float(v) for v in load_inertia]
        if len(com) != 3 or len(inertia) != 9:
            raise ValueError(f"set_load takes a CoM of 3 and an inertia of 9 values, got "
                             f"{len(com)} and {len(inertia)}")
        waiting = [threading.Event(), None]
        with self._outcomes_lock:
            self._seq = self._seq % 0xFFFFFFFF + 1
            seq = self._seq
            self._outcomes[seq] = waiting
        try:
            if self._ended is not None:
                raise self._ended
            self._send(SET_LOAD, _LOAD.pack(seq, float(load_mass), *com, *inertia))
            waiting[0].wait()
        finally:
            with self._outcomes_lock:
                self._outcomes.pop(seq, None)
        if waiting[1] is not None:
            raise waiting[1]

    def _send(self, kind: bytes, body: bytes = b"") -> None:
        try:
            with self._write_lock:
                self._proc.stdin.write(_HEADER.pack(kind, len(body)) + body)
        except (BrokenPipeError, OSError, ValueError) as exc:
            raise self.api.NetworkException(f"the robot process for {self.address!r} is "
                                            f"gone ({exc})") from None

    # -- life ------------------------------------------------------------------------------
    def close(self) -> None:
        """End the child process (its connection closes with it)."""
        proc = self._proc
        if proc.poll() is None:
            try:
                self._send(QUIT)
                proc.stdin.close()
            except Exception:  # already gone: terminated below if not
                pass
            try:
                proc.wait(CLOSE_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                proc.terminate()
                try:
                    proc.wait(CLOSE_TIMEOUT_S)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait()
        for stream in (proc.stdin, proc.stdout):
            with contextlib.suppress(Exception):  # closed already
                stream.close()


# -- the child ---------------------------------------------------------------------------------
def _end_with_parent() -> None:
    """Linux: have the kernel end this process when the thread that started it ends (a parent
    killed while pylibfranka connects or waits holds no pipe this process would notice)."""
    import ctypes
    import signal

    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL(None, use_errno=True).prctl(1, int(signal.SIGTERM))  # PR_SET_PDEATHSIG
    if os.getppid() == 1:  # the parent ended before the request
        os._exit(0)


def _child(argv: list[str]) -> int:
    if not argv or argv[0].startswith("-"):
        sys.stderr.write("usage: python -m firmware_bridge.franka_process ADDRESS "
                         "[--realtime]\n")
        return 2
    address, realtime = argv[0], "--realtime" in argv[1:]
    sys.setswitchinterval(CHILD_SWITCH_INTERVAL_S)
    _end_with_parent()
    out = sys.stdout.buffer
    lock = threading.Lock()

    def emit(kind: bytes, body: bytes = b"") -> None:
        with lock:
            out.write(_HEADER.pack(kind, len(body)) + body)
            out.flush()

    holder: list = []  # the robot, once connected

    def commands() -> None:
        stream = sys.stdin.buffer
        while True:
            frame = _read_frame(stream)
            if frame is None or frame[0] == QUIT:
                os._exit(0)  # the parent is gone or done; the reader may be inside read_once
            if frame[0] != SET_LOAD:
                continue
            seq, mass, *values = _LOAD.unpack(frame[1])
            try:
                if not holder:
                    raise ConnectionError("not connected to the robot yet")
                holder[0].set_load(mass, values[:3], values[3:])
                error = b""
            except Exception as exc:  # its class and words go to the parent
                error = _error_body(exc)
            try:
                emit(OUTCOME, _SEQ.pack(seq) + error)
            except OSError:
                os._exit(0)

    # listening from the start: a parent that ends while the robot is being connected ends
    # this process too
    threading.Thread(target=commands, name="commands", daemon=True).start()
    import pylibfranka

    config = pylibfranka.RealtimeConfig.kEnforce if realtime else \
        pylibfranka.RealtimeConfig.kIgnore
    try:
        robot = pylibfranka.Robot(address, config)
    except Exception as exc:  # its class and words go to the parent
        emit(CONNECT_FAILED, _error_body(exc))
        return 1
    holder.append(robot)
    emit(CONNECTED)
    try:
        while True:
            try:
                s = robot.read_once()
            except pylibfranka.NetworkException as exc:
                emit(READ_ERROR, _error_body(exc))
                return 0  # the robot is unusable now: the parent connects anew
            except Exception as exc:  # its class and words go to the parent
                emit(READ_ERROR, _error_body(exc))
                time.sleep(RETRY_AFTER_ERROR_S)
                continue
            emit(STATE, pack_state(s.time.to_sec(), s.q, s.dq, s.tau_J, s.m_load,
                                   s.F_x_Cload, s.I_load))
    except OSError:  # the parent is gone
        return 0


if __name__ == "__main__":
    sys.exit(_child(sys.argv[1:]))
