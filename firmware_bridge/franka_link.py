"""The pylibfranka backend (extra ``franka``): a Franka Research 3 as source and sink.

What it works with, stated plainly:

- **FR3 only.** pylibfranka 0.21 is built on libfranka >= 0.10, which speaks only to the
  Franka Research 3. A Panda (FER) needs libfranka < 0.10 and has no pylibfranka: serve it
  through a CAN or serial controller (``[link] kind = "socketcan"``, ``"slcan"``,
  ``"serial"``) or through ROS 2.
- **Exclusive FCI.** The Franka Control Interface gives one client control at a time.
  ``read_once`` raises ``InvalidOperationException`` while a control loop runs in this
  client, and the robot accepts one FCI client: this link does *not* read beside another
  program's libfranka control loop. It serves a cell where the plug-in is the FCI client and
  the arm moves under the robot's own programs (Desk) or is guided by hand.

How:

- The robot: a link opened by address talks to it through
  :class:`~firmware_bridge.franka_process.RobotProcess`, pylibfranka in a child process:
  ``read_once`` blocks without releasing Python's global interpreter lock, so a reader
  thread in this process would hold it most of the time and starve the estimator (and hold
  it for a whole second when the network is lost). The child reads every state; this
  process reads them from a pipe.
- Source: a reader thread calls ``Robot.read_once()`` (it blocks until the robot's next
  state) and queues each ``RobotState``; ``read(timeout)`` waits at most ``timeout`` s for the
  next one, else raises ``ControllerSilent``. The joint state is ``q``, ``dq`` and ``tau_J``
  (link-side torques), ``t = state.time.to_sec()`` and, since Franka states carry no cycle
  counter, ``cycle = round(t * 1000)`` (the robot's clock counts 1 ms cycles). Cycles skipped
  between two states count as ``lost``.
- Sink: ``send`` returns at once; a command thread calls ``Robot.set_load(load_mass,
  F_x_Cload, load_inertia)`` (positional: the binding names no arguments; CoM in the flange
  frame, inertia about the CoM column-major, exactly
  :meth:`sim.payload.Payload.set_load_args`; clearing sends mass 0). Its outcome comes back
  through ``last_ack`` as a :class:`~firmware_bridge.protocol.LoadAck`: applied, or refused
  (``applied=False``) with libfranka's error text when it raised ``CommandException`` (the
  robot refuses ``setLoad`` while a motion runs: "command not possible in the current
  mode"). libfranka waits up to 60 s for a command's reply; the link does not wait that long:
  a command that has not returned after ``load_timeout`` s (default 2 s, well below the
  unit's WatchdogSec=5) is acknowledged as refused with that reason, and its late outcome, if
  any, replaces it in ``last_ack``.
- The load an acknowledgement carries is the one the robot reports in a state *read after*
  ``set_load`` returned: a ``read_once`` begun before the command returned is not one, and
  neither is, necessarily, the first begun after it: libfranka hands over the states queued
  on its UDP socket in order, and the robot may have sent the next one before it applied the
  command (franky-sim's was the old load in 0 or 1 of them). So an applied command's
  acknowledgement waits for the first state read after it that reports the commanded load,
  for at most :data:`SETTLE_STATES` states; past them it carries what the robot reports (it
  holds another load: the load state reads the disagreement). A refusal carries the load of
  the first state read after it.
- The load in force: every robot state reports it (``m_load``, ``F_x_Cload``, ``I_load``,
  inertia about the CoM column-major; mass 0: none), and ``load_report`` is the last one's
  values (a :class:`~firmware_bridge.messages.LoadReport` without a sequence number: a
  Franka numbers no commands).
- Errors are matched by class, against the classes of the pylibfranka module that made the
  robot: ``NetworkException`` is :class:`~firmware_bridge.errors.ControllerSilent`,
  ``InvalidOperationException`` (FCI held elsewhere) and the rest are
  :class:`~firmware_bridge.errors.LinkError`.
- Reconnecting: after ``read_once`` raised ``NetworkException`` (libfranka's UDP receive
  timed out: no state for a second), the ``Robot`` is unusable (every later call raises
  "Net Exception"). A link opened by address (:meth:`FrankaLink.open`) drops it and connects
  anew every :data:`RECONNECT_S` s until it is back (``reconnects`` counts them); meanwhile
  ``read`` waits out its own timeout and raises ``ControllerSilent`` naming the last error,
  as for any silence. A link given a robot object cannot reconnect it and raises at once.

pylibfranka is imported only when a robot is opened.
"""

