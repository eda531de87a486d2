"""The safety gate between the estimator and the controller's ``setLoad``.

The gate's state is the load in force, as the controller confirms it
(:class:`deploy.writeback.load_state.LoadInForce`: acknowledgements, and the controller's own
reports where the link carries them). One :meth:`SafetyGate.step` a block point takes the
smoothed estimate, the raw estimate it came from (its time and its one uncertainty) and the
point's pose; every ``decision_period_s`` (default 50 ms) the step decides whether writing the
estimate makes the controller's model better. In order, it holds:

1. ``controller_silent``: no joint state for the source's silence timeout (a silence's steps
   bring no estimate); ``malformed``: the estimate breaks its contract
   (:func:`deploy.writeback.checks.read`: types, shapes, a negative or NaN ``std``, a
   covariance that is not one or disagrees with ``std``, a negative ``nis``, flags of the
   wrong type); ``stale``: it has not advanced for ``max_age_s``;
2. the candidate: the empty load (mass 0, as libfranka's ``setLoad`` takes it) while the
   mass's 2-sigma band has reached zero over the whole stability window (a removed tool;
   no CoM or inertia of such a mass is judged), else the estimate (an inertia the data do
   not determine taken from its prior), which must pass: ``not_finite``, ``inconsistent``
   (not a possible rigid body, or more inertia than a body of its mass within the arm's
   reach can have), ``over_rated`` (the payload and the declared end effector beyond the
   arm's rated payload), ``com_too_far``, ``out_of_wire_range``
   (:func:`deploy.writeback.checks.check_estimate`; the rating and the inertia at the
   2-sigma band's worst, the CoM's radius at the value written), and is ``uncertain`` while
   the mass's band reaches zero but has not for the whole window;
3. ``ack_missing``: a command awaits its answer; ``lost``: a command went unanswered for
   ``ack_timeout_s``: the load in force stays as it was and the write is retried after a
   back-off (``ack_retry_s`` doubling up to ``ack_retry_max_s``); ``refused``: the
   controller refused the last command (a Franka does while a controller runs): retried
   after ``refusal_retry_s`` doubling up to ``refusal_retry_max_s``;
   ``controller_disagrees``: the controller's own report contradicted a load it had
   confirmed: retried after the refusal's back-off, and not at all after
   ``max_disagreements`` in a row until it reports another load;
4. ``unreported``, ``out_of_distribution``, ``unverified`` (from a payload file or a restart,
   not yet tested by live data), ``uncertain`` (no band, the inertia's band too wide, or an
   undetermined inertia without a prior), ``data_disagree``
   (:func:`deploy.writeback.checks.model_doubt`);
5. ``unstable``: the estimate moved more than the stability band within ``stable_window_s``
   (hysteresis: stable below the band, unstable again only above twice it);
6. ``no_change``: the load in force lies within the estimate's band, or outside it by less
   than ``min_torque_error_nm`` of joint torque (:mod:`deploy.writeback.write_rule`), or the
   candidate is what is in force: holding is fine; ``uncertain``: a write's worst case, in
   joint torque along the recent motion, is more than ``write_margin`` of the least error the
   load in force has: the write is not sure to help;
7. ``rate_limited``: the last write was less than ``1 / max_rate_hz`` s ago. A write the
   controller refused does not count: it changed nothing, and the refusal's back-off paces
   its retry (a Franka refuses while the arm moves; the retry lands within
   ``refusal_retry_max_s`` of the motion's end).

Otherwise ``send``; its detail names the groups the data do not determine: an inertia the
data do not determine is written as the estimate's prior has it. Every decision is counted by
reason; while holding, the reason is logged at INFO at most once every :data:`HOLD_LOG_S` s,
with its figures. :meth:`SafetyGate.verdict` gives the last decision and the load in force
for the links' status (ROS 2 ``/diagnostics``) and the summary.

The gate's own time is the caller's (one clock per run: this PC's monotonic clock live, the
controller's on a replay), kept monotonic (:class:`GateClock`): a step whose time goes back,
or forward by more than :data:`CLOCK_JUMP_S`, advances it by nothing. An estimate whose own
time goes back, or forward far beyond the gate's, is a restart of the controller's clock:
the gate re-bases the estimate's age on it, logs it (at most once per :data:`HOLD_LOG_S` s)
and goes on; no restart stops the writes for longer than the stability window.
"""

