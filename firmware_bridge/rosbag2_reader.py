"""Joint states from a rosbag2 bag (``ros2 bag record /franka/joint_states``), read with
``rosbags`` (no ROS install): a bag directory holding ``metadata.yaml``, or one of its
``.db3`` (sqlite3) or ``.mcap`` files.

The topic (default ``/franka/joint_states``) must carry ``sensor_msgs/msg/JointState``;
joints are mapped by name as the ``ros2`` link maps them
(:func:`firmware_bridge.ros2_link.match_joints`: ``fr3_joint1..7`` or ``panda_joint1..7``, in
any order, other joints such as the fingers ignored); ``position``, ``velocity`` and
``effort`` (franka_ros2: tau_J, link side) give q, dq and tau. ``t`` is the message's
``header.stamp`` (s, to the nearest double of its nanoseconds); only if every message's stamp
is zero (a publisher that does not stamp) is it the bag's receive time. The bag is read whole
and checked (:mod:`firmware_bridge.recording_checks`) before anything is delivered.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path as FsPath

import numpy as np

from iem.signals.recording import Recording

from .errors import LogFileError
from .recording_checks import checked_recording, refuse_nonfinite
from .ros2_link import DEFAULT_TOPIC, JOINT_SETS, match_joints

__all__ = ["BAG_SUFFIXES", "JOINT_STATE_TYPE", "read_rosbag2"]

BAG_SUFFIXES = (".db3", ".mcap")
"""Files of a rosbag2 bag that are read on their own (sqlite3, MCAP)."""
JOINT_STATE_TYPE = "sensor_msgs/msg/JointState"


def read_rosbag2(path, topic: str = DEFAULT_TOPIC, joints: tuple[str, ...] | None = None
                 ) -> Recording:
    """The ``sensor_msgs/msg/JointState`` messages of ``topic`` in a rosbag2 bag (see the
    module docstring) as arrays; LogFileError naming the message and joint of anything wrong,
    or the bag's topics if ``topic`` is not one of them."""
    path = FsPath(path)
    try:
        reader = _open_bag(path)
    except LogFileError:
        raise
    except Exception as exc:  # rosbags, sqlite3 and MCAP parsers raise their own errors
        raise LogFileError(f"{path}: cannot read as a rosbag2 bag: {exc}") from exc
    try:
        connections = _joint_state_connections(reader, path, topic)
        messages = _read_messages(reader, connections, path, f"{topic} message", joints)
    finally:
        reader.close()
    if not messages.stamps:
        raise LogFileError(f"{path}: no messages on {topic}; a recording needs the joint "
                           "states of a motion")
    stamps = messages.stamps
    if not any(stamps):
        stamps = messages.received  # a publisher that does not stamp: the bag's receive time
    t = np.array([s / 1_000_000_000 for s in stamps])  # Python ints: the nearest double
    arrays = {"position": np.array(messages.q), "velocity": np.array(messages.dq),
              "effort": np.array(messages.tau)}

    def what(k: int) -> str:
        return f"{topic} message {k}"

    joint_set = messages.joint_set
    refuse_nonfinite(path, arrays, what, lambda field, j: f"{field} of {joint_set[j]}")
    return checked_recording(path, t, *arrays.values(), what)


def _open_bag(path: FsPath):
    from rosbags.rosbag2 import Reader

    if not path.exists():
        raise LogFileError(f"{path}: no such rosbag2 bag (a directory holding metadata.yaml, a "
                           ".db3 or a .mcap file)")
    if not (path.is_dir() or path.suffix.lower() in BAG_SUFFIXES):
        raise LogFileError(f"{path}: a rosbag2 bag is a directory holding metadata.yaml, a .db3 "
                           "or a .mcap file")
    reader = Reader(path)
    reader.open()
    return reader


