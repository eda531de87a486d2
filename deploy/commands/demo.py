"""``iem demo``: the whole loop on the simulated arm, in about a minute.

The simulated controller (the MuJoCo arm of ``--arm-model``, the Panda by default, with the
default test payload, 1 kHz in real time) plays the excitation path (20 s), a transfer (4 s)
and the new task path (6 s) once, on python-can's virtual bus; the plug-in service runs
against it over the same frames a cell would carry: it trains its initial model on the
excitation path, estimates the payload as the arm moves, forms new bags on the new path, and
writes the load back through the safety gate, which the controller acknowledges. The paths
are the arm model's (made for its limits, around its home configuration), and the plug-in's
configuration names the same arm model (``[arm] model``, with ``[gate] rated_mass_kg`` from
``--rated-mass-kg`` for an arm model from a file, which gives no rated payload). Progress
shows on the status line; at the end the summary is printed and a report folder is written
(``summary.json``, ``error.png``: error against time as in the paper's Fig. 6, ``bags.png``:
bag centres in the workspace).

The controller runs in a thread of this process (the virtual bus does not cross processes;
see :mod:`deploy.simcell.inprocess`).
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path as FsPath

import numpy as np

from deploy.options import add_arm_model, add_rated_mass, arm_description_of
from iem.model_kinds import DEFAULT_MODEL

TRANSFER_S = 4.0
HOLD_S = 1.0


def demo_path(description=None):
    """Excitation, transfer to the new task's start, new task path: one continuous path, on
    the arm model ``description`` (None: the default)."""
    from sim.paths import excitation_path, linear_path, new_task_path
    from sim.robot import arm_model

    model = arm_model(description)
    home, task = model.description.home, model.description.task
    exc = excitation_path(model=model)
    transfer = linear_path(home, task[0], TRANSFER_S, "transfer", model=model)
    new = new_task_path(model=model)
    phases = [("excitation", 0.0, exc.duration),
              ("transfer", exc.duration, exc.duration + TRANSFER_S),
              ("new task", exc.duration + TRANSFER_S,
               exc.duration + TRANSFER_S + new.duration)]
    return exc.then(transfer).then(new, name="demo"), phases


def run_demo(out_dir, seed: int = 0, kind: str | None = None, json_path=None,
             status: bool = True, log=print, arm_file=None,
             cpu_dma_latency_us: int = -1, description=None,
             rated_mass_kg: float | None = None) -> dict:
    """The demo (see the module docstring); ``arm_file``: the plug-in runs on this arm file
    (``iem calibrate``; its model is trained for it). The simulated controller's plant is
    the nominal arm of the arm model ``description`` (None: the default) either way.
    ``rated_mass_kg``: the gate's rated payload (None: the arm model's; an arm model from a
    file has none). ``cpu_dma_latency_us``: as ``[host]`` in ``cell.toml``.
    Without the extras it needs (``sim``: MuJoCo; ``plots``: matplotlib) it stops at once
    with :class:`iem.errors.MissingExtraError`, before a minute of simulation."""
    from iem.extras import require

    require("mujoco", "iem demo (the simulated arm)")
    require("matplotlib", "iem demo (its figures)")
    from deploy.service.status import StatusLine
    from deploy.simcell.inprocess import simulated_cell
    from sim.description import described
    from sim.family import default_test_payload

    out = FsPath(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    kind = kind or DEFAULT_MODEL
    payload = default_test_payload()
    truth = payload.to_phi()
    description = described(description)
    config = _demo_config(out / "model.msgpack", kind, seed, arm_file, status,
                          cpu_dma_latency_us, description, rated_mass_kg)
    path, phases = demo_path(description)
    (out / "model.msgpack").unlink(missing_ok=True)  # always from the excitation path
    log(f"iem demo: arm model {description.name}, payload {payload.name} "
        f"({payload.mass:.3f} kg), path {path.duration:.0f} s (excitation, transfer, new task), "
        f"model {kind}")
    rows: list[tuple] = []
    with simulated_cell(config, path=path, payload=payload, once=True, seed=seed,
                        status=StatusLine(status, sys.stderr, 0.25),
                        description=description) as (controller, service):
        service.on_cycle.append(lambda r: rows.append(
            (r.state.t, r.raw.bag, r.smoothed.copy(), r.state.q)))
        announced = set()

        def until() -> bool:
            t = controller.cycles * 1e-3
            for name, start, _ in phases:
                if t >= start and name not in announced:
                    announced.add(name)
                    service.status.clear()
                    log(f"t = {t:5.1f} s: {name} path")
            return t >= path.duration + HOLD_S

        controller.start()
        started = time.monotonic()
        summary = service.run(until=until)
        wall = time.monotonic() - started

    t = np.array([r[0] for r in rows])
    est = np.array([r[2] for r in rows])
    bags = np.array([r[1] for r in rows])
    summary.update(_figures_of_the_run(t, est, truth, phases, wall, summary, controller))
    summary["payload"] = payload.name
    summary["arm_model"] = description.record()
    _figures(out, t, est, bags, truth, phases, service, rows)
    text = json.dumps(summary, indent=2, default=float)
    (out / "summary.json").write_text(text + "\n")
    if json_path:
        FsPath(json_path).write_text(text + "\n")
    _print_summary(summary, out, log)
    return summary


def _demo_config(model_file, kind: str, seed: int, arm_file, status: bool,
                 cpu_dma_latency_us: int, description=None, rated_mass_kg=None):
    """The demo cell's configuration: the virtual bus, a model trained afresh at
    ``model_file``, the arm model ``description`` (an
    :class:`~sim.description.ArmDescription`; None: the default), the gate as a cell of that
    model kind needs it, rated for ``rated_mass_kg`` (None: the arm model's rated payload).

    Raises:
        iem.errors.InvalidInputError: an arm model from a file without ``rated_mass_kg``."""
    from deploy.config import cell_config
    from deploy.simcell.inprocess import virtual_link

    return cell_config(
        description, rated_mass_kg, where="demo", status=status, link=virtual_link("demo"),
        model={"path": str(model_file), "kind": kind, "seed": seed,
               "checkpoint_period_s": 10.0, "arm": str(arm_file or "")},
        # the demo's plant without an arm file is the nominal model itself: the sensor's
        # noise is all its equations carry; with one, the arm's measured noise
        arm={"noise": "arm" if arm_file else "sensor"},
        host={"cpu_dma_latency_us": cpu_dma_latency_us})


def _figures_of_the_run(t, est, truth, phases, wall: float, summary: dict,
                        controller) -> dict:
    """What the demo adds to the service's summary: the MAE over the run and per phase, the
    final estimate, the estimate rate, the simulated controller's figures and its load."""
    from iem.metrics import mae_groups

    load = controller.plant.controller_load
    return {
        "mae_groups": mae_groups(est, truth),
        "mae_groups_by_phase": {
            name: mae_groups(est[(t >= a) & (t < b)], truth) for name, a, b in phases
            if np.any((t >= a) & (t < b))},
        "final_estimate": {"phi": est[-1].tolist(), "truth": truth.tolist()},
        "estimates_per_s": summary["estimates"] / wall if wall > 0 else None,
        "controller": controller.stats(),
        "controller_load": None if load is None else {"mass": load.mass,
                                                      "com": list(load.com)},
    }


def _print_summary(s: dict, out, log) -> None:
    """The service's summary in words (:func:`deploy.service.report.summary_lines`, as
    ``iem run`` prints it), with the errors against the truth and the controller's load."""
    from deploy.service.report import summary_lines

    g = s["mae_groups"]
    errors = [f"  MAE over the run: mass {g['mass']:.4f} kg, com {g['com']:.4f} kg·m, "
              f"inertia {g['inertia']:.5f} kg·m²"]
    errors += [f"    {name:10s} mass {pg['mass']:.4f} kg, com {pg['com']:.4f} kg·m, "
               f"inertia {pg['inertia']:.5f} kg·m²"
               for name, pg in s["mae_groups_by_phase"].items()]
    log("")
    for line in summary_lines(s, f"payload {s['payload']}", errors):
        log(line)
    if s["controller_load"]:
        cl = s["controller_load"]
        log(f"  the controller's load now: {cl['mass']:.4f} kg, CoM "
            f"[{cl['com'][0]:.4f}, {cl['com'][1]:.4f}, {cl['com'][2]:.4f}] m")
    log(f"  report: {out}/summary.json, error.png, bags.png")


def _figures(out, t, est, bags, truth, phases, service, rows) -> None:
    from iem.extras import require
    from iem.types import GROUPS

    require("matplotlib", "iem demo (its figures)").use("Agg")
    import matplotlib.pyplot as plt

    err = np.abs(est - truth)
    fig, axes = plt.subplots(3, 1, figsize=(9, 7), sharex=True)
    units = {"mass": "kg", "com": "kg·m", "inertia": "kg·m²"}
    for ax, (g, idx) in zip(axes, GROUPS.items(), strict=True):
        ax.semilogy(t, err[:, list(idx)].mean(axis=1) + 1e-9, lw=0.8)
        ax.set_ylabel(f"{g} error ({units[g]})")
        for name, a, b in phases:
            ax.axvspan(a, b, alpha=0.08 if name != "transfer" else 0.18, color="grey")
            if g == "mass":
                ax.text(a + 0.2, ax.get_ylim()[1] * 0.5, name, fontsize=8)
    axes[-1].set_xlabel("controller time (s)")
    fig.suptitle("absolute error of the smoothed estimate (as the paper's Fig. 6)")
    fig.tight_layout()
    fig.savefig(out / "error.png", dpi=110)
    plt.close(fig)

    q = np.array([r[3] for r in rows[::20]])
    pts = service.kinematics.flange_positions(q)
    fig = plt.figure(figsize=(6, 5))
    ax = fig.add_subplot(projection="3d")
    ax.scatter(*pts.T, c=bags[::20], cmap="tab10", s=2, vmin=0, vmax=9)
    centres = service.model.router.flange_means if hasattr(service.model, "router") else None
    if centres is not None:
        ax.scatter(*centres.T, c="k", marker="x", s=60, label="bag centres")
        ax.legend()
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_zlabel("z (m)")
    ax.set_title(f"{service.model.n_bags} bags: the flange path coloured by bag")
    fig.tight_layout()
    fig.savefig(out / "bags.png", dpi=110)
    plt.close(fig)


def configure(parser) -> None:
    parser.add_argument("--out", default="out/demo", metavar="DIR", help="report folder")
    parser.add_argument("--json", metavar="FILE", help="also write the summary here")
    parser.add_argument("--model", choices=["IEM", "IEM+phys"], default=None,
                        help="model kind (default: the best available)")
    parser.add_argument("--seed", type=int, default=0, help="sensor-noise and learner seed")
    parser.add_argument("--no-status", action="store_true", help="no live status line")
    parser.add_argument("--arm", metavar="ARM", help="arm file for the plug-in (from "
                        "'iem calibrate'; default: the nominal arm)")
    from deploy.service.host import add_cpu_latency_option

    add_cpu_latency_option(parser)
    add_arm_model(parser)
    add_rated_mass(parser)


def run(args) -> int:
    from deploy.service.logs import setup_logging

    description = arm_description_of(args)  # a bad arm model before anything runs
    setup_logging("warning", "text")
    run_demo(args.out, seed=args.seed, kind=args.model, json_path=args.json,
             status=not args.no_status, arm_file=args.arm,
             cpu_dma_latency_us=args.cpu_dma_latency_us, description=description,
             rated_mass_kg=args.rated_mass_kg)
    return 0
