"""What every framed link shares (CAN, serial): the plug-in's end and the controller's end.

:class:`FramedLink` is the plug-in's :class:`~firmware_bridge.links.JointStateSource` and
:class:`~firmware_bridge.links.PayloadSink` over a byte or frame transport. It owns the
buffer of complete cycles, ``read`` with its silence rule, ``send`` with its sequence
numbers, ``wait_ack`` (cycles read meanwhile are kept for ``read``) and ``close``. A backend
implements only its hooks:

- ``_receive(timeout)``: take what the transport delivers within ``timeout`` s (at most), feed
  it to the decoder and hand each completed cycle to ``_deliver(state, receive_time)``;
- ``_transmit(seq, payload)``: put one payload command on the wire;
- ``_shutdown()``: release the transport;
- ``decoder``: an object with ``counters``, ``acks``, ``last_ack``, ``last_heartbeat``,
  ``resync()`` and ``diagnosis()``; ``load_report`` comes from ``last_heartbeat``.

:class:`FramedControllerPort` is the controller's end (used by the simulated controller): the
fault injector (drop, corrupt, duplicate, delay, silence) and the send counters; a backend
implements ``_emit(key, data)`` (put one frame on the wire now), ``publish``, ``heartbeat``,
``send_ack``, ``poll_commands`` and ``_shutdown``.
"""

from __future__ import annotations

import time
from collections import deque

from iem.types import JointState

from .errors import AckTimeout, ControllerSilent
from .faults import MAX_EVENTS, FaultInjector, FaultSpec
from .links import BUFFERED_CYCLES, LinkCounters
from .messages import Heartbeat, LoadAck, LoadReport

ACK_POLL_S = 0.01
"""Longest single wait of ``wait_ack`` on the transport, s."""


class FramedLink:
    """Base of the plug-in's framed links (see the module docstring for the hooks).

    Args:
        name: how the link names itself in messages.
        rate_hz: joint states per second the link delivers.
        silence_timeout: default ``read`` timeout, s.
    """

    decoder: object

    def __init__(self, *, name: str, rate_hz: float, silence_timeout: float = 0.1) -> None:
        self.name = name
        self.rate_hz = float(rate_hz)
        self.silence_timeout = float(silence_timeout)
        self.counters: LinkCounters = self.decoder.counters
        self._ready: deque[tuple[JointState, float]] = deque()
        self.last_frame_time = 0.0
        """Receive time (epoch s) of the frame that completed the cycle ``read`` returned
        last: where frame-to-estimate latency starts."""
        self._seq = 0
        self._closed = False
        self._report_of: Heartbeat | None = None
        self._report: LoadReport | None = None

    # -- hooks -----------------------------------------------------------------------------
    def _receive(self, timeout: float) -> None:  # pragma: no cover - every backend has one
        raise NotImplementedError

    def _transmit(self, seq: int, payload) -> None:  # pragma: no cover
        raise NotImplementedError

    def _shutdown(self) -> None:  # pragma: no cover
        raise NotImplementedError

    def _deliver(self, state: JointState, receive_time: float) -> None:
        """Keep a completed cycle for ``read`` (the oldest goes when the buffer is full)."""
        if len(self._ready) >= BUFFERED_CYCLES:
            self._ready.popleft()
            self.counters.overflow += 1
        self._ready.append((state, receive_time))

    # -- source ----------------------------------------------------------------------------
    @property
    def last_heartbeat(self) -> Heartbeat | None:
        return self.decoder.last_heartbeat

    def read(self, timeout: float | None = None) -> JointState:
        """The next complete cycle; ``ControllerSilent`` after ``timeout`` s without one."""
        ready = self._ready
        if not ready:
            timeout = self.silence_timeout if timeout is None else float(timeout)
            deadline = time.perf_counter() + timeout
            while not ready:
                remaining = deadline - time.perf_counter()
                if remaining <= 0:
                    self.counters.silences += 1
                    self.decoder.resync()
                    raise ControllerSilent(f"{self.name}: no complete joint state for "
                                           f"{timeout * 1e3:.0f} ms; {self.decoder.diagnosis()}")
                self._receive(remaining)
        state, self.last_frame_time = ready.popleft()
        return state

    def __iter__(self):
        while True:
            yield self.read()

    # -- sink ------------------------------------------------------------------------------
    @property
    def last_ack(self) -> LoadAck | None:
        return self.decoder.last_ack

    @property
    def load_report(self) -> LoadReport | None:
        """The load in force as the last heartbeat reports it: its sequence number
        (``LoadSeq``; the heartbeat carries no values), or None before a heartbeat."""
        hb = self.decoder.last_heartbeat
        if hb is None:
            return None
        if self._report_of is not hb:  # one report per heartbeat, built when asked for
            self._report_of = hb
            self._report = LoadReport(t=hb.t, seq=hb.load_seq, load=None, has_values=False)
        return self._report

    def send(self, payload) -> int:
        """Send a payload command (``None`` clears the load); return its sequence number."""
        if payload is not None:
            payload.check()
        seq = self._seq % 255 + 1
        self.decoder.acks.pop(seq, None)  # an ack of the previous use of this number
        self._transmit(seq, payload)
        self._seq = seq
        return seq

    def wait_ack(self, seq: int, timeout: float = 1.0) -> LoadAck:
        """Read until the ack of ``seq`` arrives (cycles read meanwhile are kept for
        ``read``); ``AckTimeout`` after ``timeout`` s."""
        deadline = time.perf_counter() + float(timeout)
        acks = self.decoder.acks
        while seq not in acks:
            remaining = deadline - time.perf_counter()
            if remaining <= 0:
                raise AckTimeout(f"{self.name}: no acknowledgement of payload command {seq} "
                                 f"within {timeout:g} s; {self.decoder.diagnosis()}")
            self._receive(min(remaining, ACK_POLL_S))
        return acks[seq]

    # -- life ------------------------------------------------------------------------------
    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self._shutdown()

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def heartbeat_text(hb) -> str:
    """The last heartbeat in words, for the links' silence diagnoses."""
    if hb is None:
        return "no heartbeat yet"
    return (f"last heartbeat {time.perf_counter() - hb.t:.2f} s ago "
            f"(controller {hb.state}, cycle {hb.cycle})")


