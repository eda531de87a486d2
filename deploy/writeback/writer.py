"""The load writer: the safety gate's decisions to the link's load command, the controller's
answers and reports back.

Once a block point is estimated, :meth:`LoadWriter.observe` hands the gate what the
controller said since the last point (its newest acknowledgement, and its own report of the
load in force where the link carries one: :attr:`firmware_bridge.links.PayloadSink.
load_report`), then the smoothed and the raw estimate and the point's pose; when a decision
is due, :meth:`LoadWriter.decide` asks the gate and sends a load it lets through with the
link's ``send`` (libfranka ``setLoad`` semantics; None: the empty load). A send that fails,
for whatever reason the link gives (a load it cannot encode, a bus-off, a full buffer), is
counted and logged, and the gate retries it after a back-off: the service goes on
estimating. No thread of its own: the service's loop calls it.
"""

from __future__ import annotations

import logging

from firmware_bridge.links import PayloadSink

from .gate import SafetyGate

log = logging.getLogger("iem.service")

GATE_DEFER = 3
"""Block points a due gate decision may wait for one in which the model did no heavy work
(the decision then does not land on top of a refresh or a projection)."""


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
        self._deferred = 0
        self._offline = 0  # would-be commands of a writer that decides only

    def acknowledgements(self, t: float) -> None:
        """Hand the gate the link's newest answer to a load command and its newest report of
        the load in force, if they are new."""
        if self.sink is None:
            return
        ack = self.sink.last_ack
        if ack is not None and ack is not self._last_ack:
            self._last_ack = ack
            if ack.applied:
                self.gate.acknowledged(ack.seq, t, ack.load, ack.t)
                log.info("controller acknowledged load command %d", ack.seq,
                         extra={"event": "load_acked", "seq": ack.seq})
            else:
                self.gate.refused(ack.seq, t, str(ack.error or ""))
        report = self.sink.load_report
        if report is not None and report is not self._last_report:
            self._last_report = report
            self.gate.controller_report(report, t)

    def observe(self, t: float, smoothed, raw, busy: bool = False, state=None) -> None:
        """One estimate at gate time ``t``: the controller's answers, the gate's observation
        (with the point's joint ``state``), then its decision if one is due (deferred up to
        :data:`GATE_DEFER` points while the model is ``busy``)."""
        self.acknowledgements(t)
        self.gate.observe(t, smoothed, raw, state)
        if not self.gate.due(t):
            return
        if busy and self._deferred < GATE_DEFER:
            self._deferred += 1
            return
        self._deferred = 0
        self.decide(t, smoothed)

    def decide(self, t: float, smoothed) -> None:
        """Ask the gate now and send what it lets through."""
        decision = self.gate.decide(t, smoothed)
        if not decision.send:
            return
        if self.sink is None:  # decide only (a replay): as if a controller applied it
            self._offline += 1
            self.gate.sent_command(self._offline, t)
            self.gate.acknowledged(self._offline, t)
            log.info("load would be sent (no controller to write to): %s", decision.detail,
                     extra={"event": "load_sent", "seq": self._offline, "written": False})
            return
        try:
            seq = self.sink.send(decision.payload)
        except Exception as exc:
            self.gate.send_failed(f"{type(exc).__name__}: {exc}", t)  # logged, retried
        else:
            self.gate.sent_command(seq, t)
            log.info("load sent (command %d): %s", seq, decision.detail,
                     extra={"event": "load_sent", "seq": seq})
