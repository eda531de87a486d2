"""The runs of ``iem bench writeback``: the service against the simulated controller, one
scenario at a time, each run recorded for :mod:`deploy.bench.writeback.score`.

A *plant* is the arm the controller simulates and the model the plug-in runs for it
(:func:`ideal_plant`, :func:`realistic_plant`). Each run puts a fresh copy of the model in a
simulated cell (:func:`deploy.simcell.inprocess.simulated_cell`: the controller at 1 kHz in real
time on python-can's virtual bus, the service beside it, the gate's defaults) and records: every
estimate (controller time, smoothed and raw parameters, the raw standard deviations, the gate's last
decision), the loads the gate sent (at the controller time of the estimate after which they went),
the gate's log lines, the service's summary and the controller's own record (``stats()``: each
command applied, the load in force, what was mounted).
"""

from __future__ import annotations

import copy
import logging
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path as FsPath

import numpy as np

from deploy.bench.writeback.score import load_of

SCENARIOS = ("tool_removed", "tool_swapped", "lost_1", "lost_3", "restart", "refusals")
TOOL = "test-3w"
"""The tool mounted from the start (:func:`sim.family.test_payloads`, 1.615 kg)."""
SWAP_TO = "test-2w"
"""The tool of ``tool_swapped`` after the change and the restart's payload B (1.34 kg)."""
LOG_KEPT = 400
"""Gate and load-writer log lines a run keeps."""


@dataclass
class Plant:
    """The arm the controller simulates and the plug-in's model for it; ``description``
    the arm model, ``rated_mass_kg`` the gate's rating (None: the arm model's)."""

    name: str
    seed: int
    model: object
    gap: object = None
    arm_file: str | None = None
    calibration: dict = field(default_factory=dict)
    description: object = None
    rated_mass_kg: float | None = None
    noise: str | None = None
    """The ``[arm] noise`` of the runs' cell (None: sensor without an arm file, else arm)."""


@dataclass
class Timing:
    """Scenario lengths, controller s: the change at ``change_s``, ``after_s`` beyond it;
    the lost-command runs ``lost_s``; the restart's first run at most ``restart_first_s``
    and its second ``restart_s``; the arm at rest ``rest_s`` after the path played once."""

    change_s: float
    after_s: float
    lost_s: float
    restart_first_s: float
    restart_s: float
    rest_s: float


TIMING = {"quick": Timing(10.0, 8.0, 12.0, 15.0, 8.0, 8.0),
          "full": Timing(15.0, 10.0, 15.0, 20.0, 10.0, 10.0)}


def tools() -> dict:
    from sim.family import test_payloads

    return test_payloads()


def ideal_plant(seed: int, log=print, description=None,
                rated_mass_kg: float | None = None) -> Plant:
    """The plant equal to its model (of the arm model ``description``; None: the default);
    IEM+phys trained for the nominal arm with the sensor's noise as its equations' error (as
    ``iem demo`` runs it)."""
    from deploy.model.training import train_initial_model

    model = train_initial_model("IEM+phys", seed=seed, noise="sensor", log=log,
                                description=description)
    return Plant("ideal", seed, model, description=description, rated_mass_kg=rated_mass_kg)


def default_plant(seed: int, log=print, description=None,
                  rated_mass_kg: float | None = None) -> Plant:
    """The ideal plant with the model a cell of the default configuration trains for itself
    (``deploy/cell.toml`` as shipped, whose every key is the default: no arm file, the
    default ``[arm] noise``, ``train_if_missing``), seeded ``seed``: what a new user's first
    ``iem run`` writes with."""
    from deploy.config import cell_config
    from deploy.model.training import noise_for, train_initial_model

    config = cell_config(description, rated_mass_kg,
                         where="bench writeback (the default configuration)")
    mc = config.model
    model = train_initial_model(mc.kind, mc.family, mc.excitation, seed, log=log,
                                arm_file=mc.arm or None, end_effector=config.arm.end_effector,
                                noise=noise_for(config.arm.noise, mc.arm),
                                description=description)
    return Plant("default", seed, model, description=description,
                 rated_mass_kg=rated_mass_kg, noise=config.arm.noise)