class FramedControllerPort:
    """Base of the controller's ends: faults, silence and send counters.

    ``tick`` starts a controller cycle (releases delayed frames, enters or leaves a silence);
    ``_send(key, data)`` passes one frame through the fault injector to ``_emit``. Send errors
    are counted (``send_errors``), not raised: a controller keeps its cycle.
    """

    def __init__(self, faults: FaultSpec | None = None, record_faults: bool = False,
                 owns: bool = True) -> None:
        self.faults = FaultInjector(faults, record=record_faults) if faults and faults.active \
            else None
        self.counters = LinkCounters()
        self._owns = owns
        self._cycle = 0
        self._silent = False
        self.sent = 0
        self.send_errors = 0
        self.last_send_error: Exception | None = None
        self.send_failures: list[tuple[int, str]] = []
        """``(cycle, message name)`` of each frame that could not be sent (the first
        :data:`~firmware_bridge.faults.MAX_EVENTS`): losses the fault injector did not make."""

    def _send_failed(self, key, exc: Exception) -> None:
        """Count a frame that could not be sent (the controller keeps its cycle)."""
        self.send_errors += 1
        self.last_send_error = exc
        if len(self.send_failures) < MAX_EVENTS:
            self.send_failures.append((self._cycle, getattr(key, "name", None) or str(key)))

    def _emit(self, key, data: bytes) -> None:  # pragma: no cover - every backend has one
        raise NotImplementedError

    def _shutdown(self) -> None:  # pragma: no cover
        raise NotImplementedError

    def tick(self, cycle: int, t: float) -> None:
        """Start of a controller cycle: release delayed frames, enter or leave a silence."""
        self._cycle = cycle
        if self.faults is not None:
            self._silent = self.faults.silent(t)
            for key, data in self.faults.due(cycle):
                self._emit(key, data)

    def _open(self) -> bool:
        """False when frames go nowhere (an slcan adapter whose channel is closed drops them
        anyway): no faults are drawn for them, so the injected counts are what a reader can
        see."""
        return True

    def _send(self, key, data: bytes) -> None:
        if self._silent:
            self.faults.silence(key, self._cycle)
            return
        if self.faults is None or not self._open():
            self._emit(key, data)
            return
        for out in self.faults.apply(key, data, self._cycle):
            self._emit(key, out)

    def close(self) -> None:
        if self._owns:
            self._shutdown()
