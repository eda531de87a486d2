"""Recordings of joint states that Franka users have: rosbag2 bags and joint-state CSVs.

The bags are written by ``rosbags``' own writer (sqlite3 and MCAP storage) from arrays, the
CSVs with Python's csv module; reading them back must give the arrays exactly. ``write_bag``
and ``write_csv`` are shared with ``tests/deploy/test_replay_formats.py``.
"""

from __future__ import annotations

import csv

import numpy as np
import pytest

from firmware_bridge.errors import EndOfStream, LogFileError
from firmware_bridge.links import JointStateSource, open_link, rate_hz
from firmware_bridge.recordings import (
    CSV_COLUMNS,
    DEFAULT_TOPIC,
    RecordingSource,
    detect_format,
    open_recording,
    read_csv,
    read_recording,
    recording_format,
)
from firmware_bridge.replay import ReplaySource
from firmware_bridge.rosbag2_reader import read_rosbag2

FR3 = tuple(f"fr3_joint{i}" for i in range(1, 8))
PANDA = tuple(f"panda_joint{i}" for i in range(1, 8))
T0_NS = 1_764_000_000_123_456_789
"""An epoch time stamp, ns: what franka_ros2 puts in header.stamp."""


def arrays(n: int = 200, seed: int = 0, t0_ns: int = T0_NS, step_ns: int = 1_000_000):
    """``(t, q, dq, tau)`` of a smooth motion; ``t`` the nearest doubles of ns stamps."""
    rng = np.random.default_rng(seed)
    ns = [t0_ns + k * step_ns for k in range(n)]
    s = np.arange(n)[:, None] * 1e-3
    phase = rng.uniform(0, np.pi, 7)
    q = 0.5 * np.sin(s + phase)
    dq = 0.5 * np.cos(s + phase)
    tau = rng.normal(0.0, 5.0, (n, 7))
    return np.array([x / 1_000_000_000 for x in ns]), q, dq, tau, ns