from __future__ import annotations

import logging
import math
from collections import Counter, deque
from dataclasses import dataclass, replace

import numpy as np

from iem.payload import Payload

from .checks import (
    Reading,
    WireCheck,
    check_estimate,
    mass_band,
    model_doubt,
    read,
    with_prior_inertia,
)
from .load_state import UNKNOWN, LoadInForce, describe, load_record
from .settings import GateConfig
from .time_window import TimeWindow
from .write_rule import RecentMotion, Regressor, torque_errors

__all__ = ["REASONS", "REJECTIONS", "Decision", "GateConfig", "SafetyGate"]

log = logging.getLogger("iem.gate")

REASONS = ("send", "malformed", "stale", "not_finite", "inconsistent", "over_rated",
           "com_too_far", "out_of_wire_range", "controller_silent", "ack_missing", "lost",
           "refused", "controller_disagrees", "unreported", "out_of_distribution",
           "unverified", "uncertain", "data_disagree", "unstable", "no_change", "rate_limited")
REJECTIONS = ("malformed", "not_finite", "inconsistent", "over_rated", "com_too_far",
              "out_of_wire_range")
"""Reasons that say the estimate itself can never be written (counted in ``rejected``)."""

UNCHECKED = ("[gate] allow_without_uncertainty = true: estimates that do not report their "
             "standard deviations, nis or ood are written unchecked by them")
"""What the gate says at start and in every verdict when it writes estimates without an
uncertainty."""
SENT_LOADS_KEPT = 10_000
"""``send`` decisions :attr:`SafetyGate.sent_loads` keeps (a write a second: almost 3 h)."""
HOLD_LOG_S = 10.0
"""While holding, the reason is logged at INFO at most once per this many seconds."""
CLOCK_JUMP_S = 60.0
"""A step whose time moves forward by more than this is a jump of the clock, not time that
passed: the gate's own time advances by nothing (longer than the longest silence timeout, so
a silence's steps are time that passed)."""
DEFER_POINTS = 3
"""Steps a due decision may wait for one in which the model did no heavy work (the decision
then does not land on top of a refresh or a projection)."""


@dataclass(frozen=True)
class Decision:
    """What the gate decided at time ``t`` (s) and why; ``phi`` is the load a ``send``
    writes, in the paper's order (None: the empty load); of a hold, the candidate it judged
    (None: the empty load, or none)."""

    t: float
    reason: str
    phi: np.ndarray | None = None
    detail: str = ""
    from_prior: tuple = ()
    """Of a ``send``: the groups the model's data do not determine, written as its prior
    has them."""

    @property
    def send(self) -> bool:
        return self.reason == "send"

    @property
    def payload(self) -> Payload | None:
        """The load as the link writes it (None: the empty load, or no body to write)."""
        phi = self.phi
        if phi is None or not (phi.shape == (10,) and np.isfinite(phi).all() and phi[0] > 0):
            return None
        return Payload.from_phi(phi, name="estimate")


