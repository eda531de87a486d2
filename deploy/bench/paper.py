"""``iem bench paper``: the paper's experiments in the simulation, our figures beside theirs.

Set-up (fixed seeds, the default sensor model of :mod:`iem.sensor`):

- The plant carries the default test payload (a configuration outside the 77 training
  payloads) and tracks the excitation path (20 s) and, separately, the new task path (6 s).
  Its controller is told the true load, so the arm follows the planned paths; the
  estimators see only the measured ``q, dq, tau_J``.
- IEM, old_IEM and BEM are trained offline on the excitation path: its bags are routed from
  the planned path and the tandem simulators (77 training payloads) give the samples at the
  planned states. Online, the tandem simulators run at the measured state with the causal
  ``ddq`` of :class:`iem.signals.filters.StateFilter`, as the plug-in does. LS needs no training.

Scenarios (every model's output smoothed the same causal way, :mod:`iem.signals.smoothing`):

- ``excitation`` (the paper's Table 2): each model estimates along the excitation path
  (IEM, old_IEM and BEM only estimate: the path is their training path; LS runs its
  recursive update from the prior).
- ``new_path`` (Table 4, Fig. 6): each model runs the new task path learning as it goes
  (IEM forms new bags, old_IEM updates in place, BEM never changes, LS restarts).
- ``forgetting`` (Fig. 5): the excitation-path MAE before and after the new task path
  (``before``/``after`` smoothed, ``before_raw``/``after_raw``), and ``weights_identical``:
  whether every excitation bag's learner is bit-identical after it (:mod:`deploy.bench.honesty`;
  the old in-place IEM's are not). For the old IEM also its ``update``
  (:mod:`iem.baselines.old_iem`), ``paper``: the paper's figures (``before`` its Table 2, ``after``
  section 5.3's, ``ratio``), and ``variants``: the same scenario for a copy with the
  ``running_centre`` update (the variant kept for comparison), from the old IEM as it was before the
new task path.
- ``revisit``: then the excitation path's first 6 s played backwards, learning on (the new
  task path never enters an excitation bag; this does), and the excitation path scored again.
- ``holdout``: IEM and IEM+phys afresh on the new task path with payloads drawn at random
  from the configurations outside the 77 (4, or 2 with ``--quick``; seeded): per payload,
  their mean and their maximum.

Every scenario reports ``mae_groups`` (the smoothed output) and ``mae_groups_raw`` (before
the smoothing). The paper describes no output smoothing: its figures compare with the raw
column. BEM is trained on the same stride of the excitation path as the IEM.

Beyond the paper (IEM+phys, :mod:`iem.physics`, runs in every scenario; on its training path
it tracks the payload with its physics but, like the IEM, does not train its learners):

- ``new_path`` also gives, per model that reports a standard deviation (LS, IEM+phys),
  ``coverage_2sigma``: the share of (sample, parameter) pairs of the raw estimate within two
  reported standard deviations of the truth (``coverage_2sigma_groups`` per group,
  ``mean_std_groups`` the mean reported standard deviation), else None; and for every model
  ``mae_groups_raw``, the MAE before the smoothing, and ``consistent_share``, the share of its
  raw estimates that are physically consistent (:mod:`iem.physics.consistency`); for IEM+phys also
  ``data_std_end``, the standard deviation per parameter that the path's equations alone give
  at its end (``data_std``: what the motion could tell, without the prior).
- ``new_path_continued``: the new task path for the models that carry a payload estimate
  between streams (``tracks_payload``: IEM+phys, LS), continuing from their state after the
  excitation path instead of starting afresh: the payload did not change, so, as the plug-in
  would, they keep what the excitation path told them of it (IEM+phys: the equations since the
  last payload change). ``new_path`` is the harder case of a payload first seen on the new
  path; this one is the plug-in's case of a payload carried from one task to the next. Same
  figures as ``new_path``.
- ``payload_change``: the new task path again (same noise), but at mid-path the payload on the
  plant switches from the test payload to ``test-4w`` (the controller is not told). Each model
  starts from its state after the excitation path (as for ``new_path``); ``detect_s`` is the
  time from the switch to the first detected change for models with a detector (None for
  the others, or if it never fires), ``false_alarms`` the changes it reported before the
  switch, and ``mae_groups`` the MAE after the switch against the new payload.

Timing: bag routing (median µs per query among 1 ... 10,000 bags), IEM estimate (median µs
per ``predict_one``) and IEM learning (median ms per ``learn_one`` of a point that trained a
learner, tandem samples included). IEM+phys on the new task path:
``phys_us_per_sample_median`` is the median of ``learn_one`` plus ``predict_one`` per
block point with the ensemble training inline, as the benchmark runs it (every point of a
forming bag pays its SGD steps, and a new bag its warm-up); ``phys_cycle_us_median`` and
``phys_cycle_us_p99`` time the whole :meth:`iem.online.OnlineIdentifier.step_block` (state
filter, kinematics, routing, estimate, physics update, smoothing) the way the plug-in runs it
on a live link (``go_live()``: the training in the learning worker), from the model as it
was before the new path (:func:`cycle_timing`). That is the code's own cost, back to back;
``phys_cycle_paced_us_median`` / ``_p99`` time the same steps fed one per block period (10
ms), the thread idle between them, as a 1 kHz cell's blocks come (with ``--quick``, the
path's first :data:`QUICK_PACED_POINTS` only: paced, every point costs its 10 ms of wall
time), and
``phys_cycle_cpu_us_mean`` / ``phys_cycle_paced_cpu_us_mean`` are the step thread's mean CPU
per block point either way (times 100 per second, paced: the share of one core the estimate
path takes, without the link reader and the gate); ``phys_cycle_points`` /
``phys_cycle_paced_points`` count the block points timed.

Every model works on block points (:mod:`iem.signals.blocks`): each rollout's 1 kHz frames are
formed into the means of 10 consecutive frames, as the plug-in's reader forms them, and the run's
arrays hold one row per block point; a scenario's switch at a frame counts from the first
block that holds a frame after it, and a detection is timed at the detecting block's last
frame (when its estimate can exist).
"""

