"""The ``iem`` command: one table of subcommands, each imported only when it runs.

A command is a module with ``configure(parser)`` (add its arguments) and ``run(args) -> int``
(exit status). A group (``iem bench ...``) is a nested table. Errors of the project
(:class:`iem.errors.IemError`) end the command with ``iem: error: <message>`` on stderr and
an exit status that tells a service manager whether to try again:

- :data:`EX_CONFIG` (78, sysexits.h's ``EX_CONFIG``), only from the service (``iem run``, which
  systemd restarts): a configuration error, which a restart cannot fix
  (:func:`is_config_error`): a bad ``cell.toml`` (unreadable, not UTF-8, not TOML, an unknown
  key, a value out of range, a model file made for another link rate), any file it names
  that is missing or cannot be read (the model, the arm file, the arm's description, the
  end effector, the initial payload, the excitation path, the recording a replay link
  plays), a bad payload or path file, an unknown link kind, profile or option, a link's
  missing extra; ``deploy/iem.service`` has ``RestartPreventExitStatus=78``;
- :data:`EX_ERROR` (2): any error of the other commands, and any other error of the service,
  e.g. a link failure (an adapter unplugged, a bus error): systemd restarts the service.

A missing optional extra (MuJoCo for the simulator, matplotlib for the plots:
:mod:`iem.extras`) is such an error too, naming the ``pip install`` to run, even where a module
imported it without :func:`iem.extras.require`. Anything else is a bug and keeps its traceback.
"""

from __future__ import annotations

import os

# The plug-in's linear algebra is small (at most about 100 unknowns) and runs beside a 1 kHz
# reader: OpenBLAS's worker threads only contend with it for the cores (on a busy 2-core PC
# they made iem calibrate's small solves up to 200 times slower). One thread, unless the
# operator says otherwise; set before NumPy loads.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import importlib
import sys

from iem.errors import IemError

EX_CONFIG = 78
"""Exit status of a configuration error (sysexits.h): the service manager does not retry."""
EX_ERROR = 2
"""Exit status of every other error of the project (and of a usage error)."""

Table = dict[str, "tuple[str, str] | tuple[dict, str]"]

BENCHES: Table = {
    "sim": ("deploy.bench.sim", "RNEA, regressor and tandem speed, plant real-time factor"),
    "paper": ("deploy.bench.paper", "the paper's experiments in simulation: results.json, report"),
    "realistic": ("deploy.bench.realistic", "the models on a perturbed arm, with and without "
                  "calibration: results.json, report"),
    "custom": ("deploy.bench.custom", "the paper benchmark's models on a payload file and a path"),
    "bridge": ("deploy.bench.bridge", "fieldbus bridge: decode throughput, latency, bus load"),
    "e2e": ("deploy.bench.e2e", "the plug-in against the simulated controller at 1 kHz"),
    "faults": ("deploy.bench.faults",
               "the plug-in on a lossy, late, corrupt stream with a silence, against a clean run"),
    "longrun": ("deploy.bench.longrun", "IEM and IEM+phys over a long random motion, per 30 s"),
    "real": ("deploy.bench.real", "the plug-in on a real Panda's recording: calibrated on one "
             "part, payloads identified on the rest"),
    "writeback": ("deploy.bench.writeback.command",
                  "the write-back, scenario by scenario, simulated"),
    "fci": ("deploy.bench.fci.command", "the plug-in against franky-sim's FR3 over the "
            "libfranka protocol: commissioning, then pick and place two ways, and the "
            "program alone"),
    "excite": ("deploy.bench.excite", "what the motion of 'iem excite' determines, on the "
               "realistic plant"),
}

COMMANDS: Table = {
    "demo": ("deploy.commands.demo", "run the main job on the simulated arm (--arm-model; the "
             "Panda by default) and print a summary"),
    "run": ("deploy.commands.run", "the plug-in service: identify the payload, write it back"),
    "train": ("deploy.commands.train", "make an initial model from the excitation path"),
    "calibrate": ("deploy.commands.calibrate", "identify the arm's departure from its model "
                  "from bare-arm traffic: the arm file"),
    "replay": ("deploy.commands.replay", "run the plug-in over a recording (CAN log, rosbag2 "
               "bag, joint-state CSV), as fast as possible"),
    "identify": ("deploy.commands.identify",
                 "identify a payload offline from a loaded and a bare log"),
    "excite": ("deploy.commands.excite", "design a short motion that determines a payload: a "
               "path CSV"),
    "set-load": ("deploy.commands.set_load", "write a payload file (or --clear: no load) to the "
                 "controller through the gate's checks"),
    "bench": (BENCHES, "benchmarks that print the project's speed and accuracy figures"),
    "sim-controller": ("deploy.commands.sim_controller",
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


def is_config_error(exc: BaseException) -> bool:
    """True for an error in what the operator configured: ``cell.toml``
    (:class:`deploy.config.ConfigError`), a payload file (:class:`iem.errors.PayloadError`),
    a path file (:class:`iem.errors.PathError`), a link kind, profile or option
    (:class:`firmware_bridge.errors.BridgeConfigError`)."""
    from deploy.config import ConfigError
    from firmware_bridge.errors import BridgeConfigError
    from iem.errors import PathError, PayloadError

    return isinstance(exc, ConfigError | PayloadError | PathError | BridgeConfigError)


SERVICE_COMMANDS = ("run",)
"""Commands a service manager runs and restarts: only they exit :data:`EX_CONFIG`."""


def exit_status(exc: IemError, command: str | None = "run") -> int:
    """:data:`EX_CONFIG` for a configuration error of the service (``iem run``, which
    systemd must not restart into the same error); :data:`EX_ERROR` for any other error,
    and for every error of the other commands (a person at a terminal reads the message)."""
    return EX_CONFIG if command in SERVICE_COMMANDS and is_config_error(exc) else EX_ERROR


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    try:
        return dispatch("iem", COMMANDS, argv,
                        "Online payload identification for a Franka-style cobot (IEM).")
    except IemError as exc:
        print(f"iem: error: {exc}", file=sys.stderr)
        return exit_status(exc, argv[0] if argv else None)
    except ImportError as exc:  # an extra's module imported without iem.extras.require
        from iem.extras import missing_extra

        error = missing_extra(exc, " ".join(["iem", *argv[:2 if argv[:1] == ["bench"] else 1]]))
        if error is None:
            raise
        print(f"iem: error: {error}", file=sys.stderr)
        return exit_status(error, argv[0] if argv else None)
    except KeyboardInterrupt:
        print("iem: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
