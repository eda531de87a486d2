"""The safety gate between the estimator and the controller's ``setLoad``.

The gate's state is the load in force, as the controller confirms it
(:class:`deploy.writeback.load_state.LoadInForce`: acknowledgements, and the controller's own
reports where the link carries them). Every ``decision_period_s`` (default 50 ms) it looks at the
smoothed estimate (and the raw estimate it came from, for its uncertainty) and decides
whether writing it makes the controller's model better. In order, it holds:

1. ``malformed``: the estimate breaks its contract (shapes, a negative or NaN ``std``, a
   negative ``nis``, flags of the wrong type); ``stale``: it is older than ``max_age_s``;
2. ``not_finite``, ``inconsistent`` (not a possible rigid body), ``over_rated`` (the payload
   and the declared end effector beyond the arm's rated payload), ``com_too_far``,
   ``out_of_wire_range`` (:mod:`deploy.writeback.checks`). Not for the empty load: when the
   mass's upper 2-sigma bound stays below ``empty_mass_kg`` over the stability window, the
   candidate is the empty load (mass 0, as libfranka's ``setLoad`` takes it), so a removed
   tool is cleared;
3. ``controller_silent``: no joint state for the source's silence timeout;
4. ``ack_missing``: a command awaits its answer; ``lost``: a command went unanswered for
   ``ack_timeout_s``: the load in force stays as it was and the write is retried after a
   back-off (``ack_retry_s`` doubling up to ``ack_retry_max_s``); ``refused``: the
   controller refused the last command (a Franka does while a controller runs): retried
   after ``refusal_retry_s`` doubling up to ``refusal_retry_max_s``;
5. ``unreported``, ``out_of_distribution``, ``unverified`` (from a payload file or a restart,
   not yet tested by live data), ``uncertain`` (no band, or the inertia's band too wide),
   ``data_disagree`` (:func:`deploy.writeback.checks.model_doubt`);
6. ``unstable``: the estimate moved more than the stability band within ``stable_window_s``
   (hysteresis: stable below the band, unstable again only above twice it);
7. ``no_change``: the load in force lies within the estimate's band, or outside it by less
   than ``min_torque_error_nm`` of joint torque (:mod:`deploy.writeback.write_rule`): holding
   is fine;
   ``uncertain``: a write's worst case, in joint torque along the recent motion, is more than
   ``write_margin`` of the least error the load in force has: the write is not sure to help;
8. ``rate_limited``: the last write was less than ``1 / max_rate_hz`` s ago.

Otherwise ``send``; its detail names the groups the data do not determine (written as the
prior has them). Every decision is counted by reason; while holding, the reason is logged at
INFO at most once every :data:`HOLD_LOG_S` s, with its figures. :meth:`SafetyGate.verdict`
gives the last decision and the load in force for the links' status (ROS 2 ``/diagnostics``)
and the summary.
"""

from __future__ import annotations

import logging
import math
from collections import Counter, deque
from dataclasses import dataclass, replace

import numpy as np

from iem.payload import Payload
from iem.types import PayloadEstimate

from .checks import WireCheck, check_estimate, contract, model_doubt, upper_mass
from .load_state import UNKNOWN, LoadInForce, describe, load_record
from .settings import GateConfig
from .time_window import TimeWindow
from .write_rule import RecentMotion, Regressor, torque_errors

__all__ = ["REASONS", "REJECTIONS", "Decision", "GateConfig", "SafetyGate"]

log = logging.getLogger("iem.gate")

REASONS = ("send", "malformed", "stale", "not_finite", "inconsistent", "over_rated",
           "com_too_far", "out_of_wire_range", "controller_silent", "ack_missing", "lost",
           "refused", "unreported", "out_of_distribution", "unverified", "uncertain",
           "data_disagree", "unstable", "no_change", "rate_limited")
REJECTIONS = ("malformed", "not_finite", "inconsistent", "over_rated", "com_too_far",
              "out_of_wire_range")
"""Reasons that say the estimate itself can never be written (counted in ``rejected``)."""

