"""``iem bench faults``: the plug-in on the stream a real link delivers, against a clean run.

The simulated controller (the arm model's MuJoCo plant, the Panda by default, with the test
payload, the excitation path back and forth at 1 kHz in real time) runs in its own process
as an slcan adapter on a pty, as a cell has it; the plug-in service runs in this process and
opens it with python-can's slcan interface (fd profile). Two runs of the same noise seed and
path, each with a fresh copy of one trained model:

- **clean**: no faults;
- **faulty**: 5 % of the frames the controller sends dropped, 1 % corrupted (one bit), 2 %
  duplicated, 2 % delayed by 3 cycles (they arrive after newer ones), and a 2 s silence in
  the middle of the run (nothing at all is sent: joint states, acknowledgements,
  heartbeats).

Each run lasts ``--seconds`` of controller time; the service reads until the controller has
ended and the link has gone quiet, so every frame sent is accounted for.

Figures (``--json FILE`` writes them with these keys):

- ``mae_groups_faulty``, ``mae_groups_clean``: MAE of the smoothed estimate (what the gate
  sees) against the truth, per group (mass kg, com kg·m, inertia kg·m²), over the 10 ms bins
  of controller time both runs estimated (``compared_cycles``), from a second after the
  later start;
  ``mae_groups_raw_faulty``/``_clean``: the same for the raw estimate.
- ``writes``: ``sent``, ``during_silence`` (loads sent between the last joint state before
  the silence and the first after it, judged by the clock of this process, not by the
  gate's own state), ``max_error_mass_kg`` and ``max_error_com_m`` (the largest error of
  any load written, against the truth), and ``acked``, ``refused``; also for the clean run
  in ``writes_clean``.
- ``counters``: the link's counters in the faulty run; ``injected``: what the injector did,
  per message (from the controller's own count, ``--stats-json``); ``expected``: the link
  counters those injections imply; ``counters_match``: true when every one equals;
  ``adapter_dropped``: frames the emulated adapter could not send because the plug-in did
  not read its pty in time (0 unless the host starves the reader; such a frame counts as
  lost in ``expected``, and a delayed one is accounted at its release cycle, so then the
  match can be off by the few such frames).
- ``gaps``: what the one gap rule made of the faulty stream: frames bridged into block
  points and frames skipped (not newer) by the reader's block former, and restarts of the
  estimator's filters.

Targets: faulty mass MAE <= 1.5x the clean run's (floor 0.001 kg); every written
load within 0.01 kg and 5 mm of CoM of the truth; no write during the silence; counters as
injected. The plant is the ideal arm (the nominal model): these figures say what the stream
does to the estimate, not what a real arm's model errors do.
"""

from __future__ import annotations

import copy
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path as FsPath

import numpy as np

from iem.model_kinds import DEFAULT_MODEL

REPO = FsPath(__file__).resolve().parents[2]

FAULTS = {"drop": 0.05, "corrupt": 0.01, "duplicate": 0.02, "delay": 0.02}
DELAY_CYCLES = 3
SILENCE_S = 2.0
WARMUP_S = 1.0
BIN_CYCLES = 10
"""Controller cycles per bin the two runs are compared over (10 ms: one block point each)."""
JOINT_STATE = "JointStateFD"


def _controller_cmd(seconds: float, seed: int, payload_file: str, stats: str,
                    faults: dict | None, fault_seed: int, description=None) -> list[str]:
    from deploy.options import arm_model_options

    cmd = [sys.executable, "-m", "deploy.cli", "sim-controller", "--interface", "slcan-pty",
           "--profile", "fd", "--seed", str(seed), "--duration", f"{seconds:g}",
           "--payload", payload_file, "--stats-json", stats, *arm_model_options(description)]
    if faults:
        for name, value in faults.items():
            cmd += [f"--{name}", f"{value:g}"]
        silence_at = seconds / 2.0
        cmd += ["--delay-cycles", str(DELAY_CYCLES), "--silence",
                f"{silence_at:g}:{SILENCE_S:g}", "--fault-seed", str(fault_seed)]
    return cmd


