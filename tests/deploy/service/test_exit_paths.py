"""How ``iem run`` ends, whatever ends it: the first failure first, the errors that followed it
after it, then the summary of what it did.

The controller here is ``iem sim-controller`` in a process of its own behind a pty (an slcan
adapter, a serial link), killed under a running ``iem run``: the link fails to receive, and
then fails to close, as a vanished adapter does.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time

import pytest

from ..conftest import REPO, cell_config, controller_process, write_toml

pytestmark = pytest.mark.hil

FIRST_ERROR = {"slcan-pty": "receiving failed", "serial-pty": "reading failed"}
"""What each link says when its controller's end of the pty has gone."""

RUNNING_S = 60.0
"""How long ``iem run`` may take to send its first load (start-up, a few s on a busy machine)."""


class Run:
    """``iem run --config CONFIG`` in a process of its own; its stdout and stderr lines, as
    they come."""

    def __init__(self, config) -> None:
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "deploy.cli", "run", "--config", str(config)], cwd=REPO,
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
            env={**os.environ, "PYTHONUNBUFFERED": "1"})
        self.out: list[str] = []
        self.err: list[str] = []
        self._pumps = [self._pump(self.proc.stdout, self.out),
                       self._pump(self.proc.stderr, self.err)]

    @staticmethod
    def _pump(stream, lines: list) -> threading.Thread:
        def pump() -> None:
            for line in stream:
                lines.append(line.rstrip("\n"))

        thread = threading.Thread(target=pump, daemon=True)
        thread.start()
        return thread

    def wait_for_a_write(self) -> None:
        """Until it has sent a load: it is estimating, points have run."""
        deadline = time.monotonic() + RUNNING_S
        while not any("load sent" in line for line in self.err):
            assert self.proc.poll() is None and time.monotonic() < deadline, self.err
            time.sleep(0.05)

    def end(self, timeout: float = 30.0) -> int:
        try:
            status = self.proc.wait(timeout)
        finally:
            if self.proc.poll() is None:
                self.proc.kill()
                self.proc.wait(10)
            for pump in self._pumps:
                pump.join(5)
        return status


def _config(tmp_path, model_file, interface: str, pty: str, fmt: str):
    link = {"kind": interface.removesuffix("-pty"), "channel": pty, "silence_timeout_s": 0.5}
    return write_toml(tmp_path / "cell.toml", cell_config(model_file, link,
                                                          log={"format": fmt}))


@pytest.mark.parametrize("interface,fmt", [("slcan-pty", "text"), ("serial-pty", "json")])
def test_a_vanished_controller_shows_its_first_error_then_the_summary(
        phys_model_file, tmp_path, interface, fmt):
    with controller_process("--interface", interface, "--duration", "120") as (ctl, pty):
        run = Run(_config(tmp_path, phys_model_file, interface, pty, fmt))
        try:
            run.wait_for_a_write()
            ctl.send_signal(signal.SIGKILL)
            ctl.wait(10)
        finally:
            status = run.end()
    assert status == 2, run.err  # a link failure: systemd restarts it
    if fmt == "json":
        records = [json.loads(line) for line in run.err]  # every line: the fatal one too
        fatal = [r for r in records if r.get("event") == "fatal"]
        assert len(fatal) == 1 and FIRST_ERROR[interface] in fatal[0]["msg"], fatal
        assert fatal[0]["level"] == "error" and fatal[0]["error_type"] == "LinkError"
        stopped = [r for r in records if r.get("event") == "stopped"]
        assert len(stopped) == 1 and records.index(fatal[0]) < records.index(stopped[0])
        summary = stopped[0]["summary"]
        assert summary["cycles"] > 0 and summary["writes"]["sent"] >= 1
    else:
        errors = [line for line in run.err if line.startswith("iem: error:")]
        assert len(errors) == 1 and FIRST_ERROR[interface] in errors[0], run.err
        # the link then failed to close too: after it, never in its place
        first = run.err.index(errors[0])
        follow = [i for i, line in enumerate(run.err) if "closing the bus failed" in line]
        assert follow and min(follow) > first, run.err
        assert run.err[min(follow)].startswith("iem: and while closing the link:")
    # the summary, in words, as iem demo prints it
    assert run.out and run.out[0].startswith("summary (IEM+phys"), run.out
    assert any(line.startswith("  writes: ") and " sent, " in line for line in run.out), run.out


def test_a_stopped_run_prints_its_summary_and_logs_it_as_json(phys_model_file, tmp_path):
    with controller_process("--interface", "serial-pty", "--duration", "120") as (_, pty):
        run = Run(_config(tmp_path, phys_model_file, "serial-pty", pty, "json"))
        try:
            run.wait_for_a_write()
            run.proc.send_signal(signal.SIGTERM)  # as systemd stops it
        finally:
            status = run.end()
    assert status == 0, run.err
    records = [json.loads(line) for line in run.err]
    assert not [r for r in records if r.get("event") == "fatal"]
    stopped = [r for r in records if r.get("event") == "stopped"]
    assert len(stopped) == 1, run.err
    summary = stopped[0]["summary"]
    assert summary["cycles"] > 0 and summary["writes"]["sent"] >= 1
    w = summary["writes"]
    assert f"  writes: {w['sent']} sent, {w['acked']} acknowledged, " in "\n".join(run.out)
    assert any(line.startswith(f"  bags {summary['bags']}; {summary['estimates']} estimates")
               for line in run.out), run.out
