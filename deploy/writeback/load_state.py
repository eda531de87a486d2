"""The load in force: what the controller holds, as only the controller can confirm it.

A load command is a small state machine (the house style's, after TCP's retransmission):

- **sent**: the link took the command (:meth:`LoadInForce.sent`); it is *pending* until
- **acked**: the controller acknowledged it as applied: its load is now **in force**; or
- **refused**: the controller answered but did not apply it (a Franka refuses ``setLoad``
  while a controller runs): the load in force stays as it was, the gate retries after a
  back-off (``refusal_retry_s``, doubling up to ``refusal_retry_max_s``); or
- **lost**: no answer within ``ack_timeout_s``: the load in force stays as it was, and the
  write is retried after a back-off (``ack_retry_s``, doubling up to ``ack_retry_max_s``).

Answers are read by sequence number only: an acknowledgement of the newest command sent (the
one pending, or the last one lost if none was sent since: a late ack) settles it; an answer
to any other command, or a second answer to the same one, is counted (``ignored_answers``) and
changes nothing.

Where the link reports what the controller holds (:class:`firmware_bridge.messages.LoadReport`:
the CAN heartbeat's ``LoadSeq``, libfranka's ``m_load``/``F_x_Cload``/``I_load``), the report
is the truth: a command it names is in force even if its acknowledgement was lost, and a
report that disagrees with what this plug-in believes is in force is logged as a mismatch and
makes the believed load the reported one (or unknown), so the gate writes again. A report
that contradicts a load this plug-in wrote and the controller confirmed is a disagreement:
the next write waits a back-off as after a refusal (``refusal_retry_s`` doubling up to
``refusal_retry_max_s``), and after ``max_disagreements`` of them in a row the gate gives up
(``controller_disagrees``) until the controller reports another load. Before the controller has said
anything the load in force is the empty load, the state a controller starts in (libfranka's
``setLoad`` with mass 0); a report, where the link has one, replaces that assumption.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

from iem.payload import Payload, set_load_values

log = logging.getLogger("iem.gate")

UNKNOWN = "unknown"
"""The load in force when a report contradicts what was written and names no values."""

HISTORY = 64
"""Commands remembered by sequence number, to read a report that names only the sequence."""

MASS_TOL_KG = 1e-4
COM_TOL_M = 1e-4
INERTIA_TOL_KGM2 = 1e-6
"""How closely a controller's report of a load's values must match the written load (its
own rounding: the CAN wire's resolution is 1 g and 0.1 mm, libfranka's doubles are exact)."""


@dataclass
class Pending:
    """A command sent and not yet answered."""

    seq: int
    load: Payload | None
    t: float


def same_load(a: Payload | None, b: Payload | None) -> bool:
    """Two loads equal to the controller's rounding: mass, CoM and inertia (None: the empty
    load; a zero mass is empty too). The one test of whether a controller's report names a
    load, for the gate and for ``iem set-load``."""
    a = None if a is None or a.mass <= MASS_TOL_KG else a
    b = None if b is None or b.mass <= MASS_TOL_KG else b
    if a is None or b is None:
        return a is None and b is None
    return abs(a.mass - b.mass) <= MASS_TOL_KG and all(
        abs(x - y) <= COM_TOL_M for x, y in zip(a.com, b.com, strict=True)) and all(
        abs(x - y) <= INERTIA_TOL_KGM2 for x, y in zip(a.inertia, b.inertia, strict=True))


def describe(load) -> str:
    """A load in words for a log line."""
    if load is None:
        return "the empty load"
    if load == UNKNOWN:
        return "an unknown load"
    return (f"{load.mass:.4f} kg at [{load.com[0]:.4f}, {load.com[1]:.4f}, "
            f"{load.com[2]:.4f}] m")


class LoadInForce:
    """What the controller holds and what became of each command.

    Args:
        ack_timeout_s: a command unanswered this long is lost.
        ack_retry_s, ack_retry_max_s: the wait before the write after a lost command, doubled
            after each further loss in a row, up to the maximum.
        refusal_retry_s, refusal_retry_max_s: the same after a refusal.
    """

    def __init__(self, ack_timeout_s: float = 0.5, ack_retry_s: float = 0.5,
                 ack_retry_max_s: float = 10.0, refusal_retry_s: float = 1.0,
                 refusal_retry_max_s: float = 10.0, max_disagreements: int = 5) -> None:
        self.ack_timeout_s = ack_timeout_s
        self.ack_retry = (ack_retry_s, ack_retry_max_s)
        self.refusal_retry = (refusal_retry_s, refusal_retry_max_s)
        self.max_disagreements = max_disagreements
        self.load: Payload | str | None = None
        """The load in force: a :class:`Payload`, None (the empty load) or :data:`UNKNOWN`."""
        self.confirmed = False
        """The controller itself said so (an ack or a report), not the start-up assumption."""
        self.pending: Pending | None = None
        self.seq_in_force = 0
        self._by_seq: dict[int, Payload | None] = {}
        self._backoff: tuple[str, float, float, str] | None = None  # why, since, wait, detail
        self._in_row = {"lost": 0, "refused": 0, "controller_disagrees": 0}
        self._answered = -math.inf  # when the link took the newest acknowledgement
        self._newest_sent: int | None = None  # the newest command's sequence number
        self._refused_seq: int | None = None  # the newest command the controller refused
        self._settled: int | None = None  # the newest command acknowledged or reported
        self._ours = False  # the load in force is one of our commands, confirmed
        self.gave_up: str | None = None
        """What the controller reported when the gate gave up writing against it (None:
        it has not given up)."""
        self.sent = 0
        self.acked = 0
        self.lost = 0
        self.refused = 0
        self.in_force = 0
        """Commands the controller confirmed in force (by its acknowledgement or report)."""
        self.mismatches = 0
        self.disagreements = 0
        """Mismatches against a load this plug-in wrote and the controller had confirmed."""
        self.send_errors = 0
        self.ignored_answers = 0
        """Answers to a command that is not the newest sent, or repeated answers."""

    # -- events ---------------------------------------------------------------------------
    def sent_command(self, seq: int, load: Payload | None, t: float) -> None:
        """The link took command ``seq`` writing ``load`` at time ``t``."""
        self.pending = Pending(int(seq), load, t)
        self._newest_sent = int(seq)
        self._by_seq[int(seq)] = load
        if len(self._by_seq) > HISTORY:
            del self._by_seq[next(iter(self._by_seq))]
        self.sent += 1

    def send_failed(self, t: float, error: str) -> None:
        """The link could not send: as a lost command (back-off, retry), counted apart and
        logged."""
        self.send_errors += 1
        self._start_backoff("lost", t, f"the link could not send the load: {error}")
        log.error("load not written, the link cannot send it: %s", error,
                  extra={"event": "load_send_failed", "error": error})

    def acknowledged(self, seq: int, t: float, load=None, received: float = -math.inf) -> None:
        """The controller applied command ``seq`` (``load``: the load its ack reports, if
        any; ``received``: when the link took the ack, on the links' clock, so that a report
        taken before it is not read as newer). Only an ack of the newest command sent
        counts, once; any other is counted in ``ignored_answers`` and changes nothing."""
        if not self._answers_newest(seq):
            return
        self.acked += 1
        self._answered = max(self._answered, received)
        self._settle(seq, self._by_seq.get(seq, load) if load is None else load, t)

    def refused_command(self, seq: int, t: float, error: str = "") -> None:
        """The controller answered ``seq`` but kept its load (``error``: why); logged. Only a
        refusal of the pending command counts; any other is counted in ``ignored_answers``."""
        ours = self.pending is not None and self.pending.seq == seq
        if not ours:
            self.ignored_answers += 1
        else:
            self.refused += 1
            self.pending = None
            self._refused_seq = int(seq)
            self._start_backoff("refused", t, f"the controller refused command {seq}"
                                              f"{f' ({error})' if error else ''}")
        wait = self.retry_wait() if ours else None
        log.warning("controller refused load command %d%s%s", seq,
                    f": {error}" if error else " (no reason given)",
                    "" if wait is None else f"; retry in {wait:.1f} s",
                    extra={"event": "load_refused", "seq": seq, "error": error,
                           "ours": ours})

    def report(self, seq: int | None, load, has_values: bool, t: float,
               received: float = math.inf) -> None:
        """The controller's own report of what it holds: the command in force ``seq`` (None:
        the link carries none) and, if ``has_values``, the load's values (None: empty);
        ``received``: when the link took it. A report taken before the last acknowledgement
        (a heartbeat that was on its way) says nothing newer and is passed over."""
        if received < self._answered:
            return
        if self.gave_up is not None:
            what = describe(load) if has_values else f"command {seq}"
            if has_values or seq is not None:
                if what == self.gave_up:
                    return  # it still holds what it held when the gate gave up
                self.gave_up = None  # it holds something else now: writes may try again
                self._in_row["controller_disagrees"] = 0
        if has_values:
            if self.pending is not None and same_load(load, self.pending.load):
                self._settle(self.pending.seq, self.pending.load, t)
            elif self.load == UNKNOWN or not same_load(load, self.load):
                if self.confirmed or self.load is not None:
                    self._mismatch(describe(load), t)
                self.load, self.confirmed, self._ours = load, True, False
            else:
                self.confirmed = True
                if self._ours:
                    self._in_row["controller_disagrees"] = 0  # it holds what we wrote
            return
        if seq is None:
            return
        if self.pending is not None and seq == self.pending.seq:
            self._settle(seq, self.pending.load, t)  # applied; only its ack was lost
            return
        if seq == self.seq_in_force:
            self.confirmed = True
            if self._ours:
                self._in_row["controller_disagrees"] = 0
            return
        if seq == 0 and self.seq_in_force == 0:
            self.confirmed = self.load is None or self.confirmed
            return
        self._mismatch(f"command {seq}", t)
        self.seq_in_force = seq
        self.load = self._by_seq.get(seq, UNKNOWN) if seq else UNKNOWN
        self._ours = False

    def tick(self, t: float) -> None:
        """A pending command unanswered for ``ack_timeout_s`` is lost."""
        p = self.pending
        if p is not None and t - p.t > self.ack_timeout_s:
            self.pending = None
            self.lost += 1
            self._start_backoff("lost", t, f"command {p.seq} not acknowledged within "
                                           f"{self.ack_timeout_s:g} s")
            log.warning("load command %d lost (no answer within %g s); %s stays in force, "
                        "retry in %.1f s", p.seq, self.ack_timeout_s, describe(self.load),
                        self._backoff[2], extra={"event": "load_lost", "seq": p.seq})

    def controller_back(self) -> None:
        """The controller returned from a silence: a loss then is explained by it, so the
        write may be tried again at once."""
        if self._backoff is not None and self._backoff[0] == "lost":
            self._backoff = None
            self._in_row["lost"] = 0

    # -- questions ------------------------------------------------------------------------
    def hold(self, t: float) -> tuple[str, str] | None:
        """``(reason, detail)`` while no command may be sent now: one is pending
        (``ack_missing``), a back-off after a loss (``lost``), a refusal (``refused``) or a
        disagreeing report (``controller_disagrees``) runs, or the gate gave up after
        ``max_disagreements`` of them (``controller_disagrees``); None when a command may
        go."""
        if self.gave_up is not None:
            return ("controller_disagrees", f"gave up after {self.max_disagreements} writes "
                    f"the controller's reports contradicted; it holds {self.gave_up}")
        if self.pending is not None:
            return "ack_missing", f"waiting for the ack of command {self.pending.seq}"
        if self._backoff is not None:
            why, since, wait, detail = self._backoff
            left = wait - (t - since)
            if left > 0:
                return why, f"{detail}; retry in {left:.1f} s"
        return None

    @property
    def newest_refused(self) -> bool:
        """Whether the controller refused the newest command sent (it kept its load: the
        command changed nothing)."""
        return self._newest_sent is not None and self._refused_seq == self._newest_sent

    def retry_wait(self) -> float | None:
        """The wait of the back-off running now, s (None: none runs)."""
        return None if self._backoff is None else self._backoff[2]

    def summary(self) -> dict:
        """The counts, and the load in force."""
        return {"sent": self.sent, "acked": self.acked, "lost": self.lost,
                "in_force": self.in_force, "refused": self.refused,
                "mismatches": self.mismatches, "disagreements": self.disagreements,
                "gave_up": self.gave_up is not None, "send_errors": self.send_errors,
                "ignored_answers": self.ignored_answers,
                "load_in_force": load_record(self.load),
                "in_force_confirmed": self.confirmed}

    # -- helpers ---------------------------------------------------------------------------
    def _answers_newest(self, seq: int) -> bool:
        """Whether an answer to ``seq`` is one to read: the newest command sent, not yet
        settled; else it is counted and ignored."""
        if seq == self._newest_sent and seq != self._settled:
            return True
        self.ignored_answers += 1
        log.debug("answer to load command %s ignored: the newest sent is %s, settled %s",
                  seq, self._newest_sent, self._settled)
        return False

    def _settle(self, seq: int, load, t: float) -> None:
        if self.pending is not None and self.pending.seq == seq:
            self.pending = None
        self.load, self.confirmed, self.seq_in_force = load, True, seq
        self._settled, self._ours = seq, True
        self.in_force += 1
        self._backoff = None
        self._in_row["lost"] = self._in_row["refused"] = 0

    def _mismatch(self, what: str, t: float) -> None:
        self.mismatches += 1
        if not self._ours:  # not a load we wrote: nothing to disagree with
            log.warning("the controller reports %s in force; this plug-in believed %s: it "
                        "will be written again", what, describe(self.load),
                        extra={"event": "load_mismatch"})
            return
        self.disagreements += 1
        if self._in_row["controller_disagrees"] + 1 >= self.max_disagreements:
            self.gave_up = what
            self._backoff = None
            log.error("the controller reports %s in force; this plug-in wrote %s, %d times "
                      "in a row contradicted: it gives up writing until the controller holds "
                      "another load", what, describe(self.load), self.max_disagreements,
                      extra={"event": "load_disagreement", "gave_up": True})
            return
        self._start_backoff("controller_disagrees", t, f"the controller reports {what} in "
                                                       f"force, not {describe(self.load)}")
        log.warning("the controller reports %s in force; this plug-in believed %s, which it "
                    "wrote: it will be written again in %.1f s", what, describe(self.load),
                    self._backoff[2],
                    extra={"event": "load_mismatch"})

    def _start_backoff(self, why: str, t: float, detail: str) -> None:
        first, most = self.ack_retry if why == "lost" else self.refusal_retry
        n = self._in_row[why]
        self._in_row[why] = n + 1
        self._backoff = (why, t, min(first * 2.0 ** min(n, 60), most), detail)


def load_record(load) -> dict | str | None:
    """A load for JSON: None (empty), ``"unknown"``, or mass, CoM and inertia (9 values about
    the CoM, column-major, as ``setLoad`` takes them)."""
    if load is None or load == UNKNOWN:
        return load
    mass, com, inertia = set_load_values(load)
    return {"mass": mass, "com": com, "inertia": inertia}

