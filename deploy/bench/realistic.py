"""``iem bench realistic``: the models on an arm that is not its nominal model.

Set-up (seed ``S``; the paper benchmark's machinery, :class:`deploy.bench.harness.Bench`):

- **The arm.** The plant carries the reality gap :class:`sim.plant.RealityGap` with seed
  ``GAP_SEED_BASE + S`` (link masses +-5 %, CoMs +-5 mm, inertias +-10 %, Gaz's friction
  times 0.7-1.3, torque offsets of 0.1 N·m): seeds never used to tune anything (the tests
  and the tuning of :mod:`sim.calibration` use gap seed 3). The controller runs on the
  nominal model (Franka's own), told the true load; the sensors have the default noise.
- **Calibration.** The bare arm runs the shipped calibration motion
  (:func:`sim.paths.calibration_path`, 30 s) with sensor-noise seed ``CAL_NOISE_BASE + S``;
  :func:`sim.calibration.calibrate` turns it into the arm file (written to ``DIR/arm.msgpack``).
  ``--arm ARM`` uses a given arm file instead.
- **Models**, trained on the planned excitation path with the plug-in's default training
  family (:data:`sim.family.DEPLOY_FAMILY`: the paper's 77 payloads and 77 random tools, as
  ``iem train`` makes them; the paper benchmark keeps the paper's 77): ``IEM``
  and ``IEM+phys`` on the nominal arm (the tandem simulators and the physics' dynamics);
  ``IEM+cal`` and ``IEM+phys+cal`` the same on the calibrated arm (tandem simulators of the
  calibrated arm, the physics' dynamics spec ``sim.arm:arm_dynamics@arm:CRC32``, that arm
  by content).
- **Batch models**: ``batch+bare`` identifies each scenario's recording offline
  with a bare recording of the same motion (noise seed ``seed + BARE_NOISE``), ``batch+arm``
  with the calibrated arm instead (:func:`sim.identify.identify`); one estimate per run.
- **Scenarios**, each on the paper's new task path (6 s), each model from its trained state,
  learning as it goes, its payload forgotten first (a new task): ``new_path`` (the default
  test payload), ``bare_arm`` (nothing mounted: truth zero), ``light_tool`` (0.4 kg),
  ``heavy_tool`` (2.8 kg, CoM 0.1 m off the flange axis), ``payload_change`` (the test
  payload switched to ``test-4w`` at mid-path, the controller not told; the figures after
  the switch, against the new payload), ``offaxis_tool`` (``sim/payloads/offaxis-tool.toml``,
  2.7 kg, CoM 5 cm off the flange axis and 8 cm out: the tool ``iem bench real`` adds too).

results.json: ``scenarios.<scenario>.<model>`` with ``mae_groups`` (smoothed, as the plug-in
writes it), ``mae_groups_raw``, ``coverage_2sigma`` and ``coverage_2sigma_groups`` (share of
raw estimates within two reported standard deviations of the truth, pooled and per group;
None for a model without uncertainty), ``false_alarms`` (change detections while the payload
is fixed; None for a model without a detector) and, for ``payload_change``, ``detect_s``.
``calibration`` holds the arm's residual RMS before/after and the held-out check.
"""

from __future__ import annotations

import copy
import json
import time
from pathlib import Path as FsPath

import numpy as np

from deploy.options import add_arm_model, arm_description_of
from iem.ensemble import IncrementalEnsemble
from iem.physics import PhysicsInformedEnsemble
from iem.sensor import DEFAULT_SENSOR
from iem.types import GROUPS, NOMINAL_RATE_HZ

from .harness import CHANGE_TO, Bench
from .realistic_report import report

MODEL_ORDER = ("IEM", "IEM+phys", "IEM+cal", "IEM+phys+cal")
BATCH_MODELS = ("batch+bare", "batch+arm")
"""Offline commissioning identification (:func:`sim.identify.identify`) of each scenario's
whole recording: with a bare recording of the same motion, or with the calibrated arm."""
BARE_NOISE = 90
"""The bare recording of the batch models has noise seed ``seed + BARE_NOISE``."""
SCENARIOS = ("new_path", "bare_arm", "light_tool", "heavy_tool", "payload_change",
             "offaxis_tool")