def realistic_plant(seed: int, out_dir, log=print, description=None,
                    rated_mass_kg: float | None = None) -> Plant:
    """``iem bench realistic``'s plant of ``seed`` (its reality gap), the bare arm calibrated
    as that bench does (written to ``out_dir``), IEM+phys trained for the calibrated arm (as
    ``iem train --arm``)."""
    from deploy.bench.realistic import RealisticBench, calibrated_arm
    from deploy.model.training import train_initial_model

    bench = RealisticBench(seed=seed, log=lambda *a: None, description=description)
    folder = FsPath(out_dir) / f"realistic-seed{seed}"
    folder.mkdir(parents=True, exist_ok=True)
    arm, held_out, arm_file = calibrated_arm(bench, folder, None, log)
    model = train_initial_model("IEM+phys", seed=seed, arm_file=str(arm_file), log=log,
                                description=description)
    return Plant("realistic", seed, model, gap=bench.gap, arm_file=str(arm_file),
                 calibration={"rms_before": arm.report["rms_before"],
                              "rms_after": arm.report["rms_after"], "held_out": held_out},
                 description=description, rated_mass_kg=rated_mass_kg)


def run_config(plant: Plant, model_file):
    """The cell of a run: the virtual bus, IEM+phys at ``model_file`` (checkpointed at the
    end only), the plant's arm file and arm model, the gate's defaults (its rating the
    plant's)."""
    from deploy.config import cell_config
    from deploy.simcell.inprocess import virtual_link

    return cell_config(
        plant.description, plant.rated_mass_kg, where="bench writeback",
        link=virtual_link("writeback"),
        model={"path": str(model_file), "kind": "IEM+phys", "seed": plant.seed,
               "checkpoint_period_s": 3600.0, "arm": plant.arm_file or ""},
        arm={"noise": plant.noise or ("arm" if plant.arm_file else "sensor")})


class _Lines(logging.Handler):
    """The gate's and the load writer's log lines of a run, at monotonic times."""

    def __init__(self) -> None:
        super().__init__(logging.INFO)
        self.lines: list[tuple[float, str, str]] = []

    def emit(self, record: logging.LogRecord) -> None:
        if len(self.lines) < LOG_KEPT:
            self.lines.append((time.monotonic(), record.levelname, record.getMessage()))


def run_cell(plant: Plant, schedule, end_s: float, model_file, *, model=None,
             drop_commands: int = 0, refuse_while_moving: bool = False, once: bool = False,
             controller_load=None, stop_when=None, path=None) -> dict:
    """One run of ``end_s`` controller s (or until ``stop_when(controller)``): the record
    described in the module docstring. ``model``: None loads ``model_file`` (a restart);
    ``controller_load``: the load the controller holds at its start."""
    from deploy.simcell.inprocess import simulated_cell

    config = run_config(plant, model_file)
    rows: list[tuple] = []
    handler = _Lines()
    loggers = [logging.getLogger(n) for n in ("iem.gate", "iem.service")]
    levels = [lg.level for lg in loggers]
    for lg in loggers:
        lg.addHandler(handler)
        lg.setLevel(logging.INFO)
    try:
        with simulated_cell(config, path=path, payload=schedule[0][1], once=once,
                            seed=plant.seed, model=model, payload_schedule=schedule,
                            drop_commands=drop_commands, gap=plant.gap,
                            refuse_while_moving=refuse_while_moving,
                            description=plant.description) as (controller, service):
            if controller_load is not None:
                controller.plant.set_controller_load(controller_load)
            gate = service.gate
            service.on_cycle.append(lambda r: rows.append(
                (time.monotonic(), float(r.state.t), np.array(r.smoothed, dtype=float),
                 np.array(r.raw.phi, dtype=float),
                 np.full(10, np.nan) if r.raw.std is None else np.array(r.raw.std, float),
                 gate.verdict()["reason"])))

            def until() -> bool:
                return controller.cycles * controller.period >= end_s or (
                    stop_when is not None and stop_when(controller))

            controller.start()
            summary = service.run(until=until)
            sent = list(gate.sent_loads)
            in_force = gate.in_force
    finally:
        for lg, level in zip(loggers, levels, strict=True):
            lg.removeHandler(handler)
            lg.setLevel(level)
    stats = controller.stats()
    mono = np.array([r[0] for r in rows])
    ctrl = np.array([r[1] for r in rows])

    def to_controller(t: float) -> float:
        return float(np.interp(t, mono, ctrl)) if mono.size else float("nan")

    return {
        "t": ctrl, "smoothed": np.array([r[2] for r in rows]).reshape(-1, 10),
        "raw": np.array([r[3] for r in rows]).reshape(-1, 10),
        "std": np.array([r[4] for r in rows]).reshape(-1, 10),
        "reasons": [r[5] for r in rows],
        "sends": [{"t": to_controller(t), "load": load_of(load)} for t, load, _ in sent],
        "log": [(round(to_controller(t), 3), level, msg) for t, level, msg in handler.lines],
        "summary": {k: summary[k] for k in ("writes", "load_in_force", "gate", "cycles")},
        "gate_in_force": in_force if isinstance(in_force, str) else load_of(in_force),
        "controller": {k: stats[k] for k in ("cycles", "overruns", "skips", "commands",
                                             "refused", "refused_moving", "dropped_commands",
                                             "load_in_force", "applied", "mounted")},
        "initial_load": load_of(controller_load),
        "schedule": [(t, load_of(p)) for t, p in schedule],
        "end_s": stats["cycles"] * 1e-3,
    }


