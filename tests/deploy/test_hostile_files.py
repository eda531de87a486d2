"""Hostile files, through the command line as a user runs it: a recording, a model file or a
cell.toml made to hang, exhaust the memory or crash the reader. Each ends within 60 s, with
one ``iem: error:`` line and no traceback, exit 2 (78 for ``iem run``'s configuration), and
its process peaks under 600 MB (``ru_maxrss`` of the child, as ``/usr/bin/time -f %M``
reports it). Before the bounds: a zero-size BLF object looped for ever writing 124 MB of
warnings in 25 s, a 1.5 MB zlib container peaked at 3.2 GB, a 30 MB model header loaded at
2.2 GB, /dev/zero, a FIFO and 5,000 nested brackets hung or crashed."""

from __future__ import annotations

import math
import os
import signal
import struct
import subprocess
import sys
import time
import zlib
from pathlib import Path

import msgpack
import numpy as np
import pytest

from tests.firmware_bridge.test_blf_reader import can_object, container, file_header
from tests.firmware_bridge.test_recordings import write_csv

SECONDS = 60
PEAK_MB = 600
N = 30_000_000  # tiny containers in a 30 MB file


def csv_recording(folder: Path) -> Path:
    t = np.arange(200) * 1e-3
    z = np.zeros((200, 7))
    return write_csv(folder / "ok.csv", t, z + 0.1, z, z + 1.0)


def model_bytes(state_extra: bytes | None = None, header_extra: bytes | None = None) -> bytes:
    """An untrained IEM's model file, with raw msgpack bytes appended to its state's map or
    its header's map (one more key each), the CRC made right."""
    from iem.model_kinds import new_model
    from iem.persistence import _record_crc, dumps

    head = msgpack.unpackb(dumps(new_model("IEM")), raw=False)
    if state_extra is not None:
        state = msgpack.packb(msgpack.unpackb(head["state"], raw=False), use_bin_type=True)
        assert 0x80 <= state[0] <= 0x8E  # a fixmap: one more entry
        head["state"] = bytes([state[0] + 1]) + state[1:] + state_extra
        head["crc32"] = _record_crc(head.get("arm"), zlib.crc32(head["state"]),
                                    head.get("family"), head["version"])
    packed = msgpack.packb(head, use_bin_type=True)
    if header_extra is not None:
        assert 0x80 <= packed[0] <= 0x8E
        packed = bytes([packed[0] + 1]) + packed[1:] + header_extra
    return packed