class SafetyGate:
    """Decides which estimates reach the controller, one step at a time (:meth:`step`);
    counts every decision, logs a holding reason at most once per :data:`HOLD_LOG_S` s (the
    load writer logs each send). The load in force is :attr:`commands`, which the load
    writer keeps (:class:`deploy.writeback.writer.LoadWriter`).

    Args:
        config: the settings (default :class:`GateConfig`).
        wire_check: the link's range check of a load (``payload -> message or None``); None
            for a link whose wire has no ranges to check.
        regressor: the arm's payload regressor ``(q, dq) -> Y`` for the torque bound along the
            recent motion (:mod:`deploy.writeback.write_rule`); None: the bound at the arm's reach.
    """

    def __init__(self, config: GateConfig | None = None, wire_check: WireCheck | None = None,
                 regressor: Regressor | None = None) -> None:
        self.config = c = GateConfig() if config is None else config
        self.wire_check = wire_check
        self.commands = LoadInForce(c.ack_timeout_s, c.ack_retry_s, c.ack_retry_max_s,
                                    c.refusal_retry_s, c.refusal_retry_max_s,
                                    c.max_disagreements)
        """The load in force and what became of each command (the load writer tells it, at
        the gate's time: :attr:`clock`)."""
        self.clock = GateClock(CLOCK_JUMP_S)
        """The gate's own time, from the caller's (:meth:`GateClock.__call__`)."""
        self.motion = RecentMotion(regressor)
        self.counts: Counter[str] = Counter()
        self._history = TimeWindow(c.stable_window_s, 5)  # m, m·c, the mass's lower bound
        self._stable = False
        self._newest = (-math.inf, -math.inf)  # (estimate time, gate time) of the newest
        self.clock_jumps = 0
        """Restarts and jumps of the controller's clock (or the caller's) the gate re-based
        on."""
        self._jump_logged = -math.inf
        self._clock_jumps_seen = 0
        self._last_decision_t = -math.inf
        self._deferred = 0
        self._last: Decision | None = None
        self._logged = (-math.inf, "")  # (t, reason) of the last holding log at INFO
        self._last_send_t = -math.inf
        self._silent = False
        self.sent_loads: deque[tuple[float, Payload | None, tuple]] = deque(
            maxlen=SENT_LOADS_KEPT)
        """The latest ``send`` decisions: ``(t, load or None for the empty load, groups
        from the prior)``."""
        if c.allow_without_uncertainty:
            log.warning(UNCHECKED, extra={"event": "gate_unchecked"})

    def controller_silent(self, silent: bool) -> None:
        """The controller fell silent (True) or is back (False)."""
        self._silent = silent
        if not silent:
            self.commands.controller_back()

    @property
    def in_force(self):
        """The load in force: a :class:`Payload`, None (empty) or ``"unknown"``."""
        return self.commands.load

    # -- the step ------------------------------------------------------------------------
    def step(self, t: float, smoothed=None, raw=None, state=None,
             busy: bool = False) -> Decision | None:
        """One step at time ``t`` (the run's clock): the smoothed estimate ``smoothed``
        (paper order) of one block point, the raw :class:`iem.types.PayloadEstimate` it came
        from (for its time and its uncertainty) and the point's joint ``state`` (its pose,
        for the torque bound) join the gate's view; then, every ``decision_period_s``, the
        decision (None when none is due; deferred up to :data:`DEFER_POINTS` steps while the
        model is ``busy`` with heavy work). A step without an estimate is a silence's: while
        the controller is silent (:meth:`controller_silent`) it holds with
        ``controller_silent``, else it decides nothing. Never raises for what it is given: a
        malformed estimate is refused with its reason."""
        now = self.clock(t)
        if self.clock.jumps != self._clock_jumps_seen:
            self._clock_jumps_seen = self.clock.jumps
            self._jumped(self.clock.last_jump, "the run's clock")
        if smoothed is None:  # no estimate: a silence
            if not self._silent or now - self._last_decision_t < self.config.decision_period_s:
                return None
            return self._decision(t, now, None, None, None, None)
        phi = _vector(smoothed)
        reading, broken = read(raw)
        self._observe(now, phi, reading, state)
        if now - self._last_decision_t < self.config.decision_period_s:
            return None
        if busy and self._deferred < DEFER_POINTS:
            self._deferred += 1
            return None
        self._deferred = 0
        return self._decision(t, now, phi, raw, reading, broken)

    def _observe(self, now: float, phi: np.ndarray, reading: Reading | None, state) -> None:
        """Add one block point to the stability window, its pose to the recent motion and
        the raw estimate's time to the age's reference (re-based on a jump)."""
        if reading is not None:
            last_t, last_now = self._newest
            when = reading.t
            if last_t == -math.inf or (
                    last_t < when <= last_t + (now - last_now) + CLOCK_JUMP_S):
                self._newest = (when, now)
            elif when != last_t:  # back, or far ahead: the controller's clock restarted
                self._newest = (when, now)
                self._jumped(when - last_t, "the controller's clock")
        if state is not None:
            self.motion.observe(now, state.q, state.dq)
        if phi.shape == (10,) and np.isfinite(phi).all():
            sigma = None if reading is None or reading.sigma is None else reading.sigma[0]
            self._history.push(now, (*phi[:4], mass_band(phi[0], sigma)[0]))
        else:
            self._history.expire(now)

    def _jumped(self, by: float, what: str) -> None:
        """A clock jump the gate re-based on: counted, logged at most once per
        :data:`HOLD_LOG_S` s of the gate's time."""
        self.clock_jumps += 1
        now = self.clock.now
        if now - self._jump_logged >= HOLD_LOG_S:
            self._jump_logged = now
            log.warning("%s jumped %s by %.6g s (a restart of the controller?): the gate goes "
                        "on from it (%d such jumps so far)", what,
                        "back" if by < 0 else "forward", abs(by), self.clock_jumps,
                        extra={"event": "clock_jump", "by_s": by})

    def _decision(self, t: float, now: float, phi: np.ndarray, raw, reading, broken
                  ) -> Decision:
        """Decide at ``t`` (gate time ``now``), count it, remember a send, log a hold."""
        self.commands.tick(now)
        decision = self._decide(t, now, phi, raw, reading, broken)
        self._last_decision_t = now
        self._last = decision
        self.counts[decision.reason] += 1
        if decision.send:
            self.sent_loads.append((t, decision.payload, decision.from_prior))
            self._last_send_t = now
        else:
            self._log_hold(decision, now)
        return decision

    def _decide(self, t: float, now: float, phi: np.ndarray | None, raw,
                reading: Reading | None, broken) -> Decision:
        c = self.config
        if self._silent:
            return Decision(t, "controller_silent", None, "no joint state from the controller")
        if broken:
            return Decision(t, broken[0], None, broken[1])
        if reading is not None:
            age = now - self._newest[1]
            if not age <= c.max_age_s:
                return Decision(t, "stale", None, f"the estimate has not advanced for "
                                                  f"{age:.3g} s at t = {_when(t)} s > "
                                                  f"{c.max_age_s:g} s")
        sigma = None if reading is None else reading.sigma
        cov = None if reading is None else reading.cov
        empty = self._empty()
        candidate = None
        if not empty:
            candidate = phi if reading is None else with_prior_inertia(phi, reading)
            reason, detail = check_estimate(candidate, c, self.wire_check, sigma, cov)
            if reason:
                return Decision(t, reason, candidate if reason != "malformed" else None,
                                detail)
        hold = self.commands.hold(now)
        if hold is not None:
            return Decision(t, hold[0], candidate, hold[1])
        doubt = model_doubt(raw, c, reading)
        if doubt is not None:
            return Decision(t, doubt[0], candidate, doubt[1])
        if not self._is_stable(empty):
            return Decision(t, "unstable", candidate, self._spread_text())
        helps = self._helps(phi, reading, candidate)
        if helps is not None:
            return Decision(t, helps[0], candidate, helps[1])
        if (not self.commands.newest_refused
                and now - self._last_send_t < 1.0 / c.max_rate_hz):
            return Decision(t, "rate_limited", candidate)
        return self._send(t, candidate, reading)

    def _send(self, t: float, phi: np.ndarray | None, reading: Reading | None) -> Decision:
        if phi is None:
            return Decision(t, "send", None, "the empty load: the mass's 2-sigma band has "
                                             f"reached zero for {self.config.stable_window_s:g} s")
        determined = None if reading is None else reading.determined
        prior = () if determined is None else tuple(g for g in ("mass", "com", "inertia")
                                                    if g not in determined)
        note = f"; {' and '.join(prior)} from the prior (the motion does not determine " \
               f"{'it' if len(prior) == 1 else 'them'})" if prior else ""
        decision = Decision(t, "send", phi, "", from_prior=prior)
        return replace(decision, detail=describe(decision.payload) + note)

    # -- helpers -------------------------------------------------------------------------
    def _empty(self) -> bool:
        """The mass's 2-sigma band reached zero (its lower bound not above it) all over the
        stability window: the estimate is not told from the empty load, which is then the
        candidate, judged by the write rule as any other (and no CoM or inertia of such a
        mass is judged)."""
        w = self._history
        if not w.n or w.last_t - w.first_t < 0.9 * self.config.stable_window_s:
            return False
        return w.column_max(4) <= 0.0

    def _helps(self, phi, reading: Reading | None, candidate) -> tuple[str, str] | None:
        """``("no_change" | "uncertain", detail)`` unless writing ``candidate`` (paper
        order; None: the empty load) helps (:mod:`deploy.writeback.write_rule`), judged with the
        estimate's one uncertainty (the larger of its ``std`` and its covariance's)."""
        c, in_force = self.config, self.commands.load
        band = np.zeros(10) if reading is None else reading.band()
        band = np.where(np.isfinite(band), band, 0.0)  # an unseen inertia: the prior's
        cov = None if reading is None else reading.cov
        if in_force == UNKNOWN:
            return None  # nothing to keep: what the controller holds is not known
        if candidate is None and in_force is None:
            return "no_change", "the empty load is in force, and the estimate is not told from it"
        candidate = np.zeros(10) if candidate is None else candidate
        have = np.zeros(10) if in_force is None else in_force.to_phi()
        hold, write = torque_errors(self.motion, have, candidate, phi, band, c.reach_m, cov)
        if not hold >= c.min_torque_error_nm:
            return ("no_change", f"{describe(in_force)} in force errs by at most "
                                 f"{max(hold, 0.0):.3f} N·m beyond the estimate's band "
                                 f"(< {c.min_torque_error_nm:g} N·m)")
        if not write <= c.write_margin * hold:
            return ("uncertain", f"a write could err by {write:.3f} N·m, more than "
                                 f"{c.write_margin:g} x the {hold:.3f} N·m the load in force "
                                 f"errs by at least (2-sigma mass {band[0]:.3f} kg)")
        return None

    def _spread(self) -> tuple[float, float] | None:
        window = self._history
        if not window.n or window.last_t - window.first_t < 0.9 * self.config.stable_window_s:
            return None  # not watched for long enough yet
        ptp = window.ptp(_mass_and_com)
        return float(ptp[0]), float(ptp[1:4].max())

    def _spread_text(self) -> str:
        spread = self._spread()
        if spread is None:
            return "estimate not yet watched for a whole stability window"
        return (f"spread over {self.config.stable_window_s:g} s: mass {spread[0]:.4f} kg, "
                f"CoM {spread[1]:.4f} m")

    def _is_stable(self, empty: bool = False) -> bool:
        """Within the stability band (the CoM's too, unless the candidate is the empty
        load, whose CoM is not defined)."""
        c = self.config
        spread = self._spread()
        if spread is None:
            self._stable = False
            return False
        m, r = spread
        if empty:
            r = 0.0
        k = 2.0 if self._stable else 1.0
        self._stable = m <= k * c.stable_mass_kg and r <= k * c.stable_com_m
        return self._stable

    def _log_hold(self, decision: Decision, now: float) -> None:
        """While holding: the reason at INFO at most once per :data:`HOLD_LOG_S` s of the
        gate's time (and at DEBUG whenever it changes)."""
        at, reason = self._logged
        if decision.reason != reason:
            log.debug("gate %s: %s", decision.reason, decision.detail)
        if now - at >= HOLD_LOG_S:
            log.info("holding: %s%s; %s in force", decision.reason,
                     f", {decision.detail}" if decision.detail else "",
                     describe(self.commands.load),
                     extra={"event": "gate", "reason": decision.reason,
                            "detail": decision.detail})
            self._logged = (now, decision.reason)
        else:
            self._logged = (at, decision.reason)

    # -- reporting -----------------------------------------------------------------------
    def verdict(self) -> dict:
        """The last decision and the load in force, for a link's status and the summary."""
        last = self._last
        out = {"reason": "" if last is None else last.reason,
               "detail": "" if last is None else last.detail,
               "load_in_force": load_record(self.commands.load)
               if self.commands.confirmed or self.commands.load is None else UNKNOWN,
               "in_force_confirmed": self.commands.confirmed}
        counts = self.commands.summary()
        for key in ("sent", "acked", "lost", "in_force", "send_errors"):
            out[key] = counts[key]
        out["refusals"] = counts["refused"]
        if self.config.allow_without_uncertainty:
            out["warning"] = UNCHECKED
        return out

    def summary(self) -> dict:
        """Counts of every decision reason; writes sent, acknowledged, lost, in force,
        rejected; the load in force; the clock jumps re-based on."""
        rejected = sum(v for k, v in self.counts.items() if k in REJECTIONS)
        return {"decisions": dict(self.counts), **self.commands.summary(),
                "rejected": rejected, "clock_jumps": self.clock_jumps}


