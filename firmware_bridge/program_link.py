"""The ``program`` link: the plug-in inside a user's own franky or pylibfranka program.

The user's program owns the robot: it runs the motions, and the robot's 1 kHz loop calls the
program's callback with each ``RobotState``. This link is the plug-in's side of that:

- Source: :meth:`ProgramLink.feed` is what the callback calls. It runs in the robot's loop,
  so it only appends the state object to a bounded deque (about a microsecond; no
  conversion, no lock, no wake-up of another thread); ``read`` (the service's reader thread)
  takes the states out and converts them: ``q``, ``dq``, ``tau_J``, ``t =
  state.time.to_sec()`` and ``cycle = round(t * 1000)``, as the ``franka`` link does.
  franky's and pylibfranka's ``RobotState`` have the same names for these (franky gives
  numpy arrays, pylibfranka lists); both are read the same way. A state fed while the deque
  is full is dropped and counted (``overflow``): the estimator has fallen a whole
  :data:`~firmware_bridge.links.BUFFERED_CYCLES` behind.
- Between motions nothing is fed: ``read`` then waits out its timeout and raises
  ``ControllerSilent``, as any link does when its controller is quiet; the service holds its
  writes until the next motion feeds states again.
- Sink: the user's robot belongs to the user's program, and the plug-in never calls it from
  a thread of its own. ``send`` keeps the command as the one to apply, and answers at once:
  while the program is feeding states (a motion runs) with a refusal (``applied=False``,
  :data:`MOVING`), as the robot itself refuses ``setLoad`` during a motion; the gate backs
  off and tries again, and a newer command replaces the kept one. Between motions the kept
  command is applied in three steps: :meth:`ProgramLink.take` takes it;
  :func:`write_load` calls the robot's ``set_load(mass, F_x_Cload, I_load)`` with it, in
  the program's thread, then reads the robot's state (``read_state``) until it reports the
  commanded load (:data:`firmware_bridge.franka_link.SETTLE_STATES` states at most);
  :meth:`ProgramLink.settle` acknowledges the command with that load: applied, or refused
  with the robot's error text. :class:`deploy.service.PayloadPlugin` takes and settles in
  the service's process (:mod:`deploy.service.plugin_process`) and writes in the program's;
  :meth:`ProgramLink.apply` does the three in one process.
- The load in force: every fed state reports it (``m_load``, ``F_x_Cload``, ``I_load``), and
  ``load_report`` is the last one's, as on the ``franka`` link.
"""

from __future__ import annotations

import time
from collections import deque

import numpy as np

from iem.payload import Payload, set_load_values
from iem.types import NOMINAL_RATE_HZ, JointState

from .errors import AckTimeout, BridgeConfigError, ControllerSilent
from .franka_link import SETTLE_STATES, load_matches, reported_load
from .links import BUFFERED_CYCLES, LinkCounters
from .messages import LoadAck, LoadReport
from .reassembly import CYCLE_MOD, Sequencer

MOVING = ("the arm is moving: the robot takes a load only between motions; the program "
          "applies it then (PayloadPlugin.apply)")
"""The refusal a command sent while the program feeds states gets."""
POLL_S = 0.001
"""How often ``read`` looks for a fed state while it waits, s."""


def write_load(robot, read_state, args, timeout: float) -> tuple[bool, str, tuple | None]:
    """``robot.set_load(*args)`` and the robot's state read after it: ``(applied, error
    text, the load it reports then)`` (:func:`load_values`; None: none read). Applied: the
    state read until it reports ``args`` (:data:`SETTLE_STATES` reads at most, within
    ``timeout`` s); refused: the robot's words and the first state after."""
    try:
        robot.set_load(*args)
    except Exception as exc:  # the robot's refusal, in its own words
        state = _read_after(robot, read_state, args, settle=False, timeout=timeout)
        return False, f"{type(exc).__name__}: {exc}", \
            None if state is None else load_values(state)
    state = _read_after(robot, read_state, args, settle=True, timeout=timeout)
    return True, "", None if state is None else load_values(state)