def cases(tmp_path: Path) -> dict[str, tuple[list[str], int]]:
    """name -> (the iem command line, the exit status it must end with)."""
    rec = str(csv_recording(tmp_path))
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    os.symlink(fifo, tmp_path / "fifo.toml")

    def write(name: str, data: bytes) -> str:
        (tmp_path / name).write_bytes(data)
        return str(tmp_path / name)

    def cell(name: str, text: str) -> str:
        return write(name, text.encode())

    model = write("ok.msgpack", model_bytes())
    replay = ["replay", "--no-status", "--model", model]
    live = f'[link]\nkind = "recording"\nchannel = "{rec}"\n[model]\npath = "{model}"\n' \
           'kind = "IEM"\ntrain_if_missing = false\n[log]\nstatus_line = "off"\n'
    return {
        "blf: an object of size 0": ([*replay, write("loop.blf", file_header() + container(
            can_object(size=0, version=9)))], 2),
        "blf: a zlib bomb": ([*replay, write("bomb.blf", file_header() + container(
            b"\x00" * (200 << 20), 2))], 2),
        "blf: an object of 4 GB": ([*replay, write("claim.blf", file_header() + container(
            can_object(size=0xFFFF_FFF0)) + container(b"\x00" * (128 << 10)) * 80)], 2),
        "csv: t = 1e306": ([*replay, str(write_csv(
            tmp_path / "far.csv", np.r_[np.arange(20) * 1e-3, 1e306], *(np.zeros((21, 7)),) * 3))],
            2),
        "model: 30 M arrays in the header": (["replay", "--no-status", rec, "--model", write(
            "header.msgpack", model_bytes(header_extra=b"\xa4junk\xdd" + struct.pack(">I", N)
                                          + b"\x90" * N))], 2),
        "model: 30 M arrays in the state": (["replay", "--no-status", rec, "--model", write(
            "state.msgpack", model_bytes(state_extra=b"\xa3zzz\xdc" + struct.pack(">H", 300)
                                         + (b"\xdd" + struct.pack(">I", N // 300)
                                            + b"\x90" * (N // 300)) * 300))], 2),
        "model: /dev/zero": (["replay", "--no-status", rec, "--model", "/dev/zero"], 2),
        "model: a FIFO": (["replay", "--no-status", rec, "--model", str(fifo)], 2),
        "cell.toml: 5,000 nested brackets": (["run", "--config", cell(
            "nested.toml", live + "[host]\na = " + "[" * 5000 + "]" * 5000 + "\n")], 78),
        "cell.toml: a FIFO": (["run", "--config", str(fifo)], 78),
        "cell.toml: a FIFO as the end effector": (["run", "--config", cell(
            "ee.toml", live + f'[arm]\nend_effector = "{tmp_path / "fifo.toml"}"\n')], 78),
    }


PEAK_MARK = "iem-peak-kb "
"""How ``/usr/bin/time`` reports the child's peak resident memory on its last stderr line."""


def run_bounded(argv: list[str]) -> tuple[int, float, float, str]:
    """``(status, wall s, peak MB, stderr)`` of ``iem argv`` in a child process, killed (and
    reported as such) after :data:`SECONDS`. The peak is ``/usr/bin/time``'s (``%M``): a
    child's own ``ru_maxrss`` starts from this process's resident size at the fork, which a
    long test session makes hundreds of MB."""
    err_path = Path(os.environ.get("TMPDIR", "/tmp")) / f"iem-hostile-{os.getpid()}.err"
    with open(err_path, "wb") as err:
        t0 = time.monotonic()
        proc = subprocess.Popen(["/usr/bin/time", "-q", "-f", PEAK_MARK + "%M", sys.executable,
                                 "-m", "deploy.cli", *argv], stdout=subprocess.DEVNULL, stderr=err,
                                env={**os.environ, "OPENBLAS_NUM_THREADS": "1"},
                                start_new_session=True)
        try:
            status = proc.wait(SECONDS)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)  # the command and time with it
            proc.wait()
            status = -9
        wall = time.monotonic() - t0
    lines = err_path.read_bytes()[-20_000:].decode("utf-8", "replace").splitlines()
    err_path.unlink()
    peak = [line for line in lines if line.startswith(PEAK_MARK)]
    text = "\n".join(line for line in lines if not line.startswith(PEAK_MARK)) + "\n"
    peak_mb = int(peak[-1].removeprefix(PEAK_MARK)) / 1024 if peak else math.inf
    return status, wall, peak_mb, text


@pytest.fixture(scope="module")
def hostile(tmp_path_factory):
    return cases(tmp_path_factory.mktemp("hostile"))


@pytest.mark.parametrize("name", ["blf: an object of size 0", "blf: a zlib bomb",
                                  "blf: an object of 4 GB", "csv: t = 1e306",
                                  "model: 30 M arrays in the header",
                                  "model: 30 M arrays in the state", "model: /dev/zero",
                                  "model: a FIFO", "cell.toml: 5,000 nested brackets",
                                  "cell.toml: a FIFO", "cell.toml: a FIFO as the end effector"])
def test_a_hostile_file_ends_quickly_and_cleanly(hostile, name):
    argv, expected = hostile[name]
    status, wall, peak_mb, err = run_bounded(argv)
    report = f"{name}: exit {status}, {wall:.1f} s, {peak_mb:.0f} MB\n{err[-2000:]}"
    assert status == expected, report
    assert wall < SECONDS and peak_mb < PEAK_MB, report
    assert "Traceback" not in err, report
    lines = err.strip().splitlines()
    assert lines and lines[-1].startswith("iem: error: "), report
