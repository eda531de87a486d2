"""The plug-in inside your own robot program: :class:`PayloadPlugin`.

For a program written with franky-control or pylibfranka that moves a Franka Research 3 and
wants the payload identified on the way, with the same service ``iem run`` runs (the
estimator, the safety gate and the load state of :class:`deploy.service.Service`, one of
each), on the ``program`` link (:mod:`firmware_bridge.program_link`)::

    from deploy.service import PayloadPlugin

    plugin = PayloadPlugin(robot, "cell.toml")     # loads the model, starts estimating
    motion.register_callback(plugin.callback)       # franky: every state of the motion
    robot.move(motion)
    plugin.apply()                                  # between motions: the load to the robot
    print(plugin.reading())                         # the estimate, its band, the verdict
    plugin.close()

- :meth:`PayloadPlugin.callback` (franky's callback signature) and :meth:`PayloadPlugin.feed`
  (one ``RobotState``: a pylibfranka control callback or ``read_once`` loop) run in the
  robot's 1 kHz loop: they append the state to a deque and return (a microsecond or two). A
  writer thread hands the states to the service's process every :data:`WRITE_PERIOD_S`
  (:mod:`deploy.service.plugin_process`), where the service estimates: the robot's loop
  needs the program's interpreter lock to call the callback, and a service estimating in a
  thread of the program held that lock when the loop needed it.
- :meth:`PayloadPlugin.apply` is called between motions (the robot refuses ``setLoad`` while
  one runs): it writes the load the gate let through, with the robot's ``set_load``, in the
  caller's thread, and returns its acknowledgement (the load in force read from the robot's
  state after the command), or None when the gate has nothing to write.
- :meth:`PayloadPlugin.reading` gives the newest estimate, its 2-sigma band and the gate's
  verdict.

The configuration is a ``cell.toml`` (or a :class:`deploy.config.CellConfig`) whose
``[link]`` kind is ``"program"``; it and ``model`` are handed to the service's process,
whose log goes to the program's standard error. franky and pylibfranka cannot be
imported into one process (both register libfranka's types with pybind11); the plug-in imports
neither.
"""

from __future__ import annotations

import contextlib
import os
import pickle
import struct
import subprocess
import sys
import threading
from collections import deque
from dataclasses import dataclass

import numpy as np

from firmware_bridge.franka_process import _HEADER, _STATE, _read_frame, pack_state
from firmware_bridge.links import BUFFERED_CYCLES
from iem.payload import Payload

# the frames between the program and the service's process (deploy.service.plugin_process)
START, TAKE, SETTLE, READING, CLOSE = b"s", b"t", b"d", b"r", b"q"
"""Program -> service's process, on its standard input."""
READY, FAILED, REPLY = b"R", b"F", b"P"
"""Service's process -> program, on its standard output: the service runs; it could not start
(the exception); the answer to a command."""
STATE = b"S"
"""A state on the states pipe."""
TAKE_BODY = struct.Struct("<Qd")  # states written by the program, the wait for them (s)


def state_frame(state) -> bytes:
    """A franky or pylibfranka ``RobotState`` as a frame of the states pipe
    (:func:`firmware_bridge.franka_process.pack_state`; franky's ``I_load`` is a 3x3
    matrix, pylibfranka's the 9 values, both taken column-major)."""
    def flat(v, order="C"):
        return np.asarray(v, dtype=float).ravel(order=order)

    return _HEADER.pack(STATE, _STATE.size) + pack_state(
        state.time.to_sec(), flat(state.q), flat(state.dq), flat(state.tau_J),
        float(state.m_load), flat(state.F_x_Cload), flat(state.I_load, "F"))


WRITE_PERIOD_S = 0.005
"""How often the writer thread hands the fed states to the service's process, s: a few
writes of several states each, rather than one wake-up of that process per state."""
CLOSE_TIMEOUT_S = 30.0
"""How long :meth:`PayloadPlugin.close` waits for the service's process to save its model and
end before it is killed, s."""
READ_STATE = {
    "franky": lambda robot: robot.state,
    "pylibfranka": lambda robot: robot.read_once(),
}
"""How a robot of each library gives one ``RobotState`` between motions, by the top-level
module of the robot's class."""


@dataclass(frozen=True)
class Reading:
    """What the plug-in knows now.

    Attributes:
        t: the robot's time of the newest estimate, s (None: no estimate yet).
        payload: the smoothed estimate as a payload (mass kg, CoM m in the flange frame,
            inertia kg·m² about the CoM), or None (no estimate yet, or a mass <= 0).
        mass_band_kg: the 2-sigma band of the mass, ``(low, high)`` (None: not reported).
        com_band_m: the 2-sigma half-width of each CoM component, m (None: not reported).
        load_in_force: the load the robot holds, as its states report it (None: empty).
        verdict: the safety gate's verdict (``deploy.gate.SafetyGate.verdict``): at least
            ``reason`` and ``detail``.
    """

    t: float | None
    payload: Payload | None
    mass_band_kg: tuple[float, float] | None
    com_band_m: tuple[float, float, float] | None
    load_in_force: Payload | None
    verdict: dict


