"""The simulated controller behind ROS 2, in a process of its own, for tests.

``python -m deploy.simcell.ros2_controller [--domain N --interface lo --peer 127.0.0.1 ...]``: the
simulated controller (:class:`deploy.simcell.controller.SimController`, the MuJoCo plant at
1 kHz) behind a :class:`firmware_bridge.ros2_peers.Ros2ControllerPort`, as franka_ros2 shows
the robot: its joint states on ``/franka/joint_states`` under the arm model's joint names
(``--arm-model``, the plant's too), its loads set through a SetLoad service. It prints
``ready`` once the port is up, runs ``--duration`` s of controller time, and writes its
statistics (commands applied or refused, the load in force) to ``--stats-json`` and, as
JSON, to stderr.
"""

from __future__ import annotations

import argparse
import json
import sys

from deploy.options import add_arm_model


def run_controller(args) -> int:
    """The simulated controller behind ROS 2 until ``--duration`` s; its statistics
    (commands applied or refused, the load in force) to ``--stats-json``."""
    from deploy.options import arm_description_of
    from firmware_bridge.ros2_dds import cyclone_config, participant
    from firmware_bridge.ros2_peers import Ros2ControllerPort
    from sim.paths import load_path_csv
    from sim.robot import arm_model

    from .controller import SimController

    description = arm_description_of(args)
    dp = participant(args.domain, cyclone_config(args.interface, tuple(args.peer)))
    port = Ros2ControllerPort(dp, args.topic, args.service, layout=args.layout,
                              arm=description.joint_names, refuse_first=args.refuse_first)
    path = (load_path_csv(args.path, model=arm_model(description)) if args.path else None)
    controller = SimController(port, path=path, once=args.once, seed=args.seed,
                               description=description)
    print("ready", flush=True)
    try:
        controller.run(duration=args.duration)
    finally:
        port.close()
    load = controller.plant.controller_load
    stats = {**controller.stats(),
             "applied": [[c.load.mass if c.load else 0.0, ok] for c, ok in controller.commands],
             "load": None if load is None else {"mass": load.mass, "com": list(load.com)}}
    if args.stats_json:
        with open(args.stats_json, "w") as f:
            json.dump(stats, f)
    print(json.dumps(stats), file=sys.stderr, flush=True)
    return 0


def main(argv=None) -> int:
    ctl = argparse.ArgumentParser(prog="python -m deploy.simcell.ros2_controller",
                                  description="the simulated controller behind ROS 2")
    ctl.add_argument("--topic", default="/franka/joint_states")
    ctl.add_argument("--service", default="/service_server/set_load")
    ctl.add_argument("--layout", choices=["cyclonedds", "fastrtps"], default="cyclonedds")
    ctl.add_argument("--domain", type=int, default=0)
    ctl.add_argument("--interface", default="")
    ctl.add_argument("--peer", action="append", default=[])
    add_arm_model(ctl)  # the plant's arm model and the joint names it publishes
    ctl.add_argument("--path", metavar="FILE", help="path CSV (default: the excitation path)")
    ctl.add_argument("--once", action="store_true", help="play the path once, then hold")
    ctl.add_argument("--duration", type=float, default=10.0, help="s of controller time")
    ctl.add_argument("--seed", type=int, default=0)
    ctl.add_argument("--refuse-first", type=int, default=0, metavar="N",
                     help="refuse the first N set_load requests (as while moving)")
    ctl.add_argument("--stats-json", metavar="FILE")
    return run_controller(ctl.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