GAP_SEED_BASE = 1000
"""The plant's reality gap has seed ``GAP_SEED_BASE + seed``."""
CAL_NOISE_BASE = 500
"""The calibration run's sensor noise has seed ``CAL_NOISE_BASE + seed``."""
SCENARIO_NOISE = {name: 10 * (i + 1) for i, name in enumerate(SCENARIOS)}
"""Each scenario's sensor-noise seed is ``seed + SCENARIO_NOISE[name]``."""

TARGETS = {  # the bench's targets: IEM+phys+cal unless noted
    ("new_path", "IEM+phys+cal"): {"mass": 0.003, "com": 0.002, "inertia": 0.0005},
    ("bare_arm", "IEM+phys+cal"): {"mass": 0.01},
    ("light_tool", "IEM+phys+cal"): {"mass": 0.005, "com": 0.004},
    ("heavy_tool", "IEM+phys+cal"): {"mass": 0.005, "com": 0.004},
    ("new_path", "IEM+cal"): {"mass": 0.014},
    ("new_path", "batch+bare"): {"mass": 0.0005, "com": 0.0003, "inertia": 0.0003},
    ("new_path", "batch+arm"): {"mass": 0.002, "com": 0.001},
}


def tools() -> dict:
    """The tools of the ``light_tool``, ``heavy_tool`` and ``offaxis_tool`` scenarios
    (outside the family)."""
    from sim.family import PAYLOAD_DIR
    from sim.payload import Payload, load_payload

    # light: an aluminium cylinder r 0.03 m, h 0.1 m, its CoM 1 cm off-axis
    m, r, h = 0.4, 0.03, 0.10
    light = Payload("light-tool", m, (0.0, 0.01, 0.05),
                    (m * (3 * r * r + h * h) / 12, 0.0, 0.0, m * (3 * r * r + h * h) / 12, 0.0,
                     m * r * r / 2))
    # heavy: a 0.2 x 0.08 x 0.08 m block along x whose CoM is 0.1 m off the flange axis
    m, a, b = 2.8, 0.20, 0.08
    heavy = Payload("heavy-tool", m, (0.08, 0.06, 0.06),
                    (m * 2 * b * b / 12, 0.0, 0.0, m * (a * a + b * b) / 12, 0.0,
                     m * (a * a + b * b) / 12))
    return {"light_tool": light, "heavy_tool": heavy,
            "offaxis_tool": load_payload(PAYLOAD_DIR / "offaxis-tool.toml")}


