"""The messages between the plug-in and the controller, whatever the link: a payload command,
its acknowledgement, the controller's heartbeat and its report of the load in force, as
frozen value types (every link kind reads and writes these; the CAN wire's codecs are
:mod:`firmware_bridge.control_codecs`)."""

from __future__ import annotations

from dataclasses import dataclass

from iem.payload import Payload

ACK_STATUS = {0: "applied", 1: "rejected_inconsistent", 2: "refused_moving"}
ACK_ERRORS = {1: "the load is not physically consistent",
              2: "command not possible in the current mode (the arm is moving)"}
"""The error text of a refusal status (the wire carries only the status)."""


@dataclass(frozen=True)
class LoadCommand:
    """A payload command as the controller receives it.

    Attributes:
        seq: sequence number, 1..255 (0 is never sent).
        load: the load to set (mass kg, CoM m in the flange frame, inertia kg·m² about the
            CoM), or None to clear it (sent as mass 0).
    """

    seq: int
    load: Payload | None


@dataclass(frozen=True)
class LoadAck:
    """The controller's acknowledgement of a payload command.

    Attributes:
        seq: the command's sequence number.
        applied: True if the load was set; False if refused (not physically consistent,
            or the controller does not take load commands now, e.g. while the arm moves).
        load: the load now in force (after the command, or the previous one if refused);
            None if no load is set.
        t: ``time.perf_counter()`` when it was received, s.
        error: why it was refused, in the controller's words (libfranka's exception text,
            e.g. "command not possible in the current mode"); empty when applied, and on
            the CAN wire, which carries only the status.
    """

    seq: int
    applied: bool
    load: Payload | None
    t: float = 0.0
    error: str = ""


@dataclass(frozen=True)
class Heartbeat:
    """The controller's heartbeat.

    Attributes:
        state: ``"running"`` (playing its path) or ``"holding"`` (at rest at the end).
        load_seq: sequence number of the load in force (0: none set by a command).
        cycle: the controller's cycle counter when it was sent.
        overruns: 1 kHz deadlines missed so far (saturates at 255 on CAN).
        t: ``time.perf_counter()`` when it was received, s.
    """

    state: str
    load_seq: int
    cycle: int
    overruns: int
    t: float = 0.0


@dataclass(frozen=True)
class LoadReport:
    """The load in force, as the controller itself reports it (every payload sink keeps the
    latest as ``load_report``, updated while ``read`` runs).

    Attributes:
        t: ``time.perf_counter()`` when the link took the report, s.
        seq: sequence number of the load command in force, as the controller says (0: none
            set by a command); None where the link carries no sequence (libfranka's robot
            state).
        load: the load in force (mass kg, CoM m in the flange frame, inertia kg·m² about the
            CoM) where ``has_values``; None for the empty load (mass 0), or when the values
            are not reported.
        has_values: True when ``load`` is the controller's own report of the values
            (libfranka's ``m_load``, ``F_x_Cload``, ``I_load``); False when only ``seq`` is
            known (the CAN and serial heartbeats carry the sequence, not the values).
    """

    t: float
    seq: int | None
    load: Payload | None
    has_values: bool