from __future__ import annotations

import copy
import json
import time
from dataclasses import asdict
from pathlib import Path as FsPath

import numpy as np

from deploy.options import add_arm_model, arm_description_of
from iem.baselines.old_iem import RUNNING_CENTRE, InPlaceEnsemble
from iem.sensor import SensorModel
from iem.signals.smoothing import DEFAULT_TAU_S
from iem.types import PARAMS

from .harness import Bench
from .honesty import HOLDOUT_COUNT, fingerprints, holdout_payloads, revisit_path, unchanged
from .report import paper_forgetting
from .timing import PACED_RATE_HZ, cycle_timing, route_timing

QUICK_PACED_POINTS = 150
"""Block points of ``--quick``'s paced timing (1.5 s of wall time)."""


def run_paper(out_dir, quick: bool = False, seed: int = 0, log=print,
              extra_models: dict | None = None, description=None) -> dict:
    """All scenarios on the arm model ``description`` (:mod:`sim.description`; None: the
    default); writes ``results.json``, ``report.md`` and figures to ``out_dir``."""
    started = time.perf_counter()
    out_dir = FsPath(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    bench = Bench(quick=quick, seed=seed, log=log, description=description)
    models = bench.trained_models(extra_models)
    trained = {n: fingerprints(m) for n, m in models.items()}  # the excitation bags' learners
    scen: dict = {"excitation": {}, "new_path": {}, "new_path_continued": {}, "forgetting": {},
                  "revisit": {}, "payload_change": {}, "holdout": {}}
    runs: dict = {"excitation": {}, "new_path": {}, "new_path_continued": {},
                  "forgetting_after": {}, "payload_change": {}}
    bags_after_excitation = models["IEM"].n_bags
    _excitation(bench, models, scen, runs)
    frozen = {n: copy.deepcopy(m) for n, m in models.items()}
    _continued(bench, frozen, scen, runs)
    cycle = paced = None
    if "IEM+phys" in frozen:
        cycle = cycle_timing(bench, copy.deepcopy(frozen["IEM+phys"]), bench.new_rollout)
        paced = cycle_timing(bench, copy.deepcopy(frozen["IEM+phys"]), bench.new_rollout,
                             rate_hz=PACED_RATE_HZ,
                             points=QUICK_PACED_POINTS if bench.quick else None)
    _new_path(bench, models, scen, runs)
    _forgetting(bench, models, frozen, trained, scen, runs)
    _revisit(bench, models, trained, scen)
    _holdout(bench, frozen, scen)
    _payload_change(bench, frozen, scen, runs)
    del frozen
    results = {
        "params": list(PARAMS),
        "models": list(models),
        "scenarios": scen,
        "timing": _timing(bench, runs, cycle, paced),
        "bags": {"after_excitation": bags_after_excitation,
                 "after_new_path": models["IEM"].n_bags},
        "setup": _setup(bench),
    }
    results["setup"]["wall_s"] = time.perf_counter() - started
    (out_dir / "results.json").write_text(json.dumps(results, indent=2) + "\n")
    from .report import write_report

    write_report(out_dir, results, runs, bench, models)
    log(f"wrote {out_dir / 'results.json'} and {out_dir / 'report.md'} "
        f"in {results['setup']['wall_s']:.0f} s")
    return results


# -- the scenarios, in the order they run (each model carries its state from one to the next)
def _excitation(bench: Bench, models: dict, scen: dict, runs: dict) -> None:
    """Each model along the excitation path (only the models without a ``fit`` learn)."""
    for name, model in models.items():
        learns_on_excitation = not hasattr(model, "fit")
        r = bench.run(model, bench.exc_rollout, learn=learns_on_excitation)
        runs["excitation"][name] = r
        scen["excitation"][name] = bench.scores(r, bench.phi, model=model)
        bench.log(f"excitation {name:8s} {_fmt(scen['excitation'][name]['mae_groups'])}")


def _continued(bench: Bench, frozen: dict, scen: dict, runs: dict) -> None:
    """The new task path for the models that carry a payload, from a copy of their state
    after the excitation path (the same payload, its estimate carried over)."""
    for name, model in frozen.items():
        if not model.tracks_payload:
            continue  # no payload state to carry: as new_path
        carried = copy.deepcopy(model)
        r = bench.run(carried, bench.new_rollout, learn=True, fresh=False)
        runs["new_path_continued"][name] = r
        scen["new_path_continued"][name] = bench.scores(r, bench.phi, convergence=True,
                                                        model=carried)
        bench.log(f"continued  {name:8s} "
                  f"{_fmt(scen['new_path_continued'][name]['mae_groups'])}")


def _new_path(bench: Bench, models: dict, scen: dict, runs: dict) -> None:
    """Each model along the new task path, learning, afresh."""
    for name, model in models.items():
        r = bench.run(model, bench.new_rollout, learn=True)
        runs["new_path"][name] = r
        scen["new_path"][name] = bench.scores(r, bench.phi, convergence=True, model=model)
        bench.log(f"new path   {name:8s} {_fmt(scen['new_path'][name]['mae_groups'])} "
                  f"converged {scen['new_path'][name]['convergence_s']}")


def _forgetting(bench: Bench, models: dict, frozen: dict, trained: dict, scen: dict,
                runs: dict) -> None:
    """The excitation path again after the new task path, for the models that carry what
    they learnt: the MAE before and after, and whether the excitation learners changed."""
    for name, model in models.items():
        if not hasattr(model, "fit"):
            continue  # forgetting concerns models that carry what they learnt
        r = bench.run(model, bench.exc_rollout, learn=False)
        runs["forgetting_after"][name] = r
        after = bench.scores(r, bench.phi)
        f = scen["forgetting"][name] = {
            "before": scen["excitation"][name]["mae_groups"],
            "after": after["mae_groups"],
            "before_raw": scen["excitation"][name]["mae_groups_raw"],
            "after_raw": after["mae_groups_raw"]}
        f["weights_identical"] = unchanged(trained[name], model)
        if model.detects_changes:
            f["changes_after"] = int(r.changes.sum())
        if isinstance(model, InPlaceEnsemble):
            f["update"] = model.update
            f["paper"] = paper_forgetting("old_IEM")
            if model.update != RUNNING_CENTRE and name in frozen:
                f["variants"] = {RUNNING_CENTRE: forgetting_variant(
                    bench, frozen[name], RUNNING_CENTRE, f["before"], f["before_raw"])}
        _log_forgetting(bench.log, name, f)


def _revisit(bench: Bench, models: dict, trained: dict, scen: dict) -> None:
    """The excitation path's first seconds backwards, learning inside the excitation bags,
    then the excitation path scored again."""
    revisit = bench.rollout(revisit_path(bench.excitation), bench.payload, bench.seed + 3)
    for name, model in models.items():
        if not hasattr(model, "fit"):
            continue
        bench.run(model, revisit, learn=True)
        r = bench.run(model, bench.exc_rollout, learn=False)
        v = scen["revisit"][name] = {
            "before": scen["excitation"][name]["mae_groups"],
            "after": bench.scores(r, bench.phi)["mae_groups"],
            "weights_identical": unchanged(trained[name], model)}
        bench.log(f"revisit    {name:8s} after/before "
                  + _fmt({g: v['after'][g] / max(v['before'][g], 1e-300)
                          for g in ("mass", "com", "inertia")}, digits=2)
                  + f", excitation learners identical: {v['weights_identical']}")


def _holdout(bench: Bench, frozen: dict, scen: dict) -> None:
    """IEM and IEM+phys afresh on the new task path with each hold-out payload; per model
    the mean and the largest MAE over them."""
    holdouts = holdout_payloads(bench.seed, 2 if bench.quick else HOLDOUT_COUNT)
    for k, payload in enumerate(holdouts):
        rollout = bench.rollout(bench.new_path, payload, bench.seed + 100 + k)
        for name in ("IEM", "IEM+phys"):
            if name not in frozen:
                continue
            model = copy.deepcopy(frozen[name])
            r = bench.run(model, rollout, learn=True)
            sc = bench.scores(r, payload.to_phi(), model=model)
            scen["holdout"].setdefault(name, {})[payload.name] = {
                "payload": {"mass": payload.mass, "com": list(payload.com)},
                "mae_groups": sc["mae_groups"], "mae_groups_raw": sc["mae_groups_raw"]}
            bench.log(f"holdout    {name:8s} {payload.name} ({payload.mass:.3f} kg) "
                      f"{_fmt(sc['mae_groups'])}")
    for by_payload in scen["holdout"].values():
        runs_ = list(by_payload.values())
        for key in ("mae_groups", "mae_groups_raw"):
            rows = [v[key] for v in runs_]
            by_payload[f"mean_{key}"] = {g: float(np.mean([r[g] for r in rows]))
                                         for g in ("mass", "com", "inertia")}
            by_payload[f"max_{key}"] = {g: float(np.max([r[g] for r in rows]))
                                        for g in ("mass", "com", "inertia")}


def _payload_change(bench: Bench, frozen: dict, scen: dict, runs: dict) -> None:
    """Each model as it was before the new task path, along it with the payload switched."""
    for name, model in frozen.items():
        r = bench.run(model, bench.change_rollout, learn=True)
        runs["payload_change"][name] = r
        c = scen["payload_change"][name] = bench.change_scores(r, model)
        bench.log(f"change     {name:8s} after the switch {_fmt(c['mae_groups'])} "
                  f"detected after {c['detect_s']} s")


def _timing(bench: Bench, runs: dict, cycle: dict | None, paced: dict | None) -> dict:
    """The ``timing`` figures (see the module docstring)."""
    iem_new = runs["new_path"]["IEM"]
    learn_ms = iem_new.learn_s[iem_new.learnt] * 1e3 if iem_new.learnt.any() else np.array([])
    timing = {
        "route_us_median": route_timing(bench.kin, queries=500 if bench.quick else 2000),
        "predict_us_median": float(np.median(iem_new.predict_s) * 1e6),
        "learn_ms_per_point_median": float(np.median(learn_ms)) if learn_ms.size else None,
        "learn_points": int(learn_ms.size),
    }
    if "IEM+phys" in runs["new_path"]:
        phys = runs["new_path"]["IEM+phys"]
        timing["phys_us_per_sample_median"] = float(np.median(phys.learn_s + phys.predict_s)
                                                    * 1e6)
    if cycle is not None:
        for key in ("median", "p99"):
            timing[f"phys_cycle_us_{key}"] = cycle[key]
        timing["phys_cycle_cpu_us_mean"] = cycle["cpu_mean"]
        for key in ("median", "p99"):
            timing[f"phys_cycle_paced_us_{key}"] = paced[key]
        timing["phys_cycle_paced_cpu_us_mean"] = paced["cpu_mean"]
        timing["phys_cycle_points"] = cycle["points"]
        timing["phys_cycle_paced_points"] = paced["points"]
        bench.log(f"timing     IEM+phys per sample, learning inline "
                  f"{timing['phys_us_per_sample_median']:.0f} µs (median); one block point, "
                  f"training in the worker: back to back {cycle['median']:.0f} / "
                  f"{cycle['p99']:.0f} µs (median / p99), CPU {cycle['cpu_mean']:.0f} µs "
                  f"(mean); one every 10 ms {paced['median']:.0f} / {paced['p99']:.0f} µs, CPU "
                  f"{paced['cpu_mean']:.0f} µs")
    return timing


def _setup(bench: Bench) -> dict:
    """The ``setup`` of the results (``wall_s`` is added at the end)."""
    return {"quick": bench.quick, "seed": bench.seed,
            "arm_model": bench.description.record(), "test_payload": bench.payload.name,
            "test_phi": bench.phi.tolist(), "training_payloads": len(bench.tandem),
            "sensor": asdict(SensorModel()),
            "smoothing_tau_s": DEFAULT_TAU_S, "excitation_s": bench.excitation.duration,
            "new_path_s": bench.new_path.duration,
            "change": {"from": bench.payload.name, "to": bench.change_payload.name,
                       "at_s": bench.change_at / 1000.0}}


def forgetting_variant(bench: Bench, trained: InPlaceEnsemble, update: str, before: dict,
                       before_raw: dict) -> dict:
    """The forgetting scenario for a copy of the old IEM ``trained`` (as it was before the
    new task path) with another in-place ``update``: the new task path, learning, then the
    excitation path. ``before``: the excitation-path MAE of ``trained`` (the same learners)."""
    variant = copy.deepcopy(trained)
    variant.update = update
    new = bench.scores(bench.run(variant, bench.new_rollout, learn=True), bench.phi)
    after = bench.scores(bench.run(variant, bench.exc_rollout, learn=False), bench.phi)
    return {"before": before, "after": after["mae_groups"], "before_raw": before_raw,
            "after_raw": after["mae_groups_raw"], "new_path": new["mae_groups"],
            "new_path_raw": new["mae_groups_raw"]}


def _log_forgetting(log, name: str, f: dict) -> None:
    groups = ("mass", "com", "inertia")

    def ratio(v):
        return {g: v["after"][g] / max(v["before"][g], 1e-300) for g in groups}

    paper = f.get("paper")
    log(f"forgetting {name:8s} after {_fmt(f['after'])}, after/before "
        + _fmt(ratio(f), digits=2)
        + (f"; paper after {_fmt(paper['after'])}, after/before "
           + _fmt(paper["ratio"], digits=2) if paper else ""))
    for kind, v in f.get("variants", {}).items():
        log(f"forgetting {name} ({kind}) after {_fmt(v['after'])}, after/before "
            + _fmt(ratio(v), digits=2))


def _fmt(groups: dict, digits: int = 4) -> str:
    return "  ".join(f"{g} {v:.{digits}g}" for g, v in groups.items())


def configure(parser) -> None:
    parser.add_argument("--out", required=True, metavar="DIR", help="folder for the results")
    parser.add_argument("--quick", action="store_true",
                        help="smaller training, same schema (about a minute)")
    parser.add_argument("--seed", type=int, default=0, help="seed of noise and learners")
    add_arm_model(parser)


def run(args) -> int:
    from iem.extras import require

    description = arm_description_of(args)  # a bad arm model before anything runs
    require("matplotlib", "iem bench paper (its figures)")  # before, not after, the runs
    run_paper(args.out, quick=args.quick, seed=args.seed, description=description)
    return 0
