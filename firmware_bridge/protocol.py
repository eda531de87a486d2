"""The wire protocol: ``protocol.dbc`` loaded once with cantools, and the codecs built from it.

The DBC is the single source of truth: frame IDs, lengths, CAN FD or classic, signal
positions, widths, scaling and ranges, cycle times, bitrates and the E2E data identifiers all
come from it. This module turns each DBC message into a :class:`FrameCodec` (bit fields,
little-endian, as the DBC declares them) once, at first use; the hot path then unpacks a
frame with one ``int.from_bytes`` and a shift and mask per signal. The tests check every
codec against cantools' own encoder and decoder on the same DBC.

The codecs live one concept a module: :mod:`.frame_codec` (one DBC message),
:mod:`.state_codec` (the joint state), :mod:`.control_codecs` (payload command,
acknowledgement, heartbeat), and the value types they carry in :mod:`.messages`; this module
builds a profile from them and re-exports their names.

Two profiles (:func:`profile`):

- ``fd``: the whole joint state in one 64-byte CAN FD frame every 1 ms (``JointStateFD``);
  payload command and acknowledgement in one 32-byte FD frame each.
- ``classic``: 8-byte frames. A cycle is ``JointStateHeader`` (cycle counter, time) and
  ``JointState1..7`` (one joint each), all with the same E2E alive counter, at the rate the
  DBC gives (``GenMsgCycleTime``; 2 ms, the largest standard rate under 60 % of 1 Mbit/s,
  see :mod:`firmware_bridge.busload`). Payload command and acknowledgement are five
  multiplexed frames each (``Mux`` 0..4) with the same ``Seq``.

Both profiles share the ``Heartbeat`` (classic frame, every 100 ms).

Resolutions (all below the default sensor noise of :class:`sim.plant.SensorModel`):
q 1e-5 rad (±5.24 rad), dq 1e-4 rad/s (±3.28 rad/s), tau_J 0.01 N·m (±327 N·m); payload mass
1e-4 kg (0..13.1 kg), CoM 1e-5 m (±1.31 m), inertia 1e-6 kg·m² (±0.524 kg·m²). Joint values
outside their range are saturated by the sender (and counted there); payload values outside
theirs are refused with :class:`~firmware_bridge.errors.EncodeError`.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path as FsPath

from iem.types import N_JOINTS

from .control_codecs import PAYLOAD_FIELDS, HeartbeatCodec, LoadAssembler, LoadCodec
from .errors import BridgeConfigError
from .frame_codec import Field, FrameCodec
from .messages import ACK_ERRORS, ACK_STATUS, Heartbeat, LoadAck, LoadCommand
from .state_codec import STATE_FIELDS, STATE_INDEX, JointStateCodec

__all__ = ["ACK_ERRORS", "ACK_STATUS", "DBC_PATH", "PAYLOAD_FIELDS", "PROFILES", "STATE_FIELDS",
           "STATE_INDEX", "Field", "FrameCodec", "Heartbeat", "HeartbeatCodec", "JointStateCodec",
           "LoadAck", "LoadAssembler", "LoadCodec", "LoadCommand", "WireProfile", "database",
           "profile"]

DBC_PATH = FsPath(__file__).with_name("protocol.dbc")

PROFILES = ("fd", "classic")
"""The wire profiles (:func:`profile`): every ``--profile`` and ``[link] profile`` takes its
choices from here."""

_MESSAGES = {
    "fd": {"joint_state": ("JointStateFD",), "command": "LoadCommandFD",
           "ack": "LoadAckFD", "heartbeat": "Heartbeat"},
    "classic": {"joint_state": ("JointStateHeader",
                                *(f"JointState{j}" for j in range(1, N_JOINTS + 1))),
                "command": "LoadCommand", "ack": "LoadAck", "heartbeat": "Heartbeat"},
}


@dataclass(frozen=True)
class WireProfile:
    """Everything one profile puts on the bus.

    Attributes:
        name: ``"fd"`` or ``"classic"``.
        joint_state: the joint-state frames (one cycle).
        command, ack: payload command and acknowledgement.
        heartbeat: the heartbeat.
        bitrate: nominal (arbitration) bitrate, bit/s.
        data_bitrate: CAN FD data-phase bitrate, bit/s (None for classic).
        period_us: the controller's cycle, µs (1000).
    """

    name: str
    joint_state: JointStateCodec
    command: LoadCodec
    ack: LoadCodec
    heartbeat: HeartbeatCodec
    bitrate: int
    data_bitrate: int | None
    period_us: int

    @property
    def is_fd(self) -> bool:
        return self.data_bitrate is not None

    def frames(self) -> list[FrameCodec]:
        """Every frame codec of the profile."""
        return [*self.joint_state.parts, self.command.frame, self.ack.frame,
                self.heartbeat.frame]


@functools.cache
def database():
    """The DBC, loaded once (cantools, strict: overlapping signals are an error)."""
    import cantools

    return cantools.database.load_file(str(DBC_PATH), strict=True)


@functools.cache
def profile(name: str = "fd") -> WireProfile:
    """The codecs of profile ``name`` (``"fd"`` or ``"classic"``), built once."""
    if name not in _MESSAGES:
        raise BridgeConfigError(f"unknown profile {name!r}; valid profiles are "
                                f"{', '.join(PROFILES)}")
    db = database()
    attrs = db.dbc.attributes
    period_us = int(attrs["IemControllerPeriodUs"].value)
    names = _MESSAGES[name]

    def codec(msg_name: str) -> FrameCodec:
        c = FrameCodec(db.get_message_by_name(msg_name))
        if c.profile not in (name, "both"):
            raise BridgeConfigError(f"{c.label} is for profile {c.profile!r}, not {name!r}")
        return c

    hb = codec(names["heartbeat"])
    states = db.get_message_by_name(names["heartbeat"]).get_signal_by_name("State").choices
    return WireProfile(
        name=name,
        joint_state=JointStateCodec(tuple(codec(n) for n in names["joint_state"]), period_us),
        command=LoadCodec(codec(names["command"]), is_ack=False),
        ack=LoadCodec(codec(names["ack"]), is_ack=True),
        heartbeat=HeartbeatCodec(hb, {int(k): str(v) for k, v in states.items()}),
        bitrate=int(attrs["Baudrate"].value),
        data_bitrate=int(attrs["IemDataBitrateFD"].value) if name == "fd" else None,
        period_us=period_us,
    )
