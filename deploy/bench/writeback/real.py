"""``iem bench writeback``'s offline case: the gate on the real recording, no controller.

``iem bench real``'s set-up (:func:`deploy.bench.real.run_real`: the first half of the real
Panda's recording calibrated as ``iem calibrate`` does, IEM+phys trained for that arm, the
held-out half written as a joint-state CSV per case, bare and with a known payload's exact
torque added: semi-synthetic), for :data:`CASES`. Each case's CSV is then replayed once more
(``iem replay``, deterministic: the same estimates) with the saved model, for the
per-estimate standard deviations its ``--out`` CSV has; the loads the gate would send are
the replay's ``writes.would_send_loads`` (a replay takes each as in force at once).

Per case: the time from the first estimate to the first write, each write's mass and CoM
error against the truth and whether the truth lies within that write's own 2-sigma band (of
the raw estimate at the write, :func:`deploy.bench.writeback.score.in_band`), and the count.
"""

from __future__ import annotations

from pathlib import Path as FsPath

import numpy as np

from deploy.bench.writeback.score import correct, in_band, load_error, load_of

CASES = ("test-3w", "probe-0.4", "tool-2.5", "bare")
FIRST_WRITE_S = 10.0
"""The target: a first write within this many s of the first estimate (payload cases)."""


def run_real_cases(out_dir, directory=None, log=print) -> dict:
    """Every case of :data:`CASES`: ``{"cases": {name: figures}, "series": {name: ...}}``
    (``series``: the per-estimate record for the figures)."""
    from deploy.bench.real import END_EFFECTOR, payloads, run_real
    from deploy.replay.core import replay
    from iem.persistence import load_model
    from sim.arm import load_arm

    out = FsPath(out_dir)
    results = run_real(out, directory, cases=CASES, log=log)
    arm_file = out / "arm.msgpack"
    model = load_model(out / "model.msgpack", resources={"arm": load_arm(arm_file)})
    every = payloads()
    cases, series = {}, {}
    for name in CASES:
        payload = None if name == "bare" else every[name]
        summary, est = replay(out / f"held-out-{name}.csv", model=model, arm_file=arm_file,
                              end_effector=END_EFFECTOR, log=lambda *a: None)
        loads = summary["writes"]["would_send_loads"]
        cases[name] = score_case(name, payload, np.array(est.t), np.array(est.std), loads)
        cases[name]["bench_real"] = {k: results["cases"][name][k]
                                     for k in ("would_send", "mae_groups", "coverage_2sigma")}
        series[name] = {"t": np.array(est.t), "smoothed": est.smoothed_array(),
                        "std": np.array(est.std).reshape(-1, 10), "loads": loads,
                        "truth": load_of(payload)}
        log(line(name, cases[name]))
    return {"held_out_s": results["held_out_s"], "calibration": results["calibration"],
            "cases": cases, "series": series}


def score_case(name: str, payload, t, std, loads: list[dict]) -> dict:
    """One case's figures from its estimates' times ``t`` and standard deviations ``std``
    and the would-send ``loads``."""
    truth = load_of(payload)
    rows = []
    for w in loads:
        i = max(int(np.searchsorted(t, w["t"], side="right")) - 1, 0)
        dm, dc = load_error(w, truth)
        rows.append({"t": w["t"], "mass": w["mass"], "mass_error_kg": dm,
                     "com_error_mm": None if dc is None else 1e3 * dc,
                     "correct": correct(w, truth), "in_band": in_band(w, truth, std[i])})
    first = (loads[0]["t"] - float(t[0])) if loads and len(t) else None
    if payload is None:
        met = not loads
        target = "no write"
    else:
        met = (first is not None and first <= FIRST_WRITE_S
               and all(r["correct"] and r["in_band"] for r in rows))
        target = (f"a write within {FIRST_WRITE_S:g} s, every write within 0.05 kg and "
                  "10 mm and its own 2σ band")
    return {"truth_mass": 0.0 if truth is None else truth["mass"], "writes": rows,
            "count": len(rows), "first_write_s": first, "target": target, "met": bool(met)}


def line(name: str, c: dict) -> str:
    """One case in words: ``real`` for the bare arm, ``semi-synthetic`` for a payload's torque
    added to it."""
    kind = "real" if name == "bare" else "semi-synthetic"
    if not c["writes"]:
        return f"{kind} {name:10s}: no write"
    w = c["writes"]
    return (f"{kind} {name:10s}: {c['count']} writes, first {c['first_write_s']:.2f} s after the "
            f"first estimate; mass errors "
            + ", ".join(f"{r['mass_error_kg']:.3f}" for r in w) + " kg; in 2σ band "
            + ", ".join(str(r["in_band"]) for r in w))