class RealisticBench(Bench):
    """The paper benchmark's set-up on the gapped plant, with a calibrated arm."""

    def __init__(self, quick: bool = False, seed: int = 0, log=print,
                 description=None) -> None:
        from sim.family import DEPLOY_FAMILY, family
        from sim.plant import RealityGap
        from sim.robot import ArmModel
        from sim.tandem import TandemSimulators

        super().__init__(quick=quick, seed=seed, log=log, description=description)
        self.gap = RealityGap(seed=GAP_SEED_BASE + seed)
        # what a cell deploys: the plug-in's default training family (the paper's 77 and 77
        # random tools), not the paper's alone
        self.family = DEPLOY_FAMILY
        self.tandem = TandemSimulators(family(DEPLOY_FAMILY),
                                       model=ArmModel(description=self.description))
        if quick:
            self.new_path = self.new_path.slice(0, 3.0)
            self.change_at = len(self.new_path) // 2

    def rollout(self, path, payload, seed, mount=None):
        t0 = time.perf_counter()
        plant = self._plant_cls(payload=payload, seed=seed, controller_load=payload,
                                gap=self.gap)
        out = plant.follow(path, mount=mount)
        self.log(f"rollout {path.name} ({path.duration:.1f} s) with "
                 f"{getattr(payload, 'name', 'no payload')}: {time.perf_counter() - t0:.1f} s")
        return out

    def calibrate(self, extra=(), source: str = "bench realistic calibration motion"):
        """The bare arm along the calibration motion, calibrated: ``(arm, held_out)``, with
        the residual RMS per joint on a held-out bare run of the excitation path. ``extra``:
        more bare recordings ``(t, q, dq, tau)`` calibrated on with it (as ``iem calibrate``
        given several logs), ``source`` what the arm file says it was fitted on."""
        from sim.arm import ArmParams
        from sim.calibration import residual_rms
        from sim.calibration_noise import calibrate_with_noise
        from sim.paths import calibration_path

        plant = self._plant_cls(payload=None, seed=CAL_NOISE_BASE + self.seed, gap=self.gap)
        r = plant.follow(calibration_path(model=self.kin))
        # as iem calibrate: the arm, and the noise it leaves in IEM+phys's equations
        arm = calibrate_with_noise([(r.t, r.q, r.dq, r.tau), *extra], source=source,
                                   description=self.description)
        nominal = ArmParams.nominal(None, self.description)
        held = self._plant_cls(payload=None, seed=CAL_NOISE_BASE + self.seed + 1,
                               gap=self.gap).follow(self.excitation)
        check = {"path": self.excitation.name,
                 "rms_nominal": residual_rms(nominal, held.t, held.q, held.dq, held.tau).tolist(),
                 "rms_calibrated": residual_rms(arm, held.t, held.q, held.dq,
                                                held.tau).tolist(),
                 "rms_true_arm": residual_rms(plant.arm, held.t, held.q, held.dq,
                                              held.tau).tolist()}
        return arm, check

    def make_models(self, arm_file=None) -> dict:
        from deploy.model.training import arm_torque_noise
        from sim.arm import arm_spec, load_arm

        q = self.quick
        common = {"seed": self.seed, "fit_epochs": 4 if q else 10,
                  "fit_stride": 20 if q else 10}
        arm = load_arm(arm_file, self.description)
        return {
            "IEM": IncrementalEnsemble(**common),
            "IEM+phys": PhysicsInformedEnsemble(ensemble=common, dynamics=self.dynamics),
            "IEM+cal": IncrementalEnsemble(**common),
            # the calibrated arm, with the noise iem calibrate measured on it (iem train)
            "IEM+phys+cal": PhysicsInformedEnsemble(
                ensemble=common, dynamics=arm_spec(arm),
                torque_noise=arm_torque_noise(arm)),
        }


def _score(run, phi, model, after: int = 0) -> dict:
    from iem.metrics import coverage as coverage_of
    from iem.metrics import groups_of, mae

    sl = slice(after, None)
    cov = coverage_of(run.raw[sl], run.std[sl], phi)
    detects = model.detects_changes
    return {
        "mae_groups": groups_of(mae(run.smoothed[sl], phi)),
        "mae_groups_raw": groups_of(mae(run.raw[sl], phi)),
        "coverage_2sigma": None if cov is None else cov["all"],
        "coverage_2sigma_groups": None if cov is None else {g: cov[g] for g in GROUPS},
        "false_alarms": int(run.changes[:after].sum() if after else run.changes.sum())
        if detects else None,
    }


