"""The safety gate between the estimator and the controller's ``setLoad``.

Every ``decision_period_s`` (default 50 ms) the gate looks at the smoothed estimate (and the
raw estimate it came from, for its uncertainty) and decides whether to write it to the
controller. In order, an estimate is refused if:

1. ``not_finite``: any parameter is NaN or infinite;
2. ``inconsistent``: it is not a physically possible rigid body (mass > 0, inertia about the
   CoM positive definite, triangle inequality);
3. ``over_rated``: the mass exceeds the robot's rated payload (3 kg for the Panda);
4. ``com_too_far``: the centre of mass lies farther than ``max_com_radius_m`` from the flange;
5. ``out_of_wire_range``: the link's wire format cannot carry a value (the link's range check,
   e.g. an inertia beyond the CAN signal's range; links without one have no such check);
6. ``controller_silent``: no joint state has arrived for the source's silence timeout;
7. ``ack_missing``: an earlier write was not acknowledged within ``ack_timeout_s``; writes stay
   stopped until an acknowledgement arrives, the controller returns from a silence, or,
   after ``ack_retry_s``, one retry;
8. ``refused``: the controller refused the last write (a Franka does while a controller
   runs); the refused load is not the written one, and the gate retries after
   ``refusal_retry_s``, doubling the wait after each further refusal up to
   ``refusal_retry_max_s``, until the controller accepts;
9. ``unreported``: the estimate does not say how good it is: it reports no standard
   deviations (``std``), no verdict of its data (``nis``) or no out-of-distribution verdict
   (``ood``), typed fields of :class:`iem.types.PayloadEstimate`. The gate fails closed:
   only ``allow_without_uncertainty`` (default false; the paper's IEM, which has no
   uncertainty, needs it) lets such an estimate through, its reported parts still checked;
10. ``out_of_distribution``: the IEM alone estimated from an input far beyond its bag's
    training inputs (``ood``); ``unverified``: the estimate started from a payload file
    (``[estimate] initial_payload``) and the model has not yet tested it against enough live
    data; ``uncertain``: the 2-sigma band on the mass, ``2 * std[0]``, is wider than
    ``max_mass_2sigma_kg``, or the 2-sigma radius of the CoM (its standard deviations
    through ``r = (m r) / m``) is wider than ``max_com_2sigma_m``; ``data_disagree``:
    ``nis`` (the mean normalised innovation squared per degree of freedom over the model's
    recent equations, about 1 when the data agree with the model) exceeds ``max_nis``;
11. ``unstable``: the estimate moved more than the stability band within ``stable_window_s``
    (hysteresis: it becomes stable when the spread is below the band and unstable again only
    when the spread exceeds twice the band);
12. ``no_change``: it differs from the last written load by less than the minimum change;
13. ``rate_limited``: the last write was less than ``1 / max_rate_hz`` s ago.

Otherwise the decision is ``send``, whose log line names the groups the model's data do not
determine (written as its prior has them; they never hold a write back). Checks 1-5, 9 and
10 look at one estimate alone and live in
:mod:`deploy.gate_checks`; this module keeps what depends on time and on the controller.
Every decision is counted by reason; it is logged when its outcome or reason differs from
the previous decision's (a steady state logs once), with the estimate that caused it.
Refusals by the controller and loads the link could not encode are counted (``refusals``,
``send_errors``) and logged each time.
"""

from __future__ import annotations

import logging
import math
from collections import Counter, deque
from dataclasses import dataclass

import numpy as np

from iem.payload import Payload

from .gate_checks import WireCheck, check_estimate, model_doubt
from .time_window import TimeWindow

log = logging.getLogger("iem.gate")

REASONS = ("send", "not_finite", "inconsistent", "over_rated", "com_too_far",
           "out_of_wire_range", "controller_silent", "ack_missing", "refused", "unreported",
           "uncertain",
           "data_disagree", "unverified", "out_of_distribution", "unstable", "no_change",
           "rate_limited")
REJECTIONS = ("not_finite", "inconsistent", "over_rated", "com_too_far", "out_of_wire_range")
"""Reasons that say the estimate itself can never be written (counted in ``rejected``)."""


def _mass_and_com(rows: np.ndarray) -> np.ndarray:
    """``[m, m c]`` rows -> ``[m, c]`` rows."""
    out = np.empty_like(rows)
    out[:, 0] = rows[:, 0]
    np.divide(rows[:, 1:4], rows[:, :1], out=out[:, 1:4])
    return out


