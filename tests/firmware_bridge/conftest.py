"""Shared helpers: frames encoded independently with cantools from the DBC, and a synthetic
stream of joint states."""

import itertools

import can
import numpy as np
import pytest
from cantools.autosar.end_to_end import apply_profile2_crc

from firmware_bridge.protocol import database
from iem.types import JointState

JOINT_MESSAGES = {
    "fd": ("JointStateFD",),
    "classic": ("JointStateHeader", *(f"JointState{j}" for j in range(1, 8))),
}
_channels = itertools.count()


def data_ids(message) -> list[int]:
    return [int(tok, 16) for tok in message.dbc.attributes["E2EDataIDList"].value.split()]


def cantools_frame(name: str, signals: dict, counter: int) -> can.Message:
    """One protected frame encoded by cantools (scaling on, strict) from physical values."""
    msg = database().get_message_by_name(name)
    values = {"E2E_CRC": 0, "E2E_Counter": counter, **signals}
    data = msg.encode(values, scaling=True, strict=True)
    data = apply_profile2_crc(data, data_ids(msg)[counter])
    return can.Message(arbitration_id=msg.frame_id, data=bytes(data), is_extended_id=False,
                       is_fd=msg.is_fd, bitrate_switch=msg.is_fd)


def joint_signals(cycle: int, time_s: float, q, dq, tau) -> dict:
    out = {"Cycle": cycle, "Time": time_s}
    for j in range(7):
        out[f"Q{j + 1}"] = q[j]
        out[f"DQ{j + 1}"] = dq[j]
        out[f"Tau{j + 1}"] = tau[j]
    return out


def cantools_cycle(profile: str, signals: dict, counter: int) -> list[can.Message]:
    """The frames of one cycle, each with only the signals its message has."""
    db = database()
    out = []
    for name in JOINT_MESSAGES[profile]:
        msg = db.get_message_by_name(name)
        mine = {s.name: signals[s.name] for s in msg.signals if s.name in signals}
        out.append(cantools_frame(name, mine, counter))
    return out


def synthetic_states(n: int, stride: int = 1, start: int = 0) -> list[JointState]:
    """Smooth, in-range joint states for cycles start, start + stride, ..."""
    out = []
    for i in range(n):
        k = start + i * stride
        ph = np.arange(7)
        out.append(JointState(t=k * 1e-3, q=0.9 * np.sin(1e-3 * k + ph),
                              dq=0.9 * np.cos(1e-3 * k + ph), tau_J=30 * np.sin(5e-4 * k + ph),
                              cycle=k))
    return out


@pytest.fixture
def channel():
    """A fresh virtual-bus channel name."""
    return f"test-{next(_channels)}"
