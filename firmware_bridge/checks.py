"""One check suite that every link passes, as :mod:`iem.checks` is for estimators.

A link is checked through a :class:`Harness`: a link of one kind of
:data:`~firmware_bridge.links.LINKS`, opened on a fresh channel, and the other end of it: a
controller that publishes joint states and answers payload commands, or a recording that
holds them. :func:`check_link` runs every ``check_*`` function of this module (listed in
:data:`CHECKS`, so a test can parametrise over them) on a factory of harnesses, each check on
a fresh one. A check that fails raises :class:`~iem.errors.CheckFailed` (an :class:`AssertionError`)
saying what was expected and what was found.

What every link does (the protocols of :mod:`firmware_bridge.links`):

- it is a :class:`~firmware_bridge.links.JointStateSource`, and a
  :class:`~firmware_bridge.links.PayloadSink` exactly where its kind says ``sink``; its
  ``rate_hz`` is :func:`~firmware_bridge.links.rate_hz` of its kind and profile;
- ``read`` returns the joint states the other end sent, in order, one per call: finite
  float arrays of shape (7,), time stamps and cycle counters that move forward; ``counters``
  count what was received and delivered, and on a clean stream nothing dropped or lost;
- with nothing to read, a live link raises
  :class:`~firmware_bridge.errors.ControllerSilent` (a :class:`TimeoutError`) after the
  timeout given, counts the silence and stays usable; a recording raises
  :class:`~firmware_bridge.errors.EndOfStream` after its last joint state, and again at every
  later ``read``;
- ``close`` may be called twice;
- a sink's ``send`` returns the command's sequence number (1..255, one more each time), and
  the other end's acknowledgement arrives through ``wait_ack`` (and ``last_ack``) with the
  load in force; an impossible payload is refused before anything is sent
  (:class:`~iem.errors.PayloadError`, no number used); an acknowledgement that does not come
  is :class:`~firmware_bridge.errors.AckTimeout`; after an applied command, ``load_report``
  names the load in force by sequence number or values, as ``LINKS[kind].load_report`` says
  the kind carries (None where it carries none);
- an unknown option names the kind's options (:class:`~firmware_bridge.errors.BridgeConfigError`,
  before anything opens), and a channel that cannot be opened raises the kind's documented
  error.

The harnesses (:class:`~firmware_bridge.link_harness.Harness`, and the controller's and the
recording's) are in :mod:`firmware_bridge.link_harness`.
"""

from __future__ import annotations

import itertools
import math
import time
from collections.abc import Callable

import numpy as np

from iem.errors import CheckFailed, PayloadError
from iem.payload import Payload
from iem.types import JointState

from .errors import AckTimeout, BridgeConfigError, ControllerSilent, EndOfStream
from .link_harness import N_STATES, READ_TIMEOUT_S, Harness
from .links import LINKS, JointStateSource, LinkCounters, PayloadSink, open_link, rate_hz
from .messages import LoadAck, LoadReport
from .reassembly import CYCLE_MOD

SILENCE_S = 0.05
"""The ``read`` timeout a check gives when nothing was sent."""
ACK_TIMEOUT_S = 10.0
"""How long a check waits for an acknowledgement, serving the other end meanwhile."""
REPORT_TIMEOUT_S = 3.0
"""How long a check waits, after the acknowledgement, for the report of the load in force."""
TOOL = Payload("tool", 0.73, (0.01, -0.02, 0.06), (2e-3, 1e-4, -2e-4, 3e-3, 3e-4, 1.5e-3))
"""A physically consistent load for the sink checks."""
IMPOSSIBLE = Payload("impossible", -1.0, (0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 1.0, 0.0, 1.0))
"""A load no sink may send: negative mass."""


def _fail(check: str, kind: str, message: str) -> CheckFailed:
    return CheckFailed(f"{check} ({kind}): {message}")


# -- helpers -------------------------------------------------------------------------------
def _read(h: Harness, name: str, n: int) -> list[JointState]:
    out = []
    for i in range(n):
        try:
            out.append(h.link.read(READ_TIMEOUT_S))
        except (ControllerSilent, EndOfStream) as exc:
            raise _fail(name, h.kind, f"read {i} of the {n} joint states sent, then "
                                      f"{type(exc).__name__}: {exc}") from exc
    return out


