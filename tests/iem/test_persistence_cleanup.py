"""Temporary files of interrupted saves: left by a killed process, removed at the next start."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

from iem.atomic_file import remove_stale_temporaries
from iem.ensemble import IncrementalEnsemble
from iem.persistence import load_model, save_model

REPO = Path(__file__).resolve().parents[2]

KILLED_MID_SAVE = """
import os, signal, sys
from iem.ensemble import IncrementalEnsemble
from iem.persistence import save_model
# SIGKILL this process the moment save_model syncs its temporary file: the save is cut off
# where a kill -9 or a power loss would cut it, after the data was written, before the rename
os.fsync = lambda fd: os.kill(os.getpid(), signal.SIGKILL)
save_model(IncrementalEnsemble(seed=2), sys.argv[1])
"""


def kill_mid_save(path: Path) -> None:
    """Run a save of ``path`` in a child process that is SIGKILLed in the middle."""
    proc = subprocess.run([sys.executable, "-c", KILLED_MID_SAVE, str(path)], cwd=REPO,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == -signal.SIGKILL, proc.stderr


def test_a_killed_save_leaves_its_temporary_file_and_the_next_start_removes_it(tmp_path):
    model = tmp_path / "model.msgpack"
    save_model(IncrementalEnsemble(seed=1), model)
    before = model.read_bytes()
    kill_mid_save(model)
    left = [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")]
    assert len(left) == 1 and left[0].name.startswith(".model.msgpack.")
    assert left[0].stat().st_size > 0  # the new data, never renamed
    assert model.read_bytes() == before  # the last good file is untouched
    assert remove_stale_temporaries(model) == left
    assert sorted(p.name for p in tmp_path.iterdir()) == ["model.msgpack"]
    assert load_model(model).name == "IEM"
    assert remove_stale_temporaries(model) == []  # nothing left to do


def test_only_its_own_pattern_of_dead_processes_next_to_the_model_is_removed(tmp_path):
    model = tmp_path / "model.msgpack"
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)
    dead_pid = int(dead.stdout)
    ours = tmp_path / f".model.msgpack.{dead_pid}.0123abcd.tmp"
    keep = [
        tmp_path / f".model.msgpack.{os.getpid()}.0123abcd.tmp",  # a live save (this process)
        tmp_path / f".other.msgpack.{dead_pid}.0123abcd.tmp",     # another target's
        tmp_path / f".model.msgpack.{dead_pid}.0123ABCD.tmp",     # not save_model's token
        tmp_path / f".model.msgpack.{dead_pid}.0123abcd.tmp.bak",
        tmp_path / f"model.msgpack.{dead_pid}.0123abcd.tmp",      # no leading dot
        tmp_path / "model.msgpack.tmp",
    ]
    for p in (ours, *keep):
        p.write_bytes(b"x")
    sub = tmp_path / "sub"
    sub.mkdir()
    elsewhere = sub / ours.name  # the same name in another folder: not next to the model
    elsewhere.write_bytes(b"x")
    assert remove_stale_temporaries(model) == [ours]
    assert all(p.exists() for p in keep) and elsewhere.exists()


def test_a_missing_folder_is_nothing_to_clean(tmp_path):
    assert remove_stale_temporaries(tmp_path / "nope" / "model.msgpack") == []


def test_the_service_start_removes_them(tmp_path, caplog):
    import logging

    from deploy.config import config_from_dict
    from deploy.model.setup import load_or_train_model

    model = tmp_path / "model.msgpack"
    save_model(IncrementalEnsemble(seed=1), model)
    kill_mid_save(model)
    config = config_from_dict({"model": {"path": str(model), "train_if_missing": False,
                                         "kind": "IEM"}})
    with caplog.at_level(logging.INFO, logger="iem.service"):
        loaded = load_or_train_model(config)
    assert loaded.name == "IEM"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["model.msgpack"]
    assert any(getattr(r, "event", "") == "stale_temporary_removed" for r in caplog.records)
