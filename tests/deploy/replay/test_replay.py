"""``iem replay``: the plug-in over recorded traffic, deterministic, writes off.

Recordings are made without real time: the simulated controller runs as fast as it can
(``realtime=False``) on a virtual-bus channel and a second bus on the same channel collects
every frame, which is then written with python-can's own writer.
"""

import hashlib
import itertools
import json
import math

import can
import numpy as np
import pytest

from deploy.cli import main
from deploy.replay.core import CSV_HEADER, replay
from deploy.simcell.controller import SimController
from firmware_bridge.can_link import open_bus
from firmware_bridge.controller_port import open_port
from firmware_bridge.protocol import profile as get_profile
from iem.persistence import save_model
from sim.family import default_test_payload
from sim.paths import new_task_path

SECONDS = 1.5
MAX_GAP_S = 1e-3
"""The longest gap between two recorded frames: one controller period (1 kHz)."""
_channels = itertools.count()


def record_sim(out, profile: str, path=None, seed: int = 0) -> int:
    """Record ``path`` (default: SECONDS of the new task path) to ``out``, sensor-noise seed
    ``seed``; return the complete cycles published."""
    channel = f"replay-test-{next(_channels)}"
    path = new_task_path().slice(0, SECONDS) if path is None else path
    recorder = open_bus("virtual", channel, profile)
    port, _ = open_port("virtual", channel, profile)
    try:
        controller = SimController(port, path=path, realtime=False, once=True, seed=seed)
        controller.run(cycles=len(path))
        writer = can.Logger(str(out))
        try:
            stamp = last = None
            while (msg := recorder.recv(0)) is not None:
                # The controller ran without real time, so the bus's wall-clock stamps only
                # give the order: a stall of this shared machine between two frames of one
                # cycle would read, in the replay, as a controller silence that forgets the
                # cycle in flight (CI lost one so). Write them on a steady clock instead:
                # no gap longer than one controller period.
                stamp = msg.timestamp if stamp is None else \
                    stamp + min(msg.timestamp - last, MAX_GAP_S)
                last, msg.timestamp = msg.timestamp, stamp
                writer.on_message_received(msg)
        finally:
            writer.stop()
    finally:
        port.close()
        recorder.shutdown()
    # one cycle per published controller cycle: fd every cycle, classic every other one
    return math.ceil(controller.cycles / get_profile(profile).joint_state.stride)


def cycle_frames(log_file, profile: str) -> int:
    """Complete cycles in a log, counted independently: the frames that open a cycle."""
    first = get_profile(profile).joint_state.by_id
    opener = min(first)  # 0x100 (fd) or 0x110, the classic header
    kwargs = {"relative_timestamp": False} if str(log_file).endswith(".asc") else {}
    return sum(1 for m in can.LogReader(str(log_file), **kwargs) if m.arbitration_id == opener)


@pytest.fixture(scope="module")
def replay_model():
    """A small IEM (2 epochs instead of 10): the replay's behaviour, not its accuracy."""
    from deploy.model.training import train_initial_model

    return train_initial_model("IEM", "paper", "builtin", 0, log=lambda _: None, fit_epochs=2)


@pytest.fixture(scope="module")
def replay_model_file(replay_model, tmp_path_factory):
    path = tmp_path_factory.mktemp("model") / "model.msgpack"
    save_model(replay_model, path)
    return path


@pytest.fixture(scope="module")
def fd_log(tmp_path_factory):
    out = tmp_path_factory.mktemp("rec") / "fd.blf"
    return out, record_sim(out, "fd")


# python-can 4.6.1's .trc writer cannot log CAN FD frames (firmware_bridge/record.py), so
# .trc is recorded with the classic profile.
@pytest.mark.parametrize(("profile", "suffix"), [
    ("fd", ".log"), ("fd", ".asc"), ("classic", ".trc"), ("classic", ".blf")])