def _batch(loaded, bare, arm, truth, after: int = 0, model=None) -> dict:
    """``batch+bare`` (``bare`` given) or ``batch+arm``: one offline identification of the
    recording (from sample ``after`` on; ``model``: the nominal arm's
    :class:`sim.robot.ArmModel`); the same keys as the online models' scores (the
    estimate is one value, raw and smoothed alike), plus ``time_s`` and, when
    :func:`sim.identify.identify` refuses the recordings, ``refused`` with its reason and
    None figures. The motion is the 6 s task path: inertia is not excited, and the
    excitation check is off, so inertia is reported as what the prior gives."""
    from iem.metrics import groups_of, mae
    from sim.identify import IdentifyError, identify

    def cut(r):
        return None if r is None else (r.t[after:], r.q[after:], r.dq[after:], r.tau[after:])

    t0 = time.perf_counter()
    try:
        result = identify(cut(loaded), bare=cut(bare), arm=None if bare is not None else arm,
                          check_excitation=False, model=model)
    except IdentifyError as exc:
        return {"mae_groups": None, "mae_groups_raw": None, "coverage_2sigma": None,
                "coverage_2sigma_groups": None, "false_alarms": None, "refused": str(exc),
                "time_s": time.perf_counter() - t0}
    err = np.abs(result.phi - truth)
    inside = err <= 2.0 * result.std
    groups = groups_of(mae(result.phi[None, :], truth))
    return {"mae_groups": groups, "mae_groups_raw": groups,
            "coverage_2sigma": float(inside.mean()),
            "coverage_2sigma_groups": {g: float(inside[list(i)].mean())
                                       for g, i in GROUPS.items()},
            "false_alarms": None, "determined_by": result.determined_by,
            "time_s": time.perf_counter() - t0}


