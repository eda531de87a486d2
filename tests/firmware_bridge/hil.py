"""Helpers to run the simulated controller in another process and to probe for vcan."""

from __future__ import annotations

import os
import selectors
import socket
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


class Controller:
    """``iem sim-controller`` in a child process (``python -m deploy.cli``, repo as cwd)."""

    def __init__(self, args: list[str], log: Path, announce: bool, timeout: float = 30.0):
        self.log = log
        self._err = open(log, "w")  # noqa: SIM115 - closed in stop()
        self.proc = subprocess.Popen([sys.executable, "-m", "deploy.cli", "sim-controller",
                                      *args], cwd=REPO, stdout=subprocess.PIPE,
                                     stderr=self._err, text=True)
        self.line = self._first_line(timeout) if announce else None

    def _first_line(self, timeout: float) -> str:
        sel = selectors.DefaultSelector()
        sel.register(self.proc.stdout, selectors.EVENT_READ)
        ready = sel.select(timeout)
        sel.close()
        line = self.proc.stdout.readline().strip() if ready else ""
        if not line:
            self.stop()
            raise RuntimeError(f"sim-controller did not announce itself within {timeout} s: "
                               f"{self.log.read_text()}")
        return line

    def stop(self) -> str:
        """Terminate (then kill) the child, wait for it; return what it wrote to stderr."""
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(10)
        self.proc.stdout.close()
        self._err.close()
        return self.log.read_text()


def vcan_unavailable() -> str | None:
    """Why vcan tests cannot run here, or None if vcan0 is (or was made) available."""
    if not hasattr(socket, "AF_CAN"):
        return "this Python has no socket.AF_CAN: vcan tests need Linux SocketCAN"
    try:
        socket.socket(socket.AF_CAN, socket.SOCK_RAW, socket.CAN_RAW).close()
    except OSError as exc:
        return (f"this kernel has no AF_CAN (socket(AF_CAN, SOCK_RAW, CAN_RAW) failed: {exc}); "
                "vcan tests run where 'ip link add dev vcan0 type vcan' works")
    if os.path.exists("/sys/class/net/vcan0"):
        try:
            with open("/sys/class/net/vcan0/mtu") as f:
                mtu = int(f.read())
        except (OSError, ValueError):
            mtu = 72
        if mtu < 72:
            return (f"vcan0 has MTU {mtu}: it drops CAN FD frames; run "
                    "'sudo deploy/setup-vcan.sh vcan' (ip link set vcan0 mtu 72)")
        return None
    for cmd in (["ip", "link", "add", "dev", "vcan0", "type", "vcan"],
                ["ip", "link", "set", "vcan0", "mtu", "72"],  # vcan drops FD frames below 72
                ["ip", "link", "set", "up", "vcan0"]):
        try:
            done = subprocess.run(cmd, capture_output=True, text=True, timeout=10)
        except (OSError, subprocess.TimeoutExpired) as exc:
            return f"'{' '.join(cmd)}' could not run: {exc}"
        if done.returncode:
            return f"'{' '.join(cmd)}' failed: {done.stderr.strip() or done.returncode}"
    return None
