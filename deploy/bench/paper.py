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
ms), the thread idle between them, as a 1 kHz cell's blocks come, and
``phys_cycle_cpu_us_mean`` / ``phys_cycle_paced_cpu_us_mean`` are the step thread's mean CPU
per block point either way (times 100 per second, paced: the share of one core the estimate
path takes, without the link reader and the gate).

Every model works on block points (:mod:`iem.signals.blocks`): each rollout's 1 kHz frames are
formed into the means of 10 consecutive frames, as the plug-in's reader forms them, and the run's
arrays hold one row per block point; a scenario's switch at a frame counts from the first
block that holds a frame after it, and a detection is timed at the detecting block's last
frame (when its estimate can exist).
"""

from __future__ import annotations

import copy
import json
import math
import time
from dataclasses import asdict, dataclass
from functools import cached_property
from pathlib import Path as FsPath

import numpy as np

from iem.baselines.bem import BatchEnsemble
from iem.baselines.least_squares import RecursiveLeastSquares
from iem.baselines.old_iem import RUNNING_CENTRE, InPlaceEnsemble
from iem.ensemble import IncrementalEnsemble
from iem.ensemble.router import BagRouter
from iem.metrics import convergence_s, groups_of, mae
from iem.metrics import coverage as coverage_of
from iem.online import OnlineIdentifier
from iem.physics import PhysicsInformedEnsemble
from iem.physics.consistency import min_eigenvalue
from iem.sensor import SensorModel
from iem.signals.blocks import BlockFormer, Blocks
from iem.signals.smoothing import DEFAULT_TAU_S
from iem.types import GROUPS, NOMINAL_POINT_RATE_HZ, NOMINAL_RATE_HZ, PARAMS

from .honesty import HOLDOUT_COUNT, fingerprints, holdout_payloads, revisit_path, unchanged
from .report import paper_forgetting

MODEL_ORDER = ("IEM", "old_IEM", "BEM", "LS", "IEM+phys")
CHANGE_TO = "test-4w"
"""The payload the ``payload_change`` scenario switches to at mid-path."""
ROUTE_SIZES = (1, 10, 100, 1000, 10000)
PACED_RATE_HZ = NOMINAL_POINT_RATE_HZ
"""The rate at which :func:`cycle_timing`'s paced run feeds block points: a Panda's 1 kHz in
blocks of 10 frames."""


def rollout_blocks(rollout) -> Blocks:
    """A rollout's frames formed into block points as the plug-in's reader forms them (the
    last, incomplete block is left out)."""
    X = np.hstack((rollout.q, rollout.dq, rollout.tau))
    return BlockFormer(rate_hz=NOMINAL_RATE_HZ).push_many(rollout.t, X,
                                                          np.arange(len(rollout)))


@dataclass
class Run:
    """One model along one rollout: smoothed and raw estimates, bags, timings."""

    t: np.ndarray
    smoothed: np.ndarray
    raw: np.ndarray
    bags: np.ndarray
    learn_s: np.ndarray
    learnt: np.ndarray
    predict_s: np.ndarray
    std: np.ndarray
    """Reported standard deviations ``(N, 10)``, NaN where the model reports none."""
    changes: np.ndarray
    """True at the block points whose estimate reported a payload change."""
    last: np.ndarray
    """Index in the rollout of each block point's last frame."""
    t_end: np.ndarray
    """Time of each block point's last frame (s from the rollout's start): when its
    estimate can exist."""