from __future__ import annotations

import queue
import threading
import time
from collections import deque

from iem.payload import Payload, set_load_values
from iem.types import NOMINAL_RATE_HZ, JointState

from .errors import AckTimeout, BridgeConfigError, ControllerSilent, LinkError
from .franka_process import RETRY_AFTER_ERROR_S, RobotProcess
from .links import BUFFERED_CYCLES, LinkCounters
from .messages import LoadAck, LoadReport
from .reassembly import CYCLE_MOD, Sequencer

LOAD_TIMEOUT_S = 2.0
"""Seconds a ``set_load`` may take before it is acknowledged as refused (timed out)."""
RECONNECT_S = 0.2
"""Pause between attempts to connect again after the connection was lost, s."""
SETTLE_STATES = 20
"""States read after ``set_load`` returned that an applied command's acknowledgement waits
for one reporting the commanded load, at most (20 ms of the robot's states)."""
LOAD_REL_TOL = 1e-5
"""Relative difference up to which a reported load value is the commanded one: the state
carries single-precision floats (7 significant digits; franky-sim packs them so)."""


def _franka_error(api, exc: Exception, name: str, what: str) -> LinkError:
    """The bridge's error for a pylibfranka exception, matched by class."""
    kind = type(exc).__name__
    if isinstance(exc, api.NetworkException):
        return ControllerSilent(f"{name}: {what} failed: {kind}: {exc}")
    if isinstance(exc, api.InvalidOperationException):
        return LinkError(f"{name}: {what} failed: {kind}: {exc} (the FCI gives one client "
                         "control at a time: is a libfranka control loop or another FCI client "
                         "running?)")
    return LinkError(f"{name}: {what} failed: {kind}: {exc}")


