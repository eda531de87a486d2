"""``iem replay``, ``iem calibrate`` and ``iem identify`` on the recordings Franka users have.

One plant rollout (:class:`sim.plant.ArmPlant` on the new task path, a payload mounted) is
written as a CAN log by ``tests.can_logs.write_log``, framed as the controller sends
it. The CAN wire quantises (``protocol.dbc``: q 1e-5 rad, dq 1e-4 rad/s, tau 0.01 N·m, t 1 µs),
so the rosbag2 bags and the CSV are written from the values the CAN log decodes to: the three
formats then carry the same joint states. The CSV holds every float as its repr, so it is
exact; a bag's header stamp holds integer nanoseconds, read back as the nearest double, which
is the decoded CAN time or one ulp from it. The filters take the nominal period and the gap
rule rounds time steps to whole cycles, so the estimates are identical to the bit.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from deploy.cli import main
from deploy.replay.core import CSV_HEADER, replay
from firmware_bridge.recordings import CSV_COLUMNS, read_recording
from sim.family import default_test_payload
from sim.paths import new_task_path
from sim.plant import ArmPlant
from tests.can_logs import write_log
from tests.firmware_bridge.test_recordings import FR3, PANDA, write_bag, write_csv

from .conftest import cell_config, stopped_summary, write_toml

SECONDS = 1.0


def stamps_ns(t) -> list[int]:
    """Integer nanoseconds of decoded CAN times (whole microseconds on the wire)."""
    return [round(float(x) * 1e9) for x in t]


def write_formats(folder, rollout, stem: str) -> dict:
    """``rollout`` as a CAN log, then the log's decoded joint states as a sqlite3 bag, an MCAP
    bag and a CSV; name -> path."""
    can_log = folder / f"{stem}.blf"
    write_log(rollout, can_log)
    rec = read_recording(can_log)
    ns = stamps_ns(rec.t)
    return {
        "can": can_log,
        # the recorded arm's joint names: the default arm model's, the Panda's
        "sqlite3": write_bag(folder / f"{stem}_sqlite3", ns, rec.q, rec.dq, rec.tau,
                             names=PANDA),
        "mcap": write_bag(folder / f"{stem}_mcap", ns, rec.q, rec.dq, rec.tau, storage="mcap",
                          order=[6, 5, 4, 3, 2, 1, 0], names=PANDA),
        "csv": write_csv(folder / f"{stem}.csv", rec.t, rec.q, rec.dq, rec.tau),
    }


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    folder = tmp_path_factory.mktemp("formats")
    path = new_task_path().slice(0, SECONDS)
    rollout = ArmPlant(payload=default_test_payload(), seed=1).follow(path)
    return write_formats(folder, rollout, "rec")


@pytest.fixture(scope="module")
def model(trained_model_file):
    from iem.persistence import load_model

    return load_model(trained_model_file)


def quiet(_):
    pass


@pytest.fixture(scope="module")
def can_replay(files, model):
    """``(summary, estimates)`` of the CAN log's replay."""
    return replay(files["can"], model=model, log=quiet)


