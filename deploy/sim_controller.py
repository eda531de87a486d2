"""The simulated controller: the MuJoCo plant at 1 kHz behind a real bus or link.

:class:`SimController` runs :class:`sim.plant.PandaPlant` cycle by cycle, tracking a
:class:`sim.paths.Path` (default :func:`sim.paths.excitation_path`): forward, then backward,
then forward again (both ends are at rest, so the turns are smooth), or once and then at
rest at its end (``once=True``). Each cycle it

1. takes the payload commands received (``port.poll_commands``), applies each with
   ``plant.set_controller_load`` if it is physically consistent, and acknowledges with the
   load now in force (a refused one keeps the previous load);
2. steps the plant and publishes the measured joint state (``port.publish``);
3. sends a heartbeat every ``heartbeat_period`` s.

In real time (the default) a deadline loop keeps the 1 kHz: sleep most of the interval, spin
the last ``spin_us`` µs on ``perf_counter``; a cycle that ends after its deadline counts as an
overrun, and more than ``MAX_LAG`` cycles behind the schedule restarts it from now (counted
in ``skips``) rather than running a burst. With ``realtime=False`` it runs as fast as it can
(tests). The true payload on the plant is ``payload`` (default
:func:`sim.family.default_test_payload`); the controller starts with no load set.

It is usable in-process (``start()`` runs it in a thread, ``stop()`` ends it), which is how
the demo and end-to-end benchmarks put it on the ``virtual`` bus beside the plug-in, and from
the command line (``iem sim-controller``), which is how cross-process tests use it. Its
port is the controller's end of a link (:func:`firmware_bridge.controller_port.open_port`).
"""

from __future__ import annotations

import sys
import threading
import time

import numpy as np

from firmware_bridge.controller_port import fault_spec, open_port
from firmware_bridge.messages import ACK_ERRORS, Heartbeat, LoadAck, LoadCommand
from firmware_bridge.protocol import PROFILES

MAX_LAG = 20
"""Cycles behind schedule after which the loop stops catching up and restarts its clock."""


