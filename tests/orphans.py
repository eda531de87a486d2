"""A child process that must not outlive the program that started it: start the program, let
it print its child's process id, kill the program outright, and see the child end."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

ENDS_WITHIN_S = 10.0


def assert_child_ends_with_its_program(program: str, cwd=None, within_s: float = ENDS_WITHIN_S
                                       ) -> None:
    """Run the Python source ``program`` (it prints its child's process id on a line of its
    own, then waits), kill it with SIGKILL, and assert the child ends within ``within_s``
    (a zombie reaped by init counts as ended); a child still running is killed and named."""
    parent = subprocess.Popen([sys.executable, "-c", program], stdout=subprocess.PIPE,
                              text=True, cwd=cwd)
    try:
        child = int(parent.stdout.readline())
        os.kill(child, 0)  # running
    finally:
        parent.kill()
        parent.wait()
        parent.stdout.close()
    deadline = time.monotonic() + within_s
    while time.monotonic() < deadline:
        try:
            os.kill(child, 0)
        except ProcessLookupError:
            return
        with open(f"/proc/{child}/stat") as f:
            if f.read().split(")")[-1].split()[0] == "Z":
                return
        time.sleep(0.05)
    os.kill(child, signal.SIGKILL)
    raise AssertionError(f"process {child} outlived the program that started it by "
                         f"{within_s:g} s")
