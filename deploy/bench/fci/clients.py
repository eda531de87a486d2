"""The two FCI clients of ``iem bench fci``, each run in a process of its own
(``python -m deploy.bench.fci.clients program|run ...``): franky-control and pylibfranka
cannot be imported into one process (both register libfranka's types with pybind11).

- ``program``: a user's franky-control program with the plug-in inside
  (:class:`deploy.service.PayloadPlugin`): it runs the pick-and-place
  (:func:`deploy.bench.fci.schedule.steps`) with ``JointMotion`` and the hand (franky's
  ``Gripper``: the scene mounts a payload when the hand closes), feeds every state of every
  motion from the motion's callback, and calls ``apply()`` after each motion. It times the
  callback (its own cost per state) and when each call began. Without ``--config``: the same
  program without the plug-in (the control loop's pace to compare with).
- ``run``: the plug-in as ``iem run`` runs it (:class:`deploy.service.Service` on the
  ``franka`` link, the FCI client) while the robot's own program (the scene) moves the arm;
  it says ``ready`` on stdout once it reads the robot and stops on SIGTERM.

Each writes a JSON file: ``rows`` (per block point: the robot's time, the smoothed mass and
mass moments ``m·r``, and the raw estimate's standard deviations of those four),
``reasons`` (per block point, the reason of the gate's latest decision), the service's
``summary``; the program also ``costs_ns`` (the callback's cost per state),
``arrivals_ns`` (when each callback began, ``perf_counter_ns``: the control loop's pace),
``applies`` (each ``apply()``: the robot's time after it, applied, the error text, the mass
in force) and ``motions_s`` (each motion's duration, wall s).
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import time

GRASP = {"width": 0.02, "speed": 0.05, "force": 20.0, "epsilon_inner": 0.01,
         "epsilon_outer": 0.1}
"""franky ``Gripper.grasp`` arguments: close on nothing (the scene holds the payload)."""
OPEN_M = 0.08


def _json_safe(value):
    try:
        return json.loads(json.dumps(value, default=str))
    except (TypeError, ValueError):
        return str(value)


def program(host: str, config: str | None, out: str, n_payloads: int, factor: float,
            fifo: int = 0) -> int:
    """The pick-and-place as a franky program, the plug-in inside (``config`` None: the same
    program without it, the control loop's pace to compare with); ``fifo``: the real-time
    priority franky's control loop takes at its first callback (``SCHED_FIFO``; 0: none)."""
    import franky

    from deploy.bench.fci.schedule import steps
    from deploy.service import PayloadPlugin

    robot = franky.Robot(host, realtime_config=franky.RealtimeConfig.Ignore)
    gripper = franky.Gripper(host)
    records = f"{out}.records"
    plugin = None if config is None else PayloadPlugin(robot, config, record_to=records)
    costs: list[int] = []
    arrivals: list[int] = []
    clock = time.perf_counter_ns
    feed = plugin.callback if plugin is not None else (lambda *_: None)

    realtime = [fifo]

    def callback(state, *rest) -> None:
        if realtime[0]:  # franky calls this from its control loop's thread
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(realtime[0]))
            realtime[0] = 0
        t0 = clock()
        arrivals.append(t0)
        feed(state, *rest)
        costs.append(clock() - t0)

    applies, motions = [], []
    try:
        gripper.move(OPEN_M, GRASP["speed"])
        for step in steps(n_payloads):
            if step.kind == "move":
                motion = franky.JointMotion(list(step.target), relative_dynamics_factor=factor)
                motion.register_callback(callback)
                start = time.monotonic()
                robot.move(motion)
                motions.append(time.monotonic() - start)
                if plugin is None:
                    continue
                ack = plugin.apply()
                t = float(robot.state.time.to_sec())
                applies.append({"t": t, "ack": ack is not None,
                                "applied": bool(ack and ack.applied),
                                "error": ack.error if ack is not None else "",
                                "mass": (ack.load.mass if ack is not None and ack.load is not None
                                         else 0.0)})
            elif step.kind == "grasp":
                gripper.grasp(GRASP["width"], GRASP["speed"], GRASP["force"],
                              epsilon_inner=GRASP["epsilon_inner"],
                              epsilon_outer=GRASP["epsilon_outer"])
            elif step.kind == "release":
                gripper.move(OPEN_M, GRASP["speed"])
            else:
                end = float(robot.state.time.to_sec()) + step.seconds
                while float(robot.state.time.to_sec()) < end:
                    time.sleep(0.01)
    finally:
        summary = plugin.close() if plugin is not None else {}
    kept = {"rows": [], "reasons": []}
    if plugin is not None:
        with open(records, encoding="utf-8") as f:
            kept = json.load(f)
        os.unlink(records)
        summary = {**summary, "states_written": plugin.written,
                   "states_dropped": plugin.dropped}
    with open(out, "w", encoding="utf-8") as f:
        json.dump({**kept, "summary": _json_safe(summary),
                   "costs_ns": costs, "arrivals_ns": arrivals, "applies": applies,
                   "motions_s": motions}, f)
    return 0


def run(config: str, out: str) -> int:
    from deploy.config import load_config
    from deploy.service import Service
    from deploy.service.plugin_process import PointRecords

    service = Service(load_config(config))
    records = PointRecords(service)
    service.on_cycle.append(records)
    signal.signal(signal.SIGTERM, lambda *_: service.stop())
    try:
        service.open()
        print("ready", flush=True)
        summary = service.run()
    finally:
        service.close()
    with open(out, "w", encoding="utf-8") as f:
        json.dump({"rows": records.rows, "reasons": records.reasons,
                   "summary": _json_safe(summary)}, f)
    return 0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m deploy.bench.fci.clients")
    sub = parser.add_subparsers(dest="client", required=True)
    p = sub.add_parser("program")
    p.add_argument("--host", required=True)
    p.add_argument("--config", help="the cell configuration (none: the program without the "
                   "plug-in)")
    p.add_argument("--out", required=True)
    p.add_argument("--payloads", type=int, required=True)
    p.add_argument("--factor", type=float, required=True)
    p.add_argument("--fifo", type=int, default=0,
                   help="the control loop's SCHED_FIFO priority (0: none)")
    r = sub.add_parser("run")
    r.add_argument("--config", required=True)
    r.add_argument("--out", required=True)
    args = parser.parse_args(argv)
    if args.client == "program":
        return program(args.host, args.config, args.out, args.payloads, args.factor,
                       args.fifo)
    return run(args.config, args.out)


if __name__ == "__main__":
    sys.exit(main())