def _run(model, seconds: float, seed: int, payload_file: str, truth, faults: dict | None,
         fault_seed: int, log, cell: dict | None = None) -> dict:
    """One run: the controller process, the service here, in the cell of
    :func:`deploy.config.cell_config`'s arguments ``cell``; what it estimated and wrote."""
    from deploy.service.loop import Service
    from deploy.service.status import StatusLine

    cell = cell or {"where": "bench faults"}
    with tempfile.TemporaryDirectory() as tmp:
        stats_file = str(FsPath(tmp) / "controller.json")
        cmd = _controller_cmd(seconds, seed, payload_file, stats_file, faults, fault_seed,
                              cell.get("description"))
        proc = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                text=True, env={**os.environ, "PYTHONUNBUFFERED": "1"})
        try:
            pty = proc.stdout.readline().strip()
            if not pty.startswith("/dev/"):
                raise RuntimeError(f"sim-controller did not announce its pty: {pty!r}; "
                                   f"{proc.stderr.read()[-2000:]}")
            service = Service(_cell_config(pty, model, tmp, cell), model=model,
                              status=StatusLine(False))
            cycles: list[tuple[float, float, np.ndarray, np.ndarray]] = []
            writes: list[tuple[float, object]] = []
            service.on_cycle.append(lambda rec: cycles.append(
                (time.monotonic(), rec.state.t, rec.smoothed, rec.raw.phi, rec.state.cycle)))
            summary = _serve(service, proc, cycles, writes, lambda: log(
                f"bench faults: {'faulty' if faults else 'clean'} run, {seconds:g} s, "
                f"controller in process {proc.pid} behind slcan on {pty}"))
        finally:
            if proc.poll() is None:
                proc.terminate()
            proc.communicate(timeout=30)
            try:
                controller = json.loads(FsPath(stats_file).read_text())
            except (OSError, ValueError):
                controller = {}
    return _figures(cycles, writes, summary, service, controller, truth, seconds,
                    faults is not None)


def _cell_config(pty: str, model, tmp: str, cell: dict):
    """The cell of a run: slcan on the controller's pty, ``model`` checkpointed in ``tmp``,
    the arm model and the gate's rating of ``cell`` (:func:`deploy.config.cell_config`'s
    arguments)."""
    from deploy.config import cell_config

    return cell_config(**cell, link={"kind": "slcan", "channel": pty, "profile": "fd",
                                     "silence_timeout_s": 0.2},
                       model={"path": str(FsPath(tmp) / "model.msgpack"), "kind": model.name,
                              "checkpoint_period_s": 3600.0})


def _serve(service, proc, cycles: list, writes: list, announce) -> dict:
    """The service until the controller process has ended and the link is quiet, each load
    it sends recorded in ``writes`` (``announce()`` once it is open); its summary."""
    from firmware_bridge.errors import LinkError

    try:
        service.open()
        send = service.link.send

        def recorded_send(payload):
            writes.append((time.monotonic(), payload))
            return send(payload)

        service.link.send = recorded_send
        announce()

        def done() -> bool:  # the controller has ended and the link is quiet
            quiet = not cycles or time.monotonic() - cycles[-1][0] > 0.5
            return proc.poll() is not None and quiet

        try:
            return service.run(until=done)
        except LinkError as exc:
            # the controller ended and took its pty with it (the reader gets EIO)
            try:
                proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                raise exc from None  # the adapter is still there: a real failure
            return service.summary()
    finally:
        try:
            service.close()
        except LinkError:
            if proc.poll() is None:
                raise  # the adapter is still there: a real failure
            # the controller has ended and taken its pty with it: nothing to close


