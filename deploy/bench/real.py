"""``iem bench real``: the plug-in on a real Panda's recording, as a user would run it.

The recording is Gaz et al.'s exciting trajectory 1 (IEEE RA-L 2019; a real Panda without a
hand, 21 s at about 1 kHz with the logger's jitter), read from ``--real DIR`` (default: the
environment's ``IEM_REAL_DIR``, else ``../shared/real`` beside the checkout); it is GPL-3.0
and never part of this project. The steps are the commands a user runs, through their files:

1. the first ``--split`` of the recording (default half) is written as a joint-state CSV and
   calibrated (``iem calibrate --end-effector none``: the arm file, with the noise the fit
   leaves in IEM+phys's equations, measured by cross-validation on that half);
2. IEM+phys is trained for that arm (``iem train --kind IEM+phys --arm``);
3. the rest is held out: replayed (``iem replay``, a CSV per case) bare, and with the exact
   torque of known payloads added to the measured torque (``Y(q, dq, ddq) phi``, ``ddq``
   from a zero-phase low-pass of the measured ``dq``): :data:`PAYLOADS`, 0.4-2.7 kg, none of
   them used to choose anything (semi-synthetic: a known payload's exact torque on a real
   bare arm's recording).

Per case it prints the MAE of the smoothed estimates and of the raw ones (mass kg, m·r kg·m,
inertia kg·m²), the final mass, the 2-sigma coverage per group, the loads the safety
gate would have written (count, the largest mass and CoM errors), and the replay's speed:
recorded s over wall s (``speed``) and over the replay's CPU s (``cpu_speed``, with the
learning's share, ``learning_cpu_s``); each line says whether
it is real (the bare arm) or semi-synthetic (a payload's torque added). ``--json FILE`` writes
it all. Nothing was tuned on the recording.
"""

from __future__ import annotations

import gzip
import json
import os
import sys
import time
from pathlib import Path as FsPath

import numpy as np

from iem.errors import InvalidInputError

SPLIT = 0.5
"""Share of the recording (from its start) that calibrates the arm; the rest is held out."""
END_EFFECTOR = "none"
"""The recorded arm carried no hand (the recording's README)."""
FILES = ("time", "positions", "velocity", "torques")
"""``gaz_traj1_<name>.txt.gz``: one value a line, 7 per sample for all but the time."""


def default_dir() -> FsPath:
    """Where the recording is: ``IEM_REAL_DIR``, else ``../shared/real`` beside the
    checkout."""
    env = os.environ.get("IEM_REAL_DIR")
    if env:
        return FsPath(env)
    return FsPath(__file__).resolve().parents[3] / "shared" / "real"


def load_recording(directory=None) -> tuple[np.ndarray, ...]:
    """``(t, q, dq, tau)`` of the real recording in ``directory``.

    Raises:
        InvalidInputError: a file is missing or unreadable (naming it).
    """
    directory = FsPath(directory) if directory else default_dir()
    out = []
    for name in FILES:
        path = directory / f"gaz_traj1_{name}.txt.gz"
        try:
            with gzip.open(path, "rt") as f:
                values = np.loadtxt(f)
        except (OSError, ValueError) as exc:
            raise InvalidInputError(f"{path}: cannot read the real recording ({exc}); give "
                                    f"--real DIR or IEM_REAL_DIR, the folder of "
                                    f"gaz_traj1_{{{','.join(FILES)}}}.txt.gz") from exc
        out.append(values if name == "time" else values.reshape(-1, 7))
    return tuple(out)


def payloads() -> dict:
    """The held-out payloads: the paper's three test configurations (1.34-1.89 kg), a light
    probe, a heavy tool and the heavy off-axis tool of ``sim/payloads/offaxis-tool.toml``
    (2.7 kg, its CoM 5 cm off the flange axis)."""
    from sim.family import PAYLOAD_DIR, test_payloads
    from sim.payload import Payload, load_payload

    return {**test_payloads(),
            "probe-0.4": Payload("probe-0.4", 0.4, (0.0, 0.01, 0.04),
                                 (2e-4, 0.0, 0.0, 2e-4, 0.0, 1e-4)),
            "tool-2.5": Payload("tool-2.5", 2.5, (0.02, -0.01, 0.08),
                                (0.01, 0.0, 0.0, 0.012, 0.0, 0.006)),
            "offaxis-tool": load_payload(PAYLOAD_DIR / "offaxis-tool.toml")}


