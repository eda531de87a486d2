"""The safety gate between the estimator and the controller's ``setLoad``.

Every ``decision_period_s`` (default 50 ms) the gate looks at the smoothed estimate and
decides whether to write it to the controller. In order, an estimate is refused if:

1. ``not_finite``: any parameter is NaN or infinite;
2. ``inconsistent``: it is not a physically possible rigid body (mass > 0, inertia about the
   CoM positive definite, triangle inequality);
3. ``over_rated``: the mass exceeds the robot's rated payload (3 kg for the Panda);
4. ``com_too_far``: the centre of mass lies farther than ``max_com_radius_m`` from the flange;
5. ``controller_silent``: no joint state has arrived for the source's silence timeout;
6. ``ack_missing``: an earlier write was not acknowledged within ``ack_timeout_s``; writes stay
   stopped until an acknowledgement arrives, the controller returns from a silence, or,
   after ``ack_retry_s``, one retry;
7. ``unstable``: the estimate moved more than the stability band within ``stable_window_s``
   (hysteresis: it becomes stable when the spread is below the band and unstable again only
   when the spread exceeds twice the band);
8. ``no_change``: it differs from the last written load by less than the minimum change;
9. ``rate_limited``: the last write was less than ``1 / max_rate_hz`` s ago.

Otherwise the decision is ``send``. Every decision is counted by reason; it is logged when
its outcome or reason differs from the previous decision's (a steady state logs once), with
the estimate that caused it.
"""

from __future__ import annotations

import logging
import math
from collections import Counter, deque
from dataclasses import dataclass

import numpy as np

from sim.payload import Payload

log = logging.getLogger("iem.gate")

REASONS = ("send", "not_finite", "inconsistent", "over_rated", "com_too_far",
           "controller_silent", "ack_missing", "unstable", "no_change", "rate_limited")


@dataclass(frozen=True)
class GateConfig:
    """Safety-gate settings (units in the names).

    Attributes:
        rated_mass_kg: largest mass ever written (the robot's rated payload).
        max_com_radius_m: largest distance of the CoM from the flange origin.
        stable_window_s: how long the estimate must stay within the band to count as stable.
        stable_mass_kg, stable_com_m: the stability band (spread over the window) for the
            mass and for each CoM coordinate.
        min_change_mass_kg, min_change_com_m: the smallest change against the last written
            load that is worth a write (mass, or any CoM coordinate).
        max_rate_hz: at most this many writes per second.
        ack_timeout_s: an acknowledgement must arrive within this time after a write.
        ack_retry_s: after a missing acknowledgement, one retry is allowed after this time.
        decision_period_s: how often the gate decides.
    """

    rated_mass_kg: float = 3.0
    max_com_radius_m: float = 0.15
    stable_window_s: float = 0.5
    stable_mass_kg: float = 0.02
    stable_com_m: float = 0.004
    min_change_mass_kg: float = 0.01
    min_change_com_m: float = 0.002
    max_rate_hz: float = 1.0
    ack_timeout_s: float = 0.5
    ack_retry_s: float = 5.0
    decision_period_s: float = 0.05


@dataclass(frozen=True)
class Decision:
    """What the gate decided at time ``t`` (s, monotonic) and why."""

    t: float
    reason: str
    payload: Payload | None = None
    detail: str = ""

    @property
    def send(self) -> bool:
        return self.reason == "send"


