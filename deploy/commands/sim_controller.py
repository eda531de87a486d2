"""``iem sim-controller``: the simulated controller (:class:`deploy.simcell.controller.
SimController`) behind a bus or link, in a process of its own, until ``--duration`` has passed
or it is stopped (SIGTERM, SIGINT); its statistics at the end, on stderr and ``--stats-json``."""

from __future__ import annotations

import sys

from deploy.options import add_arm_model, add_duration, arm_description_of, refuse_unused
from deploy.simcell.controller import SimController
from deploy.simcell.payload_schedule import SPEC_HELP, parse_schedule
from firmware_bridge.controller_port import fault_spec, open_port
from firmware_bridge.protocol import PROFILES


def configure(parser) -> None:
    from firmware_bridge.links import controller_interfaces

    kinds = controller_interfaces()
    parser.add_argument("--interface", required=True, choices=list(kinds),
                        help="; ".join(f"{k}: {v}" for k, v in kinds.items()))
    parser.add_argument("--channel", default="",
                        help="bus channel, device or URL (the *-pty interfaces open a new pty "
                        "and take none)")
    parser.add_argument("--profile", default=None, choices=PROFILES,
                        help="wire profile on CAN (default fd; the serial link has none)")
    parser.add_argument("--path", metavar="FILE",
                        help="path CSV (default: the arm model's excitation path)")
    parser.add_argument("--payload", metavar="FILE",
                        help="true payload TOML, mounted from the start (default: the default "
                             "test payload) until --payload-schedule changes it")
    parser.add_argument("--payload-schedule", metavar="SPEC", type=_schedule_arg,
                        help="change the payload mounted on the plant at controller times: "
                             f"{SPEC_HELP}. With --payload, --payload is mounted until the "
                             "first change; an entry at 0 wins over it")
    parser.add_argument("--drop-commands", metavar="N", type=_count_arg, default=0,
                        help="lose the first N load commands received: neither applied nor "
                             "acknowledged (default 0)")
    parser.add_argument("--once", action="store_true",
                        help="play the path once, then hold its end at rest")
    add_duration(parser)
    parser.add_argument("--seed", type=int, default=0, help="sensor-noise seed")
    parser.add_argument("--drop", type=float, default=0.0, help="fraction of frames dropped")
    parser.add_argument("--corrupt", type=float, default=0.0,
                        help="fraction of frames with one bit flipped")
    parser.add_argument("--duplicate", type=float, default=0.0,
                        help="fraction of frames sent twice")
    parser.add_argument("--delay", type=float, default=0.0,
                        help="fraction of frames held back --delay-cycles cycles")
    parser.add_argument("--delay-cycles", type=int, default=None,
                        help="cycles a delayed frame waits (default 3; with --delay)")
    parser.add_argument("--silence", metavar="START:LENGTH",
                        help="say nothing for LENGTH s from controller time START s")
    parser.add_argument("--fault-seed", type=int, default=None,
                        help="seed of the fault draws of --drop, --corrupt, --duplicate and "
                        "--delay (default 0)")
    parser.add_argument("--refuse-while-moving", action="store_true",
                        help="refuse load commands while the arm moves (accept them at rest), "
                        "as a real Franka refuses setLoad while a controller runs")
    parser.add_argument("--stats-json", metavar="FILE",
                        help="at exit, write the controller's counts (cycles, overruns, "
                             "commands, dropped_commands, faults injected per message) and "
                             "its own record (load_in_force, the true payload, applied, "
                             "mounted) as JSON")
    add_arm_model(parser)

def _schedule_arg(text: str):
    import argparse

    from iem.errors import PayloadError

    try:
        return parse_schedule(text)
    except PayloadError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None

def _count_arg(text: str) -> int:
    import argparse

    try:
        n = int(text)
    except ValueError:
        n = -1
    if n < 0:
        raise argparse.ArgumentTypeError(f"{text!r}: valid is an integer >= 0")
    return n

def _is_can(interface: str) -> bool:
    from firmware_bridge.links import LINKS

    return LINKS[interface.removesuffix("-pty")].bus is not None


def refuse_unused_options(args) -> None:
    """Refuse an option this run would not use (:func:`deploy.options.refuse_unused`)."""
    where = f"with --interface {args.interface}"
    if args.interface.endswith("-pty"):
        refuse_unused(args, ["--channel"], f"{where}: the controller opens a new pty and "
                      "prints its path")
    if not _is_can(args.interface):
        refuse_unused(args, ["--profile"], f"{where}: a wire profile is CAN's; the serial "
                      "link sends msgpack messages")
    if not args.delay:
        refuse_unused(args, ["--delay-cycles"], "without --delay: it is how long a delayed "
                      "frame is held")
    if not (args.drop or args.corrupt or args.duplicate or args.delay):
        refuse_unused(args, ["--fault-seed"], "without --drop, --corrupt, --duplicate or "
                      "--delay: it seeds their draws")


def run(args) -> int:
    import signal

    from iem.extras import require
    from sim.paths import load_path_csv
    from sim.payload import load_payload
    from sim.robot import arm_model

    require("mujoco", "iem sim-controller (the simulated arm)")  # before a port opens

    refuse_unused_options(args)
    description = arm_description_of(args)
    path = (load_path_csv(args.path, model=arm_model(description)) if args.path else None)
    payload = load_payload(args.payload) if args.payload else None
    profile = args.profile or "fd"
    port, announce = open_port(args.interface, args.channel, profile, fault_spec(args))
    controller = SimController(port, path=path, payload=payload, once=args.once, seed=args.seed,
                               refuse_while_moving=args.refuse_while_moving,
                               drop_commands=args.drop_commands,
                               payload_schedule=args.payload_schedule or (),
                               description=description)

    def _stop(signum, frame):
        controller._stop.set()

    signal.signal(signal.SIGTERM, _stop)
    signal.signal(signal.SIGINT, _stop)
    if announce:
        print(announce, flush=True)
    print(f"sim-controller: {description.name}, {args.interface} "
          f"{announce or args.channel!r}, "
          + (f"profile {profile}, " if _is_can(args.interface) else "")
          + f"path {controller.path.name!r} "
          f"({'once' if args.once else 'back and forth'}), payload "
          f"{getattr(controller.payload, 'name', None)!r}"
          + (f", {len(controller.schedule.entries)} payload changes scheduled"
             if controller.schedule.entries else ""),
          file=sys.stderr, flush=True)
    try:
        controller.run(duration=args.duration)
    finally:
        port.close()
        stats = controller.stats()
        print("sim-controller: " + ", ".join(f"{k} {v}" for k, v in stats.items()
                                             if k not in ("faults_by_message", "fault_events",
                                                          "send_failures", "load_in_force",
                                                          "payload", "applied", "mounted")),
              file=sys.stderr, flush=True)
        if args.stats_json:
            import json

            with open(args.stats_json, "w", encoding="utf-8") as fh:
                json.dump(stats, fh, indent=2)
    return 0