def _joint_state_connections(reader, path: FsPath, topic: str) -> list:
    """The bag's connections of ``topic``; LogFileError if there are none or they carry
    another type than JointState, naming the bag's topics."""
    connections = [c for c in reader.connections if c.topic == topic]
    if not connections:
        topics = ", ".join(f"{c.topic} ({c.msgtype})" for c in reader.connections)
        raise LogFileError(f"{path}: no topic {topic} in the bag; its topics are "
                           f"{topics or 'none'} (--topic names the JointState topic)")
    types = sorted({c.msgtype for c in connections})
    if types != [JOINT_STATE_TYPE]:
        others = [f"{c.topic}" for c in reader.connections if c.msgtype == JOINT_STATE_TYPE]
        raise LogFileError(f"{path}: topic {topic} carries {', '.join(types)}; a recording "
                           f"needs {JOINT_STATE_TYPE} (topics of that type in the bag: "
                           f"{', '.join(others) or 'none'})")
    return connections


@dataclass
class _Messages:
    """The messages' stamps and receive times (ns), and the arm's q, dq, tau per message."""

    stamps: list = field(default_factory=list)
    received: list = field(default_factory=list)
    q: list = field(default_factory=list)
    dq: list = field(default_factory=list)
    tau: list = field(default_factory=list)
    joint_set: tuple[str, ...] = JOINT_SETS["fr3"]
    """The arm's joint names in the first message (to name a joint in an error)."""


def _read_messages(reader, connections: list, path: FsPath, where: str,
                   joints: tuple[str, ...] | None = None) -> _Messages:
    """Every message of ``connections``, deserialised, the arm's joints (``joints``, the arm
    model's seven names; None: fr3's or panda's) picked by name; LogFileError naming the
    message of anything wrong."""
    from rosbags.typesys import Stores, get_typestore

    deserialize = get_typestore(Stores.LATEST).deserialize_cdr
    out = _Messages()
    index: dict[tuple[str, ...], np.ndarray] = {}
    try:
        for k, (_, receive_ns, raw) in enumerate(reader.messages(connections=connections)):
            msg = deserialize(raw, JOINT_STATE_TYPE)
            names = tuple(msg.name)
            if names not in index:
                index[names], matched = _joint_index(path, names, f"{where} {k}", joints)
                out.joint_set = matched if k == 0 else out.joint_set
            at = index[names]
            fields = []
            for name in ("position", "velocity", "effort"):
                a = np.asarray(getattr(msg, name), dtype=float)
                if a.shape != (len(names),):
                    raise LogFileError(
                        f"{path}: {where} {k}: {name} has {a.shape[0]} values for "
                        f"{len(names)} joint names; a recording needs position, velocity "
                        "and effort (tau_J) of every joint")
                fields.append(a[at])
            out.q.append(fields[0])
            out.dq.append(fields[1])
            out.tau.append(fields[2])
            out.stamps.append(msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec)
            out.received.append(int(receive_ns))
    except LogFileError:
        raise
    except Exception as exc:
        raise LogFileError(f"{path}: cannot read {where} {len(out.stamps)}: {exc}") from exc
    return out


def _joint_index(path, names: tuple[str, ...], what: str,
                 joints: tuple[str, ...] | None = None) -> tuple[np.ndarray, tuple[str, ...]]:
    """Where the arm's joints (``joints``; None: fr3's or panda's, the ros2 link's rule) are
    among ``names``, and their names."""
    found = match_joints(names, None if joints is None else tuple(joints))
    if found is not None:
        return np.array(found[0]), found[1]
    if joints is not None:
        missing = [n for n in joints if n not in names]
        raise LogFileError(f"{path}: {what} names the joints {', '.join(names) or 'none'}; the "
                           f"arm model's joints are {', '.join(joints)} (missing: "
                           f"{', '.join(missing)}); give the recording's arm model "
                           "(--arm-model, [arm] model)")
    closest = max(JOINT_SETS.values(), key=lambda s: sum(n in names for n in s))
    missing = [n for n in closest if n not in names]
    raise LogFileError(f"{path}: {what} names the joints {', '.join(names) or 'none'}; a "
                       "recording needs the seven arm joints fr3_joint1..7 or panda_joint1..7 "
                       f"(missing: {', '.join(missing)})")