SENT_LOADS_KEPT = 10_000
"""``send`` decisions :attr:`SafetyGate.sent_loads` keeps (a write a second: almost 3 h)."""
HOLD_LOG_S = 10.0
"""While holding, the reason is logged at INFO at most once per this many seconds."""
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
                                    c.refusal_retry_s, c.refusal_retry_max_s)
        """The load in force and what became of each command (the load writer tells it)."""
        self.motion = RecentMotion(regressor)
        self.counts: Counter[str] = Counter()
        self._history = TimeWindow(c.stable_window_s, 5)  # m, m·c, the mass's upper bound
        self._stable = False
        self._last_input = None  # (phi, raw) of the last step with an estimate
        self._newest = (-math.inf, -math.inf)  # (estimate time, gate time) of the newest
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
        """One step at gate time ``t``: the smoothed estimate ``smoothed`` (paper order) of
        one block point, the raw :class:`iem.types.PayloadEstimate` it came from (for its
        time and its uncertainty) and the point's joint ``state`` (its pose, for the torque
        bound) join the gate's view; then, every ``decision_period_s``, the decision (None
        when none is due; deferred up to :data:`DEFER_POINTS` steps while the model is
        ``busy`` with heavy work). A step without an estimate (a silence) decides on the
        last one. Never raises for what the estimate holds: a malformed one is refused
        with its reason."""
        if smoothed is not None:
            phi = _vector(smoothed)
            self._observe(t, phi, raw, state)
            self._last_input = (phi, raw)
        elif self._last_input is None:
            return None
        if t - self._last_decision_t < self.config.decision_period_s:
            return None
        if busy and self._deferred < DEFER_POINTS:
            self._deferred += 1
            return None
        self._deferred = 0
        return self._decision(t, *self._last_input)

    def _observe(self, t: float, phi: np.ndarray, raw, state) -> None:
        """Add one block point to the stability window, its pose to the recent motion and
        the raw estimate's time to the age's reference."""
        typed = _typed(raw)
        if typed is not None:
            when = typed.t
            if isinstance(when, int | float) and when >= self._newest[0]:
                self._newest = (float(when), t)
        if state is not None:
            self.motion.observe(t, state.q, state.dq)
        if phi.shape == (10,) and np.isfinite(phi).all():
            std = _vector(None if typed is None else typed.std)
            up = upper_mass(phi, std) if std.shape == (10,) else math.inf
            self._history.push(t, (*phi[:4], up if not math.isnan(up) else math.inf))
        else:
            self._history.expire(t)

    def _decision(self, t: float, phi: np.ndarray, raw) -> Decision:
        """Decide at ``t``, count it, remember a send, log a hold."""
        self.commands.tick(t)
        decision = self._decide(t, phi, raw)
        self._last_decision_t = t
        self._last = decision
        self.counts[decision.reason] += 1
        if decision.send:
            self.sent_loads.append((t, decision.payload, decision.from_prior))
            self._last_send_t = t
        else:
            self._log_hold(decision)
        return decision

    def _decide(self, t: float, phi: np.ndarray, estimate) -> Decision:
        c = self.config
        broken = contract(estimate, t, self._age(t, estimate), c)
        if broken:
            return Decision(t, broken[0], None, broken[1])
        empty = self._empty()
        candidate = None if empty else phi
        if not empty:
            reason, detail = check_estimate(phi, c, self.wire_check)
            if reason:
                return Decision(t, reason, phi if reason != "malformed" else None, detail)
        if self._silent:
            return Decision(t, "controller_silent", candidate, "no joint state from the controller")
        hold = self.commands.hold(t)
        if hold is not None:
            return Decision(t, hold[0], candidate, hold[1])
        doubt = model_doubt(estimate, c)
        if doubt is not None:
            return Decision(t, doubt[0], candidate, doubt[1])
        if not self._is_stable(empty):
            return Decision(t, "unstable", candidate, self._spread_text())
        helps = self._helps(phi, estimate, candidate)
        if helps is not None:
            return Decision(t, helps[0], candidate, helps[1])
        if t - self._last_send_t < 1.0 / c.max_rate_hz:
            return Decision(t, "rate_limited", candidate)
        return self._send(t, candidate, estimate)

    def _send(self, t: float, phi: np.ndarray | None, estimate) -> Decision:
        if phi is None:
            return Decision(t, "send", None, "the empty load: the mass's upper 2-sigma bound "
                                             f"stayed below {self.config.empty_mass_kg:g} kg")
        determined = None if _typed(estimate) is None else _typed(estimate).determined
        prior = () if determined is None else tuple(g for g in ("mass", "com", "inertia")
                                                    if g not in determined)
        note = f"; {' and '.join(prior)} from the prior (the motion does not determine " \
               f"{'it' if len(prior) == 1 else 'them'})" if prior else ""
        decision = Decision(t, "send", phi, "", from_prior=prior)
        return replace(decision, detail=describe(decision.payload) + note)

    # -- helpers -------------------------------------------------------------------------
    def _age(self, t: float, estimate) -> float:
        """How old ``estimate`` is at gate time ``t``: the time since the newest estimate
        reached the gate, plus how far ``estimate`` lags that one."""
        when = _typed(estimate).t if _typed(estimate) is not None else math.nan
        if not isinstance(when, int | float) or not math.isfinite(self._newest[0]):
            return 0.0
        return (t - self._newest[1]) + max(self._newest[0] - float(when), 0.0)

    def _empty(self) -> bool:
        """The mass's upper 2-sigma bound stayed below ``empty_mass_kg`` for the whole
        stability window."""
        w = self._history
        if not w.n or w.last_t - w.first_t < 0.9 * self.config.stable_window_s:
            return False
        return w.column_max(4) < self.config.empty_mass_kg

    def _helps(self, phi, estimate, candidate) -> tuple[str, str] | None:
        """``("no_change" | "uncertain", detail)`` unless writing ``candidate`` (paper
        order; None: the empty load) helps (:mod:`deploy.writeback.write_rule`)."""
        c, in_force = self.config, self.commands.load
        typed = _typed(estimate)
        std = None if typed is None else typed.std
        cov = None if typed is None or typed.cov is None else np.asarray(typed.cov, float)
        band = np.zeros(10) if std is None else 2.0 * np.asarray(std, dtype=float)
        band = np.where(np.isfinite(band), band, 0.0)  # an unseen inertia: the prior's
        candidate = np.zeros(10) if candidate is None else candidate
        if in_force == UNKNOWN:
            return None  # nothing to keep: what the controller holds is not known
        have = np.zeros(10) if in_force is None else in_force.to_phi()
        if cov is not None and not np.isfinite(cov).all():
            cov = None
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

    def _log_hold(self, decision: Decision) -> None:
        """While holding: the reason at INFO at most once per :data:`HOLD_LOG_S` s (and at
        DEBUG whenever it changes)."""
        at, reason = self._logged
        if decision.reason != reason:
            log.debug("gate %s: %s", decision.reason, decision.detail)
        if decision.t - at >= HOLD_LOG_S:
            log.info("holding: %s%s; %s in force", decision.reason,
                     f", {decision.detail}" if decision.detail else "",
                     describe(self.commands.load),
                     extra={"event": "gate", "reason": decision.reason,
                            "detail": decision.detail})
            self._logged = (decision.t, decision.reason)
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
        return out

    def summary(self) -> dict:
        """Counts of every decision reason; writes sent, acknowledged, lost, in force,
        rejected; the load in force."""
        rejected = sum(v for k, v in self.counts.items() if k in REJECTIONS)
        return {"decisions": dict(self.counts), **self.commands.summary(),
                "rejected": rejected}


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


def _typed(estimate) -> PayloadEstimate | None:
    """``estimate`` if it is the typed estimate the gate reads, else None (anything else is
    refused as ``unreported`` by :func:`deploy.writeback.checks.model_doubt`)."""
    return estimate if isinstance(estimate, PayloadEstimate) else None