class Bench:
    """The shared set-up of the paper benchmark and of ``iem bench custom``."""

    def __init__(self, quick: bool = False, seed: int = 0, log=print) -> None:
        from iem.extras import require
        from sim.family import default_test_payload, test_payloads, training_payloads
        from sim.paths import excitation_path, new_task_path

        require("mujoco", "the benchmark's simulated Panda")
        from sim.plant import PandaPlant
        from sim.robot import PandaModel
        from sim.tandem import TandemSimulators

        self.quick = quick
        self.seed = seed
        self.log = log
        self.kin = PandaModel()
        self.tandem = TandemSimulators(training_payloads(), model=PandaModel())
        self.payload = default_test_payload()
        self.phi = self.payload.to_phi()
        self.excitation = excitation_path()
        self.new_path = new_task_path()
        self.change_payload = test_payloads()[CHANGE_TO]
        self.change_at = len(self.new_path) // 2
        """Sample of the new task path at which ``payload_change`` switches the payload."""
        self._plant_cls = PandaPlant

    @cached_property
    def exc_rollout(self):
        """The plant along the excitation path with the test payload (noise seed ``seed``)."""
        return self.rollout(self.excitation, self.payload, self.seed)

    @cached_property
    def new_rollout(self):
        """The plant along the new task path with the test payload (noise seed ``seed + 1``)."""
        return self.rollout(self.new_path, self.payload, self.seed + 1)

    @cached_property
    def change_rollout(self):
        """The new task path (noise seed ``seed + 1``, as ``new_rollout``) with the payload
        switched to ``change_payload`` at ``change_at``."""
        return self.rollout(self.new_path, self.payload, self.seed + 1,
                            mount={self.change_at: self.change_payload})

    def rollout(self, path, payload, seed, mount=None):
        t0 = time.perf_counter()
        plant = self._plant_cls(payload=payload, seed=seed, controller_load=payload)
        out = plant.follow(path, mount=mount)
        self.log(f"rollout {path.name} ({path.duration:.1f} s) with {payload.name}: "
                 f"{time.perf_counter() - t0:.1f} s")
        return out

    # -- models --------------------------------------------------------------------------
    def make_models(self) -> dict:
        from sim.robot import PANDA_DYNAMICS

        q = self.quick
        common = {"seed": self.seed, "fit_epochs": 4 if q else 10,
                  "fit_stride": 20 if q else 10}
        return {
            "IEM": IncrementalEnsemble(**common),
            "old_IEM": InPlaceEnsemble(**common),
            "BEM": BatchEnsemble(seed=self.seed, fit_epochs=4 if q else 10,
                                 fit_stride=20 if q else 10, n_networks=3 if q else 5,
                                 n_trees=3 if q else 5),
            "LS": RecursiveLeastSquares(PANDA_DYNAMICS),
            "IEM+phys": PhysicsInformedEnsemble(ensemble=common, dynamics=PANDA_DYNAMICS),
        }

    def trained_models(self, extra_models: dict | None = None) -> dict:
        """The benchmark's models (plus ``extra_models``: name -> ``make(bench)``), trained."""
        models = self.make_models()
        if extra_models:
            models.update({name: make(self) for name, make in extra_models.items()})
        self.fit(models)
        return models

    def fit(self, models: dict, tandems: dict | None = None) -> None:
        """Offline training on the planned excitation path (bags and tandem samples);
        ``tandems`` maps a model's name to its own tandem simulators (default ``tandem``)."""
        path = self.excitation
        F = self.kin.flange_positions(path.q)

        for name, model in models.items():
            if not hasattr(model, "fit"):
                continue
            tandem = (tandems or {}).get(name, self.tandem)

            def samples_at(i, tandem=tandem):
                return tandem.samples(path.q[i], path.dq[i], path.ddq[i])

            t0 = time.perf_counter()
            model.fit(path.q, F, samples_at)
            self.log(f"fit {name}: {model.n_bags} bags ({time.perf_counter() - t0:.1f} s)")

    # -- runs ----------------------------------------------------------------------------
    def run(self, model, rollout, learn: bool, fresh: bool = True, tandem=None) -> Run:
        """One model along one rollout. ``fresh``: a new task with a payload the model has
        not seen, so the model first forgets the payload it was estimating (``reset()``; it
        keeps what it learnt); else the payload is the one of the model's last rollout and
        only the signal stream restarts (:meth:`iem.online.OnlineIdentifier.resume`).
        ``tandem``: the model's tandem simulators (default ``self.tandem``)."""
        if fresh:
            model.reset()
        tandem = self.tandem if tandem is None else tandem
        online = OnlineIdentifier(model, self.kin.flange_position, tandem.samples,
                                  learn=learn, timed=True)
        blocks = rollout_blocks(rollout)
        n = len(blocks)
        smoothed = np.empty((n, 10))
        raw = np.empty((n, 10))
        std = np.full((n, 10), math.nan)
        changes = np.zeros(n, dtype=bool)
        bags = np.empty(n, dtype=np.int64)
        for k in range(n):
            est, smoothed[k] = online.step_block(blocks.state(k))
            raw[k] = est.phi
            bags[k] = est.bag
            if est.std is not None:
                std[k] = est.std
            changes[k] = bool(est.extra.get("change"))
        if learn:
            model.close()
        return Run(t=blocks.t - rollout.t[0], smoothed=smoothed, raw=raw, bags=bags,
                   learn_s=np.array(online.learn_times), learnt=np.array(online.learnt),
                   predict_s=np.array(online.predict_times), std=std, changes=changes,
                   last=blocks.last, t_end=rollout.t[blocks.last] - rollout.t[0])

    def scores(self, run: Run, phi, convergence: bool = False, model=None) -> dict:
        """MAE (per parameter and group); with ``convergence`` also the convergence times,
        the raw MAE and the 2-sigma coverage of the reported standard deviations; for a
        ``model`` with a change detector, ``changes``: how many it reported (false alarms,
        the payload being fixed)."""
        per = mae(run.smoothed, phi)
        out = {"mae": per, "mae_groups": groups_of(per),
               "mae_groups_raw": groups_of(mae(run.raw, phi))}
        if model is not None and model.detects_changes:
            out["changes"] = int(run.changes.sum())
        if convergence and hasattr(model, "data_std"):
            out["data_std_end"] = {p: (v if math.isfinite(v) else None)  # None: unseen
                                   for p, v in zip(PARAMS, model.data_std.tolist(), strict=True)}
        if convergence:
            out["convergence_s"] = convergence_s(run.t, run.smoothed, phi)
            finite = np.all(np.isfinite(run.raw), axis=1)
            lam = np.full(len(run.raw), -np.inf)
            lam[finite] = min_eigenvalue(run.raw[finite])
            out["consistent_share"] = float(np.mean(lam > 0.0))
            cov = coverage_of(run.raw, run.std, phi)
            out["coverage_2sigma"] = None if cov is None else cov["all"]
            out["coverage_2sigma_groups"] = (None if cov is None else
                                             {g: cov[g] for g in GROUPS})
            out["mean_std_groups"] = (None if cov is None else
                                      {g: float(run.std[:, list(i)].mean())
                                       for g, i in GROUPS.items()})
        return out

    def change_scores(self, run: Run, model) -> dict:
        """The ``payload_change`` figures of one run (see the module docstring)."""
        k = int(np.searchsorted(run.last, self.change_at))  # the first block after it
        after = slice(k, None)
        at = self.change_at / NOMINAL_RATE_HZ  # s from the rollout's start
        phi = self.change_payload.to_phi()
        per = mae(run.smoothed[after], phi)
        out = {"detect_s": None, "false_alarms": None, "mae": per,
               "mae_groups": groups_of(per),
               "mae_groups_raw": groups_of(mae(run.raw[after], phi))}
        if model.detects_changes:
            fired = np.flatnonzero(run.changes[k:])
            out["detect_s"] = None if fired.size == 0 else float(run.t_end[k + fired[0]] - at)
            out["false_alarms"] = int(run.changes[:k].sum())
        return out