class FrankaLink:
    """Source and sink over a ``pylibfranka.Robot`` (or an object with its signatures).

    Args:
        robot: the robot.
        api: the pylibfranka module (or one with its exception classes): errors are matched
            against its ``NetworkException``, ``InvalidOperationException`` and
            ``CommandException``.
        name: how the link names itself in messages.
        silence_timeout: default ``read`` timeout, s.
        load_timeout: seconds a ``set_load`` may take before it is acknowledged as refused.
        owns_robot: drop the robot on ``close``.
    """

    def __init__(self, robot, api, *, name: str = "Franka robot", silence_timeout: float = 0.1,
                 load_timeout: float = LOAD_TIMEOUT_S, owns_robot: bool = True,
                 connect=None) -> None:
        self.robot = robot
        self.api = api
        self._connect = connect  # makes a new robot after a lost connection (None: cannot)
        self.reconnects = 0
        """Times the link connected anew after the connection was lost."""
        self.name = name
        self.rate_hz = NOMINAL_RATE_HZ
        self.silence_timeout = float(silence_timeout)
        self.load_timeout = float(load_timeout)
        self.counters = LinkCounters()
        self.last_frame_time = 0.0
        """Time (epoch s) the reader thread received the state ``read`` returned last."""
        self.last_ack: LoadAck | None = None
        self.acks: dict[int, LoadAck] = {}
        self.last_heartbeat = None
        self._order = Sequencer(self.counters, jump_limit=CYCLE_MOD)  # the robot's own clock
        self._states: queue.Queue = queue.Queue(maxsize=BUFFERED_CYCLES)
        self._ready: deque[tuple[JointState, float]] = deque()
        self._jobs: queue.Queue = queue.Queue()
        self._outcomes: queue.Queue = queue.Queue()
        self._running: tuple[int, float] | None = None  # (seq, started) of set_load in flight
        self._timed_out: set[int] = set()
        self._waiting: list[list] = []  # [seq, applied, error, reads, args, states seen]:
        # outcomes waiting for a state read after the command returned (the load it reports)
        self._reads = 0  # read_once calls begun (the reader thread counts them)
        self._lost: Exception | None = None  # the error that lost the connection
        self._load = None  # the load in the last state, as reported by the robot
        self._load_key: tuple | None = None
        self._load_t: float | None = None  # perf_counter() when that state was taken
        self._report = None
        self._seq = 0
        self._owns_robot = owns_robot
        self._stop = threading.Event()
        self._reader = threading.Thread(target=self._read_loop, name="franka-reader",
                                        daemon=True)
        self._commander = threading.Thread(target=self._command_loop, name="franka-commands",
                                           daemon=True)
        self._reader.start()
        self._commander.start()

    @classmethod
    def open(cls, address: str, *, realtime: bool = False, **options) -> FrankaLink:
        """Connect to the robot at ``address`` (pylibfranka in a child process,
        :class:`~firmware_bridge.franka_process.RobotProcess`). ``realtime=False`` passes
        ``RealtimeConfig.kIgnore``: reading states needs no real-time kernel."""
        try:
            import pylibfranka
        except ImportError as exc:
            raise BridgeConfigError("the franka link needs pylibfranka (Franka Research 3, "
                                    "libfranka >= 0.10): install the extra, pip install "
                                    "'iem-payload[franka]'") from exc
        def connect():
            return RobotProcess(address, pylibfranka, realtime=realtime)

        try:
            robot = connect()
        except Exception as exc:  # any failure to connect; the class is named in the message
            raise _franka_error(pylibfranka, exc, f"Franka robot {address!r}",
                                "connecting") from exc
        return cls(robot, pylibfranka, name=f"Franka robot {address!r}", connect=connect,
                   **options)

    # -- threads ---------------------------------------------------------------------------
    def _read_loop(self) -> None:
        while not self._stop.is_set():
            robot = self.robot
            if robot is None:
                if self._connect is None or not self._reconnect():
                    return
                continue
            self._reads += 1
            index = self._reads
            try:
                item = robot.read_once()
            except Exception as exc:  # handed to the caller's thread, mapped by class there
                item = exc.with_traceback(None)  # its frames would keep the robot (and its
                # connection, which the robot serves one client at a time) alive
            now = time.time()
            try:
                self._states.put_nowait((item, now, index))
            except queue.Full:
                self.counters.overflow += 1
            if isinstance(item, Exception):
                if self._connect is not None and isinstance(item, self.api.NetworkException):
                    self._lost = item
                    self.robot = None  # unusable now: dropped, its connection closed
                    _release(robot)
                self._stop.wait(RETRY_AFTER_ERROR_S)

    def _reconnect(self) -> bool:
        """Connect anew until it works or the link closes; False when it closed."""
        while not self._stop.is_set():
            try:
                self.robot = self._connect()
            except Exception as exc:  # the robot is not back yet; tried again
                self._lost = exc.with_traceback(None)
                self._stop.wait(RECONNECT_S)
                continue
            self.reconnects += 1
            return True
        return False

    def _command_loop(self) -> None:
        while not self._stop.is_set():
            try:
                seq, args = self._jobs.get(timeout=0.1)
            except queue.Empty:
                continue
            self._running = (seq, time.perf_counter())
            error, fatal = "", None
            try:
                self._set_load(args)
            except self.api.CommandException as exc:
                error = str(exc) or type(exc).__name__
            except (self.api.NetworkException, ConnectionError) as exc:
                error = f"{type(exc).__name__}: {exc}"
            except Exception as exc:  # anything else ends the run, from the caller's thread
                error, fatal = f"{type(exc).__name__}: {exc}", exc.with_traceback(None)
            self._running = None
            # reads begun from here on are after the command returned
            self._outcomes.put((seq, not error, error, fatal, self._reads, args))

    def _set_load(self, args) -> None:
        """``set_load`` on the robot of now; no reference to it outlives the call (a dropped
        robot must close its connection: the robot serves one client at a time)."""
        robot = self.robot
        if robot is None:
            raise ConnectionError(f"no connection to the robot ({self._lost})")
        robot.set_load(*args)

    # -- source ----------------------------------------------------------------------------
    def _joint_state(self, rs) -> JointState | None:
        self.counters.received += 1
        key = (float(rs.m_load), tuple(rs.F_x_Cload), tuple(rs.I_load))
        if key != self._load_key:  # built only when the robot reports another load
            self._load_key = key
            self._load = reported_load(key)
        self._load_t = time.perf_counter()
        t = float(rs.time.to_sec())
        cycle = round(t * NOMINAL_RATE_HZ) % CYCLE_MOD
        verdict = self._order.judge(cycle)
        if verdict != "deliver":
            setattr(self.counters, verdict, getattr(self.counters, verdict) + 1)
            return None
        self._order.deliver(cycle)
        return JointState(t=t, q=list(rs.q), dq=list(rs.dq), tau_J=list(rs.tau_J), cycle=cycle)

    def _ack(self, seq: int, applied: bool, error: str) -> None:
        ack = LoadAck(seq=seq, applied=applied, load=self._load, t=time.perf_counter(),
                      error=error)
        self.last_ack = self.acks[seq] = ack
        self.counters.acks += 1

    def _settle(self) -> None:
        """Outcomes of finished commands wait for the next state (the load it reports); a
        command running longer than ``load_timeout`` is acknowledged as refused now."""
        while True:
            try:
                seq, applied, error, fatal, done, args = self._outcomes.get_nowait()
            except queue.Empty:
                break
            if fatal is not None:
                raise _franka_error(self.api, fatal, self.name, "set_load") from fatal
            self._waiting.append([seq, applied, error, done, args, 0])
        running = self._running
        if running is not None and running[0] not in self._timed_out \
                and time.perf_counter() - running[1] > self.load_timeout:
            self._timed_out.add(running[0])
            self._ack(running[0], False, f"set_load did not return within "
                                         f"{self.load_timeout:g} s")

    def _take(self, deadline: float) -> bool:
        """Process robot states until one is ready for ``read`` or ``deadline`` passes."""
        while not self._ready:
            self._settle()
            remaining = deadline - time.perf_counter()
            if remaining <= 0:
                return False
            try:
                item, received, index = self._states.get(timeout=min(remaining, 0.05))
            except queue.Empty:
                continue
            if isinstance(item, Exception):
                if self._connect is not None and isinstance(item, self.api.NetworkException):
                    continue  # reconnecting; read's own timeout says when it is a silence
                raise _franka_error(self.api, item, self.name, "read_once") from item
            state = self._joint_state(item)
            if self._waiting:
                self._settle_waiting(index)
            if state is not None:
                self._ready.append((state, received))
        return True

    def _settle_waiting(self, index: int) -> None:
        """Acknowledge the finished commands that the state just read (``read_once`` number
        ``index``) answers: it was read after the command returned, and reports the commanded
        load or is the :data:`SETTLE_STATES`-th such state (a refusal: the first)."""
        keep = []
        for w in self._waiting:
            seq, applied, error, done, args, seen = w
            if index <= done:  # begun before the command returned
                keep.append(w)
                continue
            w[5] = seen = seen + 1
            if applied and seen < SETTLE_STATES and not load_matches(self._load_key, args):
                keep.append(w)
                continue
            self._timed_out.discard(seq)
            self._ack(seq, applied, error)
        self._waiting = keep

    def read(self, timeout: float | None = None) -> JointState:
        """The next robot state; ``ControllerSilent`` after ``timeout`` s without one."""
        timeout = self.silence_timeout if timeout is None else float(timeout)
        if not self._take(time.perf_counter() + timeout):
            self.counters.silences += 1
            lost = f"; connection lost ({self._lost}), reconnecting" \
                if self.robot is None and self._lost is not None else ""
            raise ControllerSilent(f"{self.name}: no robot state for {timeout * 1e3:.0f} ms; "
                                   f"{self.counters.summary()}{lost}")
        state, self.last_frame_time = self._ready.popleft()
        return state

    # -- sink ------------------------------------------------------------------------------
    @property
    def load_report(self) -> LoadReport | None:
        """The load in force as the last robot state reports it (``m_load``, ``F_x_Cload``,
        ``I_load``: values, no sequence number), or None before a state."""
        t = self._load_t
        if t is None:
            return None
        report = self._report
        if report is None or report.t != t:  # built when asked for, not at 1 kHz
            report = self._report = LoadReport(t=t, seq=None, load=self._load, has_values=True)
        return report

    def send(self, payload: Payload | None) -> int:
        """Queue ``set_load`` for the command thread; return the command's number at once."""
        if payload is not None:
            payload.check()
        self._seq = self._seq % 255 + 1
        self.acks.pop(self._seq, None)
        self._jobs.put((self._seq, set_load_values(payload)))
        return self._seq

    def wait_ack(self, seq: int, timeout: float = 1.0) -> LoadAck:
        """Read states (kept for ``read``) until ``seq`` is acknowledged; ``AckTimeout``
        after ``timeout`` s."""
        deadline = time.perf_counter() + float(timeout)
        while seq not in self.acks:
            if time.perf_counter() >= deadline:
                raise AckTimeout(f"{self.name}: no acknowledgement of payload command {seq} "
                                 f"within {timeout:g} s")
            self._take_one(deadline)
        return self.acks[seq]

    def _take_one(self, deadline: float) -> None:
        """Process at most one queued robot state (the state is kept for ``read``)."""
        self._settle()
        remaining = deadline - time.perf_counter()
        if remaining <= 0:
            return
        pending, self._ready = self._ready, deque()
        try:
            self._take(time.perf_counter() + min(remaining, 0.05))
        finally:
            pending.extend(self._ready)
            self._ready = pending

    # -- life ------------------------------------------------------------------------------
    def close(self) -> None:
        self._stop.set()
        for thread in (self._reader, self._commander):
            if thread is not threading.current_thread():
                thread.join(0.2)  # the reader may be inside read_once
        if self._owns_robot:
            robot, self.robot = self.robot, None  # its connection closes with it: the robot
            self._lost = None  # serves one client
            _release(robot)

    def __enter__(self) -> FrankaLink:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _release(robot) -> None:
    """End a dropped robot's connection now where it can be ended (a
    :class:`~firmware_bridge.franka_process.RobotProcess` ends its process; pylibfranka's
    ``Robot`` closes when nothing refers to it)."""
    close = getattr(robot, "close", None)
    if close is not None:
        close()