def run_scenario(name: str, plant: Plant, timing: Timing, log=print) -> list[dict]:
    """The runs of scenario ``name`` on ``plant`` (one, or two for ``restart``), each with
    ``scenario``, ``plant``, ``seed`` and what the targets need (``change_s``, ``rest_s``)."""
    every = tools()
    tool = every[TOOL]
    with tempfile.TemporaryDirectory() as tmp:
        model_file = FsPath(tmp) / "model.msgpack"
        fresh = copy.deepcopy(plant.model)
        t0 = time.perf_counter()
        if name in ("tool_removed", "tool_swapped"):
            after = None if name == "tool_removed" else every[SWAP_TO]
            runs = [run_cell(plant, [(0.0, tool), (timing.change_s, after)],
                             timing.change_s + timing.after_s, model_file, model=fresh)]
            runs[0]["change_s"] = timing.change_s
        elif name in ("lost_1", "lost_3"):
            runs = [run_cell(plant, [(0.0, tool)], timing.lost_s, model_file, model=fresh,
                             drop_commands=int(name[-1]))]
            runs[0]["drops"] = int(name[-1])
        elif name == "restart":
            runs = _restart(plant, timing, model_file, fresh, tool, every[SWAP_TO])
        elif name == "refusals":
            from sim.paths import excitation_path
            from sim.robot import arm_model

            path = excitation_path(model=arm_model(plant.description))
            runs = [run_cell(plant, [(0.0, tool)], path.duration + timing.rest_s,
                             model_file, model=fresh, refuse_while_moving=True, once=True,
                             path=path)]
            runs[0]["rest_s"] = path.duration
        else:
            raise ValueError(f"scenario {name!r}; valid are {', '.join(SCENARIOS)}")
    for i, run in enumerate(runs):
        run.update(scenario=name, plant=plant.name, seed=plant.seed, part=i)
    w = runs[-1]["summary"]["writes"]
    log(f"{name:12s} {plant.name:9s} seed {plant.seed}: {time.perf_counter() - t0:.0f} s, "
        f"writes sent {w['sent']} acked {w['acked']} lost {w['lost']}")
    return runs


def _restart(plant: Plant, timing: Timing, model_file, model, a, b) -> list[dict]:
    """Payload A until the controller holds it (at most ``restart_first_s``), the model
    saved at the service's close; then a service restarted from that file against a
    controller that carries B and holds the load written for A."""
    from deploy.bench.writeback.score import correct
    from iem.payload import Payload

    def holds_a(controller) -> bool:
        return any(correct(x, a) for x in controller.applied)

    first = run_cell(plant, [(0.0, a)], timing.restart_first_s, model_file, model=model,
                     stop_when=holds_a)
    written = first["controller"]["load_in_force"]
    held = None if written is None else Payload.from_set_load(
        written["mass"], written["com"], written["inertia"], name="A as written")
    second = run_cell(plant, [(0.0, b)], timing.restart_s, model_file, model=None,
                      controller_load=held)
    first["payload"], second["payload"] = "A", "B"
    second["old"] = load_of(a)
    second["a_written"] = load_of(held)
    return [first, second]