PAYLOADS = ("test-2w", "test-3w", "test-4w", "probe-0.4", "tool-2.5", "offaxis-tool")


def payload_torque(t, q, dq, phi, cutoff_hz: float = 20.0) -> np.ndarray:
    """The joint torques (N, 7) a payload ``phi`` adds along the recorded motion:
    ``Y(q, dq, ddq) phi``, ``ddq`` the derivative of ``dq`` through a zero-phase 4th-order
    Butterworth at ``cutoff_hz`` on the recorded time stamps."""
    from scipy.signal import butter, sosfiltfilt

    from sim.robot import ArmModel

    rate = 1.0 / float(np.median(np.diff(t)))
    sos = butter(4, cutoff_hz, fs=rate, output="sos")
    ddq = np.gradient(sosfiltfilt(sos, dq, axis=0), t, axis=0)
    model = ArmModel()
    Y = np.array([model.payload_regressor(q[k], dq[k], ddq[k]) for k in range(t.shape[0])])
    return Y @ np.asarray(phi, dtype=float)


def write_csv(path, t, q, dq, tau) -> None:
    """A joint-state CSV (:data:`firmware_bridge.recordings.CSV_COLUMNS`)."""
    from firmware_bridge.recordings import CSV_COLUMNS

    np.savetxt(path, np.hstack((np.asarray(t)[:, None], q, dq, tau)), delimiter=",",
               header=",".join(CSV_COLUMNS), comments="", fmt="%.10g")


def case_figures(summary: dict, estimates, truth_phi) -> dict:
    """What a case reports (see the module docstring)."""
    from iem.metrics import mae_groups

    raw = np.array(estimates.raw).reshape(-1, 10)
    loads = summary["writes"]["would_send_loads"]
    truth = np.asarray(truth_phi)
    m = truth[0]
    com = truth[1:4] / m if m > 0 else None
    return {
        "mae_groups": summary.get("mae_groups"),
        "mae_groups_raw": mae_groups(raw, truth),
        "coverage_2sigma": summary.get("coverage_2sigma"),
        "final_mass": float(estimates.smoothed[-1][0]),
        "would_send": len(loads),
        "max_write_mass_error": max((abs(w["mass"] - m) for w in loads), default=None),
        "max_write_com_error_m": (max((float(np.linalg.norm(np.subtract(w["com"], com)))
                                       for w in loads), default=None)
                                  if com is not None else None),
        "gate": summary["gate"],
        "arm_mismatch": summary.get("arm_mismatch"),
        "speed": summary["speed"],
        "cpu_speed": summary["cpu_speed"],
        "learning_cpu_s": summary["cpu_parts"]["learning"],
        "false_alarms": summary["payload_changes"],
    }



