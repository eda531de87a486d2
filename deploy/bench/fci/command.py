"""``iem bench fci``: the plug-in against an FR3 that speaks the robot's own protocol.

franky-sim's FR3 (:class:`deploy.simcell.FciSim`: MuJoCo Menagerie's FR3 with the Franka
Hand, its joints' armature, damping and friction in ``tau_J``; a payload body on the flange;
``setLoad`` refused while the arm moves, as a real FR3 refuses it) served over the libfranka
protocol on 127.0.0.1, and the plug-in through the real bindings (pylibfranka 0.21.3,
franky-control 2.0.0):

1. **Commissioning** (unless ``--arm`` and ``--model`` give its results): the robot's own
   program plays the calibration motion (:func:`sim.paths.calibration_path`) on the bare
   arm while ``iem calibrate --interface franka --armature`` records it through the link;
   ``iem train --arm`` makes the model for the calibrated arm.
2. **The pick-and-place** (:mod:`deploy.bench.fci.schedule`), two ways:

   - ``program``: a franky-control program with the plug-in inside
     (:class:`deploy.service.PayloadPlugin`), its motions' callbacks feeding it, ``apply()``
     after each motion (:mod:`deploy.bench.fci.clients`);
   - ``run``: the plug-in as ``iem run`` runs it, the FCI client on the ``franka`` link,
     while the robot's own program moves the arm and grasps;
   - ``bare``: the ``program`` way's program without the plug-in, for the control loop's
     pace beside it (``--fifo``: franky's loop and franky-sim at real-time priority).

Per payload change it prints (:mod:`deploy.bench.fci.score`) the time from the end of the
motion that carried the change to the correct load in force (read from the robot's
``m_load``), the load in force's error (mass, CoM, joint torque at that motion's poses), the
writes and those that put the robot farther from the truth, a non-empty load written on the
bare arm, the robot's refusals; per run the callback's cost per state (the ``program`` way),
the robot time's pace against the wall clock and the states the client lost. The targets
are printed MET or MISSED: every change correct before the arm moves again (the robot takes
no load while it moves, so not before the carrying motion ends), no write farther from the
truth, no bare write, the callback at most :data:`CALLBACK_P99_US` at the 99th percentile.

``--out DIR`` keeps the commissioning's files, each client's records and a figure per run
(:mod:`deploy.bench.fci.figures`); ``--json FILE`` writes every figure. Everything here is a
simulation: the figures hold for franky-sim's FR3 only.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path as FsPath

import numpy as np

from iem.errors import InvalidInputError

WAYS = ("program", "run", "bare")
CALLBACK_P99_US = 50.0
"""The callback's cost per state, 99th percentile, at most this (µs)."""
FACTOR = 0.25
"""franky's relative dynamics factor for the program's motions: pick to place in 3 s or more
on the FR3 (joint 1 moves 2.2 rad)."""
FR3_GATE = {"refusal_retry_s": 0.25, "refusal_retry_max_s": 0.5}
"""The gate's refusal back-off on the FR3: it refuses ``setLoad`` for as long as a motion
runs (seconds), so the default back-off (1 s doubling to 10 s) would leave a load unwritten
for seconds after the motion that carried it; a retry is one TCP command."""
CALIBRATION_MARGIN_S = (0.5, 1.5)
"""Rest before and after the calibration motion, s."""
CLIENT_TIMEOUT_S = 900.0
FIFO_PRIORITY = {"loop": 80, "robot": 70}
"""``--fifo``: the ``SCHED_FIFO`` priorities of franky's control loop and of franky-sim (the
robot's side, which on a real cell is the robot's own controller)."""


def configure(parser) -> None:
    parser.add_argument("--ways", default=",".join(WAYS),
                        help=f"comma-separated: {', '.join(WAYS)} (default all; bare: the "
                        "program without the plug-in, for the control loop's pace)")
    parser.add_argument("--arm", metavar="ARM", help="an arm file of franky-sim's FR3 from "
                        "'iem calibrate' (with --model: no commissioning run)")
    parser.add_argument("--model", metavar="FILE", help="a model trained for --arm")
    parser.add_argument("--payloads", type=int, default=3,
                        help="payloads picked and placed (1 to 3, default 3)")
    parser.add_argument("--out", metavar="DIR", help="keep the files and figures here")
    parser.add_argument("--json", metavar="FILE", help="write every figure as JSON")
    parser.add_argument("--fifo", action="store_true",
                        help="franky's control loop and franky-sim at real-time priority "
                        "(SCHED_FIFO), as on a cell PC with a real-time kernel; needs the "
                        "permission to set it (root or CAP_SYS_NICE)")


