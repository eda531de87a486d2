"""``iem set-load FILE`` and ``iem set-load --clear``: write one load to the controller.

The commissioning write: a payload file (as ``iem identify`` writes it, as ``[estimate]
initial_payload`` takes it) or the empty load (``--clear``: mass 0, as libfranka's
``setLoad`` takes it) goes to the controller of ``--config cell.toml`` (its ``[link]``),
with the link's ``send`` (libfranka ``setLoad`` semantics).

A file's load first passes the checks the safety gate makes of every load
(:func:`deploy.writeback.checks.check_estimate` with the cell's ``[gate]``): finite, physically
consistent, within the rated payload (with the declared end effector), within the CoM radius,
and within the link's wire ranges (:func:`deploy.writeback.wire.wire_check_of`). A load they
refuse is never sent. What the time-dependent checks of the gate guard against (an estimate
that is still moving, uncertain or unverified) does not apply to a file a person hands over.

Then the command waits (``--timeout``, default 5 s) for the controller's answer: its
acknowledgement, or its own report of the load's values in force where the link has one
(``load_report``, a :class:`firmware_bridge.messages.LoadReport` with ``has_values``: the
franka and ros2 links). It prints one line of what
is in force now (``--json``: a JSON object with the keys ``applied``, ``seq``,
``load_in_force`` and ``error``; the load as :func:`deploy.writeback.load_state.load_record` writes
it) and exits

- 0: the controller applied the load;
- 1: the controller refused it (its error text is printed), or nothing answered within the
  timeout (whether it is in force is then unknown);
- 2 (``iem: error: ...``): a bad file or configuration, a load the checks refuse (naming the
  reason and the limit), a link that does not write loads, FILE and ``--clear`` together or
  neither. Nothing is written.
"""

from __future__ import annotations

import json
import math
import time

from deploy.writeback.load_state import same_load
from iem.errors import InvalidInputError

EXIT_APPLIED = 0
EXIT_NOT_APPLIED = 1
"""The controller refused the load or did not answer within the timeout."""
POLL_S = 0.05
"""How long one wait for the answer lasts before the controller's load report is looked at."""


class SetLoadError(InvalidInputError):
    """A load ``iem set-load`` refuses to send (the reason and the limit in the message)."""


def load_text(load) -> str:
    """A load in words: ``none (mass 0)`` or mass, CoM and the inertia's diagonal."""
    if load is None or not load.mass > 0.0:
        return "none (mass 0)"
    ixx, _, _, iyy, _, izz = load.inertia
    return (f"{load.mass:.4f} kg at [{load.com[0]:.4f}, {load.com[1]:.4f}, {load.com[2]:.4f}] "
            f"m, inertia diag [{ixx:.3g}, {iyy:.3g}, {izz:.3g}] kg·m²")


def checked_load(path: str, gate, wire_check=None):
    """The payload file at ``path`` as a load the gate's checks let through; SetLoadError
    naming the reason and the limit otherwise (PayloadError for a bad file)."""
    from deploy.writeback.checks import check_estimate
    from sim.payload import load_payload

    payload = load_payload(path)
    reason, detail = check_estimate(payload.to_phi(), gate, wire_check)
    if reason:
        raise SetLoadError(f"{path}: not written, the gate refuses it ({reason}): {detail}")
    return payload  # the file's own values, not their round trip through phi


def _empty_as_none(load):
    """A load of mass 0 is the empty load (libfranka reports no load as mass 0)."""
    return None if load is None or not load.mass > 0.0 else load


def _reported(link, load, sent_at: float):
    """The controller's own report, taken after ``sent_at`` (``time.perf_counter``), if it
    says the values of ``load`` are in force. A report of a sequence number alone confirms
    nothing here: this command's numbers start again at 1, so an earlier run's number may
    still be in force."""
    report = link.load_report  # a PayloadSink's (None where its controller reports none)
    if report is None or not report.has_values or not report.t > sent_at:
        return None
    return report if same_load(report.load, load) else None