SENT_LOADS_KEPT = 10_000
"""``send`` decisions :attr:`SafetyGate.sent_loads` keeps (a write a second: almost 3 h)."""
_QUIET = ("unstable", "uncertain", "no_change", "rate_limited")
"""Reasons that are a normal part of converging: logged at DEBUG, the others at INFO."""

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
        max_mass_2sigma_kg: no write while the model's 2-sigma band on the mass
            (``2 * std[0]``, kg) is wider than this.
        max_com_2sigma_m: no write while the model's 2-sigma radius of the CoM (m) is wider
            than this: by default issue 10's 5 mm, the error a written load may have.
        max_nis: no write while the model's ``nis`` (mean normalised innovation squared per
            degree of freedom, dimensionless, about 1 when the data agree with the model)
            exceeds this.
        allow_without_uncertainty: write estimates that do not report ``std``, ``nis`` or
            ``ood`` (the paper's IEM); by default they are held back (``unreported``).
        refusal_retry_s: after the controller refuses a write, retry after this time (s);
            the wait doubles with each further refusal in a row ...
        refusal_retry_max_s: ... up to this (s).
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
    max_mass_2sigma_kg: float = 0.02
    max_com_2sigma_m: float = 0.005
    max_nis: float = 3.0
    allow_without_uncertainty: bool = False
    refusal_retry_s: float = 1.0
    refusal_retry_max_s: float = 10.0


@dataclass(frozen=True)
class Decision:
    """What the gate decided at time ``t`` (s, monotonic) and why."""

    t: float
    reason: str
    payload: Payload | None = None
    detail: str = ""
    from_prior: tuple = ()
    """Of a ``send``: the groups the model's data do not determine (not in its ``determined``),
    written as its prior has them."""

    @property
    def send(self) -> bool:
        return self.reason == "send"


class SafetyGate:
    """Decides which estimates reach the controller; counts and logs every decision.

    Args:
        config: the settings (default :class:`GateConfig`).
        wire_check: the link's range check of a load (``payload -> message or None``), e.g.
            ``functools.partial(firmware_bridge.protocol.payload_wire_error, profile="fd")``;
            None for a link whose wire has no ranges to check.
    """

    def __init__(self, config: GateConfig | None = None,
                 wire_check: WireCheck | None = None) -> None:
        self.config = GateConfig() if config is None else config
        self.wire_check = wire_check
        self.counts: Counter[str] = Counter()
        self._history = TimeWindow(self.config.stable_window_s, 4)  # m, m·c per cycle
        self._stable = False
        self._estimate = None  # the raw estimate last observed (its std and extra)
        self._last_decision_t = -math.inf
        self._last_reason = ""
        self._last_sent: Payload | None = None
        self._last_sent_t = -math.inf
        self._before_send: tuple[Payload | None, float] = (None, -math.inf)
        self._command: tuple[int, Payload | None, float] | None = None  # seq, load before it
        self._awaiting: tuple[int, float] | None = None  # (seq, sent at) without an ack yet
        self._ack_failed_t: float | None = None
        self._refusal: tuple[int, float, str] | None = None  # (seq, at, error) to retry after
        self._refusals_in_row = 0
        self._silent = False
        self.acked = 0
        self.sent = 0
        self.refusals = 0
        self.send_errors = 0
        self.sent_loads: deque[tuple[float, Payload, tuple]] = deque(maxlen=SENT_LOADS_KEPT)
        """The latest ``send`` decisions: ``(t, load, groups from the prior)``."""

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
        self._command = (seq, *self._before_send)
        self.sent += 1

    def acknowledged(self, seq: int) -> None:
        """The controller acknowledged (applied) command ``seq``."""
        if self._awaiting is not None and self._awaiting[0] == seq:
            self._awaiting = None
            self.acked += 1
        self._ack_failed_t = None
        if self._command is not None and self._command[0] == seq:
            self._command = None  # its load is the written one: no retry pending
            self._refusal = None
            self._refusals_in_row = 0

    def refused(self, seq: int, t: float, error: str = "") -> None:
        """The controller answered command ``seq`` but did not apply it (``error``: its
        reason, if it gave one). Counted and logged; the load before it stays the written
        one, and the gate retries after ``refusal_retry_s`` (doubling up to
        ``refusal_retry_max_s`` while refusals go on)."""
        self.refusals += 1
        if self._awaiting is not None and self._awaiting[0] == seq:
            self._awaiting = None
        self._ack_failed_t = None  # the controller answers: not an ack problem
        ours = self._command is not None and self._command[0] == seq
        if ours:
            _, self._last_sent, self._last_sent_t = self._command
            self._command = None
            self._refusals_in_row += 1
            self._refusal = (seq, t, error)
        log.warning("controller refused load command %d%s%s", seq,
                    f": {error}" if error else " (no reason given)",
                    f"; retry in {self._retry_wait():.1f} s" if ours else "",
                    extra={"event": "load_refused", "seq": seq, "error": error,
                           "refusals_in_row": self._refusals_in_row})

    def send_failed(self, error: str) -> None:
        """The link could not write the load of the last ``send`` decision (``error``, e.g.
        an ``EncodeError``): counted and logged; the load before it stays the written one."""
        self.send_errors += 1
        self._last_sent = self._before_send[0]
        log.error("load not written, the link cannot send it: %s", error,
                  extra={"event": "load_send_failed", "error": error})

    @property
    def last_sent(self) -> Payload | None:
        """The last load written (sent and not refused), or None."""
        return self._last_sent

    # -- the decision --------------------------------------------------------------------
    def due(self, t: float) -> bool:
        return t - self._last_decision_t >= self.config.decision_period_s

    def observe(self, t: float, phi: np.ndarray, estimate=None) -> None:
        """Add the smoothed estimate ``phi`` of one cycle to the stability window;
        ``estimate`` is the raw :class:`iem.types.PayloadEstimate` it came from (its ``std``
        and ``nis`` are checked by :meth:`decide`)."""
        if estimate is not None:
            self._estimate = estimate
        if np.isfinite(phi).all():  # copied into the window's ring
            self._history.push(t, phi[:4])
        else:
            self._history.expire(t)

    def decide(self, t: float, phi: np.ndarray, estimate=None) -> Decision:
        """Decide on the estimate ``phi`` (paper order) at time ``t``; ``estimate`` is the
        raw estimate (default: the one last given to :meth:`observe`)."""
        if estimate is None:
            estimate = self._estimate
        decision = self._decide(t, np.asarray(phi, dtype=float), estimate)
        self._last_decision_t = t
        self.counts[decision.reason] += 1
        if decision.reason != self._last_reason:
            level = logging.DEBUG if decision.reason in _QUIET else logging.INFO
            log.log(level, "gate %s%s", decision.reason,
                    f": {decision.detail}" if decision.detail else "",
                    extra={"event": "gate", "reason": decision.reason,
                           "detail": decision.detail})
            self._last_reason = decision.reason
        if decision.send:
            self.sent_loads.append((t, decision.payload, decision.from_prior))
            self._before_send = (self._last_sent, self._last_sent_t)
            self._last_sent = decision.payload
            self._last_sent_t = t
        return decision

    def _decide(self, t: float, phi: np.ndarray, estimate) -> Decision:
        c = self.config
        payload, reason, detail = check_estimate(phi, c, self.wire_check)
        if reason:
            return Decision(t, reason, payload, detail)
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
        if self._refusal is not None:
            seq, at, error = self._refusal
            left = self._retry_wait() - (t - at)
            if left > 0:
                return Decision(t, "refused", payload,
                                f"the controller refused command {seq}"
                                f"{f' ({error})' if error else ''}; retry in {left:.1f} s")
        doubt = model_doubt(estimate, c)
        if doubt is not None:
            return Decision(t, doubt[0], payload, doubt[1])
        if not self._is_stable():
            return Decision(t, "unstable", payload, self._spread_text())
        if self._last_sent is not None and not self._changed(payload):
            return Decision(t, "no_change", payload)
        if t - self._last_sent_t < 1.0 / c.max_rate_hz:
            return Decision(t, "rate_limited", payload)
        determined = getattr(estimate, "determined", None)
        prior = () if determined is None else tuple(g for g in ("mass", "com", "inertia")
                                                    if g not in determined)
        note = f"; {' and '.join(prior)} from the prior (the motion does not determine " \
               f"{'it' if len(prior) == 1 else 'them'})" if prior else ""
        return Decision(t, "send", payload,
                        f"mass {payload.mass:.4f} kg, CoM "
                        f"[{payload.com[0]:.4f}, {payload.com[1]:.4f}, {payload.com[2]:.4f}] m"
                        + note, from_prior=prior)

    # -- helpers -------------------------------------------------------------------------
    def _retry_wait(self) -> float:
        """The wait before the next write after ``_refusals_in_row`` refusals in a row."""
        c = self.config
        n = max(self._refusals_in_row - 1, 0)
        return min(c.refusal_retry_s * 2.0 ** min(n, 60), c.refusal_retry_max_s)

    def _spread(self) -> tuple[float, float] | None:
        window = self._history
        if not window.n:
            return None
        if window.last_t - window.first_t < 0.9 * self.config.stable_window_s:
            return None  # not watched for long enough yet
        ptp = window.ptp(_mass_and_com)
        return float(ptp[0]), float(ptp[1:].max())

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
        rejected = sum(v for k, v in self.counts.items() if k in REJECTIONS)
        return {"decisions": dict(self.counts), "sent": self.sent, "acked": self.acked,
                "rejected": rejected}