def run_realistic(out_dir, quick: bool = False, seed: int = 0, log=print,
                  arm_file=None, description=None) -> dict:
    """All scenarios on the arm model ``description`` (None: the default); writes
    ``results.json`` and ``report.md`` to ``out_dir``."""
    from sim.robot import ArmModel
    from sim.tandem import TandemSimulators

    started = time.perf_counter()
    out_dir = FsPath(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    bench = RealisticBench(quick=quick, seed=seed, log=log, description=description)
    arm, held_out, arm_file = calibrated_arm(bench, out_dir, arm_file, log)
    cal_tandem = TandemSimulators(bench.tandem.phi, model=ArmModel(arm=arm))
    tandems = {"IEM+cal": cal_tandem, "IEM+phys+cal": cal_tandem}
    models = bench.make_models(arm_file)
    bench.fit(models, tandems)
    payloads = {"new_path": bench.payload, "bare_arm": None, **tools(),
                "payload_change": bench.payload}
    scen: dict = {name: {} for name in SCENARIOS}
    bare_run = bench.rollout(bench.new_path, None, seed + BARE_NOISE)
    for name in SCENARIOS:
        scen[name] = _scenario(bench, name, payloads[name], models, tandems, bare_run, arm)
    results = {
        "models": [*MODEL_ORDER, *BATCH_MODELS],
        "scenarios": scen,
        "calibration": {"arm_file": str(arm_file), "report": arm.report,
                        "held_out": held_out},
        "targets": {f"{s}.{m}": t for (s, m), t in TARGETS.items()},
        "setup": _setup(bench, payloads),
    }
    results["setup"]["wall_s"] = time.perf_counter() - started
    (out_dir / "results.json").write_text(json.dumps(results, indent=2) + "\n")
    (out_dir / "report.md").write_text(report(results))
    log(f"wrote {out_dir / 'results.json'} and {out_dir / 'report.md'} "
        f"in {results['setup']['wall_s']:.0f} s")
    return results


def calibrated_arm(bench: RealisticBench, out_dir: FsPath, arm_file, log):
    """``(arm, held_out, arm_file)``: the bare arm calibrated (its file written to
    ``out_dir``, its held-out residuals), or the given ``arm_file`` (held out: None)."""
    from sim.arm import load_arm, save_arm

    if arm_file is not None:
        return load_arm(arm_file, bench.description), None, arm_file
    t0 = time.perf_counter()
    arm, held_out = bench.calibrate()
    arm_file = out_dir / "arm.msgpack"
    save_arm(arm, arm_file)
    log(f"calibrated the arm in {time.perf_counter() - t0:.1f} s: residual RMS "
        + " ".join(f"{b:.3f}->{a:.3f}" for b, a in zip(arm.report["rms_before"],
                                                     arm.report["rms_after"], strict=True)))
    return arm, held_out, arm_file


def _scenario(bench: RealisticBench, name: str, payload, models: dict, tandems: dict,
              bare_run, arm) -> dict:
    """One scenario: every model on a copy of itself along the new task path with
    ``payload`` (switched at mid-path for ``payload_change``), then the batch models."""
    log = bench.log
    mount = {bench.change_at: bench.change_payload} if name == "payload_change" else None
    rollout = bench.rollout(bench.new_path, payload, bench.seed + SCENARIO_NOISE[name],
                            mount=mount)
    truth = np.zeros(10) if payload is None else payload.to_phi()
    after = 0
    if name == "payload_change":
        truth, after = bench.change_payload.to_phi(), bench.change_at
    out = {}
    for model_name in MODEL_ORDER:
        model = copy.deepcopy(models[model_name])
        r = bench.run(model, rollout, learn=True, tandem=tandems.get(model_name))
        first = int(np.searchsorted(r.last, after))  # the first block point after it
        s = _score(r, truth, model, first)
        if name == "payload_change" and model.detects_changes:
            fired = np.flatnonzero(r.changes[first:])
            s["detect_s"] = (None if fired.size == 0 else
                             float(r.t_end[first + fired[0]] - after / NOMINAL_RATE_HZ))
        out[model_name] = s
        g = s["mae_groups"]
        log(f"{name:14s} {model_name:13s} mass {g['mass']:.4f} com {g['com']:.4f} "
            f"inertia {g['inertia']:.5f} cov {s['coverage_2sigma']} "
            f"alarms {s['false_alarms']}")
    for model_name, bare in (("batch+bare", bare_run), ("batch+arm", None)):
        s = out[model_name] = _batch(rollout, bare, arm, truth, after, model=bench.kin)
        g = s["mae_groups"]
        log(f"{name:14s} {model_name:13s} " + (
            f"refused: {s['refused']}" if g is None else
            f"mass {g['mass']:.5f} com {g['com']:.5f} inertia {g['inertia']:.5f} "
            f"({s['time_s']:.1f} s)"))
    return out


def _setup(bench: RealisticBench, payloads: dict) -> dict:
    """The ``setup`` of the results (``wall_s`` is added at the end)."""
    gap = bench.gap
    return {"quick": bench.quick, "seed": bench.seed,
            "arm_model": bench.description.record(), "gap": {
        "seed": gap.seed, "mass_rel": gap.mass_rel,
        "inertia_rel": gap.inertia_rel, "com_abs": gap.com_abs,
        "friction_factor": list(gap.friction_factor or ()),
        "offset_std": gap.offset_std},
        "calibration_noise_seed": CAL_NOISE_BASE + bench.seed,
        "sensor": {"sigma_q": DEFAULT_SENSOR.sigma_q, "sigma_dq": DEFAULT_SENSOR.sigma_dq,
                   "sigma_tau": DEFAULT_SENSOR.sigma_tau},
        "payloads": {k: (None if p is None else p.name) for k, p in payloads.items()},
        "family": bench.family, "training_payloads": len(bench.tandem),
        "change": {"to": CHANGE_TO, "at_s": bench.change_at / 1000.0},
        "new_path_s": bench.new_path.duration}


def configure(parser) -> None:
    parser.add_argument("--out", required=True, metavar="DIR", help="folder for the results")
    parser.add_argument("--seed", type=int, default=0,
                        help="seed of the gap (plus 1000), the noise and the learners")
    parser.add_argument("--quick", action="store_true",
                        help="shorter training and a 3 s new path, same schema (for tests)")
    parser.add_argument("--arm", metavar="ARM",
                        help="use this arm file instead of calibrating the bare arm")
    add_arm_model(parser)


def run(args) -> int:
    description = arm_description_of(args)  # a bad arm model before anything runs
    run_realistic(args.out, quick=args.quick, seed=args.seed, arm_file=args.arm,
                  description=description)
    return 0
