"""Shared pieces of the plug-in's end-to-end tests: private copies of the session's trained
models (tests/conftest.py), controllers, configs."""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]


def _private_copy(trained: Path, tmp_path: Path, name: str) -> Path:
    """A copy of a trained model file that one test may overwrite."""
    path = tmp_path / name
    shutil.copyfile(trained, path)
    return path


@pytest.fixture
def model_file(trained_model_file, tmp_path) -> Path:
    return _private_copy(trained_model_file, tmp_path, "model.msgpack")


@pytest.fixture
def phys_model_file(trained_phys_model_file, tmp_path) -> Path:
    return _private_copy(trained_phys_model_file, tmp_path, "model-phys.msgpack")


@pytest.fixture
def fr3_phys_model_file(trained_fr3_phys_model_file, tmp_path) -> Path:
    return _private_copy(trained_fr3_phys_model_file, tmp_path, "model-fr3.msgpack")


def model_kind(path) -> str:
    """The kind a model file holds (its ``kind`` field): what its ``[model] kind`` must be."""
    import msgpack

    return msgpack.unpackb(Path(path).read_bytes(), raw=False)["kind"]


def cell_config(model_path, link: dict, **sections) -> dict:
    """A cell.toml as a dict: the given link, the model file and the kind it holds (if it
    exists), no status line; the gate lets a model without uncertainty write (the paper's
    IEM of ``model_file`` needs it; IEM+phys reports it, so it changes nothing there)."""
    model = {"path": str(model_path), "train_if_missing": False}
    if Path(model_path).exists():
        model["kind"] = model_kind(model_path)
    doc = {"link": link, "model": model,
           "gate": {"allow_without_uncertainty": True},
           "log": {"status_line": "off", "level": "info", "format": "json"}}
    for name, table in sections.items():
        doc.setdefault(name, {}).update(table)
    return doc


def write_toml(path: Path, doc: dict) -> Path:
    lines = []
    for section, table in doc.items():
        lines.append(f"[{section}]")
        for key, value in table.items():
            if isinstance(value, bool):
                text = "true" if value else "false"
            elif isinstance(value, str):
                text = '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
            else:
                text = repr(value)
            lines.append(f"{key} = {text}")
        lines.append("")
    path.write_text("\n".join(lines))
    return path


def new_task_csv(path: Path) -> Path:
    from sim.paths import new_task_path, save_path_csv

    save_path_csv(new_task_path(), path)
    return path


@contextlib.contextmanager
def controller_process(*args: str, timeout: float = 30.0):
    """``iem sim-controller`` in its own process on a pty; yields ``(process, pty path)``.

    The process is stopped (SIGTERM, then SIGKILL) and waited for on the way out.
    """
    cmd = [sys.executable, "-m", "deploy.cli", "sim-controller", *args]
    proc = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, env={**os.environ, "PYTHONUNBUFFERED": "1"})
    try:
        line = proc.stdout.readline().strip()
        if not line.startswith("/dev/"):
            proc.kill()
            _, err = proc.communicate(timeout=timeout)
            raise RuntimeError(f"sim-controller did not announce its pty: {line!r}; {err}")
        yield proc, line
    finally:
        stop_process(proc)


def stop_process(proc: subprocess.Popen, timeout: float = 10.0) -> tuple[str, str]:
    """Stop ``proc`` (SIGTERM, then SIGKILL), wait for it; its remaining ``(stdout, stderr)``.

    Safe to call twice: the second call returns what the first collected.
    """
    done = getattr(proc, "_collected", None)
    if done is not None:
        return done
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
    try:
        out, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, err = proc.communicate(timeout=timeout)
    proc._collected = (out or "", err or "")
    return proc._collected


def service_process(config: Path, *extra: str) -> subprocess.Popen:
    """``iem run --config`` in its own process (its JSON logs on stderr)."""
    return subprocess.Popen([sys.executable, "-m", "deploy.cli", "run", "--config",
                             str(config), *extra], cwd=REPO, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"})


def fatal_line(err: str) -> str:
    """The failure ``iem`` ended with, as ``iem: error: <message>``, from its stderr ``err``:
    the last line, or, in ``iem run``'s JSON logging, its ``fatal`` record."""
    import json

    last = err.strip().splitlines()[-1]
    if last.startswith("{"):
        record = json.loads(last)
        assert record.get("event") == "fatal", last
        return f"iem: error: {record['msg']}"
    return last


def stopped_summary(logs: str) -> dict:
    """The summary of ``iem run``'s ``stopped`` event in its JSON logs ``logs``."""
    import json

    events = [json.loads(line) for line in logs.splitlines() if line.startswith("{")]
    stopped = [e for e in events if e.get("event") == "stopped"]
    assert len(stopped) == 1, logs
    return stopped[0]["summary"]


def wait_for(predicate, timeout: float, step: float = 0.1):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(step)
    return None
