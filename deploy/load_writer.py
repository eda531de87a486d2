"""The load writer: the safety gate's decisions to the link's load command, acknowledgements
back.

Once a block point is estimated, :meth:`LoadWriter.observe` gives the gate the smoothed and
the raw estimate (and any acknowledgement the link has received since); when a decision is
due, :meth:`LoadWriter.decide` asks the gate and sends a load it lets through with the link's
``send`` (libfranka ``setLoad`` semantics). A load the link still cannot encode
(``EncodeError``: the gate's wire check should have caught it) is counted and logged, never
fatal. An applied acknowledgement goes to the gate's ``acknowledged``, a refusal
(``applied=False``, with the controller's ``error`` text where the link has one) to its
``refused``, which retries later. No thread of its own: the service's loop calls it.
"""

from __future__ import annotations

import logging

from .gate import SafetyGate

log = logging.getLogger("iem.service")

GATE_DEFER = 3
"""Block points a due gate decision may wait for one in which the model did no heavy work
(the decision then does not land on top of a refresh or a projection)."""


class LoadWriter:
    """Gate to sink.

    Args:
        gate: the safety gate.
        link: the open link (its ``send`` and ``last_ack``).
        write: send the loads the gate lets through (False: decide only, as a replay).
    """

    def __init__(self, gate: SafetyGate, link, write: bool) -> None:
        self.gate = gate
        # a link that can take a load (a replay's source cannot): it sends and answers
        self.sink = link if write and hasattr(link, "send") else None
        self._last_ack = None
        self._deferred = 0

    def acknowledgements(self, t: float) -> None:
        """Hand the gate the link's newest answer to a load command, if it is new."""
        ack = None if self.sink is None else self.sink.last_ack
        if ack is None or ack is self._last_ack:
            return
        self._last_ack = ack
        if ack.applied:
            self.gate.acknowledged(ack.seq)
            log.info("controller acknowledged load command %d", ack.seq,
                     extra={"event": "load_acked", "seq": ack.seq})
        else:
            self.gate.refused(ack.seq, t, str(getattr(ack, "error", "") or ""))

    def observe(self, t: float, smoothed, raw, busy: bool = False) -> None:
        """One estimate at gate time ``t``: acknowledgements, the gate's observation, then
        its decision if one is due (deferred up to :data:`GATE_DEFER` points while the model
        is ``busy``)."""
        self.acknowledgements(t)
        self.gate.observe(t, smoothed, raw)
        if not self.gate.due(t):
            return
        if busy and self._deferred < GATE_DEFER:
            self._deferred += 1
            return
        self._deferred = 0
        self.decide(t, smoothed)

    def decide(self, t: float, smoothed) -> None:
        """Ask the gate now and send what it lets through."""
        from firmware_bridge.errors import EncodeError

        decision = self.gate.decide(t, smoothed)
        if not decision.send or self.sink is None:
            return
        try:
            seq = self.sink.send(decision.payload)
        except EncodeError as exc:  # the gate's wire check should have caught it:
            self.gate.send_failed(str(exc))  # counted, logged, go on
        else:
            self.gate.sent_command(seq, t)
            log.info("load sent (command %d): %s", seq, decision.detail,
                     extra={"event": "load_sent", "seq": seq})