def _iem(*args: str) -> list[str]:
    return [sys.executable, "-m", "deploy.cli", *args]


def commission(out: FsPath, log=print) -> tuple[FsPath, FsPath, dict]:
    """Calibrate franky-sim's bare FR3 through the link and train the model for it:
    ``(arm file, model file, figures)``."""
    from deploy.simcell import FciSim
    from sim.arm import load_arm
    from sim.paths import calibration_path
    from sim.robot import ArmModel

    arm_file, model_file = out / "arm.msgpack", out / "model.msgpack"
    path = calibration_path(model=ArmModel(description="fr3"))
    before, after = (round(s * 1e3) for s in CALIBRATION_MARGIN_S)
    q = np.vstack([np.repeat(path.q[:1], before, 0), path.q, np.repeat(path.q[-1:], after, 0)])
    t0 = time.monotonic()
    with FciSim(initial_q=path.q[0]) as scene:
        cal = subprocess.Popen(_iem("calibrate", "--interface", "franka", "--channel",
                                    scene.host, "--duration", f"{q.shape[0] / 1e3:g}",
                                    "--arm-model", "fr3", "--armature", "--out",
                                    str(arm_file)), stdout=subprocess.PIPE,
                               stderr=subprocess.STDOUT, text=True)
        time.sleep(1.0)  # connected and reading
        scene.play(q)
        text, _ = cal.communicate(timeout=CLIENT_TIMEOUT_S)
        wall = time.monotonic() - t0
    (out / "calibrate.txt").write_text(text)
    if cal.returncode:
        raise InvalidInputError(f"iem calibrate on franky-sim failed: {text.strip()[-500:]}")
    arm = load_arm(arm_file)
    rep, noise = arm.report, arm.noise or {}
    figures = {"calibration_s": rep["duration_s"], "wall_s": wall,
               "rms_before": rep["rms_before"], "rms_after": rep["rms_after"],
               "armature": arm.armature.tolist(), "friction_phi1": arm.friction[:, 0].tolist(),
               "noise_std": noise.get("std"), "phantom_payload": noise.get("bias_std")}
    log(f"calibrated franky-sim's bare FR3 on {rep['duration_s']:.1f} s of its calibration "
        f"motion: residual RMS per joint {np.round(rep['rms_before'], 3).tolist()} -> "
        f"{np.round(rep['rms_after'], 3).tolist()} N·m; armature "
        f"{np.round(arm.armature, 3).tolist()} kg·m²")
    if noise.get("bias_std"):
        b = noise["bias_std"]
        log(f"  the calibrated arm's leftover reads as a payload of {b[0]:.4f} kg, m·r "
            f"{max(b[1:4]):.4f} kg·m (RMS)")
    train = subprocess.run(_iem("train", "--arm", str(arm_file), "--arm-model", "fr3",
                                "--out", str(model_file)), capture_output=True, text=True,
                           timeout=CLIENT_TIMEOUT_S)
    if train.returncode:
        raise InvalidInputError(f"iem train failed: {train.stderr.strip()[-500:]}")
    log(train.stdout.strip().splitlines()[-2] if train.stdout.strip() else "trained")
    return arm_file, model_file, figures


def _cell(path: FsPath, link: dict, model: FsPath, arm: FsPath) -> FsPath:
    lines = [f'[link]\nkind = "{link["kind"]}"']
    if "channel" in link:
        lines.append(f'channel = "{link["channel"]}"')
    lines += [f'[model]\npath = "{model.resolve()}"\narm = "{arm.resolve()}"\n'
              "train_if_missing = false",
              '[arm]\nmodel = "fr3"', "[gate]"]
    lines += [f"{k} = {v!r}" for k, v in FR3_GATE.items()]
    lines.append('[log]\nlevel = "warning"\nstatus_line = "off"')
    path.write_text("\n".join(lines) + "\n")
    return path


def realtime(pid: int, priority: int) -> None:
    """Every thread of process ``pid`` at ``SCHED_FIFO`` ``priority``; a clear error where the
    machine does not let this process set it."""
    import os

    try:
        for tid in os.listdir(f"/proc/{pid}/task"):
            os.sched_setscheduler(int(tid), os.SCHED_FIFO, os.sched_param(priority))
    except (PermissionError, AttributeError, FileNotFoundError) as exc:
        raise InvalidInputError(f"--fifo: this machine does not let the bench set real-time "
                                f"priority ({type(exc).__name__}: {exc}); run it as root or "
                                "with CAP_SYS_NICE, or without --fifo") from exc


