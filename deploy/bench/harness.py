"""The benchmarks' harness in the simulation: the set-up, the models, one model along one
rollout and its scores (:class:`Bench`), shared by ``iem bench paper``, ``iem bench custom``
and ``iem bench realistic``.

Every model works on block points (:mod:`iem.signals.blocks`): each rollout's 1 kHz frames
are formed into the means of 10 consecutive frames, as the plug-in's reader forms them
(:func:`rollout_blocks`), and a :class:`Run` holds one row per block point.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from functools import cached_property, partial

import numpy as np

from iem.baselines.bem import BatchEnsemble
from iem.baselines.least_squares import RecursiveLeastSquares
from iem.baselines.old_iem import InPlaceEnsemble
from iem.ensemble import IncrementalEnsemble
from iem.metrics import convergence_s, groups_of, mae
from iem.metrics import coverage as coverage_of
from iem.online import OnlineIdentifier
from iem.physics import PhysicsInformedEnsemble
from iem.physics.consistency import min_eigenvalue
from iem.signals.blocks import BlockFormer, Blocks
from iem.types import GROUPS, NOMINAL_RATE_HZ, PARAMS

__all__ = ["CHANGE_TO", "Bench", "Run", "rollout_blocks"]

CHANGE_TO = "test-4w"
"""The payload the ``payload_change`` scenario switches to at mid-path."""


def rollout_blocks(rollout) -> Blocks:
    """A rollout's frames formed into block points as the plug-in's reader forms them (the
    last, incomplete block is left out)."""
    return BlockFormer(rate_hz=NOMINAL_RATE_HZ).push_many(rollout.t, rollout.features,
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
    """The shared set-up of the paper benchmark and of ``iem bench custom``, on the arm model
    ``description`` (:mod:`sim.description`; None: the default): its plant, its kinematics,
    its paths (made for its limits, home and task) and its nominal dynamics for the models
    that compute with one (LS, IEM+phys)."""

    def __init__(self, quick: bool = False, seed: int = 0, log=print,
                 description=None) -> None:
        from iem.extras import require
        from sim.family import default_test_payload, test_payloads, training_payloads
        from sim.paths import excitation_path, new_task_path

        require("mujoco", "the benchmark's simulated arm")
        from sim.description import described
        from sim.plant import ArmPlant
        from sim.robot import ArmModel
        from sim.tandem import TandemSimulators

        self.quick = quick
        self.seed = seed
        self.log = log
        self.description = described(description)
        self.kin = ArmModel(description=self.description)
        self.tandem = TandemSimulators(training_payloads(),
                                       model=ArmModel(description=self.description))
        self.payload = default_test_payload()
        self.phi = self.payload.to_phi()
        self.excitation = excitation_path(model=self.kin)
        self.new_path = new_task_path(model=self.kin)
        self.change_payload = test_payloads()[CHANGE_TO]
        self.change_at = len(self.new_path) // 2
        """Sample of the new task path at which ``payload_change`` switches the payload."""
        self._plant_cls = partial(ArmPlant, description=self.description)

    @property
    def dynamics(self) -> str:
        """The dynamics spec of the arm model's nominal arm: :data:`sim.arm.NOMINAL_DYNAMICS`
        on the default arm model, else :func:`sim.arm.nominal_spec` (the arm by content)."""
        from sim.arm import NOMINAL_DYNAMICS, nominal_spec
        from sim.description import DEFAULT_ARM_MODEL

        if self.description.name == DEFAULT_ARM_MODEL:
            return NOMINAL_DYNAMICS
        return nominal_spec(None, self.description)

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
        q = self.quick
        common = {"seed": self.seed, "fit_epochs": 4 if q else 10,
                  "fit_stride": 20 if q else 10}
        return {
            "IEM": IncrementalEnsemble(**common),
            "old_IEM": InPlaceEnsemble(**common),
            "BEM": BatchEnsemble(seed=self.seed, fit_epochs=4 if q else 10,
                                 fit_stride=20 if q else 10, n_networks=3 if q else 5,
                                 n_trees=3 if q else 5),
            "LS": RecursiveLeastSquares(self.dynamics),
            "IEM+phys": PhysicsInformedEnsemble(ensemble=common, dynamics=self.dynamics),
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