def _check_states(h: Harness, name: str, got: list[JointState], sent) -> None:
    for s in got:
        if not isinstance(s, JointState):
            raise _fail(name, h.kind, f"read returned a {type(s).__name__}, not a JointState")
        for field in ("q", "dq", "tau_J"):
            v = getattr(s, field)
            if not (isinstance(v, np.ndarray) and v.shape == (7,) and v.dtype == float
                    and np.all(np.isfinite(v))):
                raise _fail(name, h.kind, f"{field} of cycle {s.cycle} is {v!r}; expected 7 "
                                          "finite floats")
        if not (isinstance(s.t, float) and math.isfinite(s.t)):
            raise _fail(name, h.kind, f"t of cycle {s.cycle} is {s.t!r}, not a finite float")
        if not (isinstance(s.cycle, int) and 0 <= s.cycle < CYCLE_MOD):
            raise _fail(name, h.kind, f"cycle {s.cycle!r} is not an integer in 0..2**32-1")
    for a, b in itertools.pairwise(got):
        if not (b.t > a.t and 0 < (b.cycle - a.cycle) % CYCLE_MOD < CYCLE_MOD // 2):
            raise _fail(name, h.kind, f"cycle {a.cycle} at t = {a.t!r} s is followed by cycle "
                                      f"{b.cycle} at t = {b.t!r} s: not forward")
    if sent is None or h.tolerance is None:
        return
    if [s.cycle for s in got] != [s.cycle for s in sent]:
        raise _fail(name, h.kind, f"cycles read {[s.cycle for s in got]}, sent "
                                  f"{[s.cycle for s in sent]}")
    for a, b in zip(got, sent, strict=True):
        if abs(a.t - b.t) > 1e-6:
            raise _fail(name, h.kind, f"cycle {a.cycle}: t = {a.t!r} s read, {b.t!r} s sent")
        for field, tol in zip(("q", "dq", "tau_J"), h.tolerance, strict=True):
            err = float(np.max(np.abs(getattr(a, field) - getattr(b, field))))
            if err > tol:
                raise _fail(name, h.kind, f"cycle {a.cycle}: {field} is {err:.3g} off what "
                                          f"was sent; the link allows {tol:g}")


def _await_ack(h: Harness, name: str, seq: int) -> LoadAck:
    """The acknowledgement of ``seq``, serving the other end between short waits."""
    deadline = time.monotonic() + ACK_TIMEOUT_S
    while True:
        h.serve()
        try:
            return h.link.wait_ack(seq, 0.05)
        except AckTimeout:
            if time.monotonic() > deadline:
                raise _fail(name, h.kind, f"no acknowledgement of command {seq} within "
                                          f"{ACK_TIMEOUT_S:g} s") from None


def _same_load(ack_load, sent: Payload | None) -> bool:
    if sent is None or ack_load is None:
        return sent is None and ack_load is None
    return (abs(ack_load.mass - sent.mass) <= 1e-4
            and np.allclose(ack_load.com, sent.com, atol=1e-5, rtol=0)
            and np.allclose(ack_load.inertia, sent.inertia, atol=2e-6, rtol=0))


# -- the checks ----------------------------------------------------------------------------
def check_protocols(make) -> None:
    """A JointStateSource; a PayloadSink exactly where the kind says so; its rate."""
    name = "protocols"
    with make() as h:
        link, spec = h.link, LINKS[h.kind]
        if not isinstance(link, JointStateSource):
            raise _fail(name, h.kind, f"{type(link).__name__} is not a JointStateSource")
        if isinstance(link, PayloadSink) != spec.sink:
            raise _fail(name, h.kind, f"{type(link).__name__} is "
                                      f"{'' if spec.sink else 'not '}expected to be a "
                                      f"PayloadSink (LINKS says sink={spec.sink})")
        if not (isinstance(link.name, str) and link.name):
            raise _fail(name, h.kind, f"name {link.name!r} is not a non-empty str")
        if not isinstance(link.counters, LinkCounters):
            raise _fail(name, h.kind, f"counters is a {type(link.counters).__name__}")
        if link.rate_hz != rate_hz(h.kind, h.profile):
            raise _fail(name, h.kind, f"rate_hz {link.rate_hz!r}; the kind's is "
                                      f"{rate_hz(h.kind, h.profile)!r}")


def check_reads_joint_states(make) -> None:
    """What was sent is read, in order, one joint state per call: 7 finite floats each,
    time and cycle forward; ``last_frame_time`` an epoch receive time (0.0 for a
    recording)."""
    name = "reads joint states"
    with make() as h:
        sent = h.publish(N_STATES)
        got = _read(h, name, N_STATES)
        _check_states(h, name, got, sent)
        t = h.link.last_frame_time
        live = h.recorded is None
        if not isinstance(t, float) or (abs(t - time.time()) > 600 if live else t != 0.0):
            raise _fail(name, h.kind, f"last_frame_time {t!r}: expected "
                                      f"{'an epoch time of now' if live else '0.0'}")


def check_counters(make) -> None:
    """A clean stream: received >= delivered >= read, nothing dropped, lost or silent."""
    name = "counters"
    with make() as h:
        h.publish(N_STATES)
        _read(h, name, N_STATES)
        c = h.link.counters
        if not c.received >= c.delivered >= N_STATES:
            raise _fail(name, h.kind, f"received {c.received}, delivered {c.delivered} after "
                                      f"{N_STATES} joint states read")
        if c.dropped() or c.lost or c.silences or c.overflow:
            raise _fail(name, h.kind, f"a clean stream counted {c.summary()}; silences "
                                      f"{c.silences}, overflow {c.overflow}")


def check_silence_or_end(make) -> None:
    """Nothing to read: a live link raises ControllerSilent (a TimeoutError) after the
    timeout given, counts it and reads on; a recording raises EndOfStream, and again."""
    name = "silence or end"
    with make() as h:
        if h.recorded is not None:
            h.publish(h.recorded)
            _read(h, name, h.recorded)
            for _ in range(2):
                try:
                    s = h.link.read(SILENCE_S)
                except EndOfStream:
                    continue
                raise _fail(name, h.kind, f"read past the recording's {h.recorded} joint "
                                          f"states: cycle {s.cycle}")
            return
        first = _read(h, name, len(h.publish(N_STATES) or [None] * N_STATES))
        started = time.monotonic()
        try:
            s = h.link.read(SILENCE_S)
        except ControllerSilent as exc:
            if not isinstance(exc, TimeoutError):
                raise _fail(name, h.kind, "ControllerSilent is not a TimeoutError") from exc
        else:
            raise _fail(name, h.kind, f"nothing was sent, yet read returned cycle {s.cycle}")
        if time.monotonic() - started < SILENCE_S * 0.9:
            raise _fail(name, h.kind, f"ControllerSilent before the {SILENCE_S:g} s given")
        if h.link.counters.silences != 1:
            raise _fail(name, h.kind, f"silences {h.link.counters.silences} after one")
        again = _read(h, name, len(h.publish(N_STATES) or [None] * N_STATES))
        _check_states(h, name, first + again, None)


def check_close_idempotent(make) -> None:
    """``close`` twice raises nothing."""
    name = "close idempotent"
    with make() as h:
        h.link.close()
        try:
            h.link.close()
        except Exception as exc:
            raise _fail(name, h.kind, f"a second close raised {type(exc).__name__}: {exc}"
                        ) from exc


def check_send_and_ack(make) -> None:
    """A sink: ``send`` gives 1, 2, ...; each command is acknowledged with the load in force
    (None after a clear), also as ``last_ack``."""
    name = "send and ack"
    with make() as h:
        if not LINKS[h.kind].sink:
            return
        h.publish(N_STATES)  # a link that reads its acks from the stream has one
        for expected, load in ((1, TOOL), (2, None)):
            seq = h.link.send(load)
            if seq != expected:
                raise _fail(name, h.kind, f"send returned {seq!r}, expected {expected}")
            ack = _await_ack(h, name, seq)
            if not (isinstance(ack, LoadAck) and ack.seq == seq and ack.applied):
                raise _fail(name, h.kind, f"command {seq} acknowledged with {ack!r}")
            if not _same_load(ack.load, load):
                raise _fail(name, h.kind, f"command {seq} ({load}) acknowledged with the load "
                                          f"{ack.load}")
            last = h.link.last_ack
            if last is None or last.seq != seq:
                raise _fail(name, h.kind, f"last_ack is {last!r} after the ack of {seq}")


def _report_names(kind: str, report, seq: int, load: Payload | None) -> bool:
    carries = LINKS[kind].load_report
    if report is None or not isinstance(report, LoadReport):
        return False
    if carries == "seq":
        return report.seq == seq
    return report.has_values and _same_load(report.load, load)


def check_load_report(make) -> None:
    """A sink: ``load_report`` is None before the controller said anything; after an applied
    command it names the load in force, by sequence number or by values as the kind carries
    (``LINKS[kind].load_report``), after a clear too; a kind that carries none keeps it
    None."""
    name = "load report"
    with make() as h:
        if not LINKS[h.kind].sink:
            return
        link, carries = h.link, LINKS[h.kind].load_report
        if link.load_report is not None:
            raise _fail(name, h.kind, f"load_report {link.load_report!r} before anything was "
                                      "read")
        h.publish(N_STATES)
        _read(h, name, N_STATES)
        for load in (TOOL, None):
            seq = link.send(load)
            _await_ack(h, name, seq)
            deadline = time.monotonic() + REPORT_TIMEOUT_S
            while not _report_names(h.kind, link.load_report, seq, load):
                if not carries and link.load_report is None:
                    break
                if time.monotonic() > deadline:
                    raise _fail(name, h.kind, f"after command {seq} ({load}) was applied, "
                                              f"load_report is {link.load_report!r}; it "
                                              f"carries {carries or 'nothing'}")
                h.serve()
                _read(h, name, len(h.publish(1) or [None]))
            if not carries and link.load_report is not None:
                raise _fail(name, h.kind, f"load_report {link.load_report!r}: LINKS says the "
                                          "kind carries none")
            report = link.load_report
            if report is not None and not (isinstance(report.t, float)
                                           and abs(report.t - time.perf_counter()) < 600):
                raise _fail(name, h.kind, f"load_report.t {report.t!r}: expected a "
                                          "time.perf_counter() of now")


def check_refuses_impossible_payload(make) -> None:
    """A sink refuses a load that is not physically consistent before sending it:
    PayloadError, and no sequence number used."""
    name = "refuses impossible payload"
    with make() as h:
        if not LINKS[h.kind].sink:
            return
        try:
            seq = h.link.send(IMPOSSIBLE)
        except PayloadError:
            pass
        else:
            raise _fail(name, h.kind, f"sent an impossible payload as command {seq}")
        if (seq := h.link.send(None)) != 1:
            raise _fail(name, h.kind, f"the next command got {seq}; the refused one took a "
                                      "number")


def check_ack_timeout(make) -> None:
    """A sink: an acknowledgement that does not come is AckTimeout (a TimeoutError)."""
    name = "ack timeout"
    with make() as h:
        if not LINKS[h.kind].sink:
            return
        try:
            ack = h.link.wait_ack(200, SILENCE_S)  # never sent
        except AckTimeout as exc:
            if not isinstance(exc, TimeoutError):
                raise _fail(name, h.kind, "AckTimeout is not a TimeoutError") from exc
        else:
            raise _fail(name, h.kind, f"an ack of a command never sent: {ack!r}")


def check_bad_options(make) -> None:
    """An unknown option is a BridgeConfigError naming the kind's options; a channel that
    cannot be opened raises the kind's documented error."""
    name = "bad options"
    with make() as h:
        try:
            other = open_link(h.kind, h.channel, profile=h.profile, no_such_option=1)
        except BridgeConfigError as exc:
            if "its options are" not in str(exc):
                raise _fail(name, h.kind, f"the error names no options: {exc}") from exc
        else:
            other.close()
            raise _fail(name, h.kind, "an unknown option was accepted")
        if h.bad_channel is None:
            return
        channel, error = h.bad_channel
        try:
            other = open_link(h.kind, channel, profile=h.profile)
        except error:
            pass
        except Exception as exc:
            raise _fail(name, h.kind, f"channel {channel!r} raised {type(exc).__name__}: "
                                      f"{exc}; documented: {error.__name__}") from exc
        else:
            other.close()
            raise _fail(name, h.kind, f"channel {channel!r} opened")


CHECKS: tuple[Callable[..., None], ...] = (
    check_protocols,
    check_reads_joint_states,
    check_counters,
    check_silence_or_end,
    check_close_idempotent,
    check_send_and_ack,
    check_load_report,
    check_refuses_impossible_payload,
    check_ack_timeout,
    check_bad_options,
)
"""Every check, in the order :func:`check_link` runs them."""
SINK_CHECKS = (check_send_and_ack, check_load_report, check_refuses_impossible_payload,
               check_ack_timeout)
"""The checks of a sink; on a link that is none they check nothing."""


def check_link(make: Callable[[], Harness]) -> None:
    """Run every check of :data:`CHECKS` on ``make`` (a factory of fresh harnesses).

    Raises:
        CheckFailed: the first check that fails, with what was expected and found.
    """
    for check in CHECKS:
        check(make)
