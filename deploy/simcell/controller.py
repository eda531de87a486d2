"""The simulated controller: the MuJoCo plant at 1 kHz behind a real bus or link.

:class:`SimController` runs :class:`sim.plant.ArmPlant` cycle by cycle, tracking a
:class:`sim.paths.Path` (default :func:`sim.paths.excitation_path`): forward, then backward,
then forward again (both ends are at rest, so the turns are smooth), or once and then at
rest at its end (``once=True``). Each cycle it

1. takes the payload commands received (``port.poll_commands``), applies each with
   ``plant.set_controller_load`` if it is physically consistent, and acknowledges with the
   load now in force (a refused one keeps the previous load); the first ``drop_commands``
   are lost instead, as on a bad wire: neither applied nor acknowledged;
2. mounts the payloads ``payload_schedule`` has due (``plant.set_payload``: what the arm
   carries, not what the controller believes), steps the plant and publishes the measured
   joint state (``port.publish``);
3. sends a heartbeat every ``heartbeat_period`` s, with the sequence number of the load in
   force (``load_seq``: the last command applied; a lost or refused one leaves it).

In real time (the default) a deadline loop keeps the 1 kHz: sleep most of the interval, spin
the last ``spin_us`` µs on ``perf_counter``; a cycle that ends after its deadline counts as an
overrun, and more than ``MAX_LAG`` cycles behind the schedule restarts it from now (counted
in ``skips``) rather than running a burst. With ``realtime=False`` it runs as fast as it can
(tests). The true payload on the plant is ``payload`` (default
:func:`sim.family.default_test_payload`) until ``payload_schedule`` changes it (an entry at
0 s replaces it from the start); the controller starts with no load set. ``stats()`` is its
own record: counts, the load in force, every command applied and every payload mounted.

It is usable in-process (``start()`` runs it in a thread, ``stop()`` ends it), which is how
the demo and end-to-end benchmarks put it on the ``virtual`` bus beside the plug-in, and from
the command line (``iem sim-controller``), which is how cross-process tests use it. Its
port is the controller's end of a link (:func:`firmware_bridge.controller_port.open_port`).
"""

from __future__ import annotations

import threading
import time

from firmware_bridge.errors import BridgeConfigError
from firmware_bridge.messages import ACK_ERRORS, Heartbeat, LoadAck, LoadCommand
from iem.payload import set_load_values

from .path_player import PathPlayer
from .payload_schedule import PayloadSchedule

MAX_LAG = 20
"""Cycles behind schedule after which the loop stops catching up and restarts its clock."""


