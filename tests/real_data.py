"""The real Panda recording, for the tests that measure against it.

A real Franka Emika Panda (no hand) on Gaz et al.'s exciting trajectory 1, 21 s at about
1 kHz with the logger's jitter (GPL-3.0: read where it lies, never copied into this
repository). :func:`real_recording` gives it as ``(t, q, dq, tau)`` or skips the test.

Where it lies: the folder named by the environment variable ``IEM_REAL_DIR`` if it is set,
else ``../shared/real`` beside the repository's folder
(``Path(__file__).resolve().parents[1] / ".." / "shared" / "real"``), holding
``gaz_traj1_{time,positions,velocity,torques}.txt.gz``.
"""

from __future__ import annotations

import gzip
import os
from functools import cache
from pathlib import Path

import numpy as np
import pytest

ENV = "IEM_REAL_DIR"
"""The environment variable that names the recording's folder."""
FILES = {name: f"gaz_traj1_{name}.txt.gz"
         for name in ("time", "positions", "velocity", "torques")}
"""The recording's files in that folder."""


def real_dir() -> Path:
    """The folder the recording is looked for in (``$IEM_REAL_DIR``, else
    ``../shared/real`` beside the repository)."""
    env = os.environ.get(ENV)
    return Path(env) if env else Path(__file__).resolve().parents[1] / ".." / "shared" / "real"


@cache
def _load(folder: Path) -> tuple[np.ndarray, ...]:
    def read(name):
        with gzip.open(folder / FILES[name]) as f:
            return np.loadtxt(f)

    t = read("time").ravel()
    q, dq, tau = (read(name).reshape(-1, 7) for name in ("positions", "velocity", "torques"))
    for a in (t, q, dq, tau):
        a.flags.writeable = False
    return t, q, dq, tau


def real_recording() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(t (N,), q, dq, tau (N, 7))`` of the real recording (s, rad, rad/s, N·m; read-only
    arrays, read once per session), or skip the calling test, saying where it was looked
    for."""
    folder = real_dir()
    missing = [f for f in FILES.values() if not (folder / f).is_file()]
    if missing:
        pytest.skip(f"the real Panda recording is not in {folder} (missing "
                    f"{', '.join(missing)}): set {ENV} to the folder that holds it")
    return _load(folder.resolve())