def reported_load(key) -> Payload | None:
    """The load a robot state reports, from its ``(m_load, F_x_Cload, I_load)`` (I_load's 9
    values column-major); None for the empty load (mass 0)."""
    mass, com, inertia = key
    return None if mass == 0.0 else Payload.from_set_load(mass, list(com), list(inertia),
                                                           name="robot")


def load_matches(reported, args) -> bool:
    """Whether a state's load ``reported`` (``m_load``, ``F_x_Cload``, ``I_load``; None: no
    state yet) is the commanded ``args`` (``set_load``'s mass, CoM, inertia), to the
    state's single precision (:data:`LOAD_REL_TOL`); any empty load (mass 0) is the empty
    load."""
    if reported is None:
        return False
    mass = float(args[0])
    if not _close(reported[0], mass):
        return False
    return mass == 0.0 or all(_close(a, b) for a, b in zip(
        (*reported[1], *reported[2]), (*args[1], *args[2]), strict=True))


def _close(a: float, b: float) -> bool:
    return abs(float(a) - float(b)) <= LOAD_REL_TOL * max(abs(float(b)), 1e-3)


def open_franka_link(kind: str, channel: str, *, profile: str = "fd",
                     silence_timeout: float = 0.1, realtime: bool = False,
                     load_timeout: float = LOAD_TIMEOUT_S) -> FrankaLink:
    """Opener for :func:`firmware_bridge.links.open_link`: ``channel`` is the robot's IP
    (``profile`` is a CAN notion and not used)."""
    return FrankaLink.open(channel, realtime=realtime, silence_timeout=silence_timeout,
                           load_timeout=load_timeout)