def await_answer(link, seq: int, load, timeout: float, deadline: float | None = None,
                 sent_at: float = 0.0) -> dict:
    """Wait up to ``timeout`` s (until ``deadline`` on ``time.monotonic``, if given) for the
    answer to command ``seq`` (``load`` sent at ``sent_at``, ``time.perf_counter``): its
    acknowledgement, or a report of the load's values in force; the result as :func:`run`
    prints it."""
    from deploy.writeback.load_state import load_record
    from firmware_bridge.errors import AckTimeout

    if deadline is None:
        deadline = time.monotonic() + timeout
    while True:
        left = deadline - time.monotonic()
        try:
            ack = link.wait_ack(seq, max(0.0, min(left, POLL_S)))
        except AckTimeout:
            ack = None
        if ack is not None:
            return {"applied": bool(ack.applied), "seq": seq,
                    "load_in_force": load_record(_empty_as_none(ack.load)),
                    "error": "" if ack.applied else (ack.error or
                                                     "refused (no error text on this link)")}
        report = _reported(link, load, sent_at)
        if report is not None:
            return {"applied": True, "seq": seq,
                    "load_in_force": load_record(_empty_as_none(report.load)), "error": ""}
        if left <= 0:
            return {"applied": False, "seq": seq, "load_in_force": "unknown",
                    "error": f"no answer from the controller to command {seq} within "
                             f"{timeout:g} s"}


def _wait_for_service(link, timeout: float) -> None:
    """Give a link that discovers its controller (ROS 2) up to ``timeout`` s to find it."""
    ready = getattr(link, "wait_for_service", None)
    if ready is not None:
        ready(timeout)


def _line(result: dict, where: str) -> str:
    from iem.payload import Payload

    force = result["load_in_force"]
    if force == "unknown":
        state = "unknown"
    elif force is None:
        state = load_text(None)
    else:
        state = load_text(Payload.from_set_load(force["mass"], force["com"], force["inertia"]))
    if result["applied"]:
        return f"iem set-load: applied (command {result['seq']}) on {where}; in force: {state}"
    return (f"iem set-load: NOT applied (command {result['seq']}) on {where}: "
            f"{result['error']}; in force: {state}")


# -- command line --------------------------------------------------------------------------
def configure(parser) -> None:
    parser.add_argument("file", nargs="?", metavar="FILE",
                        help="payload TOML to write (iem identify's output)")
    parser.add_argument("--clear", action="store_true",
                        help="write the empty load (mass 0) instead of a file")
    parser.add_argument("--config", required=True, metavar="FILE",
                        help="cell.toml: its [link] is the controller, its [gate] the checks")
    parser.add_argument("--timeout", type=float, default=5.0, metavar="S",
                        help="wait this long for the controller's answer (default 5 s)")
    parser.add_argument("--json", action="store_true",
                        help="print the result as JSON (applied, seq, load_in_force, error)")


def run(args) -> int:
    from deploy.config import load_config
    from deploy.writeback.wire import wire_check_of
    from firmware_bridge.links import LINKS, link_kind, open_link

    if bool(args.file) == bool(args.clear):
        raise SetLoadError("give either a payload FILE or --clear (the empty load), "
                           f"not {'both' if args.clear else 'neither'}")
    if not (math.isfinite(args.timeout) and args.timeout > 0):
        raise SetLoadError(f"--timeout {args.timeout!r}: valid is a number of s > 0")
    config = load_config(args.config)
    lc = config.link
    if not link_kind(lc.kind).sink:
        writers = ", ".join(k for k, v in LINKS.items() if v.sink)
        raise SetLoadError(f"{config.source}: [link] kind {lc.kind!r} does not write loads; "
                           f"kinds that do: {writers}")
    load = None if args.clear else checked_load(args.file, config.gate)  # before any link
    link = open_link(lc.kind, lc.channel, profile=lc.profile,
                     silence_timeout=lc.silence_timeout_s, **config.link_options())
    try:
        if load is not None:
            load = checked_load(args.file, config.gate, wire_check_of(link))
        deadline = time.monotonic() + args.timeout
        _wait_for_service(link, args.timeout)
        sent_at = time.perf_counter()
        seq = link.send(load)
        result = await_answer(link, seq, load, args.timeout, deadline, sent_at)
    finally:
        link.close()
    if args.json:
        print(json.dumps(result))
    else:
        print(_line(result, f"{lc.kind} {lc.channel!r}"))
    return EXIT_APPLIED if result["applied"] else EXIT_NOT_APPLIED