class PathPlayer:
    """Reference ``(q, dq, ddq)`` at controller cycle ``k``: the path forward, backward, ...

    With ``once`` the path is played once and then its last sample held at rest.
    """

    def __init__(self, path, once: bool = False) -> None:
        self.path = path
        self.once = once
        self.n = len(path)
        self._zeros = np.zeros(path.q.shape[1])

    def at(self, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        p, n = self.path, self.n
        if n == 1:
            return p.q[0], self._zeros, self._zeros
        if self.once:
            if k >= n - 1:
                return p.q[-1], self._zeros, self._zeros
            return p.q[k], p.dq[k], p.ddq[k]
        period = 2 * (n - 1)
        i = k % period
        if i < n - 1:
            return p.q[i], p.dq[i], p.ddq[i]
        j = period - i  # backward: q(T - t), dq -> -dq, ddq unchanged
        return p.q[j], -p.dq[j], p.ddq[j]

    def holding(self, k: int) -> bool:
        return self.once and k >= self.n - 1


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
    """

    def __init__(self, port, *, path=None, payload=None, once: bool = False, seed: int = 0,
                 sensor=None, realtime: bool = True, heartbeat_period: float = 0.1,
                 spin_us: float = 200.0, refuse_while_moving: bool = False) -> None:
        from iem.extras import require
        from sim.family import default_test_payload
        from sim.paths import excitation_path

        require("mujoco", "the simulated controller")
        from sim.plant import DT, PandaPlant

        self.port = port
        self.path = excitation_path() if path is None else path
        self.payload = default_test_payload() if payload is None else payload
        self.player = PathPlayer(self.path, once=once)
        self.plant = PandaPlant(payload=self.payload, sensor=sensor, seed=seed)
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
        self.commands: list[tuple[LoadCommand, bool]] = []
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
        self.commands.append((cmd, ok))
        self.port.send_ack(LoadAck(seq=cmd.seq, applied=ok, load=self.plant.controller_load,
                                   error=error))

    def step(self) -> None:
        """One controller cycle (without waiting for its deadline)."""
        k = self.cycles
        self.port.tick(k, k * self.period)
        for cmd in self.port.poll_commands():
            self._apply(cmd, k)
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
        port = self.port
        return {"cycles": self.cycles, "overruns": self.overruns, "skips": self.skips,
                "commands": len(self.commands),
                "refused": sum(1 for _, ok in self.commands if not ok),
                "refused_moving": self.refused_moving,
                "sent": getattr(port, "sent", 0), "send_errors": getattr(port, "send_errors", 0),
                "saturated": getattr(port, "saturated", 0),
                "faults": dict(port.faults.counts) if getattr(port, "faults", None) else {},
                "faults_by_message": (dict(port.faults.by_message)
                                      if getattr(port, "faults", None) else {}),
                "fault_events": list(port.faults.events) if getattr(port, "faults", None) else [],
                "send_failures": list(getattr(port, "send_failures", []))}


# -- command line --------------------------------------------------------------------------
def configure(parser) -> None:
    from firmware_bridge.links import controller_interfaces

    kinds = controller_interfaces()
    parser.add_argument("--interface", required=True, choices=list(kinds),
                        help="; ".join(f"{k}: {v}" for k, v in kinds.items()))
    parser.add_argument("--channel", default="",
                        help="bus channel, device or URL (not used by the *-pty interfaces)")
    parser.add_argument("--profile", default="fd", choices=PROFILES,
                        help="wire profile on CAN (default fd)")
    parser.add_argument("--path", metavar="FILE", help="path CSV (default: the excitation path)")
    parser.add_argument("--payload", metavar="FILE",
                        help="true payload TOML (default: the default test payload)")
    parser.add_argument("--once", action="store_true",
                        help="play the path once, then hold its end at rest")
    parser.add_argument("--duration", type=float, help="stop after this many s")
    parser.add_argument("--seed", type=int, default=0, help="sensor-noise seed")
    parser.add_argument("--drop", type=float, default=0.0, help="fraction of frames dropped")
    parser.add_argument("--corrupt", type=float, default=0.0,
                        help="fraction of frames with one bit flipped")
    parser.add_argument("--duplicate", type=float, default=0.0,
                        help="fraction of frames sent twice")
    parser.add_argument("--delay", type=float, default=0.0,
                        help="fraction of frames held back --delay-cycles cycles")
    parser.add_argument("--delay-cycles", type=int, default=3, help="cycles a delayed frame waits")
    parser.add_argument("--silence", metavar="START:LENGTH",
                        help="say nothing for LENGTH s from controller time START s")
    parser.add_argument("--fault-seed", type=int, default=0, help="seed of the fault draws")
    parser.add_argument("--refuse-while-moving", action="store_true",
                        help="refuse load commands while the arm moves (accept them at rest), "
                        "as a real Franka refuses setLoad while a controller runs")
    parser.add_argument("--stats-json", metavar="FILE",
                        help="at exit, write the controller's counts (cycles, overruns, "
                             "commands, faults injected per message) as JSON")


def run(args) -> int:
    import signal

    from iem.extras import require
    from sim.paths import load_path_csv
    from sim.payload import load_payload

    require("mujoco", "iem sim-controller (the simulated Panda)")  # before a port opens

    path = load_path_csv(args.path) if args.path else None
    payload = load_payload(args.payload) if args.payload else None
    port, announce = open_port(args.interface, args.channel, args.profile, fault_spec(args))
    controller = SimController(port, path=path, payload=payload, once=args.once, seed=args.seed,
                               refuse_while_moving=args.refuse_while_moving)

    def _stop(signum, frame):
        controller._stop.set()

    signal.signal(signal.SIGTERM, _stop)
    signal.signal(signal.SIGINT, _stop)
    if announce:
        print(announce, flush=True)
    print(f"sim-controller: {args.interface} {announce or args.channel!r}, profile "
          f"{args.profile}, path {controller.path.name!r} "
          f"({'once' if args.once else 'back and forth'}), payload {controller.payload.name!r}",
          file=sys.stderr, flush=True)
    try:
        controller.run(duration=args.duration)
    finally:
        port.close()
        stats = controller.stats()
        print("sim-controller: " + ", ".join(f"{k} {v}" for k, v in stats.items()
                                             if k not in ("faults_by_message", "fault_events",
                                                          "send_failures")),
              file=sys.stderr, flush=True)
        if args.stats_json:
            import json

            with open(args.stats_json, "w", encoding="utf-8") as fh:
                json.dump(stats, fh, indent=2)
    return 0