def test_every_format_replays_to_the_same_estimates(files, model, can_replay):
    can_summary, can_est = can_replay
    assert can_summary["format"] == "can" and can_summary["profile"] == "fd"
    raw, smoothed = np.array(can_est.raw), can_est.smoothed_array()
    for name in ("sqlite3", "mcap", "csv"):
        summary, est = replay(files[name], model=model, log=quiet)
        path = files[name]
        assert summary["format"] == ("csv" if name == "csv" else "rosbag2"), name
        assert summary["profile"] is None and summary["log_file"] == str(path)
        assert len(est) == len(can_est) == -(-(int(SECONDS * 1000) + 1) // 10), name
        assert est.cycle == can_est.cycle and est.bag == can_est.bag, name
        np.testing.assert_allclose(est.t, can_est.t, rtol=1e-15, atol=0, err_msg=name)
        np.testing.assert_array_equal(np.array(est.raw), raw, err_msg=name)
        np.testing.assert_array_equal(est.smoothed_array(), smoothed, err_msg=name)
        assert summary["gate"] == can_summary["gate"], name
        assert summary["frames"]["lost"] == 0 and not summary["frames"]["dropped"], name
        if name == "csv":
            assert est.t == can_est.t  # the CSV holds the decoded times exactly


def test_the_command_line_reads_a_bag(files, trained_model_file, tmp_path, capsys):
    """``iem replay REC --model M --json S --out CSV --topic T``: the CSV of estimates equals
    the CAN log's but for the time column's last digit."""
    outs = {}
    for name in ("can", "mcap"):
        out, summary = tmp_path / f"{name}.csv", tmp_path / f"{name}.json"
        assert main(["replay", str(files[name]), "--model", str(trained_model_file),
                     "--json", str(summary), "--out", str(out), "--topic",
                     "/franka/joint_states", "--no-status"]) == 0
        outs[name] = np.loadtxt(out, delimiter=",", skiprows=1)
        assert out.read_text().splitlines()[0] == ",".join(CSV_HEADER)
    np.testing.assert_array_equal(outs["mcap"][:, 1:], outs["can"][:, 1:])
    s = json.loads(summary.read_text())
    assert (s["format"], s["profile"], s["log_file"]) == ("rosbag2", None, str(files["mcap"]))
    assert f"replay of {files['mcap']} (rosbag2 recording" in capsys.readouterr().out


def test_format_overrides_detection(files, model, can_replay, trained_model_file, tmp_path,
                                    capsys):
    """A joint-state CSV named like a CAN log: read as a CAN log unless told otherwise."""
    disguised = tmp_path / "joints.log"
    disguised.write_bytes(files["csv"].read_bytes())
    assert main(["replay", str(disguised), "--model", str(trained_model_file),
                 "--no-status"]) == 2
    err = capsys.readouterr().err
    assert "joints.log: " in err and "cannot read as .log" in err
    summary, est = replay(disguised, model=model, log=quiet, format="csv")
    assert summary["format"] == "csv"
    np.testing.assert_array_equal(est.smoothed_array(), can_replay[1].smoothed_array())
    assert main(["replay", str(files["csv"]), "--format", "rosbag2", "--no-status"]) == 2
    assert "a rosbag2 bag is a directory holding metadata.yaml" in capsys.readouterr().err
    with pytest.raises(SystemExit) as usage:  # argparse's usage error
        main(["replay", str(files["csv"]), "--format", "bag"])
    assert usage.value.code == 2
    assert "invalid choice: 'bag' (choose from 'can', 'rosbag2', 'csv')" in \
        capsys.readouterr().err


# -- bad recordings: exit status 2, and a message naming what is wrong and what is valid ------
def _rows(files):
    rec = read_recording(files["csv"])
    n = 30
    return rec.t[:n].copy(), rec.q[:n].copy(), rec.dq[:n].copy(), rec.tau[:n].copy()


def bad_inputs(folder, files) -> list[tuple[str, list[str], list[str]]]:
    """``(what, iem replay arguments, expected parts of the message)``."""
    t, q, dq, tau = _rows(files)
    ns = stamps_ns(t)
    cases = []

    def csv_case(what, expected, t=t, q=q, dq=dq, tau=tau, **kw):
        path = write_csv(folder / f"{what.replace(' ', '_')}.csv", t, q, dq, tau, **kw)
        cases.append((what, [str(path)], expected))

    def bag_case(what, expected, args=(), ns=ns, q=q, dq=dq, tau=tau, names=PANDA, **kw):
        path = write_bag(folder / what.replace(" ", "_"), ns, q, dq, tau, names=names, **kw)
        cases.append((what, [str(path), *args], expected))

    csv_case("csv without columns", ["missing: dq4, tau3", "needs the columns t (s), q1..q7"],
             columns=[c for c in CSV_COLUMNS if c not in ("dq4", "tau3")])
    nan = q.copy()
    nan[6, 1] = np.nan
    csv_case("csv nan", ["line 8, column q2: nan is not a finite number",
                         "refuses the whole file"], q=nan)
    inf = tau.copy()
    inf[3, 6] = -np.inf
    csv_case("csv inf", ["line 5, column tau7: -inf is not a finite number"], tau=inf)
    back = t.copy()
    back[[10, 11]] = back[[11, 10]]
    csv_case("csv unsorted", ["line 13: t = 0.01 s goes back from line 12's 0.011 s",
                              "must increase strictly"], t=back)
    again = t.copy()
    again[20] = again[19]
    csv_case("csv repeated", ["line 22: t = 0.019 s repeats line 21's 0.019 s"], t=again)
    csv_case("csv header only", ["0 joint state(s); a recording needs at least 10"], t=t[:0],
             q=q[:0], dq=dq[:0], tau=tau[:0])
    # two rows 1.75 ms apart: too short, not a 570 Hz recording the model was not made for
    slow = t[:2] * 1.75
    csv_case("csv of two rows", ["2 joint state(s); a recording needs at least 10 (its rate "
                                 "is the median of its steps"], t=slow, q=q[:2], dq=dq[:2],
             tau=tau[:2])
    far = t.copy()
    far[-1] = 1e306  # once an OverflowError with a traceback
    csv_case("csv at t = 1e306", [f"line {len(t) + 1}: t = 1e+306 s is beyond any recording's "
                                  "time stamps; valid are |t| <= 1e+10 s"], t=far)
    early = t - 1e306
    csv_case("csv at t = -1e306", ["line 2: t = -1e+306 s is beyond"], t=early)
    empty = folder / "empty.csv"
    empty.write_text("")
    cases.append(("csv empty", [str(empty)], ["empty.csv: empty", "t,q1,q2"]))
    word = folder / "word.csv"
    word.write_text(_with_word(files["csv"]))
    cases.append(("csv word", [str(word)], ["line 3, column dq1: 'fast' is not a number"]))
    pycan = folder / "bus.csv"
    pycan.write_text("timestamp,arbitration_id,extended,remote,error,dlc,data\n")
    cases.append(("python-can csv", [str(pycan)], ["python-can CSV CAN log", ".blf, .log"]))

    bag_case("bag without a joint", ["message 0 names the joints panda_joint1", "missing: "
                                     "panda_joint7", "the arm model's joints are panda_joint1"],
             q=q[:, :6], dq=dq[:, :6], tau=tau[:, :6], names=PANDA[:6], order=range(6))
    bag_case("bag of another arm", ["message 0 names the joints fr3_joint1", "the arm model's "
                                    "joints are panda_joint1", "--arm-model"], names=FR3)
    nan_effort = tau.copy()
    nan_effort[4, 2] = np.nan
    bag_case("bag nan", ["/franka/joint_states message 4, effort of panda_joint3: nan"],
             tau=nan_effort)
    bag_case("bag repeated", ["message 9: t = ", "repeats /franka/joint_states message 8's"],
             ns=[*ns[:9], ns[8], *ns[10:]])
    bag_case("bag topic", ["no topic /robot/joint_states in the bag; its topics are "
                           "/franka/joint_states (sensor_msgs/msg/JointState)"],
             args=["--topic", "/robot/joint_states"])
    bag_case("bag type", ["topic /franka/joint_states carries std_msgs/msg/Float64; a "
                          "recording needs sensor_msgs/msg/JointState"],
             msgtype="std_msgs/msg/Float64")
    bag_case("bag empty", ["no messages on /franka/joint_states"], ns=[])
    missing = folder / "none_such"
    cases.append(("no such path", [str(missing)], ["none_such: no such file or directory",
                                                   "a rosbag2 bag (its directory"]))
    plain = folder / "plain"  # a folder that is no bag stands for the recordings in it
    plain.mkdir()
    (plain / "notes.txt").write_text("not a recording\n")
    cases.append(("no recording", [str(plain)], ["plain: no recording in this folder",
                                                 "a rosbag2 bag (its directory"]))
    return cases


def _with_word(csv_file) -> str:
    """The CSV with the second data row's dq1 replaced by a word."""
    lines = csv_file.read_text().splitlines()
    header = lines[0].split(",")
    fields = lines[2].split(",")
    fields[header.index("dq1")] = "fast"
    lines[2] = ",".join(fields)
    return "\n".join(lines[:40]) + "\n"


def test_bad_recordings_exit_2_and_say_what_is_wrong(files, tmp_path, capsys):
    for what, args, expected in bad_inputs(tmp_path, files):
        assert main(["replay", *args, "--no-status"]) == 2, what
        err = capsys.readouterr().err
        assert err.startswith("iem: error: "), (what, err)
        for part in expected:
            assert part in err, (what, part, err)


def test_calibrate_and_identify_take_the_same_formats(tmp_path, monkeypatch, capsys):
    """iem identify's loaded and bare recordings in different formats give the result the CAN
    logs give; iem calibrate reads the same joint states from every format (what its
    numerics make of them, 3-25 s a run on this machine, is sim.calibration's tests' matter:
    the run stops once read); both name a bad recording as iem replay does."""
    import deploy.commands.calibrate
    from deploy.commands.calibrate import calibrate_sources, read_states
    from deploy.commands.identify import read_log
    from sim.identify import identify
    from sim.paths import excitation_path
    from sim.plant import RealityGap

    path = excitation_path(4.0, seed=0, period=2.0)
    gap = RealityGap(seed=11)
    loaded = write_formats(tmp_path, ArmPlant(payload=default_test_payload(), seed=1,
                                                gap=gap).follow(path), "loaded")
    bare = write_formats(tmp_path, ArmPlant(seed=2, gap=gap).follow(path), "bare")
    want = identify(read_log(loaded["can"]), bare=read_log(bare["can"]))
    out, summary = tmp_path / "tool.toml", tmp_path / "tool.json"
    assert main(["identify", "--loaded", str(loaded["csv"]), "--bare", str(bare["mcap"]),
                 "--out", str(out), "--json", str(summary)]) == 0
    got = json.loads(summary.read_text())
    np.testing.assert_allclose(list(got["phi"].values()), want.phi, rtol=1e-9, atol=1e-12)
    assert "wrote" in capsys.readouterr().out

    class Read(Exception):
        """Raised with what calibrate_sources read, before its numerics."""

    def stop_after_reading(source, *args):
        raise Read(read_states(source, *args))

    monkeypatch.setattr(deploy.commands.calibrate, "read_states", stop_after_reading)
    read = {}
    for name, path in bare.items():
        with pytest.raises(Read) as info:
            calibrate_sources([path], topic="/franka/joint_states")
        read[name] = info.value.args[0]
    monkeypatch.undo()
    for name, (t, *joints) in read.items():
        assert t.shape == (4001,), name
        np.testing.assert_allclose(t, read["can"][0], rtol=1e-15, atol=0, err_msg=name)
        for a, b in zip(joints, read["can"][1:], strict=True):
            np.testing.assert_array_equal(a, b, err_msg=name)

    bad = tmp_path / "bad.csv"
    bad.write_text(",".join(CSV_COLUMNS[:-1]) + "\n")
    assert main(["identify", "--loaded", str(bad), "--bare", str(bare["csv"]),
                 "--out", str(out)]) == 2
    assert "bad.csv: a joint-state CSV needs the columns" in capsys.readouterr().err
    assert main(["identify", "--loaded", str(loaded["sqlite3"]), "--bare", str(bare["csv"]),
                 "--topic", "/joint_states", "--out", str(out)]) == 2
    assert "no topic /joint_states in the bag" in capsys.readouterr().err
    assert main(["calibrate", str(bad), "--out", str(tmp_path / "arm.msgpack")]) == 2
    assert "missing: tau7" in capsys.readouterr().err
    assert main(["calibrate", str(bare["mcap"]), "--topic", "/joint_states", "--out",
                 str(tmp_path / "arm.msgpack")]) == 2
    assert "no topic /joint_states in the bag" in capsys.readouterr().err
    assert main(["calibrate", str(bare["csv"]), "--format", "rosbag2", "--out",
                 str(tmp_path / "arm.msgpack")]) == 2
    assert "a rosbag2 bag is a directory" in capsys.readouterr().err


def test_iem_run_replays_a_recording_link(files, model_file, tmp_path, capsys):
    """``[link] kind = "recording"`` in cell.toml: the service reads the CSV to its end."""
    cell = write_toml(tmp_path / "cell.toml",
                      cell_config(model_file, {"kind": "recording",
                                               "channel": str(files["csv"])}))
    assert main(["run", "--config", str(cell)]) == 0
    cycles = stopped_summary(capsys.readouterr().err)["cycles"]
    assert cycles == -(-(int(SECONDS * 1000) + 1) // 10)  # block points


def test_iem_run_over_a_recording_never_writes_the_model(files, model_file, tmp_path, capsys):
    """A recorded link (kind "recording" or "replay") never writes ``[model] path``, as ``iem
    replay`` never does without ``--save-model``: no checkpoint while it runs (every 1 s
    here), none at the stop, and a model trained because none was there stays in memory.
    ``iem run`` over a recording overwrote the model file."""
    before, mtime = model_file.read_bytes(), model_file.stat().st_mtime_ns
    doc = cell_config(model_file, {"kind": "recording", "channel": str(files["csv"])},
                      model={"checkpoint_period_s": 1.0})
    assert main(["run", "--config", str(write_toml(tmp_path / "cell.toml", doc))]) == 0
    assert model_file.read_bytes() == before and model_file.stat().st_mtime_ns == mtime
    new = tmp_path / "new.msgpack"
    doc = cell_config(new, {"kind": "replay", "channel": str(files["can"])},
                      model={"train_if_missing": True, "kind": "IEM+phys"},
                      arm={"noise": "sensor"})
    assert main(["run", "--config", str(write_toml(tmp_path / "new.toml", doc))]) == 0
    assert not new.exists()
    assert "trained a model in memory" in capsys.readouterr().err