def run_real(out_dir, directory=None, split: float = SPLIT, cases=None, log=print) -> dict:
    """Calibrate, train and replay as the module docstring says; the results dict."""
    from deploy.model.training import train_initial_model
    from deploy.replay.core import replay
    from iem.persistence import save_model
    from sim.arm import save_arm
    from sim.calibration import segments
    from sim.calibration_noise import calibrate_with_noise

    out = FsPath(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    t, q, dq, tau = load_recording(directory)
    cut = t[0] + split * (t[-1] - t[0])
    fit = t <= cut
    write_csv(out / "calibration.csv", t[fit], q[fit], dq[fit], tau[fit])
    t0 = time.perf_counter()
    arm = calibrate_with_noise(segments(t[fit], q[fit], dq[fit], tau[fit]),
                               source=f"the first {split:.0%} of the real recording",
                               end_effector=END_EFFECTOR)
    arm_file = out / "arm.msgpack"
    save_arm(arm, arm_file)
    log(f"calibrated on {t[fit][-1] - t[0]:.1f} s in {time.perf_counter() - t0:.1f} s: "
        f"residual RMS per joint {np.round(arm.report['rms_after'], 3).tolist()} N·m")
    model = train_initial_model("IEM+phys", arm_file=arm_file, end_effector=END_EFFECTOR,
                                log=log)
    save_model(model, out / "model.msgpack")
    held = ~fit
    th, qh, dqh, tauh = t[held], q[held], dq[held], tau[held]
    every = payloads()
    results = {"split": split, "calibration": {"rms_before": arm.report["rms_before"],
                                               "rms_after": arm.report["rms_after"],
                                               "noise": arm.noise},
               "held_out_s": float(th[-1] - th[0]), "cases": {}}
    for name in cases or ("bare", *PAYLOADS):
        payload = None if name == "bare" else every[name]
        phi = np.zeros(10) if payload is None else payload.to_phi()
        path = out / f"held-out-{name}.csv"
        write_csv(path, th, qh, dqh,
                  tauh if payload is None else tauh + payload_torque(th, qh, dqh, phi))
        truth = payload if payload is not None else _bare()
        summary, estimates = replay(path, model=model, truth=truth, arm_file=arm_file,
                                    end_effector=END_EFFECTOR, log=lambda *a: None)
        results["cases"][name] = case_figures(summary, estimates, phi)
        log(_line(name, phi[0], results["cases"][name]))
    return results


def _bare():
    """The truth of the bare arm: zero parameters (a Payload cannot be massless)."""

    class Bare:
        name = "bare"

        @staticmethod
        def to_phi():
            return np.zeros(10)

    return Bare()


def _line(name: str, mass: float, c: dict) -> str:
    g, r, cov = c["mae_groups"], c["mae_groups_raw"], c["coverage_2sigma"]
    cov_text = "n/a" if cov is None or cov["mass"] is None else \
        "/".join(f"{cov[k]:.2f}" for k in ("mass", "com", "inertia"))
    writes = f"{c['would_send']} writes"
    if c["would_send"]:
        writes += f" (worst mass {c['max_write_mass_error']:.4f} kg"
        if c["max_write_com_error_m"] is not None:
            writes += f", CoM {1000 * c['max_write_com_error_m']:.1f} mm"
        writes += ")"
    kind = "real" if name == "bare" else "semi-synthetic"
    return (f"{name:10s} {mass:5.2f} kg ({kind}): MAE smoothed mass {g['mass']:.4f} "
            f"com {g['com']:.4f} inertia {g['inertia']:.5f} | raw {r['mass']:.4f} {r['com']:.4f} "
            f"{r['inertia']:.5f} | final mass {c['final_mass']:+.4f} | 2σ coverage "
            f"m/com/I {cov_text} | {writes} | false alarms {c['false_alarms']} | "
            f"{c['speed']:.1f}x real time, {c['cpu_speed']:.1f}x per CPU s (learning "
            f"{c['learning_cpu_s']:.2f} s)")


def configure(parser) -> None:
    parser.add_argument("--real", metavar="DIR", help="folder of the real recording (default: "
                        "IEM_REAL_DIR, else ../shared/real beside the checkout)")
    parser.add_argument("--out", default="out/bench-real", metavar="DIR",
                        help="where the CSVs, the arm file and the model go")
    parser.add_argument("--split", type=float, default=SPLIT,
                        help="share of the recording that calibrates (default 0.5)")
    parser.add_argument("--json", metavar="FILE", help="write the results as JSON")
    from deploy.options import add_arm_model

    add_arm_model(parser)


def require_panda(description, what: str) -> None:
    """Refuse an arm model other than the Panda for ``what``: the real recording is a
    Panda's (Gaz et al. 2019).

    Raises:
        iem.errors.InvalidInputError: naming the arm model given and the valid one."""
    from sim.description import DEFAULT_ARM_MODEL

    if description is not None and description.name != DEFAULT_ARM_MODEL:
        raise InvalidInputError(f"{what} runs on the real Panda's recording (Gaz et al. "
                                f"2019), not on the arm model {description.name!r}; valid "
                                f"is --arm-model {DEFAULT_ARM_MODEL} (the default)")


def run(args) -> int:
    from deploy.options import arm_description_of

    require_panda(arm_description_of(args), "iem bench real")
    if not 0.2 <= args.split <= 0.8:
        raise InvalidInputError(f"--split {args.split} is out of range; valid is 0.2 to 0.8")
    print("real Panda recording (Gaz et al. 2019, no hand), calibrated on the first "
          f"{args.split:.0%}, held out on the rest; the bare row is real data, each payload's "
          "row a known payload's exact torque added to that real bare-arm recording "
          "(semi-synthetic)", file=sys.stderr)
    results = run_real(args.out, args.real, args.split,
                       log=lambda msg: print(msg, flush=True))
    if args.json:
        FsPath(args.json).write_text(json.dumps(results, indent=2, default=float) + "\n",
                                     encoding="utf-8")
    return 0
