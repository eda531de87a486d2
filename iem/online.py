"""The online loop shared by the plug-in and the benchmarks: controller frames in, block
points through an estimator, estimates out.

Frames go through a :class:`iem.signals.blocks.BlockFormer` (:meth:`OnlineIdentifier.step`), or come
already formed into block points (:meth:`OnlineIdentifier.step_block`: the link reader's
thread and a replay form them): the estimator works once per block point, the means of
``q, dq, tau`` over 10 frames by default (100 points per second from a 1 kHz controller).
Every filter below runs at that point rate.

Per block point: the causal :class:`iem.signals.filters.StateFilter` gives the
state ``(q, dq, ddq)`` the tandem simulators run at (they move in tandem with the real arm,
at its measured state); the flange position comes from forward kinematics of the measured
``q``; the estimator learns from the point (the tandem samples are computed only if it asks
for them) and predicts; the estimate is smoothed with
:class:`iem.signals.smoothing.ExponentialSmoother` (the raw estimate stays available).

One gap rule (:mod:`iem.signals.gaps`) decides, from the time stamps, for every filter of the path:
the state filter applies it, and its verdict goes to the estimator and the smoothing. Lost
cycles up to the state filter's ``max_gap_s`` are bridged (``estimator.gap(k)``: its signal
filters interpolate the missing inputs; the smoothing decays by their time);
a sample that is not newer than the last one used (a duplicate, a frame overtaken by newer
ones) is counted in ``skipped`` and changes nothing: the last estimate is returned again.

An estimate whose ``extra`` holds ``"reset": True`` (a detected payload change; IEM+phys's
estimates from its prior alone, and its first with the physics) restarts the smoothing at
that estimate, so the old payload's estimates, or the superseded ones, do not linger in the
output.
When the state filter starts afresh (the first sample of a stream, the first after a gap longer
than its ``max_gap_s`` or a time stamp that goes backwards, or after
:meth:`OnlineIdentifier.resume`), the estimator's own signal filters restart too, through its
``resume()`` (its payload estimate stays: a silence is not a new payload). With learning on,
a cycle is the estimator's ``learn_predict_one`` (``learn_one`` and ``predict_one`` apart when
``timed``); with ``learn=False`` every sample goes through ``observe_one(x, flange)`` (what
the estimator follows of the payload without training, as IEM+phys's physics), then
``predict_one``. Every one of these is declared by :class:`iem.base.Estimator`, with defaults
in :class:`iem.base.BaseEstimator`.

The kinematics and the tandem simulators are passed in as callables, so this module stays
numpy-only: ``flange_position(q) -> (3,)`` and ``tandem(q, dq, ddq) -> (X, Y)``
(``sim.robot.ArmModel.flange_position`` and ``sim.tandem.TandemSimulators.samples``).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import replace

import numpy as np

from .base import Estimator
from .signals.blocks import BlockFormer
from .signals.filters import DEFAULT_CUTOFF_HZ, StateFilter, usable_cutoff
from .signals.gaps import RESTART, SKIP
from .signals.smoothing import ExponentialSmoother
from .types import JointState, PayloadEstimate


class OnlineIdentifier:
    """Runs an estimator cycle by cycle.

    Args:
        estimator: any :class:`iem.base.Estimator`.
        flange_position: forward kinematics, ``q -> flange position (3,)`` in m.
        tandem: ``(q, dq, ddq) -> (X (K, 21), Y (K, 10))``, the tandem simulators.
        learn: if False the estimator only predicts (evaluation of a frozen model).
        state_filter: the causal filter giving the tandem state, at the point rate
            (default: :class:`iem.signals.filters.StateFilter` at ``former``'s point rate).
        smoother: the output smoothing (default: EMA with 0.2 s at the point rate).
        former: what forms frames into block points for :meth:`step` (default: 10 frames of
            a 1 kHz controller).
        timed: record the time of every ``learn_one`` and ``predict_one`` call (s) in
            ``learn_times``/``predict_times``, and whether the point was learnt from
            (asked for tandem samples) in ``learnt``.
    """

    def __init__(self, estimator: Estimator, flange_position: Callable,
                 tandem: Callable | None, learn: bool = True,
                 state_filter: StateFilter | None = None,
                 smoother: ExponentialSmoother | None = None, timed: bool = False,
                 former: BlockFormer | None = None) -> None:
        self.former = BlockFormer() if former is None else former
        rate = self.former.point_rate_hz
        self.estimator = estimator
        self.flange_position = flange_position
        self.tandem = tandem
        self.learn = learn
        self.state_filter = (StateFilter(usable_cutoff(DEFAULT_CUTOFF_HZ, rate), rate)
                             if state_filter is None else state_filter)
        self.smoother = ExponentialSmoother(dt=1.0 / rate) if smoother is None else smoother
        self.raw: PayloadEstimate | None = None
        self._smoothed: np.ndarray | None = None
        self._steps = 1
        self._held: PayloadEstimate | None = None
        self._learned = 0
        self._learned_lock = threading.Lock()
        self.timed = timed
        self.learn_times: list[float] = []
        self.predict_times: list[float] = []
        self.learnt: list[bool] = []

    @property
    def learned_points(self) -> int:
        """Points learnt from: whose tandem samples were made (by the estimator's learning
        worker, for a point that joins a bag being formed)."""
        return self._learned

    def _count_learned(self) -> None:
        with self._learned_lock:  # the cycle and the learning worker both count
            self._learned += 1

    @property
    def skipped(self) -> int:
        """Frames and block points not used: not newer than the last one used (the gap
        rule's counts, at the frame and at the point rate)."""
        return self.former.skipped + self.state_filter.gaps.skipped

    def reset(self) -> None:
        """Start a new task: filters and smoother restart (the model is kept)."""
        self.resume()
        self.smoother.reset()
        self.raw = self._smoothed = self._held = None

    def resume(self) -> None:
        """The signal stream restarted: from the next sample the state filter and the
        estimator's own signal filters (its ``resume()``) start again; the estimate is
        kept. An open block is dropped."""
        self.former.reset()
        self.state_filter.reset()
        self._held = None

    def step(self, frame: JointState) -> tuple[PayloadEstimate, np.ndarray] | None:
        """Add one controller frame: a block it closes is learnt from and estimated at
        (:meth:`step_block`); returns that block's raw estimate and smoothed phi (the last
        block's, if bridged lost frames closed more than one), or, for a
        frame that closes no block, the last ones again, with neither ``"change"`` nor
        ``"reset"`` (they are said once, with the block they belong to); None before the
        first block."""
        points = self.former.push(frame.t, frame.q, frame.dq, frame.tau_J, frame.cycle)
        if points:
            flags = {}
            for point in points:  # more than one: lost frames bridged across a block's end
                out = self.step_block(point)
                flags.update({k: True for k in ("change", "reset") if out[0].extra.get(k)})
            self._held = None
            if flags.keys() - out[0].extra.keys():  # said by an earlier one: said here
                out = (replace(out[0], extra={**out[0].extra, **flags}), out[1])
            return out
        if self.raw is None:
            return None
        if self._held is None:
            extra = {k: v for k, v in self.raw.extra.items() if k not in ("change", "reset")}
            self._held = replace(self.raw, extra=extra)
        return self._held, self._smoothed.copy()

    def step_block(self, state: JointState) -> tuple[PayloadEstimate, np.ndarray]:
        """Learn from and estimate at one block point (:mod:`iem.signals.blocks`); returns the raw
        estimate and the smoothed phi."""
        x = state.features()
        q, dq, ddq = self.state_filter(state.q, state.dq, state.t)
        steps = self.state_filter.steps  # its gap rule decides for the estimator too
        if steps == SKIP and self.raw is not None:
            return self.raw, self._smoothed.copy()
        if steps == RESTART:
            self.estimator.resume()
        elif steps > 1:
            self.estimator.gap(steps)
        self._steps = max(steps, 1)
        flange = self.flange_position(state.q)
        if self.learn:
            tandem, count = self.tandem, self._count_learned
            asked = []

            def samples():  # may be called later, in the estimator's learning worker
                asked.append(True)
                count()
                return tandem(q, dq, ddq)

            if not self.timed:
                return self._finish(self.estimator.learn_predict_one(x, flange, samples,
                                                                     t=state.t))
            t0 = time.perf_counter()
            self.estimator.learn_one(x, flange, samples)
            self.learn_times.append(time.perf_counter() - t0)
            self.learnt.append(bool(asked))
        else:
            self.estimator.observe_one(x, flange)
        t0 = time.perf_counter()
        raw = self.estimator.predict_one(x, flange, t=state.t)
        if self.timed:
            self.predict_times.append(time.perf_counter() - t0)
        return self._finish(raw)

    def _finish(self, raw: PayloadEstimate) -> tuple[PayloadEstimate, np.ndarray]:
        """Keep the raw estimate and smooth it (afresh if the estimator says the payload
        changed: ``raw.extra["reset"]``)."""
        self.raw = raw
        if raw.extra.get("reset"):
            self.smoother.reset()
        self._smoothed = self.smoother(raw.phi, self._steps)
        return raw, self._smoothed