class SafetyGate:
    """Decides which estimates reach the controller; counts and logs every decision."""

    def __init__(self, config: GateConfig | None = None) -> None:
        self.config = GateConfig() if config is None else config
        self.counts: Counter[str] = Counter()
        self._history: deque[tuple[float, np.ndarray]] = deque()
        self._stable = False
        self._last_decision_t = -math.inf
        self._last_reason = ""
        self._last_sent: Payload | None = None
        self._last_sent_t = -math.inf
        self._awaiting: tuple[int, float] | None = None  # (seq, sent at) without an ack yet
        self._ack_failed_t: float | None = None
        self._silent = False
        self.acked = 0
        self.sent = 0

    # -- inputs from the service ---------------------------------------------------------
    def controller_silent(self, silent: bool) -> None:
        self._silent = silent
        if not silent:
            # the controller is back: an ack missed during the silence is explained by it,
            # so a write may be tried again at once rather than after ack_retry_s
            self._awaiting = None
            self._ack_failed_t = None

    def sent_command(self, seq: int, t: float) -> None:
        """The service wrote the load of the last ``send`` decision as command ``seq``."""
        self._awaiting = (seq, t)
        self.sent += 1

    def acknowledged(self, seq: int) -> None:
        """The controller acknowledged command ``seq``."""
        if self._awaiting is not None and self._awaiting[0] == seq:
            self._awaiting = None
            self.acked += 1
        self._ack_failed_t = None

    @property
    def last_sent(self) -> Payload | None:
        return self._last_sent

    # -- the decision --------------------------------------------------------------------
    def due(self, t: float) -> bool:
        return t - self._last_decision_t >= self.config.decision_period_s

    def observe(self, t: float, phi: np.ndarray) -> None:
        """Add the smoothed estimate of one cycle to the stability window."""
        if np.all(np.isfinite(phi)):
            self._history.append((t, np.asarray(phi, dtype=float)[:4].copy()))
        while self._history and t - self._history[0][0] > self.config.stable_window_s:
            self._history.popleft()

    def decide(self, t: float, phi: np.ndarray) -> Decision:
        """Decide on the estimate ``phi`` (paper order) at time ``t``."""
        decision = self._decide(t, np.asarray(phi, dtype=float))
        self._last_decision_t = t
        self.counts[decision.reason] += 1
        if decision.reason != self._last_reason:
            level = logging.INFO if decision.send or decision.reason in (
                "not_finite", "inconsistent", "over_rated", "com_too_far", "controller_silent",
                "ack_missing") else logging.DEBUG
            log.log(level, "gate %s%s", decision.reason,
                    f": {decision.detail}" if decision.detail else "",
                    extra={"event": "gate", "reason": decision.reason,
                           "detail": decision.detail})
            self._last_reason = decision.reason
        if decision.send:
            self._last_sent = decision.payload
            self._last_sent_t = t
        return decision

    def _decide(self, t: float, phi: np.ndarray) -> Decision:
        c = self.config
        if phi.shape != (10,) or not np.all(np.isfinite(phi)):
            return Decision(t, "not_finite", detail="estimate has NaN or infinite values")
        if not phi[0] > 0.0:
            return Decision(t, "inconsistent", detail=f"mass {phi[0]:.4g} kg is not > 0")
        payload = Payload.from_phi(phi, name="estimate")
        problems = payload.consistency_violations()
        if problems:
            return Decision(t, "inconsistent", payload, "; ".join(problems))
        if payload.mass > c.rated_mass_kg:
            return Decision(t, "over_rated", payload,
                            f"mass {payload.mass:.3f} kg > rated {c.rated_mass_kg:g} kg")
        radius = math.sqrt(sum(v * v for v in payload.com))
        if radius > c.max_com_radius_m:
            return Decision(t, "com_too_far", payload,
                            f"CoM {radius:.3f} m from the flange > {c.max_com_radius_m:g} m")
        if self._silent:
            return Decision(t, "controller_silent", payload, "no joint state from the controller")
        if self._awaiting is not None:
            seq, at = self._awaiting
            if t - at > c.ack_timeout_s:
                self._awaiting = None
                self._ack_failed_t = t
                return Decision(t, "ack_missing", payload,
                                f"command {seq} not acknowledged within {c.ack_timeout_s:g} s")
            return Decision(t, "ack_missing", payload, f"waiting for the ack of command {seq}")
        if self._ack_failed_t is not None and t - self._ack_failed_t < c.ack_retry_s:
            return Decision(t, "ack_missing", payload,
                            f"acknowledgements stopped; retry in "
                            f"{c.ack_retry_s - (t - self._ack_failed_t):.1f} s")
        if not self._is_stable():
            return Decision(t, "unstable", payload, self._spread_text())
        if self._last_sent is not None and not self._changed(payload):
            return Decision(t, "no_change", payload)
        if t - self._last_sent_t < 1.0 / c.max_rate_hz:
            return Decision(t, "rate_limited", payload)
        return Decision(t, "send", payload,
                        f"mass {payload.mass:.4f} kg, CoM "
                        f"[{payload.com[0]:.4f}, {payload.com[1]:.4f}, {payload.com[2]:.4f}] m")

    # -- helpers -------------------------------------------------------------------------
    def _spread(self) -> tuple[float, float] | None:
        if not self._history:
            return None
        span = self._history[-1][0] - self._history[0][0]
        if span < 0.9 * self.config.stable_window_s:
            return None  # not watched for long enough yet
        values = np.array([v for _, v in self._history])
        mass = values[:, 0]
        com = values[:, 1:4] / mass[:, None]
        return float(np.ptp(mass)), float(np.ptp(com, axis=0).max())

    def _spread_text(self) -> str:
        spread = self._spread()
        if spread is None:
            return "estimate not yet watched for a whole stability window"
        return (f"spread over {self.config.stable_window_s:g} s: mass {spread[0]:.4f} kg, "
                f"CoM {spread[1]:.4f} m")

    def _is_stable(self) -> bool:
        c = self.config
        spread = self._spread()
        if spread is None:
            self._stable = False
            return False
        m, r = spread
        if self._stable:
            self._stable = m <= 2 * c.stable_mass_kg and r <= 2 * c.stable_com_m
        else:
            self._stable = m <= c.stable_mass_kg and r <= c.stable_com_m
        return self._stable

    def _changed(self, payload: Payload) -> bool:
        c, last = self.config, self._last_sent
        if abs(payload.mass - last.mass) >= c.min_change_mass_kg:
            return True
        return any(abs(a - b) >= c.min_change_com_m
                   for a, b in zip(payload.com, last.com, strict=True))

    def summary(self) -> dict:
        """Counts of every decision reason, and writes sent / acknowledged / rejected."""
        rejected = sum(v for k, v in self.counts.items()
                       if k in ("not_finite", "inconsistent", "over_rated", "com_too_far"))
        return {"decisions": dict(self.counts), "sent": self.sent, "acked": self.acked,
                "rejected": rejected}
