"""``iem bench writeback``: the write-back, scenario by scenario, on the simulated controller.

The plug-in service against the simulated controller (:mod:`deploy.bench.writeback.scenarios`:
1 kHz in real time on python-can's virtual bus, the gate's defaults), on the ideal plant
(IEM+phys trained with the sensor's noise as its equations' error, as ``iem demo`` runs it),
on the realistic plant (``iem bench realistic``'s reality gap of the seed, the bare arm
calibrated as that bench does, IEM+phys trained for the calibrated arm) and with the default
configuration (the ideal plant, IEM+phys as a cell of the shipped ``deploy/cell.toml``
trains it for itself: no arm file, the default ``[arm] noise``), per seed:

- ``tool_removed``: test-3w (1.615 kg) from the start, removed at the change; the controller
  starts at 0 kg;
- ``tool_swapped``: test-3w swapped for test-2w (1.34 kg) at the change;
- ``lost_1``, ``lost_3``: test-3w from the start, the controller loses the first 1 or 3 load
  commands (neither applied nor acknowledged);
- ``restart``: test-3w (A) until the controller holds it, the model saved at the service's
  close; a service restarted from that file against a controller that carries test-2w (B)
  and holds the load written for A;
- ``refusals``: the excitation path played once, then at rest; the controller refuses load
  commands while the arm moves;

and, offline, the real recording (:mod:`deploy.bench.writeback.real`, ``real``:
semi-synthetic, no controller). A load is *correct* within 0.05 kg and 10 mm of the truth;
what is in force is the controller's own record (each command it applied). A write is
*farther* when the load it applies errs more in mass or CoM distance than the load before
it (:mod:`deploy.bench.writeback.score`). The targets (:func:`targets_of`) are printed MET or
MISSED beside the figures; every simulated figure holds in simulation only.

``--json FILE`` writes every figure; ``--out DIR`` a figure per run
(:mod:`deploy.bench.writeback.figures`, the ``plots`` extra), the arm files and the real
recording's CSVs.
"""

from __future__ import annotations

import json
import sys
import tempfile
import time
from pathlib import Path as FsPath

from deploy.bench.writeback.scenarios import SCENARIOS, TIMING
from deploy.bench.writeback.score import (
    fmt,
    held_text,
    like,
    reason_shares,
    time_to_correct,
    worst,
    writes,
)
from iem.errors import InvalidInputError

PLANTS = ("ideal", "realistic", "default")
ALL = (*SCENARIOS, "real")
CORRECT_WITHIN_S = {"ideal": 2.0, "realistic": 5.0, "default": 2.0}
"""tool_removed and tool_swapped: the correct load in force within this many s of the
change."""
LOST_WITHIN_S = 10.0
RESTART_WITHIN_S = 5.0
REST_WITHIN_S = 10.0
"""refusals: the correct load in force within this many s of the arm coming to rest (the
gate's longest refusal back-off)."""


def targets_of(run: dict) -> dict | None:
    """The target of a run: ``{"target", "measured", "met", "why"}`` (None: a run that only
    sets up another, the restart's first)."""
    c = run["controller"]
    applied, schedule, initial = c["applied"], run["schedule"], run["initial_load"]
    end, name = run["end_s"], run["scenario"]
    since, limit, extra, ok = 0.0, None, "", True
    if name in ("tool_removed", "tool_swapped"):
        since, limit = run["change_s"], CORRECT_WITHIN_S[run["plant"]]
        target = f"correct load in force within {limit:g} s of the change"
    elif name in ("lost_1", "lost_3"):
        sends = run["sends"]
        since = sends[0]["t"] if sends else end
        limit, w = LOST_WITHIN_S, run["summary"]["writes"]
        ok = w["lost"] == run["drops"] and w["in_force"] == len(applied)
        target = (f"correct load in force within {limit:g} s of the first (lost) command; "
                  f"{run['drops']} counted lost, not in force")
        extra = f"; lost {w['lost']}, in force {w['in_force']}, applied {len(applied)}"
    elif name == "restart":
        if run["part"] == 0:
            return None
        limit = RESTART_WITHIN_S
        old = like([s["load"] for s in run["sends"]], run["old"]) + like(applied, run["old"])
        ok = old == 0
        target = f"A never written again; B in force within {limit:g} s"
        extra = f"; A written {old} times"
    elif name == "refusals":
        since, limit = run["rest_s"], REST_WITHIN_S
        moving = sum(1 for a in applied if a["t"] < since)
        ok = moving == 0
        target = (f"refused while moving, correct load in force within {limit:g} s of "
                  "rest")
        extra = f"; applied while moving {moving}, refused {c['refused_moving']}"
    else:
        raise ValueError(f"scenario {name!r}")
    ttc = time_to_correct(initial, applied, schedule, since, end)
    met = ok and ttc is not None and ttc <= limit
    why = ""
    if not met:
        why = held_text(reason_shares(run["t"], run["reasons"], since, end))
    return {"target": target, "measured": f"{fmt(ttc)} s{extra}", "time_to_correct_s": ttc,
            "met": bool(met), "why": why}