class Latest:
    """The newest estimate of the service (an ``on_cycle`` observer), and the
    :class:`Reading` it makes with the load in force and the gate's verdict."""

    def __init__(self) -> None:
        self._last = None
        self._lock = threading.Lock()

    def __call__(self, record) -> None:
        std = getattr(record.raw, "std", None)
        with self._lock:
            self._last = (float(record.state.t), np.array(record.smoothed, dtype=float),
                          None if std is None else np.array(std, dtype=float))

    def reading(self, report, verdict: dict) -> Reading:
        """The :class:`Reading` with ``report`` (the link's load report, or None) and the
        gate's ``verdict``."""
        with self._lock:
            last = self._last
        in_force = None if report is None else report.load
        if last is None:
            return Reading(None, None, None, None, in_force, dict(verdict))
        t, smoothed, std = last
        payload = None
        if smoothed[0] > 0.0:
            payload = Payload.from_phi(smoothed, name="estimate")
        mass_band = com_band = None
        if std is not None:
            mass_band = (float(smoothed[0] - 2 * std[0]), float(smoothed[0] + 2 * std[0]))
            if smoothed[0] > 0.0:
                com_band = tuple(float(2 * s / smoothed[0]) for s in std[1:4])
        return Reading(t, payload, mass_band, com_band, in_force, dict(verdict))