def run_way(way: str, work: FsPath, arm: FsPath, model: FsPath, n_payloads: int,
            log=print, fifo: bool = False) -> dict:
    """One run of the pick-and-place, ``way`` ``"program"``, ``"run"`` or ``"bare"`` (the
    program without the plug-in): the scene's truth log and the client's records."""
    from deploy.bench.fci.schedule import MOTION_S, payload_files, poses, steps
    from deploy.simcell import FciSim
    from sim.paths import linear_path
    from sim.payload import load_payload
    from sim.robot import ArmModel

    payloads = [load_payload(p) for p in payload_files()[:n_payloads]]
    copy = work / f"model-{way}.msgpack"  # each run learns into its own copy
    if way != "bare":  # the program alone has no model
        shutil.copyfile(model, copy)
    records = work / f"{way}.json"
    t0 = time.monotonic()
    with FciSim(initial_q=poses()["home"]) as scene:
        if fifo:
            realtime(scene.pid, FIFO_PRIORITY["robot"])
        if way in ("program", "bare"):
            config = []
            if way == "program":
                cell = _cell(work / "cell-program.toml", {"kind": "program"}, copy, arm)
                config = ["--config", str(cell)]
            scene.grasp_queue(payloads)
            client = subprocess.run(
                [sys.executable, "-m", "deploy.bench.fci.clients", "program", "--host",
                 scene.host, *config, "--out", str(records), "--payloads",
                 str(n_payloads), "--factor", str(FACTOR), "--fifo",
                 str(FIFO_PRIORITY["loop"] if fifo else 0)], capture_output=True, text=True,
                timeout=CLIENT_TIMEOUT_S)
            if client.returncode:
                raise InvalidInputError(f"the franky program failed: "
                                        f"{client.stderr.strip()[-800:]}")
            end = scene.status()["t"]
        else:
            cell = _cell(work / "cell-run.toml", {"kind": "franka", "channel": scene.host},
                         copy, arm)
            errors = work / "run.log"  # a file: a full pipe would stall the service's logs
            with errors.open("w") as err_file:
                client = subprocess.Popen(
                    [sys.executable, "-m", "deploy.bench.fci.clients", "run", "--config",
                     str(cell), "--out", str(records)], stdout=subprocess.PIPE,
                    stderr=err_file, text=True)
            try:
                if client.stdout.readline().strip() != "ready":
                    raise InvalidInputError(f"iem run's service did not start: "
                                            f"{errors.read_text()[-800:]}")
                kinematics = ArmModel(description="fr3")
                position = np.array(scene.status()["q"])
                queue = list(payloads)
                for step in steps(n_payloads):
                    if step.kind == "move":
                        target = np.array(step.target)
                        scene.play(linear_path(position, target, MOTION_S,
                                               model=kinematics).q)
                        scene.wait_still()
                        position = target
                    elif step.kind == "grasp":
                        scene.mount(queue.pop(0))
                    elif step.kind == "release":
                        scene.unmount()
                    else:
                        scene.wait(step.seconds)
                end = scene.status()["t"]
            finally:
                client.terminate()
                client.communicate(timeout=CLIENT_TIMEOUT_S)
            if client.returncode not in (0, -15):
                raise InvalidInputError(f"iem run's service failed: "
                                        f"{errors.read_text().strip()[-800:]}")
        events = scene.events()
    wall = time.monotonic() - t0
    data = json.loads(records.read_text())
    (work / f"{way}-truth.json").write_text(json.dumps({"events": events, "end_s": end}))
    return {"way": way, "events": events, "end_s": end, "wall_s": wall, **data}


def score_run(run: dict) -> dict:
    """The run's figures (:mod:`deploy.bench.fci.score`)."""
    from deploy.bench.fci.score import arrivals_ms, changes, cost_us
    from sim.robot import ArmModel

    kinematics = ArmModel(description="fr3")
    zero = np.zeros(7)

    def regressor(q):
        return kinematics.payload_regressor(q, zero, zero)

    rows = ([] if run["way"] == "bare" else
            changes(run["events"], regressor, run["end_s"], run.get("rows"), run.get("reasons")))
    summary = run.get("summary") or {}
    frames = summary.get("frames") or {}
    return {"way": run["way"], "changes": rows, "callback_us": cost_us(run.get("costs_ns")),
            "arrivals_ms": arrivals_ms(run.get("arrivals_ns")),
            "pace": run["end_s"] / max(run["wall_s"], 1e-9),
            "states_received": frames.get("received"), "states_lost": frames.get("lost"),
            "writes": summary.get("writes"), "motions_s": run.get("motions_s"),
            "applies": run.get("applies")}


