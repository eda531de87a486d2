"""``iem replay`` of many recordings: a folder, a glob or several paths, in ``--jobs`` processes.

A small fleet: two plant rollouts of 1 s with different payloads and noise seeds, one written
as a CAN log (``tests.can_logs.write_log``), the other as a rosbag2 bag folder, and a CAN log
that is not one. Each recording replayed among the others in two processes must give what
``iem replay`` of that file alone gives, to the byte.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from deploy.cli import main
from deploy.replay.many import recordings_of
from sim.family import default_test_payload
from sim.family import test_payloads as named_test_payloads
from sim.paths import new_task_path
from sim.plant import ArmPlant
from tests.can_logs import write_log
from tests.firmware_bridge.test_recordings import PANDA, write_bag

from ..conftest import REPO

SECONDS = 1.0
RUN_TIME_KEYS = ("wall_s", "speed", "estimates_per_s", "cpu_s", "cpu_parts", "step_cpu_s",
                 "replay_cpu_s", "cpu_speed")
"""Summary keys that measure the run, not the replay: they differ between any two runs."""


@pytest.fixture(scope="module")
def fleet(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("fleet")
    path = new_task_path().slice(0, SECONDS)
    write_log(ArmPlant(payload=default_test_payload(), seed=1).follow(path),
              folder / "a.blf")
    other = ArmPlant(payload=named_test_payloads()["test-4w"], seed=2).follow(path)
    write_bag(folder / "b_bag", [round(float(t) * 1e9) for t in other.t], other.q, other.dq,
              other.tau, names=PANDA)  # the simulated arm is a Panda
    (folder / "bad.blf").write_bytes(b"not a blf file at all" * 10)
    (folder / "notes.txt").write_text("not a recording\n")
    return folder


def test_a_folder_stands_for_its_recordings_and_one_recording_for_itself(tmp_path):
    for name in ("x.blf", "y.csv", "z.mcap", "notes.txt"):
        (tmp_path / name).write_text("")
    (tmp_path / "bag").mkdir()
    (tmp_path / "bag" / "metadata.yaml").write_text("")
    (tmp_path / "plain").mkdir()
    (tmp_path / "plain" / "w.blf").write_text("")  # in a sub-folder: not looked at
    expected = [tmp_path / n for n in ("bag", "x.blf", "y.csv", "z.mcap")]
    assert recordings_of([tmp_path]) == expected
    assert recordings_of([tmp_path], "can") == [tmp_path / "x.blf"]
    assert recordings_of([str(tmp_path / "*.blf"), tmp_path / "y.csv"]) == \
        [tmp_path / "x.blf", tmp_path / "y.csv"]
    assert recordings_of([tmp_path / "x.blf", tmp_path / "x.blf"]) == [tmp_path / "x.blf"]
    assert recordings_of([tmp_path, tmp_path / "plain"]) == [*expected, tmp_path / "plain/w.blf"]
    for one in ("x.blf", "bag", "missing.blf"):  # one recording: replayed as today
        assert recordings_of([tmp_path / one]) is None


def test_an_empty_folder_or_glob_is_an_error_naming_what_was_looked_for(tmp_path, capsys):
    def error(*argv) -> str:
        assert main(["replay", *map(str, argv), "--no-status"]) == 2
        return capsys.readouterr().err

    (tmp_path / "notes.txt").write_text("not a recording\n")
    err = error(tmp_path)
    assert err.startswith(f"iem: error: {tmp_path}: no recording in this folder; looked for "
                          "a CAN log (.blf")
    assert "joint-state CSV" in err
    err = error(tmp_path / "*.blf")
    assert f"'{tmp_path / '*.blf'}' matches nothing: no recording; looked for" in err
    assert "matches 1 paths but no recording" in error(tmp_path / "*.txt")
    assert "no recording in this folder; looked for csv recordings" in \
        error(tmp_path, "--format", "csv")
    with pytest.raises(SystemExit) as usage:
        main(["replay", str(tmp_path), "--jobs", "0"])
    assert usage.value.code == 2
    assert "'0': valid is a whole number of processes, 1 or more" in capsys.readouterr().err


def _without_run_time(summary: dict) -> dict:
    return {k: v for k, v in summary.items() if k not in RUN_TIME_KEYS}


def test_two_jobs_give_each_recording_what_it_gives_alone_and_a_bad_one_costs_its_row(
        fleet, trained_model_file, tmp_path, capsys):
    model = str(trained_model_file)
    out, many_json = tmp_path / "estimates", tmp_path / "many.json"
    assert main(["replay", str(fleet), "--model", model, "--jobs", "2", "--out", str(out),
                 "--json", str(many_json), "--no-status"]) == 2
    captured = capsys.readouterr()
    doc = json.loads(many_json.read_text())
    assert doc["jobs"] == 2
    entries = doc["recordings"]
    assert [Path(e["file"]).name for e in entries] == ["a.blf", "b_bag", "bad.blf"]
    bad = entries[2]
    assert bad["summary"] is None and bad["final_phi"] is None
    assert bad["error"].startswith(f"{fleet / 'bad.blf'}: ")
    assert sorted(p.name for p in out.iterdir()) == ["a.blf.csv", "b_bag.csv"]
    for entry in entries[:2]:
        alone_csv, alone_json = tmp_path / "alone.csv", tmp_path / "alone.json"
        assert main(["replay", entry["file"], "--model", model, "--out", str(alone_csv),
                     "--json", str(alone_json), "--no-status"]) == 0
        name = Path(entry["file"]).name
        assert entry["error"] is None
        assert (out / f"{name}.csv").read_bytes() == alone_csv.read_bytes()
        alone = json.loads(alone_json.read_text())
        assert _without_run_time(entry["summary"]) == _without_run_time(alone)
        last = np.loadtxt(alone_csv, delimiter=",", skiprows=1)[-1]
        assert entry["final_phi"] == last[13:23].tolist()  # the last smoothed estimate
    assert entries[0]["final_phi"] != entries[1]["final_phi"]  # two payloads, two rows
    table = captured.out[captured.out.index("recording "):].splitlines()
    assert table[0].split() == ["recording", "frames", "recorded", "s", "wall", "s", "speed",
                                "mass", "kg", "CoM", "mm", "error"]
    a_row = table[1].split()
    assert a_row[0] == str(fleet / "a.blf")
    assert a_row[1] == str(entries[0]["summary"]["frames"]["received"])
    assert float(a_row[5]) == pytest.approx(entries[0]["final_phi"][0], abs=1e-4)
    assert table[3].startswith(str(fleet / "bad.blf")) and bad["error"] in table[3]
    assert table[4].startswith("3 recordings, 1 failed, in ")
    assert f"iem: error: 1 of 3 recordings failed: {fleet / 'bad.blf'}" in captured.err


def _children(pid: int) -> list[int]:
    """The pids of ``pid``'s replay processes (multiprocessing's spawned children)."""
    found = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            ppid = int(stat.read_text().rsplit(")", 1)[1].split()[1])
            cmdline = (stat.parent / "cmdline").read_bytes()
        except (OSError, IndexError, ValueError):
            continue
        if ppid == pid and b"spawn_main" in cmdline:
            found.append(int(stat.parent.name))
    return found


def _gone(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] == "Z"
    except OSError:
        return True


def _as_from_a_terminal() -> None:
    """Ctrl-C as a terminal delivers it: SIGINT at its default in the child. A shell without
    job control starts a background command (``make test &``) with SIGINT ignored, every
    process below inherits that, and Python keeps an ignored SIGINT ignored."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def test_ctrl_c_stops_the_children(fleet, tmp_path):
    """Without ``--model`` each child first trains a fresh model (seconds of work), so a
    Ctrl-C that only stopped the parent would leave them to finish and write their CSVs."""
    out = tmp_path / "estimates"
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
    proc = subprocess.Popen([sys.executable, "-m", "deploy.cli", "replay", str(fleet),
                             "--jobs", "2", "--out", str(out), "--no-status"], cwd=REPO,
                            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            preexec_fn=_as_from_a_terminal)
    try:
        deadline = time.monotonic() + 60
        while len(children := _children(proc.pid)) < 2 and time.monotonic() < deadline:
            assert proc.poll() is None, proc.stderr.read().decode()
            time.sleep(0.05)
        assert len(children) == 2
        proc.send_signal(signal.SIGINT)
        code = proc.wait(timeout=60)
        assert code == 130, proc.stderr.read().decode()[-3000:]
    finally:
        proc.kill()
        proc.wait()
    assert all(_gone(pid) for pid in children)
    assert list(out.iterdir()) == []  # no replay finished
