"""The load writer: the safety gate's decisions to the link's load command, the controller's
answers and reports back.

:meth:`LoadWriter.step` takes one block point's estimate: it tells the load in force
(:attr:`deploy.writeback.gate.SafetyGate.commands`) what the controller said since the last
point (its newest acknowledgement, and its own report of the load in force where the link
carries one: :attr:`firmware_bridge.links.PayloadSink.load_report`), steps the gate with the
smoothed and the raw estimate and the point's pose, and sends a load the gate lets through
with the link's ``send`` (libfranka ``setLoad`` semantics; None: the empty load). A send that
fails, for whatever reason the link gives (a load it cannot encode, a bus-off, a full
buffer), is counted and logged, and the gate retries it after a back-off: the service goes
on estimating. No thread of its own: the service's loop calls it.
"""

from __future__ import annotations

import logging

from firmware_bridge.links import PayloadSink

from .gate import Decision, SafetyGate

log = logging.getLogger("iem.service")


class LoadWriter:
    """Gate to sink.

    Args:
        gate: the safety gate.
        link: the open link: a :class:`~firmware_bridge.links.PayloadSink` where ``write``.
        write: send the loads the gate lets through (False: decide only, as a replay: a
            load the gate lets through is then taken as in force at once, as a controller
            that applies every command would, so the next decisions judge against it).

    A link that cannot write is refused where the service opens it
    (:func:`deploy.service.capabilities.check_sink`).
    """

    def __init__(self, gate: SafetyGate, link, write: bool) -> None:
        self.gate = gate
        self.sink: PayloadSink | None = link if write else None
        self._last_ack = None
        self._last_report = None
        self._offline = 0  # would-be commands of a writer that decides only

    def answers(self, t: float) -> None:
        """Tell the load in force the link's newest answer to a load command and its newest
        report of the load in force, if they are new (``t``: the gate's own time)."""
        if self.sink is None:
            return
        commands = self.gate.commands
        ack = self.sink.last_ack
        if ack is not None and ack is not self._last_ack:
            self._last_ack = ack
            if ack.applied:
                commands.acknowledged(ack.seq, t, ack.load, ack.t)
                log.info("controller acknowledged load command %d", ack.seq,
                         extra={"event": "load_acked", "seq": ack.seq})
            else:
                commands.refused_command(ack.seq, t, str(ack.error or ""))
        report = self.sink.load_report
        if report is not None and report is not self._last_report:
            self._last_report = report
            commands.report(report.seq, report.load, report.has_values, t, report.t)

    def step(self, t: float, smoothed, raw, state=None, busy: bool = False
             ) -> Decision | None:
        """One estimate at gate time ``t``: the controller's answers, the gate's step (with
        the point's joint ``state``; ``busy``: the model did heavy work in it), and the send
        of a load it lets through. Returns the gate's decision (None: none was due)."""
        self.answers(self.gate.clock(t))  # the load in force keeps the gate's own time
        decision = self.gate.step(t, smoothed, raw, state, busy)
        if decision is not None and decision.send:
            self.write(decision)
        return decision

    def write(self, decision: Decision) -> None:
        """Send the load of a ``send`` decision and tell the load in force (at the gate's
        own time)."""
        t, load, commands = self.gate.clock.now, decision.payload, self.gate.commands
        if self.sink is None:  # decide only (a replay): as if a controller applied it
            self._offline += 1
            commands.sent_command(self._offline, load, t)
            commands.acknowledged(self._offline, t)
            log.info("load would be sent (no controller to write to): %s", decision.detail,
                     extra={"event": "load_sent", "seq": self._offline, "written": False})
            return
        try:
            seq = self.sink.send(load)
        except Exception as exc:
            commands.send_failed(t, f"{type(exc).__name__}: {exc}")  # logged, retried
        else:
            commands.sent_command(seq, load, t)
            log.info("load sent (command %d): %s", seq, decision.detail,
                     extra={"event": "load_sent", "seq": seq})