def _figures(cycles, writes, summary, service, controller, truth, seconds, faulty) -> dict:
    out = {"cycles": summary["cycles"], "summary": summary,
           "per_cycle": {c[4] // BIN_CYCLES: (c[2], c[3]) for c in cycles}}
    during = 0
    if faulty:  # wall-clock window between the last state before and the first after
        start, end = seconds / 2.0, seconds / 2.0 + SILENCE_S
        before = [c[0] for c in cycles if c[1] < start]
        after = [c[0] for c in cycles if c[1] >= end]
        lo = before[-1] if before else -np.inf
        hi = after[0] if after else np.inf
        during = sum(1 for w, _ in writes if lo < w < hi)
    mass_err = [abs(p.mass - truth.mass) for _, p in writes if p is not None]
    com_err = [float(np.linalg.norm(np.subtract(p.com, truth.com)))
               for _, p in writes if p is not None]
    out["writes"] = {"sent": len(writes), "during_silence": during,
                     "max_error_mass_kg": max(mass_err, default=0.0),
                     "max_error_com_m": max(com_err, default=0.0),
                     "acked": summary["writes"]["acked"],
                     "refused": summary["writes"]["refused_by_controller"]}
    counters = service.link.counters.as_dict()
    out["counters"] = counters
    out["injected"] = controller.get("faults_by_message", {})
    # the cycles read: a record's cycle is its block point's last frame's, and the first
    # block of the stream holds block_frames frames (no gap can come before its first)
    # ... and the frames of the block still open when the run ended came after its last
    first = cycles[0][4] - (service.block_frames - 1) if cycles else 0
    seen = (first, cycles[-1][4] + service.tally.former.pending) if cycles else (0, -1)
    failures = [tuple(f) for f in controller.get("send_failures", [])]
    out["adapter_dropped"] = len(failures)
    out["expected"] = expected_counters(controller.get("fault_events", []), *seen, failures)
    out["controller"] = {k: v for k, v in controller.items()
                         if k not in ("faults_by_message", "fault_events")}
    # the reader's block former bridges lost frames and skips stale ones; the point-rate
    # rule restarts the filters after a longer gap
    former, points = service.tally.former, service.online.state_filter.gaps
    out["gaps"] = {"bridged": former.bridged, "skipped": former.skipped,
                   "restarts": points.restarts}
    return out


def _score(clean: dict, faulty: dict, truth) -> None:
    """MAE of both runs over the same instants: the :data:`BIN_CYCLES`-cycle bins of
    controller time both estimated (a block point in each: their blocks end on different
    cycles once a gap has shifted one run's), from ``WARMUP_S`` after the later of their
    first bins (the faulty run has holes, the silence above all; comparing over all of each
    run's own points would weigh their starts differently)."""
    from iem.metrics import mae_groups

    a, b = clean.pop("per_cycle"), faulty.pop("per_cycle")
    common = sorted(set(a) & set(b))
    if common:
        start = max(min(a), min(b)) + round(WARMUP_S * 1000.0 / BIN_CYCLES)
        common = [c for c in common if c >= start]
    phi = truth.to_phi()
    for run, per in ((clean, a), (faulty, b)):
        smoothed = np.array([per[c][0] for c in common]).reshape(-1, 10)
        raw = np.array([per[c][1] for c in common]).reshape(-1, 10)
        run["mae_groups"] = mae_groups(smoothed, phi)
        run["mae_groups_raw"] = mae_groups(raw, phi)
        run["compared_cycles"] = len(common)


def expected_counters(events, first: int, last: int, failures=()) -> dict:
    """The link counters that the injector's fault events imply for the cycles the service
    saw, ``first`` to ``last`` (fd profile: one joint-state frame per cycle).

    Every corrupted frame fails its E2E CRC, whatever its message; a duplicated joint state is
    a bit-identical repeat; a delayed joint state (released ``DELAY_CYCLES`` cycles later,
    before that cycle's own frame) arrives after newer ones (out of order) unless none of the
    cycles in between reached the reader (then it is delivered late); a joint-state cycle is
    lost when its frame was dropped, corrupted, delayed or kept back by the silence. Frames
    before the service opened the adapter were never sent (no fault is drawn for them); faults
    after the last cycle the service saw are not visible to it.
    """
    out = dict.fromkeys(("crc", "duplicate", "out_of_order", "lost"), 0)
    # frames the adapter could not send (``failures``: the reader fell so far behind that
    # its backlog filled): a joint state's cycle is lost, a corrupted frame never arrives
    failed = {(c, name) for c, name in failures}
    lost_js = {c for c, name in failed if name == JOINT_STATE}
    faulted_js = {c for c, name, _ in events if name == JOINT_STATE}
    missing = {c for c, name, action in events if name == JOINT_STATE
               and action in ("drop", "corrupt", "delay", "silenced")} | lost_js
    for cycle in lost_js:
        if first <= cycle <= last and cycle not in faulted_js:
            out["lost"] += 1
    for cycle, name, action in events:
        if not first <= cycle <= last:
            continue
        if (cycle, name) in failed:
            if name == JOINT_STATE and action != "duplicate":
                out["lost"] += 1
            continue
        if action == "corrupt":
            out["crc"] += 1
        if name != JOINT_STATE:
            continue
        if action == "duplicate":
            out["duplicate"] += 1
        elif action == "delay" and all(cycle + k in missing for k in range(1, DELAY_CYCLES)):
            continue  # released before any newer state arrived: delivered late, not lost
        elif action == "delay":
            out["out_of_order"] += 1
        if action in ("drop", "corrupt", "delay", "silenced"):
            out["lost"] += 1
    return out


def measure(seconds: float = 30.0, seed: int = 1, fault_seed: int = 2, kind: str | None = None,
            log=print, description=None, rated_mass_kg: float | None = None) -> dict:
    """Both runs on the arm model ``description`` (None: the default), the gate rated for
    ``rated_mass_kg`` (None: the arm model's rated payload)."""
    from deploy.config import cell_config
    from deploy.model.training import train_initial_model
    from sim.family import test_payloads

    kind = kind or DEFAULT_MODEL
    payload_file = str(REPO / "sim" / "payloads" / "test-3w.toml")
    truth = test_payloads()["test-3w"]
    cell = {"description": description, "rated_mass_kg": rated_mass_kg, "where": "bench faults"}
    cell_config(**cell)  # an end effector beyond the rated payload fails before training
    model = train_initial_model(kind, seed=0, log=lambda *a: None,
                                noise="sensor",  # the simulated arm is its model
                                description=description)
    clean = _run(copy.deepcopy(model), seconds, seed, payload_file, truth, None, fault_seed, log,
                 cell)
    faulty = _run(copy.deepcopy(model), seconds, seed, payload_file, truth, FAULTS, fault_seed,
                  log, cell)
    _score(clean, faulty, truth)
    expected = faulty["expected"]
    counters = faulty["counters"]
    return {
        "model": kind, "seconds": seconds, "seed": seed, "fault_seed": fault_seed,
        "faults": {**FAULTS, "delay_cycles": DELAY_CYCLES, "silence_s": SILENCE_S},
        "plant": "ideal (the nominal arm model)",
        "mae_groups_faulty": faulty["mae_groups"], "mae_groups_clean": clean["mae_groups"],
        "mae_groups_raw_faulty": faulty["mae_groups_raw"],
        "mae_groups_raw_clean": clean["mae_groups_raw"],
        "writes": faulty["writes"], "writes_clean": clean["writes"],
        "counters": counters, "injected": faulty["injected"], "expected": expected,
        "counters_match": all(counters.get(k) == v for k, v in expected.items()),
        "adapter_dropped": faulty["adapter_dropped"],
        "gaps": faulty["gaps"], "gaps_clean": clean["gaps"],
        "compared_cycles": faulty["compared_cycles"],
        "cycles": {"faulty": faulty["cycles"], "clean": clean["cycles"]},
        "controller": faulty["controller"],
    }


def configure(parser) -> None:
    parser.add_argument("--seconds", type=float, default=30.0,
                        help="controller time of each run, s (default 30)")
    parser.add_argument("--seed", type=int, default=1, help="sensor-noise seed of both runs")
    parser.add_argument("--fault-seed", type=int, default=2, help="seed of the fault draws")
    parser.add_argument("--model", choices=["IEM", "IEM+phys"], default=None,
                        help="model kind (default: the best available)")
    parser.add_argument("--json", metavar="FILE", help="also write the figures as JSON")
    from deploy.options import add_arm_model, add_rated_mass

    add_arm_model(parser)
    add_rated_mass(parser)


def run(args) -> int:
    from deploy.options import arm_description_of
    from iem.errors import InvalidInputError

    if not args.seconds >= 2 * SILENCE_S + 2 * WARMUP_S:
        raise InvalidInputError(f"--seconds {args.seconds:g}: valid is at least "
                                f"{2 * SILENCE_S + 2 * WARMUP_S:g} s (the run holds a "
                                f"{SILENCE_S:g} s silence in its middle)")
    f = measure(args.seconds, seed=args.seed, fault_seed=args.fault_seed, kind=args.model,
                description=arm_description_of(args), rated_mass_kg=args.rated_mass_kg)
    mf, mc = f["mae_groups_faulty"], f["mae_groups_clean"]
    rf, rc = f["mae_groups_raw_faulty"], f["mae_groups_raw_clean"]
    target = max(1.5 * mc["mass"], 0.001)
    print(f"bench faults: {f['model']}, {f['seconds']:g} s per run, noise seed {f['seed']}, "
          f"fault seed {f['fault_seed']}; plant: ideal arm")
    print(f"{'MAE':24s} {'mass kg':>10s} {'com kg·m':>10s} {'inertia':>10s}")
    for label, g in (("clean, smoothed", mc), ("faulty, smoothed", mf), ("clean, raw", rc),
                     ("faulty, raw", rf)):
        print(f"{label:24s} {g['mass']:10.5f} {g['com']:10.5f} {g['inertia']:10.5f}")
    print(f"faulty mass MAE {mf['mass']:.5f} kg, target <= {target:.5f} "
          f"({'met' if mf['mass'] <= target else 'NOT met'})")
    w = f["writes"]
    print(f"writes (faulty run): sent {w['sent']}, acknowledged {w['acked']}, during the silence "
          f"{w['during_silence']}, largest error of a written load: mass "
          f"{w['max_error_mass_kg']:.4f} kg, CoM {w['max_error_com_m'] * 1e3:.2f} mm "
          f"(targets 0, 0.01 kg, 5 mm)")
    wc = f["writes_clean"]
    print(f"writes (clean run): sent {wc['sent']}, largest error mass "
          f"{wc['max_error_mass_kg']:.4f} kg, CoM {wc['max_error_com_m'] * 1e3:.2f} mm")
    c, e = f["counters"], f["expected"]
    print("link counters vs injected: " + ", ".join(
        f"{k} {c.get(k)}/{v}" for k, v in e.items()) +
        f" -> {'match' if f['counters_match'] else 'MISMATCH'}"
        + (f" ({f['adapter_dropped']} frames the adapter dropped because the reader fell "
           "behind are counted as lost)" if f["adapter_dropped"] else ""))
    g = f["gaps"]
    print(f"gap rule (faulty run): {g['bridged']} frames bridged, {g['skipped']} frames "
          f"skipped, {g['restarts']} restarts")
    if args.json:
        FsPath(args.json).write_text(json.dumps(f, indent=2, default=str) + "\n")
    return 0