def figures_of(run: dict) -> dict:
    """A run's figures for the table and the JSON (no time series)."""
    c = run["controller"]
    rows = writes(run["initial_load"], c["applied"], run["schedule"])
    return {"scenario": run["scenario"], "plant": run["plant"], "seed": run["seed"],
            "part": run["part"], "writes": rows, "sends": run["sends"],
            "worst_mass_error_kg": worst(rows, "mass_error_kg"),
            "worst_com_error_mm": worst(rows, "com_error_mm"),
            "farther": sum(r["farther"] for r in rows),
            "counts": run["summary"]["writes"], "decisions": run["summary"]["gate"],
            "controller": {k: v for k, v in c.items() if k != "applied"},
            "gate_in_force": run["gate_in_force"], "log": run["log"],
            "end_s": run["end_s"], "target": targets_of(run)}


def measure(seeds, plants, scenarios, quick: bool, out_dir, real_dir=None,
            log=print, description=None, rated_mass_kg: float | None = None) -> dict:
    """Every run, on the arm model ``description`` (None: the default), the gate rated for
    ``rated_mass_kg`` (None: the arm model's rated payload); the figures, with ``runs`` (the
    records, for the figures) beside them."""
    from deploy.bench.writeback.scenarios import (
        default_plant,
        ideal_plant,
        realistic_plant,
        run_scenario,
    )
    from deploy.config import cell_config

    # an end effector beyond the rated payload fails before training
    cell_config(description, rated_mass_kg, where="bench writeback")

    timing = TIMING["quick" if quick else "full"]
    records, figures, setup = [], [], []
    sim = [s for s in scenarios if s != "real"]
    for seed in seeds:
        for kind in plants if sim else ():
            t0 = time.perf_counter()
            if kind == "realistic":
                plant = realistic_plant(seed, out_dir, log=log, description=description,
                                        rated_mass_kg=rated_mass_kg)
            else:
                plant = (ideal_plant if kind == "ideal" else default_plant)(
                    seed, log=log, description=description, rated_mass_kg=rated_mass_kg)
            setup.append({"plant": kind, "seed": seed, "calibration": plant.calibration,
                          "set_up_s": time.perf_counter() - t0})
            for name in sim:
                for run in run_scenario(name, plant, timing, log=log):
                    records.append(run)
                    figures.append(figures_of(run))
    real = None
    if "real" in scenarios:
        from deploy.bench.writeback.real import run_real_cases

        real = run_real_cases(FsPath(out_dir) / "real", real_dir, log=log)
    return {"quick": quick, "seeds": list(seeds), "plants": list(plants),
            "timing": vars(timing), "setup": setup, "runs": figures,
            "real": None if real is None else {k: v for k, v in real.items()
                                               if k != "series"},
            "_records": records, "_real": real}


def table(results: dict) -> str:
    """The table printed on stdout."""
    lines = ["iem bench writeback: simulation only (the ideal and the realistic plant, the "
             "default configuration), "
             "except 'real'; correct = within 0.05 kg and 10 mm of the truth; in force = "
             "the controller's own record; farther = a write whose load errs more in mass "
             "or CoM distance than the load before it",
             _row("scenario", "plant", "seed", "to correct", "writes", "worst kg/mm",
                  "farther", "sent/ack/lost/in force", "ctrl kg", "result")]
    for f in results["runs"]:
        t, w = f["target"], f["counts"]
        load = f["controller"]["load_in_force"]
        name = f["scenario"] + (f" {'AB'[f['part']]}" if f["scenario"] == "restart" else "")
        lines.append(_row(
            name, f["plant"], f["seed"],
            "" if t is None else f"{fmt(t['time_to_correct_s'])} s", len(f["writes"]),
            f"{fmt(f['worst_mass_error_kg'], '.3f')}/{fmt(f['worst_com_error_mm'], '.1f')}",
            f["farther"], f"{w['sent']}/{w['acked']}/{w['lost']}/{w['in_force']}",
            f"{0.0 if load is None else load['mass']:.3f}",
            "setup" if t is None else ("MET" if t["met"] else "MISSED")))
    lines += ["", "targets (simulation only):"]
    groups: dict = {}
    for f in results["runs"]:
        if f["target"] is not None:
            groups.setdefault((f["scenario"], f["plant"]), []).append(f)
    for (scenario, plant), runs in groups.items():
        met = all(f["target"]["met"] for f in runs)
        measured = "; ".join(f"seed {f['seed']}: {f['target']['measured']}" for f in runs)
        why = "; ".join(f"seed {f['seed']} {f['target']['why']}" for f in runs
                        if f["target"]["why"])
        lines.append(f"  {scenario} ({plant}): {runs[0]['target']['target']}, every seed: "
                     f"{measured}: {'MET' if met else 'MISSED'}"
                     + (f" ({why})" if why else ""))
    real = results.get("real")
    if real:
        lines += ["", f"real recording, offline (semi-synthetic: the payload's exact torque "
                      f"added to a real bare arm's held-out {real['held_out_s']:.1f} s; the "
                      "loads the gate would send):"]
        for name, c in real["cases"].items():
            w = c["writes"]
            errs = ", ".join(f"{r['mass_error_kg']:.3f} kg/{fmt(r['com_error_mm'], '.1f')} mm"
                             f" band {'yes' if r['in_band'] else 'no'}" for r in w)
            lines.append(f"  {name:10s} {c['count']} writes, first "
                         f"{fmt(c['first_write_s'])} s after the first estimate"
                         + (f" ({errs})" if errs else "")
                         + f"; target {c['target']}: {'MET' if c['met'] else 'MISSED'}")
    return "\n".join(lines)