class SimController:
    """The plant behind a controller port (a :class:`~firmware_bridge.can_link.CanControllerPort`
    or :class:`~firmware_bridge.serial_link.SerialControllerPort`).

    Args:
        port: where joint states, heartbeats and acks go and commands come from.
        path: the path to play (default: the 20 s excitation path).
        payload: the true payload on the plant (default: the default test payload).
        once: play the path once, then hold its end at rest.
        seed: sensor-noise seed.
        sensor: sensor model (default :class:`sim.plant.SensorModel`).
        realtime: keep 1 kHz in real time (False: as fast as possible).
        heartbeat_period: s between heartbeats.
        spin_us: the last part of each interval spent spinning instead of sleeping, µs.
        refuse_while_moving: refuse load commands while the arm moves and accept them at
            rest, as a real Franka refuses setLoad while a controller runs: the ack says
            applied=False with the error "command not possible in the current mode (the arm
            is moving)" and the load stays.
        drop_commands: the first this many load commands received are lost: neither applied
            nor acknowledged (counted in ``dropped_commands``).
        payload_schedule: ``[(t, Payload | None), ...]``: at controller time ``t`` s the
            plant carries that payload (None: nothing); see
            :mod:`deploy.simcell.payload_schedule`.
        gap: the plant's reality gap (:class:`sim.plant.RealityGap`: an arm that departs
            from its model as a real one does); None: the ideal plant, the nominal model.
        description: the arm model (:mod:`sim.description`; None: the default): the plant's
            arm and, without ``path``, the excitation path made for its limits.
    """

    def __init__(self, port, *, path=None, payload=None, once: bool = False, seed: int = 0,
                 sensor=None, realtime: bool = True, heartbeat_period: float = 0.1,
                 spin_us: float = 200.0, refuse_while_moving: bool = False,
                 drop_commands: int = 0, payload_schedule=(), gap=None,
                 description=None) -> None:
        from iem.extras import require
        from sim.family import default_test_payload
        from sim.paths import excitation_path

        require("mujoco", "the simulated controller")
        from sim.description import described
        from sim.plant import DT, ArmPlant
        from sim.robot import arm_model

        if isinstance(drop_commands, bool) or not isinstance(drop_commands, int) \
                or drop_commands < 0:
            raise BridgeConfigError(f"drop_commands {drop_commands!r}: valid is an integer "
                                    ">= 0")
        self.schedule = PayloadSchedule(payload_schedule, DT)
        self.port = port
        self.description = described(description)
        self.path = (excitation_path(model=arm_model(self.description)) if path is None
                     else path)
        self.payload = default_test_payload() if payload is None else payload
        at_start, first = self.schedule.at_start()
        if at_start:
            self.payload = first
        self.player = PathPlayer(self.path, once=once)
        self.plant = ArmPlant(payload=self.payload, sensor=sensor, seed=seed, gap=gap,
                              description=self.description)
        self.plant.reset(self.path.q[0], self.path.dq[0])
        self.period = DT
        self.realtime = realtime
        self.hb_every = max(1, round(heartbeat_period / DT))
        self.spin = spin_us * 1e-6
        self.cycles = 0
        self.overruns = 0
        self.skips = 0
        self.load_seq = 0
        self.refuse_while_moving = refuse_while_moving
        self.refused_moving = 0
        self.drop_commands = drop_commands
        self.dropped_commands = 0
        self.commands: list[tuple[LoadCommand, bool]] = []
        self.applied: list[dict] = []
        """Every command applied: ``{"t": controller time s, "seq", "mass", "com"}``."""
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.error: BaseException | None = None

    # -- one cycle -------------------------------------------------------------------------
    def moving(self, k: int) -> bool:
        """True while the arm moves at cycle ``k`` (not holding at rest at the path's end)."""
        return not self.player.holding(k)

    def _apply(self, cmd: LoadCommand, k: int) -> None:
        load = cmd.load
        error = ""
        if self.refuse_while_moving and self.moving(k):
            error = ACK_ERRORS[2]
            self.refused_moving += 1
        elif not (load is None or load.is_consistent()):
            error = ACK_ERRORS[1]
        ok = not error
        if ok:
            self.plant.set_controller_load(load)
            self.load_seq = cmd.seq
            mass, com, _ = set_load_values(load)
            self.applied.append({"t": k * self.period, "seq": cmd.seq, "mass": mass,
                                 "com": com})
        self.commands.append((cmd, ok))
        self.port.send_ack(LoadAck(seq=cmd.seq, applied=ok, load=self.plant.controller_load,
                                   error=error))

    def step(self) -> None:
        """One controller cycle (without waiting for its deadline)."""
        k = self.cycles
        self.port.tick(k, k * self.period)
        for cmd in self.port.poll_commands():
            if self.dropped_commands < self.drop_commands:
                self.dropped_commands += 1  # lost on the wire: no load, no ack
                continue
            self._apply(cmd, k)
        for payload in self.schedule.due(k):
            self.plant.set_payload(payload)
        state = self.plant.step(*self.player.at(k))
        self.port.publish(state)
        if k % self.hb_every == 0:
            self.port.heartbeat(Heartbeat(
                state="holding" if self.player.holding(k) else "running",
                load_seq=self.load_seq, cycle=k, overruns=self.overruns))
        self.cycles = k + 1

    # -- loops -----------------------------------------------------------------------------
    def run(self, duration: float | None = None, cycles: int | None = None) -> None:
        """Run until ``stop()``, ``duration`` s of controller time, or ``cycles`` cycles."""
        limit = None
        if cycles is not None:
            limit = self.cycles + int(cycles)
        elif duration is not None:
            limit = self.cycles + round(duration / self.period)
        period, spin = self.period, self.spin
        perf, sleep = time.perf_counter, time.sleep
        deadline = perf()
        stop = self._stop
        while not stop.is_set() and (limit is None or self.cycles < limit):
            self.step()
            if not self.realtime:
                continue
            deadline += period
            now = perf()
            if now > deadline:
                self.overruns += 1
                if now - deadline > MAX_LAG * period:
                    self.skips += 1
                    deadline = now
                continue
            if deadline - now > spin:
                sleep(deadline - now - spin)
            while perf() < deadline:
                sleep(0)  # yield the GIL while spinning: the plug-in may share the process

    def start(self) -> SimController:
        """Run in a daemon thread until :meth:`stop`."""
        def target():
            try:
                self.run()
            except BaseException as exc:  # kept for the owner; the thread must not die silently
                self.error = exc

        self._stop.clear()
        self._thread = threading.Thread(target=target, name="sim-controller", daemon=True)
        self._thread.start()
        return self

    def stop(self, timeout: float = 2.0) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout)
            self._thread = None

    def close(self) -> None:
        self.stop()
        self.port.close()

    def __enter__(self) -> SimController:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()

    def stats(self) -> dict:
        """The controller's counts and its own record (docs/outputs.md lists the keys):
        ``load_in_force`` (``{"mass", "com", "inertia"}``, inertia 9 numbers column-major
        about the CoM, or None), ``payload`` (what the plant carries: its ``name`` and the
        same three, or None), ``applied`` (every command applied) and ``mounted`` (every
        payload mounted: the one at the start, then every change of the schedule)."""
        port = self.port
        load = self.plant.controller_load
        in_force = None
        if load is not None:
            mass, com, inertia = set_load_values(load)
            in_force = {"mass": mass, "com": com, "inertia": inertia}
        carried = self.plant.payload
        payload = None
        if carried is not None:
            mass, com, inertia = set_load_values(carried)
            payload = {"name": carried.name, "mass": mass, "com": com, "inertia": inertia}
        mounted = list(self.schedule.mounted)
        if not (mounted and mounted[0]["t"] == 0.0):  # no change at 0: the start's payload
            mounted.insert(0, {"t": 0.0, "payload": getattr(self.payload, "name", None)})
        return {"cycles": self.cycles, "overruns": self.overruns, "skips": self.skips,
                "commands": len(self.commands),
                "refused": sum(1 for _, ok in self.commands if not ok),
                "refused_moving": self.refused_moving,
                "dropped_commands": self.dropped_commands,
                "load_seq": self.load_seq, "load_in_force": in_force, "payload": payload,
                "applied": list(self.applied), "mounted": mounted,
                "sent": getattr(port, "sent", 0), "send_errors": getattr(port, "send_errors", 0),
                "saturated": getattr(port, "saturated", 0),
                "faults": dict(port.faults.counts) if getattr(port, "faults", None) else {},
                "faults_by_message": (dict(port.faults.by_message)
                                      if getattr(port, "faults", None) else {}),
                "fault_events": list(port.faults.events) if getattr(port, "faults", None) else [],
                "send_failures": list(getattr(port, "send_failures", []))}