def cycle_timing(bench: Bench, model, rollout, rate_hz: float | None = None) -> dict:
    """µs per :meth:`iem.online.OnlineIdentifier.step_block` of ``model`` along ``rollout``'s
    block points (a new task, learning on) with its ensemble's training in the learning
    worker, as the plug-in runs it on a live link (:meth:`iem.base.Estimator.go_live`):
    ``{"median", "p99", "cpu_mean"}`` (``cpu_mean``: the step thread's CPU). The worker's own
    time is not counted (it competes for the interpreter, so it shows in the step's time as
    it would there).

    ``rate_hz``: one step per period of that rate, the thread idle between them, as on a live
    link; None: back to back. Paced, the same steps cost more: each is a short burst of
    interpreter and NumPy code that starts with cold caches and predictors. The paced figure
    is the one a cell meets; the back-to-back one is the code's own cost."""
    model.reset()
    model.go_live()  # the live link's set-up, as deploy.service makes it
    online = OnlineIdentifier(model, bench.kin.flange_position, bench.tandem.samples,
                              learn=True)
    blocks = rollout_blocks(rollout)
    times = np.empty(len(blocks))
    cpu = np.empty(len(blocks))
    period = None if rate_hz is None else 1.0 / float(rate_hz)
    try:
        due = time.perf_counter()
        for k in range(len(blocks)):
            state = blocks.state(k)
            if period is not None:  # the next block comes one period after the last
                due += period
                wait = due - time.perf_counter()
                if wait > 0.0:
                    time.sleep(wait)
            c0, t0 = time.thread_time(), time.perf_counter()
            online.step_block(state)
            times[k] = time.perf_counter() - t0
            cpu[k] = time.thread_time() - c0
    finally:
        model.stop()
    return {"median": float(np.median(times) * 1e6),
            "p99": float(np.percentile(times, 99) * 1e6),
            "cpu_mean": float(cpu.mean() * 1e6)}


