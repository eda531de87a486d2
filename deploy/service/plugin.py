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
  robot's 1 kHz loop: they append the state to a deque and return (a microsecond or two); the
  service estimates in a thread of its own.
- :meth:`PayloadPlugin.apply` is called between motions (the robot refuses ``setLoad`` while
  one runs): it writes the load the gate let through, with the robot's ``set_load``, in the
  caller's thread, and returns its acknowledgement (the load in force read from the robot's
  state after the command), or None when the gate has nothing to write.
- :meth:`PayloadPlugin.reading` gives the newest estimate, its 2-sigma band and the gate's
  verdict.

The configuration is a ``cell.toml`` (or a :class:`deploy.config.CellConfig`) whose
``[link]`` kind is ``"program"``. franky and pylibfranka cannot be
imported into one process (both register libfranka's types with pybind11); the plug-in imports
neither.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass

import numpy as np

from iem.payload import Payload

CATCH_UP_POLL_S = 0.002
CATCH_UP_S = 0.05
"""After the fed states are read, how long :meth:`PayloadPlugin.apply` gives the service for
the last block point and the gate's decision on it (its decision period), s."""
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


class PayloadPlugin:
    """The plug-in in a franky or pylibfranka program (see the module docstring).

    Args:
        robot: the program's ``franky.Robot`` or ``pylibfranka.Robot``.
        config: the cell configuration: a ``cell.toml`` path or a
            :class:`deploy.config.CellConfig`.
        read_state: how to read one state from ``robot`` between motions (None: by the
            robot's library, :data:`READ_STATE`).
        model: the estimator to use (None: the configuration's model file).
    """

    def __init__(self, robot, config, *, read_state=None, model=None) -> None:
        from deploy.config import ConfigError, load_config
        from firmware_bridge.program_link import ProgramLink

        from .loop import Service

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
        self.link = ProgramLink(robot, read_state, silence_timeout=cfg.link.silence_timeout_s)
        self.service = Service(cfg, link=self.link, model=model)
        self._last = None
        self._lock = threading.Lock()
        self.service.on_cycle.append(self._keep)
        self.service.open()
        self.summary: dict | None = None
        self._thread = threading.Thread(target=self._run, name="iem-plugin", daemon=True)
        self._thread.start()

    # -- the robot's loop --------------------------------------------------------------------
    def feed(self, robot_state) -> None:
        """One ``RobotState`` from the robot's loop (appended; estimated in another thread)."""
        self.link.feed(robot_state)

    def callback(self, robot_state, *_) -> None:
        """franky's motion callback (``robot_state, time_step, rel_time, abs_time,
        control_signal``): :meth:`feed`."""
        self.link.feed(robot_state)

    # -- between motions ---------------------------------------------------------------------
    def apply(self, timeout: float = 1.0):
        """Write the load the gate let through with the robot's ``set_load`` (call it between
        motions); the :class:`firmware_bridge.protocol.LoadAck` (applied or refused, and the
        load the robot reports after it), or None when the gate has nothing to write.

        It first lets the service estimate what the motion fed and has not been estimated
        yet (the service may lag behind the robot's loop), for at most half of ``timeout``
        s, so the load written is judged on the whole motion."""
        deadline = time.monotonic() + 0.5 * timeout
        while self.link.backlog and time.monotonic() < deadline:
            time.sleep(CATCH_UP_POLL_S)
        if time.monotonic() < deadline:
            time.sleep(min(CATCH_UP_S, deadline - time.monotonic()))  # its last decision
        return self.link.apply(0.5 * timeout)

    def reading(self) -> Reading:
        """The newest estimate, its band, the load in force and the gate's verdict."""
        with self._lock:
            last = self._last
        report = self.link.load_report
        verdict = dict(self.service.gate.verdict())
        if last is None:
            return Reading(None, None, None, None, None if report is None else report.load,
                           verdict)
        t, smoothed, std = last
        payload = None
        if smoothed[0] > 0.0:
            payload = Payload.from_phi(smoothed, name="estimate")
        mass_band = com_band = None
        if std is not None:
            mass_band = (float(smoothed[0] - 2 * std[0]), float(smoothed[0] + 2 * std[0]))
            if smoothed[0] > 0.0:
                com_band = tuple(float(2 * s / smoothed[0]) for s in std[1:4])
        return Reading(t, payload, mass_band, com_band,
                       None if report is None else report.load, verdict)

    # -- life --------------------------------------------------------------------------------
    def _keep(self, record) -> None:
        std = getattr(record.raw, "std", None)
        with self._lock:
            self._last = (float(record.state.t), np.array(record.smoothed, dtype=float),
                          None if std is None else np.array(std, dtype=float))

    def _run(self) -> None:
        self.summary = self.service.run()

    def close(self) -> dict | None:
        """Stop estimating, save the model (its checkpoint) and return the run's summary."""
        self.service.stop()
        self._thread.join()
        self.service.close()
        return self.summary

    def __enter__(self) -> PayloadPlugin:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