def _row(*cells) -> str:
    widths = (13, 9, 4, 10, 6, 12, 7, 22, 7, 6)
    return " ".join(f"{c!s:<{n}}" if i < 2 or i == 9 else f"{c!s:>{n}}"
                    for i, (c, n) in enumerate(zip(cells, widths, strict=True))).rstrip()


def _seeds(text: str) -> list[int]:
    try:
        seeds = [int(s) for s in text.split(",") if s.strip()]
    except ValueError:
        seeds = []
    if not seeds or any(s < 0 for s in seeds):
        raise InvalidInputError(f"--seeds {text!r}: valid is a comma-separated list of "
                                "integers >= 0, e.g. 0,1,2")
    return seeds


def _scenarios(text: str) -> list[str]:
    names = [s.strip() for s in text.split(",") if s.strip()]
    bad = [s for s in names if s not in ALL]
    if not names or bad:
        raise InvalidInputError(f"--scenarios {text!r}: valid are {', '.join(ALL)} "
                                "(comma-separated)")
    return names


def configure(parser) -> None:
    parser.add_argument("--seeds", default="0,1,2", help="comma-separated seeds (default "
                        "0,1,2): sensor noise, learners and the realistic plant's gap")
    parser.add_argument("--quick", action="store_true",
                        help="the first seed only, shorter scenarios")
    parser.add_argument("--plant", choices=(*PLANTS, "both", "all"), default=None,
                        help="which plant: ideal (its model trained with the sensor's noise), "
                        "realistic, default (the ideal plant with the model the default "
                        "configuration trains), both (ideal and realistic) or all (default)")
    parser.add_argument("--scenarios", default=",".join(ALL),
                        help=f"comma-separated, of {', '.join(ALL)} (default all)")
    parser.add_argument("--json", metavar="FILE", help="write every figure as JSON")
    parser.add_argument("--out", metavar="DIR", help="a figure per run (needs the plots "
                        "extra), the arm files and the real recording's CSVs")
    parser.add_argument("--real", metavar="DIR", help="folder of the real recording "
                        "(default: IEM_REAL_DIR, else ../shared/real beside the checkout)")
    from deploy.options import add_arm_model, add_rated_mass

    add_arm_model(parser)
    add_rated_mass(parser)


def run(args) -> int:
    from deploy.bench.real import require_panda
    from deploy.options import arm_description_of, refuse_unused
    from iem.extras import require

    seeds = _seeds(args.seeds)[:1] if args.quick else _seeds(args.seeds)
    scenarios = _scenarios(args.scenarios)
    description = arm_description_of(args)
    if "real" in scenarios:
        require_panda(description, "iem bench writeback's real scenario")
    else:
        refuse_unused(args, ["--real"], "without the real scenario: it is that scenario's "
                      "recording")
    if set(scenarios) == {"real"}:
        refuse_unused(args, ["--plant"], "with the real scenario alone: it runs on the "
                      "recording, not on a simulated plant")
    plants = {None: PLANTS, "all": PLANTS, "both": ("ideal", "realistic")}.get(
        args.plant, (args.plant,))
    if args.out:
        require("matplotlib", "iem bench writeback --out (its figures)")

    def log(msg: str) -> None:
        print(msg, file=sys.stderr, flush=True)

    with tempfile.TemporaryDirectory() as tmp:
        folder = FsPath(args.out) if args.out else FsPath(tmp)
        results = measure(seeds, plants, scenarios, args.quick, folder, args.real, log=log,
                          description=description, rated_mass_kg=args.rated_mass_kg)
        if args.out:
            from deploy.bench.writeback.figures import write_figures

            names = write_figures(folder, results["_records"], results["_real"])
            log(f"wrote {len(names)} figures to {folder}")
    print(table(results))
    if args.json:
        clean = {k: v for k, v in results.items() if not k.startswith("_")}
        FsPath(args.json).write_text(json.dumps(clean, indent=2, default=_plain) + "\n",
                                     encoding="utf-8")
    return 0


def _plain(value):
    """JSON for numpy values."""
    import numpy as np

    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"{type(value).__name__} is not JSON")
