"""``iem bench longrun``: IEM and IEM+phys over a long random task motion.

Set-up (everything seeded by ``--seed``):

- The motion (:mod:`deploy.bench.random_motion`): rest-to-rest quintic segments between
  random waypoints within the joint limits less a margin, each as short as 90 % of the
  velocity and acceleration limits allow.
- The plant (:class:`sim.plant.ArmPlant`, perfect arm, default sensor model) carries the
  test payload (``test-3w``) and is told it, so it follows the motion.
- The models are trained as ``iem train`` does
  (:func:`deploy.model.training.train_initial_model`) and fed through
  :class:`iem.online.OnlineIdentifier` as the service feeds them, learning as they go.

Per 30 s window (the last one also takes the tail of the last segment past the run's length,
a few seconds, rather than scoring it alone) and model: ``bags``, ``nbytes``, the process's
``rss_mb`` (both models and the plant live in it), ``route_us`` (p50/p99 of the model's
:meth:`BagRouter.route` on every 10th sample, timed apart from the estimator;
``route_cpu_us`` the same in this thread's CPU time, which leaves out the time the machine
ran other work), ``retired`` and ``promoted`` (the budget's bags retired and promoted from
probation so far, :mod:`iem.ensemble.budget`), ``estimate_us`` (p50/p99 of ``predict_one``),
``learn_ms`` (median, max and total of the ``learn_one`` calls that learnt from a point, and
how many) and ``mae`` per group (mass, com, inertia) of the smoothed estimate against the
true payload; ``changes``: payload changes reported (false alarms: the payload never
changes); ``ood_share``: the share of estimates flagged out of distribution
(``ood``; the IEM's own estimates carry it).

Then the first minute of the motion is driven backwards (every segment reversed, in reverse
order: the same poses, every velocity reversed) by a fresh plant, and each model, as it is
at the end of the run, estimates along it with learning off (IEM+phys forgets the payload
first, as for a new task): ``reverse_mae``.

The models run with :data:`LONGRUN_PARAMS` (training on the samples driven backwards too,
and a bag budget, ``--budget``) unless ``--plain`` (the paper's rule: neither); they train in
the cycle (``background=False``: seeded runs reproduce) unless ``--background`` (the worker thread:
``learn_ms`` is then what the cycle itself spends). Last, ``at_budget``: a model
of ``--budget`` bags (the trained IEM's learners copied onto random poses within the limits)
saved and loaded: ``load_s``, ``file_mb``, ``route_us`` (p50/p99 over 2,000 random queries)
and the RSS it adds. Then ``route_sizes`` (new; after ``rss_mb_end`` is taken): route µs
p50/p99 of the float32 scan against exact distances to every bag on maps of ``--sizes`` bags
(:mod:`deploy.bench.routing`); ``--routing-only`` prints that alone, without the motion.

JSON keys: ``windows`` (a list), ``max_window_mae`` {model: {mass, com, inertia}},
``reverse_mae`` {model: {...}}, ``false_alarms`` {model: n} (None: no detector),
``bags_end``, ``rss_mb_end``, ``route_us_p99_end`` (each {model: value}), plus ``setup``.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path as FsPath

import numpy as np

from deploy.options import add_arm_model, arm_description_of, refuse_unused
from iem.ensemble.budget import DEFAULT_BUDGET_BAGS
from iem.metrics import groups_of, mae
from iem.online import OnlineIdentifier
from iem.types import JointState

from .harness import rollout_blocks
from .random_motion import random_segments, reversed_path
from .window_feed import WindowFeed, percentiles, rss_mb

MODELS = ("IEM", "IEM+phys")
WINDOW_S = 30.0
REVERSE_S = 60.0
DEFAULT_BUDGET = DEFAULT_BUDGET_BAGS
ROUTE_SIZES = (2000, 20000, 100000)
"""Bags of the maps the scan and exact distances are timed on (``route_sizes``)."""
LONGRUN_PARAMS = {"reversal": "sim.coverage:reversed_velocities", "coverage": None}
"""The ensemble's parameters for long runs (plus ``budget_bags``): the plug-in's
(:data:`deploy.model.training.DEPLOY_ENSEMBLE`)."""
PLAIN_PARAMS = {"reversal": None, "coverage": None, "budget_bags": None}
"""``--plain``: the paper's rule, none of the plug-in's ensemble settings."""


def train_models(seed: int, log, params: dict | None = None, description=None) -> dict:
    from deploy.model.training import train_initial_model

    return {kind: train_initial_model(kind, seed=seed, log=log, noise="sensor",
                                      description=description, **(params or {}))
            for kind in MODELS}


def run_longrun(minutes: float = 10.0, seed: int = 0, log=print,
                params: dict | None = None, sizes=ROUTE_SIZES, description=None) -> dict:
    """The long run on the arm model ``description`` (None: the default); returns the
    results (see the module docstring)."""
    from iem.extras import require
    from sim.family import default_test_payload, training_payloads

    require("mujoco", "iem bench longrun (the simulated arm)")
    from sim.robot import ArmModel
    from sim.tandem import TandemSimulators

    started = time.perf_counter()
    kin = ArmModel(description=description)
    payload = default_test_payload()
    tandem = TandemSimulators(training_payloads(), model=ArmModel(description=description))
    models = train_models(seed, log, params, description)
    feeds = {name: WindowFeed(name, m, kin, tandem) for name, m in models.items()}
    drive = _drive(feeds, payload, float(minutes) * 60.0, seed, kin, log)
    for m in models.values():
        m.close()
        m.drain()  # the training still in the worker lands before the replay

    reverse_mae, reverse_s = reverse_figures(models, drive.first_minute, payload, seed, kin,
                                             tandem, log)
    del drive.first_minute  # the replay's data die with it, before the figures at the budget

    at_budget = budget_figures(models["IEM"], (params or {}).get("budget_bags") or DEFAULT_BUDGET,
                               kin, seed)
    log(f"at the budget: {at_budget}")
    windows = drive.windows
    results = {
        "windows": windows,
        "max_window_mae": {name: {g: max(w[name]["mae"][g] for w in windows)
                                  for g in ("mass", "com", "inertia")} for name in models},
        "reverse_mae": reverse_mae,
        "false_alarms": {name: (f.changes_total
                                if models[name].detects_changes else None)
                         for name, f in feeds.items()},
        "bags_end": {name: int(m.n_bags) for name, m in models.items()},
        "rss_mb_end": rss_mb(),
        "route_us_p99_end": {name: windows[-1][name]["route_us"]["p99"] for name in models},
        "route_cpu_us_p99_end": {name: windows[-1][name]["route_cpu_us"]["p99"]
                                 for name in models},
        "at_budget": at_budget,
        "setup": {"minutes": minutes, "seed": seed, "arm_model": kin.description.record(),
                  "payload": payload.name,
                  "segments": drive.segments, "samples": drive.samples,
                  "reverse_s": reverse_s, "params": params or {},
                  "wall_s": time.perf_counter() - started},
    }
    results["route_sizes"] = route_sizes(kin, sizes, seed, log)
    log("max window MAE: " + "; ".join(f"{n} {_fmt(v)}"
                                         for n, v in results["max_window_mae"].items()))
    log(f"false alarms {results['false_alarms']}  bags {results['bags_end']}  "
        f"RSS {results['rss_mb_end']:.0f} MB  route p99 {results['route_us_p99_end']} µs  "
        f"({results['setup']['wall_s']:.0f} s)")
    return results


@dataclass
class _Drive:
    """What driving the motion gave: the windows' figures, the segments of its first
    :data:`REVERSE_S` seconds (for the reverse replay), and how many segments and frames."""

    windows: list
    first_minute: list
    segments: int
    samples: int


def _drive(feeds: dict, payload, seconds: float, seed: int, kin, log) -> _Drive:
    """The plant along ``seconds`` of random motion, every frame fed to every model, the
    figures taken every :data:`WINDOW_S`."""
    from sim.plant import ArmPlant

    phi = payload.to_phi()
    plant = ArmPlant(payload=payload, seed=seed, controller_load=payload,
                     description=kin.description)
    windows: list[dict] = []
    first_minute = []
    t_sim, k, next_window, started_plant = 0.0, 0, WINDOW_S, False
    segments = 0
    for seg in random_segments(seconds, seed, kin):
        if t_sim < REVERSE_S:
            first_minute.append(seg)
        segments += 1
        n = len(seg)
        first = 0 if not started_plant else 1  # a joined segment's first sample is the last's
        if not started_plant:
            plant.reset(seg.q[0], seg.dq[0])
            started_plant = True
        for i in range(first, n):
            s = plant.step(seg.q[i], seg.dq[i], seg.ddq[i])
            state = JointState(t=s.t, q=s.q, dq=s.dq, tau_J=s.tau_J, cycle=k)
            for feed in feeds.values():
                feed.step(state, k)
            k += 1
            t_sim = k / 1000.0
            if t_sim >= next_window - 1e-9 and next_window < seconds - 1e-9:
                w = {"t_end_s": t_sim, **{name: f.window(phi) for name, f in feeds.items()}}
                windows.append(w)
                log(_fmt_window(w))
                next_window += WINDOW_S
    if feeds["IEM"].smoothed:  # the last window, with the tail of the last segment past
        # the run's length (scored alone, a 2 s tail was the IEM's worst "window")
        w = {"t_end_s": t_sim, **{name: f.window(phi) for name, f in feeds.items()}}
        windows.append(w)
        log(_fmt_window(w))
    return _Drive(windows, first_minute, segments, k)


def reverse_figures(models: dict, segments: list, payload, seed: int, kin, tandem,
                    log=print) -> tuple[dict, float]:
    """The segments driven backwards by a fresh plant, each model estimating along them with
    learning off (IEM+phys forgets the payload first): ``({model: MAE per group}, seconds)``.
    A function of its own so that the rollout (tens of MB) is freed when it returns."""
    from sim.plant import ArmPlant

    phi = payload.to_phi()
    reverse = reversed_path(segments)
    back_plant = ArmPlant(payload=payload, seed=seed + 1000, controller_load=payload,
                          description=kin.description)
    rollout = back_plant.follow(reverse)
    reverse_mae = {}
    for name, m in models.items():
        m.reset()
        online = OnlineIdentifier(m, kin.flange_position, tandem.samples, learn=False)
        blocks = rollout_blocks(rollout)
        out = np.empty((len(blocks), 10))
        for i in range(len(blocks)):
            out[i] = online.step_block(blocks.state(i))[1]
        reverse_mae[name] = groups_of(mae(out, phi))
        log(f"reverse {name:8s} " + _fmt(reverse_mae[name]))
    return reverse_mae, reverse.duration


def route_sizes(kin, sizes, seed: int, log=print) -> list[dict]:
    """Route µs, scan against exact distances, on maps of ``sizes`` bags
    (:mod:`deploy.bench.routing`)."""
    from deploy.bench.routing import format_rows, scan_vs_exact

    rows = scan_vs_exact(kin, sizes, seed) if sizes else []
    if rows:
        log("route µs p50/p99, scan vs exact:\n" + format_rows(rows))
    return rows


def budget_figures(model, n: int, kin, seed: int, queries: int = 2000) -> dict:
    """A model of ``n`` bags (``model``'s learners copied onto random poses): its file's
    size and load time, the RSS the loaded model adds, and route p50/p99 among its bags."""
    import gc
    import tempfile

    from iem.ensemble import IncrementalEnsemble
    from iem.ensemble.router import BagRouter
    from iem.persistence import load_model, save_model

    rng = np.random.default_rng([seed, 2000])
    Q = rng.uniform(kin.q_min, kin.q_max, size=(n, 7))
    big = IncrementalEnsemble.from_state(model.to_state())
    big._router = BagRouter.from_means(Q, kin.flange_positions(Q), big.delta, big.rho)
    src = [model.learner(b) for b in range(model.n_bags)]
    big._learners = [src[i % len(src)].copy_for(src[i % len(src)].center, seed=[seed, i])
                     for i in range(n)]
    big._gen = [0] * n
    big._open, big._kept, big._training = -1, None, None
    with tempfile.TemporaryDirectory() as tmp:
        path = FsPath(tmp) / "budget.iem"
        save_model(big, path)
        size = path.stat().st_size
        del big
        gc.collect()
        rss0 = rss_mb()
        t0 = time.perf_counter()
        loaded = load_model(path)
        load_s = time.perf_counter() - t0
        rss1 = rss_mb()
    probe = rng.uniform(kin.q_min, kin.q_max, size=(queries, 7))
    flange = kin.flange_positions(probe)
    times = np.empty(queries)
    cpu = np.empty(queries)
    router = loaded.router
    for i in range(queries):
        c0, t0 = time.thread_time(), time.perf_counter()
        router.route(probe[i], flange[i])
        times[i] = time.perf_counter() - t0
        cpu[i] = time.thread_time() - c0
    return {"bags": n, "file_mb": size / 1e6, "load_s": load_s, "rss_added_mb": rss1 - rss0,
            "nbytes_mb": loaded.nbytes() / 1e6, "route_us": percentiles(times * 1e6),
            "route_cpu_us": percentiles(cpu * 1e6)}


def _fmt(groups: dict) -> str:
    return "  ".join(f"{g} {v:.4g}" for g, v in groups.items())


def _fmt_window(w: dict) -> str:
    parts = [f"t {w['t_end_s']:6.0f} s"]
    for name in MODELS:
        f = w[name]
        lm = f["learn_ms"]["median"]
        parts.append(f"{name}: {f['bags']} bags {f['nbytes'] / 1e6:.2f} MB "
                     f"route p99 {f['route_us']['p99']:.0f} µs "
                     f"est p50 {f['estimate_us']['p50']:.0f} µs "
                     f"learn {'-' if lm is None else f'{lm:.1f}'} ms "
                     f"mass {f['mae']['mass']:.4f} alarms {f['changes']}")
    return " | ".join(parts) + f" | RSS {w[MODELS[0]]['rss_mb']:.0f} MB"


def configure(parser) -> None:
    parser.add_argument("--minutes", type=float, default=None,
                        help="length of the motion (default 10)")
    parser.add_argument("--seed", type=int, default=0, help="seed of motion, noise, learners")
    parser.add_argument("--json", metavar="FILE", help="also write the results as JSON")
    parser.add_argument("--budget", type=int, default=None, metavar="BAGS",
                        help=f"bag budget of the ensemble (default {DEFAULT_BUDGET}; its newest "
                             "10 %% are on probation, iem/ensemble/budget.py)")
    parser.add_argument("--background", action="store_true",
                        help="train in the worker thread, off the cycle (not reproducible: "
                             "when training lands depends on the machine)")
    parser.add_argument("--plain", action="store_true",
                        help="the paper's rule: no reversed samples, no coverage training, "
                             "no budget")
    parser.add_argument("--sizes", default=",".join(map(str, ROUTE_SIZES)), metavar="N,N,...",
                        help="bags of the maps on which route µs of the scan and of exact "
                             "distances are compared (default 2000,20000,100000; '' for none)")
    parser.add_argument("--routing-only", action="store_true",
                        help="only the scan-vs-exact routing figures, without the motion")
    add_arm_model(parser)


def parse_sizes(text: str) -> tuple[int, ...]:
    """``--sizes``: comma-separated bag counts, each >= 1 ('' for none)."""
    from iem.errors import InvalidInputError

    parts = [part.strip() for part in text.split(",") if part.strip()]
    if not all(part.isdigit() and int(part) >= 1 for part in parts):
        raise InvalidInputError(f"--sizes must be comma-separated bag counts >= 1 "
                                f"(e.g. 2000,20000), got {text!r}")
    return tuple(int(part) for part in parts)


def run(args) -> int:
    from iem.errors import InvalidInputError

    if args.routing_only:
        refuse_unused(args, ["--minutes", "--budget", "--background", "--plain"],
                      "with --routing-only: they are the motion's")
    if args.plain:
        refuse_unused(args, ["--budget"], "with --plain: the paper's rule has no budget")
    minutes = 10.0 if args.minutes is None else args.minutes
    budget = DEFAULT_BUDGET if args.budget is None else args.budget
    if not minutes > 0:
        raise InvalidInputError(f"--minutes must be > 0, got {minutes}")
    if budget < 2:
        raise InvalidInputError(f"--budget must be >= 2 bags, got {budget}")
    sizes = parse_sizes(args.sizes)
    description = arm_description_of(args)
    if args.routing_only:
        from sim.robot import ArmModel

        results = {"route_sizes": route_sizes(ArmModel(description=description), sizes,
                                              args.seed)}
    else:
        params = (dict(PLAIN_PARAMS) if args.plain
                  else {**LONGRUN_PARAMS, "budget_bags": budget})
        if args.background:
            params["background"] = True
        results = run_longrun(minutes, args.seed, params=params, sizes=sizes,
                              description=description)
    if args.json:
        FsPath(args.json).write_text(json.dumps(results, indent=2) + "\n")
        print(f"wrote {args.json}")
    return 0