def write_bag(path, t_ns, q, dq, tau, *, storage: str = "sqlite3", topic: str = DEFAULT_TOPIC,
              names=FR3, order=None, extra=(), stamp: bool = True, msgtype=None,
              receive_ns=None):
    """A rosbag2 bag at ``path`` (a new directory) written by rosbags: one
    ``sensor_msgs/msg/JointState`` per row on ``topic``, the joints listed in ``order`` (a
    permutation of the seven) followed by the joint names ``extra`` (values 0); ``stamp``
    False leaves header.stamp zero; ``msgtype`` (a type with one float64 ``data``) writes
    that type on the topic instead; ``receive_ns``: the bag's receive times."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    js, header, time = (store.types[n] for n in ("sensor_msgs/msg/JointState",
                                                 "std_msgs/msg/Header",
                                                 "builtin_interfaces/msg/Time"))
    order = list(range(7)) if order is None else list(order)
    names = [names[i] for i in order] + list(extra)
    pad = np.zeros(len(extra))
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    with Writer(path, version=9, storage_plugin=plugin) as writer:
        conn = writer.add_connection(topic, msgtype or js.__msgtype__, typestore=store)
        for k, ns in enumerate(t_ns):
            if msgtype is not None:  # a message with one float64 'data' (std_msgs/msg/Float64)
                data = store.serialize_cdr(store.types[msgtype](data=float(k)), msgtype)
            else:
                sec, nanosec = divmod(ns, 1_000_000_000) if stamp else (0, 0)
                msg = js(header=header(stamp=time(sec=sec, nanosec=nanosec), frame_id=""),
                         name=names,
                         position=np.concatenate((np.asarray(q[k], float)[order], pad)),
                         velocity=np.concatenate((np.asarray(dq[k], float)[order], pad)),
                         effort=np.concatenate((np.asarray(tau[k], float)[order], pad)))
                data = store.serialize_cdr(msg, js.__msgtype__)
            received = ns + 250_000 if receive_ns is None else receive_ns[k]
            writer.write(conn, received, data)
    return path


def write_csv(path, t, q, dq, tau, columns=CSV_COLUMNS, extra: dict | None = None):
    """A joint-state CSV: the columns in the order given, every float as its repr (exact),
    plus ``extra`` columns (name -> values) at the end."""
    values = {"t": np.asarray(t)}
    for prefix, a in (("q", q), ("dq", dq), ("tau", tau)):
        for j in range(7):
            values[f"{prefix}{j + 1}"] = np.asarray(a)[:, j]
    extra = extra or {}
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow([*columns, *extra])
        for k in range(len(t)):
            w.writerow([repr(float(values[c][k])) for c in columns]
                       + [str(v[k]) for v in extra.values()])
    return path


def assert_same(rec, t, q, dq, tau):
    for got, want in ((rec.t, t), (rec.q, q), (rec.dq, dq), (rec.tau, tau)):
        np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_a_bag_written_by_rosbags_reads_back_to_the_arrays(tmp_path, storage):
    t, q, dq, tau, ns = arrays()
    bag = write_bag(tmp_path / "bag", ns, q, dq, tau, storage=storage)
    storage_file = next(bag.glob("*.mcap" if storage == "mcap" else "*.db3"))
    for path in (bag, storage_file):  # the bag's directory, or its storage file alone
        assert detect_format(path) == "rosbag2"
        assert_same(read_rosbag2(path), t, q, dq, tau)
    assert t[0] == T0_NS / 1e9  # the header stamp, to the nearest double


def test_joints_are_mapped_by_name_whatever_their_order(tmp_path):
    """A panda bag whose messages list the arm's joints shuffled and the fingers after them,
    as the ros2 link maps them (firmware_bridge.ros2_link.match_joints)."""
    t, q, dq, tau, ns = arrays(seed=1)
    order = [3, 6, 0, 5, 1, 4, 2]
    bag = write_bag(tmp_path / "bag", ns, q, dq, tau, names=PANDA, order=order,
                    extra=("panda_finger_joint1", "panda_finger_joint2"), storage="mcap")
    assert_same(read_recording(bag), t, q, dq, tau)


def test_an_unstamped_bag_takes_the_receive_time(tmp_path):
    _, q, dq, tau, ns = arrays()
    receive = [T0_NS + 7 + k * 1_000_000 for k in range(len(ns))]
    bag = write_bag(tmp_path / "bag", ns, q, dq, tau, stamp=False, receive_ns=receive)
    rec = read_rosbag2(bag)
    np.testing.assert_array_equal(rec.t, [x / 1_000_000_000 for x in receive])
    # one message stamped at 0 among stamped ones is a time stamp like any other: here the
    # first, so the recording starts at t = 0 (a simulation's clock)
    ns0 = [k * 1_000_000 for k in range(len(ns))]
    rec0 = read_rosbag2(write_bag(tmp_path / "sim", ns0, q, dq, tau))
    assert rec0.t[0] == 0.0 and rec0.t[1] == 0.001


def test_a_csv_reads_back_with_its_columns_in_any_order_and_others_ignored(tmp_path):
    t, q, dq, tau, _ = arrays(seed=2)
    rng = np.random.default_rng(0)
    columns = [CSV_COLUMNS[i] for i in rng.permutation(len(CSV_COLUMNS))]
    path = write_csv(tmp_path / "state.txt", t, q, dq, tau, columns=columns,
                     extra={"m_load": np.zeros(len(t)), "mode": ["move"] * len(t)})
    assert detect_format(path) == "csv"  # by its header, whatever the suffix
    assert_same(read_csv(path), t, q, dq, tau)


def test_the_source_delivers_the_recording_as_recorded(tmp_path):
    """t as recorded (no resampling, no filling), the index as the cycle, EndOfStream at the
    end; a 5 ms gap counts 4 lost cycles and a 0.2 s gap a silence, nothing is dropped."""
    t, q, dq, tau, _ = arrays(n=50)
    t = t - t[0]
    t[30:] += 0.004
    t[40:] += 0.2
    path = write_csv(tmp_path / "rec.csv", t, q, dq, tau)
    with open_recording(path) as source:
        assert isinstance(source, RecordingSource) and isinstance(source, JointStateSource)
        assert source.rate_hz == rate_hz("recording")
        first = source.read(0.0)
        rest = list(source)
        with pytest.raises(EndOfStream, match="end of the recording after 50 joint states"):
            source.read()
    states = [first, *rest]
    assert [s.cycle for s in states] == list(range(50))
    np.testing.assert_array_equal([s.t for s in states], t)
    np.testing.assert_array_equal(np.array([s.tau_J for s in states]), tau)
    c = source.counters
    assert (c.received, c.delivered, c.lost, c.silences) == (50, 50, 4 + 200, 1)
    assert not c.dropped() and source.truncated is False and source.bad_lines == 0


def test_read_many_gives_what_read_gives_one_by_one_and_the_same_counters(tmp_path):
    """``iem replay``'s bulk read of a recording: chunks that end inside and exactly at the
    end, across a lost-cycle gap and a silence, give the states, cycles and counters of
    ``read`` one by one; the end reads 0; at the recorded pace it declines (None)."""
    t, q, dq, tau, _ = arrays(n=50)
    t = t - t[0]
    t[30:] += 0.004
    t[40:] += 0.2
    path = write_csv(tmp_path / "rec.csv", t, q, dq, tau)
    one = open_recording(path)
    states = list(one)
    for chunk in (7, 25, 50, 64):
        source = open_recording(path)
        T, X = np.zeros(chunk), np.zeros((chunk, 21))
        cycles = np.zeros(chunk, dtype=np.int64)
        got_t, got_x, got_c = [], [], []
        while n := source.read_many(chunk, T, X, cycles):
            got_t.extend(T[:n]), got_x.extend(X[:n].copy()), got_c.extend(cycles[:n])
        assert source.read_many(chunk, T, X, cycles) == 0
        np.testing.assert_array_equal(got_t, [s.t for s in states])
        np.testing.assert_array_equal(got_x, [np.concatenate((s.q, s.dq, s.tau_J))
                                              for s in states])
        assert got_c == [s.cycle for s in states]
        assert vars(source.counters) == vars(one.counters), chunk
    paced = open_link("recording", str(path))
    assert paced.read_many(8, T, X, cycles) is None


def test_the_link_kind_paces_the_recording_as_recorded(tmp_path):
    """``open_link("recording", ...)`` as ``iem run`` opens it: each joint state when it is
    due, a gap longer than ``skip`` shortened to it; ``iem replay``'s ``pace="fast"`` does not
    wait."""
    import time

    t, q, dq, tau, _ = arrays(n=100)
    t = t - t[0]
    t[50:] += 1.0  # 99 ms of joint states around a 1 s gap
    path = write_csv(tmp_path / "rec.csv", t, q, dq, tau)
    start = time.perf_counter()
    link = open_link("recording", str(path), skip=0.05)
    assert isinstance(link, RecordingSource) and len(list(link)) == 100
    paced = time.perf_counter() - start
    assert 0.099 + 0.049 <= paced < 1.0
    start = time.perf_counter()
    assert len(list(open_recording(path))) == 100
    assert time.perf_counter() - start < paced


def test_detection_and_its_override(tmp_path):
    t, q, dq, tau, _ = arrays(n=20)
    assert [detect_format(tmp_path / f"x{s}") for s in (".blf", ".log", ".asc", ".trc")] == \
        ["can"] * 4
    assert detect_format(tmp_path / "missing.csv") == "csv"
    assert detect_format(tmp_path / "bag.db3") == "rosbag2"
    with pytest.raises(LogFileError, match=r"unknown log format '\.db'; valid recordings are "
                                           r"a CAN log \(\.blf, \.log, \.asc, \.trc\)"):
        detect_format(tmp_path / "x.db")
    (tmp_path / "folder").mkdir()
    with pytest.raises(LogFileError, match=r"a directory without metadata\.yaml is not a rosbag2"):
        detect_format(tmp_path / "folder")
    pycan = tmp_path / "bus.csv"
    pycan.write_text("timestamp,arbitration_id,extended,remote,error,dlc,data\n")
    with pytest.raises(LogFileError, match="python-can CSV CAN log"):
        detect_format(pycan)
    # a joint-state CSV named like a CAN log: detected as one, read as a CSV when told so
    disguised = write_csv(tmp_path / "joints.log", t, q, dq, tau)
    assert detect_format(disguised) == "can"
    assert recording_format(disguised, "csv") == "csv"
    assert_same(read_recording(disguised, "csv"), t, q, dq, tau)
    with pytest.raises(LogFileError, match="unknown recording format 'bag'; valid are can, "
                                           "rosbag2, csv"):
        recording_format(disguised, "bag")
    assert isinstance(open_recording(write_csv(tmp_path / "j.csv", t, q, dq, tau)),
                      RecordingSource)


def test_a_can_log_opens_as_the_replay_source(tmp_path):
    """open_recording gives the CAN path the replay source it always had."""
    from sim.paths import new_task_path
    from sim.plant import ArmPlant
    from tests.can_logs import write_log

    log = tmp_path / "bus.blf"
    write_log(ArmPlant(seed=0).follow(new_task_path().slice(0, 0.05)), log)
    with open_recording(log) as source:
        assert isinstance(source, ReplaySource)
        n = len(list(source))
    rec = read_recording(log)
    assert len(rec) == n == 51
    with pytest.raises(LogFileError, match="a CAN log; open it as the link kind 'replay'"):
        open_link("recording", str(log))