class GateClock:
    """The gate's own time, from the caller's, kept monotonic: the caller's time plus an
    offset, which changes only when the caller's time goes back, or forward by more than
    ``jump_s`` (a restart, a jump of the clock): then the gate's time advances by nothing,
    counted in :attr:`jumps`. A time that is not a finite number advances it by nothing,
    uncounted.

    Args:
        jump_s: the largest forward step taken as time that passed, s.
    """

    def __init__(self, jump_s: float) -> None:
        self.jump_s = float(jump_s)
        self.now = 0.0
        """The gate's time after the last call, s."""
        self.jumps = 0
        self.last_jump = 0.0
        """The last jump, s (negative: back)."""
        self._last: float | None = None
        self._offset = 0.0

    def __call__(self, t) -> float:
        """The gate's time at the caller's time ``t`` (the same ``t`` again: the same)."""
        if not _finite(t):
            return self.now
        t = float(t)
        if self._last is not None and t != self._last and not (
                0.0 < t - self._last <= self.jump_s):
            self.jumps += 1
            self.last_jump = t - self._last
            self._offset = self.now - t
        self._last = t
        self.now = t + self._offset
        return self.now


def _finite(value) -> bool:
    return isinstance(value, int | float | np.integer | np.floating) and not isinstance(
        value, bool) and math.isfinite(value)


def _when(t) -> str:
    return f"{float(t):.3f}" if _finite(t) else repr(t)[:20]


def _mass_and_com(rows: np.ndarray) -> np.ndarray:
    """``[m, m c, ...]`` rows -> ``[m, c]`` rows."""
    out = np.empty((rows.shape[0], 4))
    out[:, 0] = rows[:, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        np.divide(rows[:, 1:4], rows[:, :1], out=out[:, 1:4])
    return out


def _vector(value) -> np.ndarray:
    """``value`` as a flat float array; one NaN for what is not numbers at all."""
    if value is None:
        return np.full(1, math.nan)
    try:
        return np.asarray(value, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        return np.full(1, math.nan)