class PayloadPlugin:
    """The plug-in in a franky or pylibfranka program (see the module docstring).

    Args:
        robot: the program's ``franky.Robot`` or ``pylibfranka.Robot``.
        config: the cell configuration: a ``cell.toml`` path or a
            :class:`deploy.config.CellConfig`.
        read_state: how to read one state from ``robot`` between motions (None: by the
            robot's library, :data:`READ_STATE`).
        model: the estimator to use (None: the configuration's model file).
        record_to: a JSON file the service writes at :meth:`close`: every block point's
            time, smoothed mass and first moment, their standard deviations (``rows``) and
            the reason of the gate's latest decision then (``reasons``); None: none.
    """

    def __init__(self, robot, config, *, read_state=None, model=None,
                 record_to=None) -> None:
        from deploy.config import ConfigError, load_config

        cfg = load_config(config) if isinstance(config, str | bytes) or hasattr(
            config, "__fspath__") else config
        if cfg.link.kind != "program":
            raise ConfigError(f"{cfg.source}: [link] kind = {cfg.link.kind!r}; the plug-in "
                              "inside a program needs kind = \"program\" (it also makes the "
                              "arm model the FR3's, which libfranka serves)")
        if read_state is None:
            library = type(robot).__module__.split(".")[0]
            if library not in READ_STATE:
                raise TypeError(f"PayloadPlugin: a robot of {type(robot).__module__}."
                                f"{type(robot).__name__}; valid are a franky.Robot or a "
                                "pylibfranka.Robot, or give read_state=")
            read_state = READ_STATE[library]
        self.robot, self.read_state = robot, read_state
        self.summary: dict | None = None
        self.written = 0
        """States written to the service's process."""
        # the states dropped, each count by one thread only (a += from two threads can lose
        # one): the robot's loop (feed) and the writer (under its lock)
        self._dropped_fed = self._dropped_written = 0
        self._lock = threading.Lock()  # one command at a time
        self._closed = False
        self._fed: deque = deque()
        self._write_lock = threading.Lock()
        self._stop = threading.Event()
        self._child, self._states = _start(cfg, model, record_to)
        self._thread = threading.Thread(target=self._writer, name="iem-plugin-writer",
                                        daemon=True)
        self._thread.start()

    # -- the robot's loop --------------------------------------------------------------------
    def feed(self, robot_state) -> None:
        """One ``RobotState`` from the robot's loop: appended for the writer thread, never
        waited for (beyond :data:`~firmware_bridge.links.BUFFERED_CYCLES` states waiting, it
        is dropped and counted in :attr:`dropped`)."""
        fed = self._fed
        if len(fed) >= BUFFERED_CYCLES:
            self._dropped_fed += 1
            return
        fed.append(robot_state)

    @property
    def dropped(self) -> int:
        """States fed and never handed to the service: fed while
        :data:`~firmware_bridge.links.BUFFERED_CYCLES` states waited for the writer (the
        service's process that far behind, its pipe full), or after its process ended."""
        return self._dropped_fed + self._dropped_written

    def _write(self) -> None:
        """The states fed so far, to the service's process (one write; it waits while the
        pipe is full, the callback never does)."""
        with self._write_lock:
            fed, frames = self._fed, []
            while fed:
                frames.append(state_frame(fed.popleft()))
            if frames:
                try:
                    os.write(self._states, b"".join(frames))
                except OSError:  # the service's process is gone
                    self._dropped_written += len(frames)
                    return
                self.written += len(frames)

    def _writer(self) -> None:
        while not self._stop.wait(WRITE_PERIOD_S):
            self._write()

    def callback(self, robot_state, *_) -> None:
        """franky's motion callback (``robot_state, time_step, rel_time, abs_time,
        control_signal``): :meth:`feed`."""
        self.feed(robot_state)

    # -- between motions ---------------------------------------------------------------------
    def apply(self, timeout: float = 1.0):
        """Write the load the gate let through with the robot's ``set_load`` (call it between
        motions); the :class:`firmware_bridge.protocol.LoadAck` (applied or refused, and the
        load the robot reports after it), or None when the gate has nothing to write.

        It first lets the service estimate what the motion fed and has not been estimated
        yet (the service may lag behind the robot's loop), for at most half of ``timeout``
        s, so the load written is judged on the whole motion."""
        from firmware_bridge.program_link import write_load

        self._write()
        kept = self._call(TAKE, TAKE_BODY.pack(self.written, 0.5 * timeout))
        if kept is None:
            return None
        seq, args = kept
        answer = write_load(self.robot, self.read_state, args, 0.5 * timeout)
        return self._call(SETTLE, pickle.dumps((seq, *answer)))

    def reading(self) -> Reading:
        """The newest estimate, its band, the load in force and the gate's verdict."""
        return self._call(READING)

    # -- life --------------------------------------------------------------------------------
    def _call(self, kind: bytes, body: bytes = b""):
        with self._lock:
            if self._closed:
                raise RuntimeError("PayloadPlugin: closed")
            frame = _ask(self._child, kind, body)
            if frame is None:
                raise RuntimeError(f"PayloadPlugin: the service's process ended (exit code "
                                   f"{self._child.poll()})")
            return pickle.loads(frame[1])

    def close(self) -> dict | None:
        """Stop estimating, save the model (its checkpoint) and return the run's summary."""
        if self._closed:
            return self.summary
        self._stop.set()
        self._thread.join()
        self._write()
        try:
            self.summary = self._call(CLOSE)
        finally:
            self._closed = True
            with contextlib.suppress(OSError):
                os.close(self._states)
            with contextlib.suppress(OSError):
                self._child.stdin.close()
            try:
                self._child.wait(timeout=CLOSE_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                self._child.kill()
                self._child.wait()
            self._child.stdout.close()
        return self.summary

    def __enter__(self) -> PayloadPlugin:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _ask(child: subprocess.Popen, kind: bytes, body: bytes) -> tuple[bytes, bytes] | None:
    """One command to the service's process and its answer frame ``(kind, body)``; None if
    the process is gone (its pipes closed)."""
    try:
        child.stdin.write(_HEADER.pack(kind, len(body)) + body)
        child.stdin.flush()
        return _read_frame(child.stdout)
    except OSError:
        return None


def _widen(fd: int, size: int) -> None:
    """Make the pipe ``fd`` hold ``size`` bytes, or as much as this system lets an
    unprivileged process ask for (Linux; elsewhere it keeps its default)."""
    import fcntl

    op = getattr(fcntl, "F_SETPIPE_SZ", None)
    if op is None:
        return
    try:
        with open("/proc/sys/fs/pipe-max-size", encoding="ascii") as f:
            size = min(size, int(f.read()))
    except (OSError, ValueError):
        pass
    with contextlib.suppress(OSError):
        fcntl.fcntl(fd, op, size)


def _start(config, model, record_to) -> tuple[subprocess.Popen, int]:
    """The service's process, started with ``config`` and ``model`` and running: ``(the
    process, the write end of its states pipe)``; what stopped it from starting is raised
    here."""
    read_end, write_end = os.pipe()
    try:
        child = subprocess.Popen([sys.executable, "-m", "deploy.service.plugin_process",
                                  str(read_end)], stdin=subprocess.PIPE,
                                 stdout=subprocess.PIPE, pass_fds=(read_end,))
    finally:
        os.close(read_end)
    _widen(write_end, BUFFERED_CYCLES * (_HEADER.size + _STATE.size))
    frame = _ask(child, START, pickle.dumps(
        (config, model, None if record_to is None else os.fspath(record_to))))
    if frame is None or frame[0] != READY:
        os.close(write_end)
        with contextlib.suppress(OSError):
            child.stdin.close()
        child.wait(timeout=CLOSE_TIMEOUT_S)
        child.stdout.close()
        if frame is not None and frame[0] == FAILED:
            raise pickle.loads(frame[1])
        raise RuntimeError(f"PayloadPlugin: the service's process did not start (exit code "
                           f"{child.returncode})")
    return child, write_end
