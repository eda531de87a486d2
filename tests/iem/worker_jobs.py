"""Jobs for the learning worker's tests: picklable (module level, light imports), since a
background worker runs its jobs in a child process."""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class FileGate:
    """A job that holds the worker until the file ``path`` exists (so no training can land
    meanwhile); it creates ``path.started`` when it begins."""

    path: str

    def __call__(self, trainer) -> None:
        Path(self.path + ".started").touch()
        end = time.monotonic() + 60
        while not Path(self.path).exists():
            assert time.monotonic() < end, "the gate was never released"
            time.sleep(0.005)

    def started(self, timeout: float = 60) -> bool:
        end = time.monotonic() + timeout
        while not Path(self.path + ".started").exists():
            if time.monotonic() > end:
                return False
            time.sleep(0.005)
        return True

    def release(self) -> None:
        Path(self.path).touch()


def boom(trainer) -> None:
    raise ValueError("bad batch")


@dataclass(frozen=True)
class Touch:
    """A job that creates the file ``path``."""

    path: str

    def __call__(self, trainer) -> None:
        Path(self.path).touch()


def burn(trainer) -> None:
    """30 ms of CPU."""
    end = time.thread_time() + 0.03
    while time.thread_time() < end:
        pass


def gone(pid: int) -> bool:
    """Whether process ``pid`` has ended (absent, or a zombie no one reaped yet)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] in ("Z", "X")
    except FileNotFoundError:
        return True


def wait_gone(pid: int, timeout: float = 60) -> bool:
    end = time.monotonic() + timeout
    while not gone(pid):
        if time.monotonic() > end:
            return False
        time.sleep(0.02)
    return True