def targets(result: dict, settle_s: float) -> list[tuple[str, bool, str]]:
    """``(target, met, measured)`` of one way's figures."""
    from deploy.bench.writeback.score import fmt, held_text

    rows = result["changes"]
    late = [r for r in rows if r["latency_s"] is None or r["latency_s"] > settle_s]
    held = [f"{r['truth_mass']:.3f} kg: {held_text(r['held'])}" for r in late if r.get("held")]
    out = [(f"each change correct within {settle_s:g} s of the end of the motion that "
            "carried it (before the arm moves again)", not late,
            ", ".join(fmt(r["latency_s"], ".2f") for r in rows) + " s"
            + (f" ({'; '.join(held)})" if held else "")),
           ("no write farther from the truth", sum(r["farther"] for r in rows) == 0,
            str(sum(r["farther"] for r in rows))),
           ("the bare arm never written", sum(r["bare_writes"] for r in rows) == 0,
            str(sum(r["bare_writes"] for r in rows)))]
    if result["callback_us"] is not None:
        c = result["callback_us"]
        out.append((f"callback p99 <= {CALLBACK_P99_US:g} µs per state",
                    c["p99"] <= CALLBACK_P99_US,
                    f"p50 {c['p50']:.1f}, p99 {c['p99']:.1f}, max {c['max']:.0f} µs over "
                    f"{c['n']} states"))
    return out


def print_way(result: dict, log=print) -> None:
    from deploy.bench.fci.schedule import SETTLE_S
    from deploy.bench.writeback.score import fmt

    bare = result["way"] == "bare"
    log(f"\n{result['way']}{' (the program without the plug-in)' if bare else ''}: robot time "
        f"ran at {result['pace']:.2f}x the wall clock"
        + ("" if bare else f"; states received {result['states_received']}, lost "
                           f"{result['states_lost']}"))
    a = result.get("arrivals_ms")
    if a is not None:
        log(f"  the control loop's pace (from one callback's start to the next, within a "
            f"motion): p50 {a['p50']:.3f}, p99 {a['p99']:.3f}, p99.9 {a['p999']:.3f}, max "
            f"{a['max']:.2f} ms; {a['late']} of {a['n']} at 2 ms or more")
    if bare:
        return
    log("  change          motion s  latency s  mass err kg  CoM err mm  torque err N·m  "
        "writes  farther  bare  refused(moving)")
    for r in result["changes"]:
        what = f"{'mount' if r['truth_mass'] else 'release'} {r['truth_mass']:.3f} kg"
        log(f"  {what:<15} {r['motion_s']:8.2f} {fmt(r['latency_s'], '10.2f'):>10} "
            f"{r['mass_error_kg']:12.4f} {fmt(r['com_error_mm'], '11.1f'):>11} "
            f"{fmt(r['torque_error_nm'], '15.3f'):>15} {r['writes']:7d} {r['farther']:8d} "
            f"{r['bare_writes']:5d} {r['refusals']:6d}({r['refusals_moving']})")
    for target, met, measured in targets(result, SETTLE_S):
        log(f"  {'MET   ' if met else 'MISSED'} {target}: {measured}")


def run(args) -> int:
    from deploy.bench.fci.figures import write_figure

    ways = [w.strip() for w in args.ways.split(",") if w.strip()]
    bad = [w for w in ways if w not in WAYS]
    if bad or not ways:
        raise InvalidInputError(f"--ways {args.ways!r}: valid are {', '.join(WAYS)}")
    if not 1 <= args.payloads <= 3:
        raise InvalidInputError(f"--payloads {args.payloads}: valid is 1 to 3")
    if (args.arm is None) != (args.model is None):
        raise InvalidInputError("give --arm and --model together (a commissioned arm and its "
                                "model), or neither (commission franky-sim's FR3 first)")
    tmp = None if args.out else tempfile.TemporaryDirectory(prefix="iem-bench-fci-")
    work = FsPath(args.out or tmp.name)
    work.mkdir(parents=True, exist_ok=True)
    try:
        print("iem bench fci: franky-sim 1.0.4's FR3 over the libfranka protocol on "
              "127.0.0.1 (simulation)")
        result: dict = {"ways": {}}
        if args.arm is None:
            arm, model, result["commissioning"] = commission(work)
        else:
            arm, model = FsPath(args.arm), FsPath(args.model)
        for way in ways:
            raw = run_way(way, work, arm, model, args.payloads, fifo=args.fifo)
            scored = result["ways"][way] = score_run(raw)
            print_way(scored)
            if args.out:
                name = write_figure(work / f"fci-{way}.png", raw,
                                    f"iem bench fci, {way}: franky-sim's FR3 (simulation)")
                print(f"  figure {work / name}")
        if args.json:
            FsPath(args.json).write_text(json.dumps(result, indent=2, default=float) + "\n")
    finally:
        if tmp is not None:
            tmp.cleanup()
    return 0
