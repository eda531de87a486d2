"""The ``iem`` command: one table of subcommands, each imported only when it runs.

A command is a module with ``configure(parser)`` (add its arguments) and ``run(args) -> int``
(exit status). A group (``iem bench ...``) is a nested table. Errors of the project
(:class:`iem.errors.IemError`) end the command with their message and exit status 2;
anything else is a bug and keeps its traceback.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from iem.errors import IemError

Table = dict[str, "tuple[str, str] | tuple[dict, str]"]

BENCHES: Table = {
    "sim": ("sim.bench", "RNEA, regressor and tandem speed, plant real-time factor"),
    "paper": ("iem.bench.paper", "the paper's experiments in simulation: results.json, report"),
    "custom": ("iem.bench.custom", "the paper benchmark's models on a payload file and a path"),
    "bridge": ("firmware_bridge.bench", "fieldbus bridge: decode throughput, latency, bus load"),
    "e2e": ("deploy.bench_e2e", "the plug-in against the simulated controller at 1 kHz"),
    "faults": ("deploy.bench_faults",
               "the plug-in on a lossy, late, corrupt stream with a silence, against a clean run"),
    "longrun": ("iem.bench.longrun", "IEM and IEM+phys over a long random motion, per 30 s"),
}

COMMANDS: Table = {
    "demo": ("deploy.demo", "run the main job on the simulated Panda and print a summary"),
    "run": ("deploy.service", "the plug-in service: identify the payload, write it back"),
    "train": ("deploy.training", "make an initial model from the excitation path"),
    "replay": ("deploy.replay", "run the plug-in over recorded CAN traffic, as fast as possible"),
    "bench": (BENCHES, "benchmarks that print the project's speed and accuracy figures"),
    "sim-controller": ("firmware_bridge.sim_controller",
                       "the simulated controller: the plant at 1 kHz behind a bus or link"),
    "bus-load": ("firmware_bridge.busload", "bits per frame and bus load of a wire profile"),
    "record": ("firmware_bridge.record", "record a CAN bus to .blf, .log, .asc or .trc"),
}


def _usage(prog: str, table: Table, description: str | None) -> str:
    width = max(len(name) for name in table)
    lines = [f"usage: {prog} COMMAND [options]", ""]
    if description:
        lines += [description, ""]
    lines.append("commands:")
    lines += [f"  {name:<{width}}  {help_}" for name, (_, help_) in table.items()]
    lines += ["", f"'{prog} COMMAND --help' shows a command's options."]
    return "\n".join(lines)


def dispatch(prog: str, table: Table, argv: list[str], description: str | None = None) -> int:
    """Run the command named by ``argv[0]`` from ``table`` with the rest of ``argv``."""
    if not argv or argv[0] in ("-h", "--help"):
        print(_usage(prog, table, description))
        return 0 if argv else 2
    name, rest = argv[0], argv[1:]
    if name not in table:
        print(f"{prog}: unknown command {name!r}; valid commands are: {', '.join(table)}",
              file=sys.stderr)
        return 2
    target, help_ = table[name]
    if isinstance(target, dict):
        return dispatch(f"{prog} {name}", target, rest, help_)
    module = importlib.import_module(target)
    parser = argparse.ArgumentParser(prog=f"{prog} {name}", description=help_)
    module.configure(parser)
    args = parser.parse_args(rest)
    return int(module.run(args) or 0)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    try:
        return dispatch("iem", COMMANDS, argv,
                        "Online payload identification for a Franka-style cobot (IEM).")
    except IemError as exc:
        print(f"iem: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("iem: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