def test_replay_twice_gives_identical_estimates_one_per_block(tmp_path, replay_model, profile,
                                                             suffix):
    out = tmp_path / f"bus{suffix}"
    published = record_sim(out, profile)
    assert cycle_frames(out, profile) == published
    first, est1 = replay(out, profile=profile, model=replay_model, log=lambda _: None)
    second, est2 = replay(out, profile=profile, model=replay_model, log=lambda _: None)
    frames = 10 if profile == "fd" else 5  # about 100 block points a second: 1 kHz, 500 Hz
    assert first["estimates"] == len(est1) == -(-published // frames)  # one per block point
    assert not first["frames"]["dropped"] and first["frames"]["lost"] == 0
    assert est1.csv_text() == est2.csv_text()
    assert first["gate"] == second["gate"]  # the gate runs on the recorded clock


def test_a_stall_inside_a_recorded_cycle_costs_that_cycle_only(tmp_path, replay_model):
    """What CI met before the recordings were written on a steady clock: 0.15 s between two
    frames of one classic cycle is a controller silence, as the live link would have seen
    it. The cycle in flight is forgotten and counted lost; every other cycle is estimated
    (the block points bridge the one lost frame: as many as without the stall)."""
    out, stalled = tmp_path / "bus.blf", tmp_path / "stalled.blf"
    published = record_sim(out, "classic")
    frames = list(can.LogReader(str(out)))
    per_cycle = len(frames) // published
    writer = can.Logger(str(stalled))
    try:
        for k, msg in enumerate(frames):
            msg.timestamp += 0.15 * (k >= 100 * per_cycle + per_cycle // 2)
            writer.on_message_received(msg)
    finally:
        writer.stop()
    summary, est = replay(stalled, profile="classic", model=replay_model, log=lambda _: None)
    assert summary["frames"]["lost"] == 1 and len(est) == -(-published // 5)  # 500 Hz
    assert summary["frames"]["dropped"] == {"orphaned": per_cycle}


def test_cli_writes_csv_json_and_keeps_the_model_file(tmp_path, fd_log, replay_model_file,
                                                      capsys):
    log_file, published = fd_log
    before = hashlib.sha256(replay_model_file.read_bytes()).hexdigest()
    truth = tmp_path / "truth.toml"
    from sim.payload import save_payload

    save_payload(default_test_payload(), truth)
    csvs = []
    for i in range(2):
        csv, summary = tmp_path / f"est{i}.csv", tmp_path / f"summary{i}.json"
        assert main(["replay", str(log_file), "--model", str(replay_model_file),
                     "--truth", str(truth), "--out", str(csv), "--json", str(summary),
                     "--no-status"]) == 0
        csvs.append(csv.read_bytes())
    assert csvs[0] == csvs[1]
    lines = csvs[0].decode().splitlines()
    assert lines[0] == ",".join(CSV_HEADER)
    assert lines[0].startswith("t,cycle,bag,m,mrx,") and lines[0].endswith(",Iyz_std,Izz_std")
    assert ",Izz_s,m_std," in lines[0]  # the standard deviations after today's columns
    assert len(lines) == 1 + -(-published // 10)  # one row per block point
    assert all(len(line.split(",")) == 33 for line in lines)
    assert all(v == "nan" for v in lines[1].split(",")[23:])  # the IEM gives no std
    s = json.loads(summary.read_text())
    for key in ("mae_groups", "bags", "estimates", "frames", "writes"):
        assert key in s
    assert s["estimates"] == -(-published // 10)
    assert set(s["mae_groups"]) == {"mass", "com", "inertia"}
    assert all(math.isfinite(v) for v in s["mae_groups"].values())
    assert s["writes"]["sent"] == 0 and s["writes"]["would_send"] == s["gate"].get("send", 0)
    loads = s["writes"]["would_send_loads"]
    assert len(loads) == s["writes"]["would_send"]
    assert all(set(w) == {"t", "mass", "com", "inertia", "from_prior"} for w in loads)
    assert s["coverage_2sigma"] == {"mass": None, "com": None, "inertia": None}
    out = capsys.readouterr().out
    assert "MAE against" in out and "the gate would have sent" in out
    assert hashlib.sha256(replay_model_file.read_bytes()).hexdigest() == before


def test_the_replay_reports_its_cpu_and_speed_per_cpu_second(fd_log, replay_model):
    """``cpu_speed`` is the recorded time over the CPU of the replay's threads, the loop's
    (learning inline in it) and the reader's; never more than the wall time allows."""
    log_file, _ = fd_log
    summary, _ = replay(log_file, model=replay_model, log=lambda _: None)
    parts = summary["cpu_parts"]
    assert summary["replay_cpu_s"] == parts["cycle"] + parts["reader"] > 0.0
    assert summary["cpu_speed"] == summary["recorded_s"] / summary["replay_cpu_s"]
    assert parts["learning"] <= parts["cycle"]  # inline: a part of the loop's CPU
    assert summary["replay_cpu_s"] <= summary["wall_s"] * 1.05  # one thread's CPU (+ clocks)


def test_save_model_writes_the_learnt_model(tmp_path, fd_log, replay_model,
                                           replay_model_file):
    from iem.persistence import load_model

    log_file, _ = fd_log
    saved = tmp_path / "learnt.msgpack"
    summary, _ = replay(log_file, model=replay_model, save_model_to=saved, log=lambda _: None)
    learnt = load_model(saved)
    assert learnt.n_bags == summary["bags"] > replay_model.n_bags  # the new path formed bags
    assert load_model(replay_model_file).n_bags == replay_model.n_bags  # the input is unchanged


def test_bad_files_exit_2_with_clear_errors(tmp_path, fd_log, replay_model_file, capsys):
    def error(*argv):
        assert main(["replay", *map(str, argv), "--model", str(replay_model_file),
                     "--no-status"]) == 2
        return capsys.readouterr().err

    assert "no such log file" in error(tmp_path / "missing.blf")
    assert "unknown log format '.db'" in error(tmp_path / "x.db")
    garbled = tmp_path / "garbled.log"
    garbled.write_text("(1.0) vcan0 100#zz\n")
    assert "garbled.log" in error(garbled)
    bad = tmp_path / "bad.blf"
    bad.write_bytes(b"not a blf file at all" * 10)
    assert "bad.blf" in error(bad)
    empty = tmp_path / "empty.asc"
    empty.write_text("not a CAN log\n")
    assert "empty.asc: no CAN frames in it" in error(empty)
    wrong = error(fd_log[0], "--profile", "classic")
    assert "no complete joint-state cycle of the classic profile" in wrong
    assert "recorded with --profile fd?" in wrong
    missing_model = tmp_path / "none.msgpack"
    assert main(["replay", str(bad), "--model", str(missing_model)]) == 2
    assert "none.msgpack" in capsys.readouterr().err


def test_an_empty_blf_and_a_random_asc_are_said_once_and_clearly(tmp_path, replay_model_file,
                                                                 capsys):
    """An empty ``.blf`` names what a BLF file starts with (not python-can's "unpack requires
    a buffer of 72 bytes"); a random ``.asc`` says each warning once (the rate's peek at the
    start no longer says them too)."""
    empty = tmp_path / "empty.blf"
    empty.write_bytes(b"")
    assert main(["replay", str(empty), "--model", str(replay_model_file), "--no-status"]) == 2
    err = capsys.readouterr().err
    assert "empty.blf: empty (0 bytes): a BLF file starts with its header" in err, err
    random = tmp_path / "random.asc"
    random.write_bytes(np.random.default_rng(0).integers(0, 256, 4000, np.uint8).tobytes())
    assert main(["replay", str(random), "--model", str(replay_model_file), "--no-status"]) == 2
    err = capsys.readouterr().err
    assert err.count("random.asc is truncated") == 1, err
    assert err.count("lines python-can could not read") == 1, err
    assert err.count("iem: error:") == 1


# -- damaged logs: a truncated one replays what it holds, a bad line is skipped and counted --
def test_a_truncated_blf_replays_what_it_holds_and_says_so(tmp_path, fd_log, replay_model_file,
                                                           capsys):
    log_file, published = fd_log
    data = log_file.read_bytes()
    cut = tmp_path / "cut.blf"
    cut.write_bytes(data[:len(data) // 2])
    held = sum(1 for _ in can.LogReader(str(cut)))  # python-can's own reader: what it holds
    assert 0 < held < sum(1 for _ in can.LogReader(str(log_file)))
    out = tmp_path / "summary.json"
    assert main(["replay", str(cut), "--model", str(replay_model_file), "--json", str(out),
                 "--no-status"]) == 0
    s = json.loads(out.read_text())
    assert s["truncated"] is True and 0 < s["estimates"] < published
    assert s["frames"]["received"] == held
    captured = capsys.readouterr()
    assert "cut.blf is truncated" in captured.err and "TRUNCATED" in captured.out
    whole = tmp_path / "whole.json"
    assert main(["replay", str(log_file), "--model", str(replay_model_file), "--json",
                 str(whole), "--no-status"]) == 0
    assert json.loads(whole.read_text())["truncated"] is False


@pytest.mark.parametrize("suffix", [".log", ".asc"])
def test_a_bad_line_is_skipped_and_counted_not_fatal(tmp_path, suffix):
    from firmware_bridge.replay import ReplaySource

    clean = tmp_path / f"clean{suffix}"
    record_sim(clean, "fd")
    lines = clean.read_text().splitlines()
    frame_lines = [i for i, line in enumerate(lines) if "#" in line or "CANFD" in line]
    damaged_at = frame_lines[len(frame_lines) // 3], frame_lines[2 * len(frame_lines) // 3]
    for i in damaged_at:  # a joint-state frame line whose data python-can cannot parse
        lines[i] = lines[i].replace("#", "#Z", 1) if suffix == ".log" else \
            lines[i].replace(" f 64 ", " f 64 ZZ ", 1)
    bad = tmp_path / f"bad{suffix}"
    bad.write_text("\n".join(lines) + "\n")
    kwargs = {"relative_timestamp": False} if suffix == ".asc" else {}
    with pytest.raises(Exception):  # noqa: B017 - python-can's reader alone stops there
        list(can.LogReader(str(bad), **kwargs))
    expected = sum(1 for _ in can.LogReader(str(clean), **kwargs)) - len(damaged_at)
    with ReplaySource(bad, "fd") as src:
        states = list(src)
    assert src.frames == expected and src.bad_lines == 2 and src.counters.malformed == 2
    assert not src.truncated
    with ReplaySource(clean, "fd") as whole:
        all_states = list(whole)
    assert 0 < len(all_states) - len(states) <= 2  # only the damaged cycles are missing