def route_timing(kin, sizes=ROUTE_SIZES, queries: int = 2000, seed: int = 0) -> dict:
    """Median µs of one :meth:`BagRouter.route` among ``n`` bags spread over the workspace."""
    rng = np.random.default_rng(seed)
    out = {}
    for n in sizes:
        qs = rng.uniform(kin.q_min, kin.q_max, size=(n, 7))
        router = BagRouter.from_means(qs, kin.flange_positions(qs))
        probe_q = rng.uniform(kin.q_min, kin.q_max, size=(queries, 7))
        probe_f = kin.flange_positions(probe_q)
        times = np.empty(queries)
        for i in range(queries):
            t0 = time.perf_counter()
            router.route(probe_q[i], probe_f[i])
            times[i] = time.perf_counter() - t0
        out[str(n)] = float(np.median(times) * 1e6)
    return out


def run_paper(out_dir, quick: bool = False, seed: int = 0, log=print,
              extra_models: dict | None = None) -> dict:
    """All scenarios; writes ``results.json``, ``report.md`` and figures to ``out_dir``."""
    started = time.perf_counter()
    out_dir = FsPath(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    bench = Bench(quick=quick, seed=seed, log=log)
    models = bench.trained_models(extra_models)
    names = list(models)
    trained = {n: fingerprints(m) for n, m in models.items()}  # the excitation bags' learners

    scen: dict = {"excitation": {}, "new_path": {}, "new_path_continued": {}, "forgetting": {},
                  "revisit": {}, "payload_change": {}, "holdout": {}}
    runs: dict = {"excitation": {}, "new_path": {}, "new_path_continued": {},
                  "forgetting_after": {}, "payload_change": {}}
    bags_after_excitation = models["IEM"].n_bags
    for name, model in models.items():
        learns_on_excitation = not hasattr(model, "fit")
        r = bench.run(model, bench.exc_rollout, learn=learns_on_excitation)
        runs["excitation"][name] = r
        scen["excitation"][name] = bench.scores(r, bench.phi, model=model)
        log(f"excitation {name:8s} {_fmt(scen['excitation'][name]['mae_groups'])}")
    frozen = {n: copy.deepcopy(m) for n, m in models.items()}
    for name, model in frozen.items():  # the same payload, its estimate carried over
        if not model.tracks_payload:
            continue  # no payload state to carry: as new_path
        carried = copy.deepcopy(model)
        r = bench.run(carried, bench.new_rollout, learn=True, fresh=False)
        runs["new_path_continued"][name] = r
        scen["new_path_continued"][name] = bench.scores(r, bench.phi, convergence=True,
                                                        model=carried)
        log(f"continued  {name:8s} {_fmt(scen['new_path_continued'][name]['mae_groups'])}")
    cycle = paced = None
    if "IEM+phys" in frozen:
        cycle = cycle_timing(bench, copy.deepcopy(frozen["IEM+phys"]), bench.new_rollout)
        paced = cycle_timing(bench, copy.deepcopy(frozen["IEM+phys"]), bench.new_rollout,
                             rate_hz=PACED_RATE_HZ)
    for name, model in models.items():
        r = bench.run(model, bench.new_rollout, learn=True)
        runs["new_path"][name] = r
        scen["new_path"][name] = bench.scores(r, bench.phi, convergence=True, model=model)
        log(f"new path   {name:8s} {_fmt(scen['new_path'][name]['mae_groups'])} "
            f"converged {scen['new_path'][name]['convergence_s']}")
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
        _log_forgetting(log, name, f)
    revisit = bench.rollout(revisit_path(bench.excitation), bench.payload, seed + 3)
    for name, model in models.items():  # learning inside the excitation bags, then scored
        if not hasattr(model, "fit"):
            continue
        bench.run(model, revisit, learn=True)
        r = bench.run(model, bench.exc_rollout, learn=False)
        scen["revisit"][name] = {"before": scen["excitation"][name]["mae_groups"],
                                 "after": bench.scores(r, bench.phi)["mae_groups"],
                                 "weights_identical": unchanged(trained[name], model)}
        log(f"revisit    {name:8s} after/before "
            + _fmt({g: scen['revisit'][name]['after'][g]
                    / max(scen['revisit'][name]['before'][g], 1e-300)
                    for g in ("mass", "com", "inertia")}, digits=2)
            + f", excitation learners identical: {scen['revisit'][name]['weights_identical']}")
    holdouts = holdout_payloads(seed, 2 if quick else HOLDOUT_COUNT)
    for k, payload in enumerate(holdouts):
        rollout = bench.rollout(bench.new_path, payload, seed + 100 + k)
        for name in ("IEM", "IEM+phys"):
            if name not in frozen:
                continue
            model = copy.deepcopy(frozen[name])
            r = bench.run(model, rollout, learn=True)
            sc = bench.scores(r, payload.to_phi(), model=model)
            scen["holdout"].setdefault(name, {})[payload.name] = {
                "payload": {"mass": payload.mass, "com": list(payload.com)},
                "mae_groups": sc["mae_groups"], "mae_groups_raw": sc["mae_groups_raw"]}
            log(f"holdout    {name:8s} {payload.name} ({payload.mass:.3f} kg) "
                f"{_fmt(sc['mae_groups'])}")
    for by_payload in scen["holdout"].values():
        runs_ = list(by_payload.values())
        for key in ("mae_groups", "mae_groups_raw"):
            rows = [v[key] for v in runs_]
            by_payload[f"mean_{key}"] = {g: float(np.mean([r[g] for r in rows]))
                                         for g in ("mass", "com", "inertia")}
            by_payload[f"max_{key}"] = {g: float(np.max([r[g] for r in rows]))
                                        for g in ("mass", "com", "inertia")}
    for name, model in frozen.items():  # each model as it was before the new task path
        r = bench.run(model, bench.change_rollout, learn=True)
        runs["payload_change"][name] = r
        scen["payload_change"][name] = bench.change_scores(r, model)
        c = scen["payload_change"][name]
        log(f"change     {name:8s} after the switch {_fmt(c['mae_groups'])} "
            f"detected after {c['detect_s']} s")
    del frozen

    iem_new = runs["new_path"]["IEM"]
    learn_ms = iem_new.learn_s[iem_new.learnt] * 1e3 if iem_new.learnt.any() else np.array([])
    timing = {
        "route_us_median": route_timing(bench.kin, queries=500 if quick else 2000),
        "predict_us_median": float(np.median(iem_new.predict_s) * 1e6),
        "learn_ms_per_point_median": float(np.median(learn_ms)) if learn_ms.size else None,
        "learn_points": int(learn_ms.size),
    }
    if "IEM+phys" in runs["new_path"]:
        phys = runs["new_path"]["IEM+phys"]
        timing["phys_us_per_sample_median"] = float(np.median(phys.learn_s + phys.predict_s)
                                                    * 1e6)
    if cycle is not None:
        timing["phys_cycle_us_median"] = cycle["median"]
        timing["phys_cycle_us_p99"] = cycle["p99"]
        timing["phys_cycle_cpu_us_mean"] = cycle["cpu_mean"]
        timing["phys_cycle_paced_us_median"] = paced["median"]
        timing["phys_cycle_paced_us_p99"] = paced["p99"]
        timing["phys_cycle_paced_cpu_us_mean"] = paced["cpu_mean"]
        log(f"timing     IEM+phys per sample, learning inline "
            f"{timing['phys_us_per_sample_median']:.0f} µs (median); one cycle, training in "
            f"the worker: back to back {cycle['median']:.0f} / {cycle['p99']:.0f} µs "
            f"(median / p99), CPU {cycle['cpu_mean']:.0f} µs (mean); at 1 kHz "
            f"{paced['median']:.0f} / {paced['p99']:.0f} µs, CPU {paced['cpu_mean']:.0f} µs")
    results = {
        "params": list(PARAMS),
        "models": names,
        "scenarios": scen,
        "timing": timing,
        "bags": {"after_excitation": bags_after_excitation,
                 "after_new_path": models["IEM"].n_bags},
        "setup": {"quick": quick, "seed": seed, "test_payload": bench.payload.name,
                  "test_phi": bench.phi.tolist(), "training_payloads": len(bench.tandem),
                  "sensor": asdict(SensorModel()),
                  "smoothing_tau_s": DEFAULT_TAU_S, "excitation_s": bench.excitation.duration,
                  "new_path_s": bench.new_path.duration,
                  "change": {"from": bench.payload.name, "to": bench.change_payload.name,
                             "at_s": bench.change_at / 1000.0}},
    }
    results["setup"]["wall_s"] = time.perf_counter() - started
    (out_dir / "results.json").write_text(json.dumps(results, indent=2) + "\n")
    from .report import write_report

    write_report(out_dir, results, runs, bench, models)
    log(f"wrote {out_dir / 'results.json'} and {out_dir / 'report.md'} "
        f"in {results['setup']['wall_s']:.0f} s")
    return results


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


def run(args) -> int:
    from iem.extras import require

    require("matplotlib", "iem bench paper (its figures)")  # before, not after, the runs
    run_paper(args.out, quick=args.quick, seed=args.seed)
    return 0
