"""``iem bench excite``: what the motion of ``iem excite`` determines, on the realistic plant.

The motion (:func:`sim.excite.excite_path`, ``--seconds`` from the arm model's home) is
designed once; the bench prints its duration, its condition number beside the excitation
path's and the new task path's (the scaled payload regressor, :func:`sim.excite.
condition_number`), and the limits it keeps (its peaks against the arm model's). Then, per
seed, on ``iem bench realistic``'s plant of that seed (its reality gap, the bare arm
calibrated as that bench does, IEM+phys trained for the calibrated arm as ``iem train
--arm`` makes it), the plant runs the motion bare and with each of :data:`PAYLOADS`, and
from the motion's data alone:

- ``identify+bare``: ``iem identify`` of the loaded recording with the bare one;
- ``identify+arm``: ``iem identify`` of the loaded recording with the arm file;
- ``live``: IEM+phys's smoothed estimate at the motion's end, learning as it goes;

and the same two with the arm calibrated on the motion's bare run too (the calibration motion
and the bare run together, as ``iem calibrate bare-arm.blf bare-motion.blf`` does, IEM+phys
trained for that arm): ``identify+arm_motion`` and ``live_arm_motion``, what a cell that
records the motion once bare at commissioning gets; and with that arm's torque sensors' gain
read from the calibration motion played with a known load, :data:`KNOWN_LOAD`, which is not
one of :data:`PAYLOADS` (``iem calibrate ... --known-load --known-payload``;
:mod:`sim.calibration.gain`): ``identify+arm_known_load`` and ``live_arm_known_load``. The
loaded runs have noise seeds of their own. Each seed's ``gain`` gives the gains read and the
plant's own (the simulation knows them).

Each is compared with :data:`TARGET` (mass kg, CoM mm). ``--json FILE`` writes it all.
Simulation only.
"""

from __future__ import annotations

import json
import sys
import tempfile
import time
from pathlib import Path as FsPath

import numpy as np

from ..options import add_arm_model, arm_description_of

TARGET = (0.02, 5.0)
"""Mass within 0.02 kg and CoM within 5 mm of the truth."""
PAYLOADS = ("test-3w", "light-tool", "offaxis-tool")
"""The paper's test payload (1.615 kg), ``iem bench realistic``'s 0.4 kg light tool and its
2.7 kg off-axis tool."""
KINDS = ("identify+bare", "identify+arm", "live", "identify+arm_motion", "live_arm_motion",
         "identify+arm_known_load", "live_arm_known_load")
"""What each payload's row holds, in the order printed."""
KNOWN_LOAD = "test-4w"
"""The known load the sensors' gain is read with (1.89 kg; not one of :data:`PAYLOADS`)."""
KNOWN_NOISE = 7
"""The known load's run of the calibration motion has noise seed ``CAL_NOISE_BASE + seed +
KNOWN_NOISE``."""
EXCITE_NOISE = 300
"""The motion's rollouts have noise seeds ``seed + EXCITE_NOISE`` (bare) and one more
(loaded)."""


def _payloads() -> dict:
    from sim.family import test_payloads

    from .realistic import tools

    every = tools()
    return {"test-3w": test_payloads()["test-3w"], "light-tool": every["light_tool"],
            "offaxis-tool": every["offaxis_tool"]}


def errors(phi, truth) -> tuple[float, float]:
    """``(mass error kg, CoM distance mm)`` of ``phi`` from ``truth`` (paper order)."""
    phi, truth = np.asarray(phi, dtype=float), np.asarray(truth, dtype=float)
    com = np.linalg.norm(phi[1:4] / phi[0] - truth[1:4] / truth[0]) if phi[0] > 0 else np.inf
    return float(phi[0] - truth[0]), float(1000.0 * com)


def design_figures(path, design, model) -> dict:
    """The motion's duration, conditions (its own, the excitation path's and the new task
    path's) and the limits it keeps."""
    from sim.excite import DESIGN_RATE_HZ, condition_number
    from sim.paths import excitation_path, new_task_path

    every = round(1000 / DESIGN_RATE_HZ)
    others = {p.name: condition_number(model, p.q[::every], p.dq[::every], p.ddq[::every])
              for p in (excitation_path(model=model), new_task_path(model=model))}
    return {"seconds": path.duration, "condition": design.condition,
            "condition_of": others,
            "q_peak_share": (np.array(design.q_peak) / np.array(design.q_room)).tolist(),
            "dq_peak_share": (np.array(design.dq_peak) / np.array(design.dq_max)).tolist(),
            "ddq_peak_share": (np.array(design.ddq_peak) / np.array(design.ddq_max)).tolist()}


