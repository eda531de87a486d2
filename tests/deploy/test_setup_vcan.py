"""deploy/setup-vcan.sh runs the right commands: checked with fake ``ip``, ``modprobe`` and
``id`` first on PATH that log their arguments (no root, no kernel CAN needed)."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[2] / "deploy" / "setup-vcan.sh"

FAKE = """#!/bin/sh
echo "$(basename "$0") $*" >> "$FAKE_LOG"
if [ "$(basename "$0")" = id ]; then echo 0; exit 0; fi
if [ "$1 $2" = "link show" ]; then exit "${IP_SHOW_RC:-1}"; fi
exit 0
"""


def run(tmp_path: Path, *args: str, show_rc: int = 1) -> tuple[int, list[str], str]:
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir(exist_ok=True)
    for name in ("ip", "modprobe", "id"):
        tool = bin_dir / name
        tool.write_text(FAKE)
        tool.chmod(0o755)
    log = tmp_path / "calls.log"
    log.write_text("")
    env = {**os.environ, "PATH": f"{bin_dir}:{os.environ['PATH']}", "FAKE_LOG": str(log),
           "IP_SHOW_RC": str(show_rc)}
    done = subprocess.run(["bash", str(SCRIPT), *args], env=env, capture_output=True,
                          text=True, timeout=30)
    calls = [line for line in log.read_text().splitlines() if not line.startswith("id ")]
    return done.returncode, calls, done.stdout + done.stderr


def test_vcan_is_made_fd_capable(tmp_path):
    rc, calls, out = run(tmp_path, "vcan")
    assert rc == 0, out
    assert calls == ["modprobe vcan",
                     "ip link show dev vcan0",
                     "ip link add dev vcan0 type vcan",
                     "ip link set vcan0 down",
                     "ip link set vcan0 mtu 72",
                     "ip link set vcan0 up"]
    assert "mtu 72" in out


def test_an_existing_vcan_gets_the_fd_mtu_too(tmp_path):
    rc, calls, _ = run(tmp_path, "vcan", "vcan1", show_rc=0)
    assert rc == 0
    assert "ip link set vcan1 mtu 72" in calls
    assert not any(c.startswith("ip link add") for c in calls)


def test_can_gets_restart_ms(tmp_path):
    rc, calls, out = run(tmp_path, "can", "can0", show_rc=0)
    assert rc == 0, out
    assert ("ip link set can0 type can bitrate 1000000 dbitrate 5000000 fd on restart-ms 100"
            in calls)
    assert calls[-1] == "ip link set can0 up"


@pytest.mark.parametrize(("args", "message"), [
    (("can",), "'can' needs an interface name"),
    (("can", "can0", "fast", "5000000"), "BITRATE must be a positive integer"),
    (("frob",), "unknown command 'frob'"),
])
def test_bad_arguments_exit_2_with_a_reason(tmp_path, args, message):
    rc, calls, out = run(tmp_path, *args)
    assert rc == 2 and message in out and calls == []