def _read_after(robot, read_state, args, settle: bool, timeout: float):
    """The robot's state read after the command: the first that reports ``args`` (at most
    :data:`SETTLE_STATES` reads), or the first read at all (``settle`` False)."""
    deadline = time.perf_counter() + timeout
    state = None
    for _ in range(SETTLE_STATES):
        state = read_state(robot)
        if not settle or load_matches(load_values(state), args) \
                or time.perf_counter() > deadline:
            break
    return state


def load_values(state) -> tuple[float, tuple, tuple]:
    """``(m_load, F_x_Cload, I_load)`` of a franky or pylibfranka ``RobotState`` (I_load
    column-major: franky gives the 3x3 matrix, pylibfranka the 9 values)."""
    return (float(state.m_load), tuple(np.asarray(state.F_x_Cload, dtype=float).ravel()),
            tuple(np.asarray(state.I_load, dtype=float).ravel(order="F")))


class ProgramLink:
    """Source and sink inside a user's program (see the module docstring).

    Args:
        robot: the user's ``franky.Robot`` or ``pylibfranka.Robot`` (its ``set_load`` is
            called by :meth:`apply` only); None where the program writes the load itself
            (:func:`write_load`, in another process).
        read_state: reads one ``RobotState`` from ``robot`` between motions (franky:
            ``robot.state``; pylibfranka: ``robot.read_once()``); None with ``robot``.
        name: how the link names itself in messages.
        silence_timeout: default ``read`` timeout, s.
        capacity: states the deque holds for the estimator.
    """

    def __init__(self, robot, read_state, *, name: str = "the program's robot",
                 silence_timeout: float = 0.1, capacity: int = BUFFERED_CYCLES) -> None:
        self.robot = robot
        self.read_state = read_state
        self.name = name
        self.rate_hz = NOMINAL_RATE_HZ
        self.silence_timeout = float(silence_timeout)
        self.counters = LinkCounters()
        self.last_frame_time = 0.0
        self.last_ack: LoadAck | None = None
        self.acks: dict[int, LoadAck] = {}
        self.last_heartbeat = None
        self._fed: deque = deque()
        self._capacity = int(capacity)
        self._order = Sequencer(self.counters, jump_limit=CYCLE_MOD)
        self._load_key: tuple | None = None
        self._load: Payload | None = None
        self._load_t: float | None = None
        self._report: LoadReport | None = None
        self._kept: tuple[int, tuple] | None = None  # (seq, set_load args) to apply
        self._seq = 0
        self._moving = False

    # -- the program's side -----------------------------------------------------------------
    def feed(self, state) -> None:
        """Take one ``RobotState`` (the motion's callback calls this at 1 kHz)."""
        fed = self._fed
        if len(fed) >= self._capacity:
            self.counters.overflow += 1
            return
        fed.append((state, time.time()))
        self._moving = True

    @property
    def backlog(self) -> int:
        """States fed and not yet read by the estimator."""
        return len(self._fed)

    def apply(self, timeout: float = 1.0) -> LoadAck | None:
        """Between motions: the kept command to the robot's ``set_load`` (see the module
        docstring); its acknowledgement, or None when no command waits."""
        kept = self.take()
        if kept is None:
            return None
        seq, args = kept
        return self.settle(seq, *write_load(self.robot, self.read_state, args, timeout))

    def take(self) -> tuple[int, tuple] | None:
        """Between motions: the kept command, taken (``(sequence, set_load's arguments)``, or
        None when none waits); the program no longer feeds a motion."""
        self._moving = False
        kept, self._kept = self._kept, None
        return kept

    def settle(self, seq: int, applied: bool, error: str,
               values: tuple | None) -> LoadAck:
        """The robot's answer to the taken command ``seq`` (:func:`write_load`'s): its
        acknowledgement, with the load the robot reported after it (``values``, as
        :func:`load_values` gives them; None: none read)."""
        return self._ack(seq, applied, error, values)

    # -- source ----------------------------------------------------------------------------
    def _take_load(self, state) -> None:
        key = load_values(state)
        if key != self._load_key:
            self._load_key = key
            self._load = reported_load(key)
        self._load_t = time.perf_counter()

    def read(self, timeout: float | None = None) -> JointState:
        """The next fed state; ``ControllerSilent`` after ``timeout`` s without one."""
        timeout = self.silence_timeout if timeout is None else float(timeout)
        deadline = time.perf_counter() + timeout
        while True:
            try:
                state, received = self._fed.popleft()
            except IndexError:
                if time.perf_counter() >= deadline:
                    self.counters.silences += 1
                    raise ControllerSilent(f"{self.name}: no robot state fed for "
                                           f"{timeout * 1e3:.0f} ms (between motions?); "
                                           f"{self.counters.summary()}") from None
                time.sleep(POLL_S)
                continue
            self.counters.received += 1
            self._take_load(state)
            t = float(state.time.to_sec())
            cycle = round(t * NOMINAL_RATE_HZ) % CYCLE_MOD
            verdict = self._order.judge(cycle)
            if verdict != "deliver":
                setattr(self.counters, verdict, getattr(self.counters, verdict) + 1)
                continue
            self._order.deliver(cycle)
            self.last_frame_time = received
            return JointState(t=t, q=np.asarray(state.q, dtype=float).ravel(),
                              dq=np.asarray(state.dq, dtype=float).ravel(),
                              tau_J=np.asarray(state.tau_J, dtype=float).ravel(), cycle=cycle)

    # -- sink ------------------------------------------------------------------------------
    @property
    def load_report(self) -> LoadReport | None:
        """The load in force as the last fed state reports it, or None before one."""
        t = self._load_t
        if t is None:
            return None
        report = self._report
        if report is None or report.t != t:
            report = self._report = LoadReport(t=t, seq=None, load=self._load,
                                               has_values=True)
        return report

    def send(self, payload: Payload | None) -> int:
        """Keep ``payload`` (None: the empty load) as the load to apply between motions;
        refused at once while a motion feeds states."""
        if payload is not None:
            payload.check()
        self._seq = self._seq % 255 + 1
        self.acks.pop(self._seq, None)
        self._kept = (self._seq, set_load_values(payload))
        if self._moving:
            self._ack(self._seq, False, MOVING, None)
        return self._seq

    def _ack(self, seq: int, applied: bool, error: str, values) -> LoadAck:
        load = self._load
        if values is not None:
            load = reported_load(values)
        ack = LoadAck(seq=seq, applied=applied, load=load, t=time.perf_counter(),
                      error=error)
        self.last_ack = self.acks[seq] = ack
        self.counters.acks += 1
        return ack

    def wait_ack(self, seq: int, timeout: float = 1.0) -> LoadAck:
        """The acknowledgement of ``seq`` (it comes from :meth:`apply`); ``AckTimeout``
        after ``timeout`` s."""
        deadline = time.perf_counter() + float(timeout)
        while seq not in self.acks:
            if time.perf_counter() >= deadline:
                raise AckTimeout(f"{self.name}: no acknowledgement of payload command {seq} "
                                 f"within {timeout:g} s (applied between motions)")
            time.sleep(POLL_S)
        return self.acks[seq]

    def close(self) -> None:
        self._fed.clear()


def open_program_link(kind: str, channel: str, *, profile: str = "fd",
                      silence_timeout: float = 0.1) -> ProgramLink:
    """Opener for :func:`firmware_bridge.links.open_link`: a program link cannot be opened
    from a configuration; the program makes it (:class:`deploy.service.PayloadPlugin`)."""
    raise BridgeConfigError("[link] kind 'program' is the plug-in inside your own franky or "
                            "pylibfranka program: create it there with "
                            "deploy.service.PayloadPlugin(robot, config); 'iem run' cannot "
                            "open it (for the robot itself use kind 'franka')")