def run_seed(path, seed: int, out_dir, log=print, description=None) -> dict:
    """The motion on ``iem bench realistic``'s plant of ``seed``: identify and live figures
    per payload, and the sensors' gain read with the known load (``gain``)."""
    from deploy.model.training import train_initial_model
    from sim.arm import save_arm
    from sim.calibration.gain import with_gain
    from sim.family import test_payloads
    from sim.identify import identify
    from sim.paths import calibration_path
    from sim.robot import ArmModel
    from sim.tandem import TandemSimulators

    from .realistic import CAL_NOISE_BASE, RealisticBench, calibrated_arm

    bench = RealisticBench(seed=seed, log=lambda *a: None, description=description)
    folder = FsPath(out_dir) / f"seed{seed}"
    folder.mkdir(parents=True, exist_ok=True)
    arm, _, arm_file = calibrated_arm(bench, folder, None, log)
    bare = bench.rollout(path, None, seed + EXCITE_NOISE)
    cut = lambda r: (r.t, r.q, r.dq, r.tau)  # noqa: E731
    # the arm calibrated on the motion's bare run too: what a cell that records it once
    # bare at commissioning gives iem calibrate
    arm_motion, _ = bench.calibrate(extra=[cut(bare)], source="bench excite calibration "
                                                              "motion and the motion, bare")
    motion_file = folder / "arm-with-motion.msgpack"
    save_arm(arm_motion, motion_file)
    # that arm's sensors' gain, read with a known load along the calibration motion
    known = test_payloads()[KNOWN_LOAD]
    known_run = bench.rollout(calibration_path(model=bench.kin), known,
                              CAL_NOISE_BASE + seed + KNOWN_NOISE)
    arm_known = with_gain(arm_motion, [cut(known_run)], known)
    gain = arm_known.gain
    known_file = folder / "arm-known-load.msgpack"
    save_arm(arm_known, known_file)
    plant_gain = bench.gap.unmodelled(bench.description).gain  # what the simulation knows
    log(f"seed {seed} gain read with {KNOWN_LOAD} " + " ".join(f"{g:+.4f}" for g in gain)
        + " (plant " + " ".join(f"{g:+.4f}" for g in plant_gain) + ")")
    live = {}
    for kind, its_arm, its_file in (("live", arm, arm_file),
                                    ("live_arm_motion", arm_motion, motion_file),
                                    ("live_arm_known_load", arm_known, known_file)):
        live[kind] = (train_initial_model("IEM+phys", seed=seed, arm_file=str(its_file),
                                          log=lambda *a: None, description=description),
                      TandemSimulators(bench.tandem.phi, model=ArmModel(arm=its_arm)))
    out = {}
    for name, payload in _payloads().items():
        loaded = bench.rollout(path, payload, seed + EXCITE_NOISE + 1)
        truth = payload.to_phi()
        row = {}
        for kind, kw in (("identify+bare", {"bare": cut(bare)}), ("identify+arm", {"arm": arm}),
                         ("identify+arm_motion", {"arm": arm_motion}),
                         ("identify+arm_known_load", {"arm": arm_known})):
            row[kind] = errors(identify(cut(loaded), check_excitation=False,
                                        model=bench.kin, **kw).phi, truth)
        for kind, (model, tandem) in live.items():
            run = bench.run(_fresh(model), loaded, learn=True, tandem=tandem)
            row[kind] = errors(run.smoothed[-1], truth)
        out[name] = {kind: row[kind] for kind in KINDS}
        log(f"seed {seed} {name:12s} " + " | ".join(
            f"{k} {m:+.4f} kg {c:5.1f} mm" for k, (m, c) in out[name].items()))
    out["gain"] = {"read": gain.tolist(), "measured": arm_known.report["gain"]["measured"],
                   "plant": plant_gain.tolist()}
    return out


def _fresh(model):
    import copy

    return copy.deepcopy(model)


def run_excite(seeds, seconds: float, out_dir, log=print, description=None) -> dict:
    from sim.excite import excite_path
    from sim.robot import ArmModel

    started = time.perf_counter()
    kin = ArmModel(description=description)
    path, design = excite_path(seconds, model=kin)
    figures = design_figures(path, design, kin)
    log(f"excite motion: {figures['seconds']:.1f} s, condition {figures['condition']:.0f} "
        f"(excitation path {figures['condition_of']['excitation']:.0f}, new task path "
        f"{figures['condition_of']['new-task']:.0f}); peaks / limits: q "
        f"{max(figures['q_peak_share']):.2f} of the room, dq "
        f"{max(figures['dq_peak_share']):.2f}, ddq {max(figures['ddq_peak_share']):.2f}")
    results = {"design": figures, "seeds": {}, "target": {"mass_kg": TARGET[0],
                                                         "com_mm": TARGET[1]}}
    for seed in seeds:
        results["seeds"][seed] = run_seed(path, seed, out_dir, log, description)
    met = {kind: all(abs(rows[name][kind][0]) <= TARGET[0] and rows[name][kind][1] <= TARGET[1]
                     for rows in results["seeds"].values() for name in PAYLOADS)
           for kind in KINDS}
    results["met"] = met
    results["wall_s"] = time.perf_counter() - started
    log("target (within 0.02 kg and 5 mm, every payload and seed, simulation only): "
        + ", ".join(f"{k}: {'MET' if v else 'MISSED'}" for k, v in met.items()))
    return results


def configure(parser) -> None:
    parser.add_argument("--seeds", default="0,1,2", help="seeds of the realistic plant")
    parser.add_argument("--seconds", type=float, default=10.0,
                        help="duration of the designed motion, s (default 10)")
    parser.add_argument("--out", metavar="DIR", help="folder for the arm files (default: a "
                        "temporary one)")
    parser.add_argument("--json", metavar="FILE", help="write the figures as JSON")
    add_arm_model(parser)


def run(args) -> int:
    from iem.errors import InvalidInputError

    description = arm_description_of(args)
    try:
        seeds = [int(s) for s in str(args.seeds).split(",") if s.strip()]
    except ValueError as exc:
        raise InvalidInputError(f"--seeds {args.seeds!r}: valid is a comma-separated list of "
                                f"integers, e.g. 0,1,2") from exc
    print("iem bench excite: simulation only (the realistic plant)", file=sys.stderr)
    with tempfile.TemporaryDirectory() as tmp:
        results = run_excite(seeds, args.seconds, args.out or tmp,
                             log=lambda m: print(m, flush=True), description=description)
    if args.json:
        FsPath(args.json).write_text(json.dumps(results, indent=2) + "\n", encoding="utf-8")
    return 0
