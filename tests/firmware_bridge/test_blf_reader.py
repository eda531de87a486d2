"""The BLF reader within bounds (:mod:`firmware_bridge.blf_reader`): it reads the frames
python-can's reader reads, and every file that breaks a bound ends at once with an error
naming the byte and the bound, where python-can's reader loops forever, inflates without
limit or re-joins an object with every container after it."""

from __future__ import annotations

import re
import struct
import zlib

import can
import numpy as np
import pytest
from can.io.blf import (
    CAN_FD_MESSAGE_64,
    CAN_FD_MSG_64_STRUCT,
    CAN_MESSAGE,
    CAN_MSG_STRUCT,
    FILE_HEADER_SIZE,
    FILE_HEADER_STRUCT,
    LOG_CONTAINER,
    LOG_CONTAINER_STRUCT,
    OBJ_HEADER_BASE_STRUCT,
    OBJ_HEADER_V1_STRUCT,
)

from firmware_bridge.blf_reader import MAX_CONTAINER_BYTES, BlfError, BlfReader
from firmware_bridge.errors import LogFileError
from firmware_bridge.replay import ReplaySource
from tests.watchdog import within


# -- a BLF file, object by object ----------------------------------------------------------
def file_header(size: int = FILE_HEADER_SIZE) -> bytes:
    head = FILE_HEADER_STRUCT.pack(b"LOGG", size, 5, 0, 0, 0, 2, 6, 8, 1, 0, 0, 0, 0,
                                   *([0] * 8), *([0] * 8))
    return head + b"\x00" * (FILE_HEADER_SIZE - len(head))


def container(data: bytes, method: int = 0) -> bytes:
    body = data if method == 0 else zlib.compress(data, 9)
    size = OBJ_HEADER_BASE_STRUCT.size + LOG_CONTAINER_STRUCT.size + len(body)
    return (OBJ_HEADER_BASE_STRUCT.pack(b"LOBJ", 16, 1, size, LOG_CONTAINER)
            + LOG_CONTAINER_STRUCT.pack(method, len(data)) + body + b"\x00" * (size % 4))


def can_object(ticks: int = 0, can_id: int = 0x100, size: int | None = None,
               version: int = 1) -> bytes:
    body = (OBJ_HEADER_V1_STRUCT.pack(2, 0, 0, ticks)
            + CAN_MSG_STRUCT.pack(1, 0, 8, can_id, bytes(range(8))))
    size = OBJ_HEADER_BASE_STRUCT.size + len(body) if size is None else size
    return OBJ_HEADER_BASE_STRUCT.pack(b"LOBJ", 32, version, size, CAN_MESSAGE) + body


def write(path, *parts: bytes):
    path.write_bytes(b"".join(parts))
    return path


def same(a: can.Message, b: can.Message) -> bool:
    keys = ("timestamp", "arbitration_id", "is_extended_id", "is_remote_frame", "is_rx",
            "is_error_frame", "is_fd", "bitrate_switch", "error_state_indicator", "dlc",
            "data", "channel")
    return all(getattr(a, k) == getattr(b, k) for k in keys)


# -- the frames python-can reads -----------------------------------------------------------
def test_it_reads_the_frames_python_can_reads(tmp_path):
    """Every kind of frame python-can's writer writes (CAN, CAN FD with and without bit-rate
    switch, remote and error frames, extended IDs, both directions), across containers,
    compressed: the same frames, time stamps to the bit."""
    rng = np.random.default_rng(0)
    frames = []
    for k in range(3000):
        kind = k % 5
        data = bytes(rng.integers(0, 256, 64 if kind == 1 else 8, dtype=np.uint8))
        frames.append(can.Message(
            timestamp=1000.0 + k * 1.37e-3, arbitration_id=int(rng.integers(0, 0x7FF)),
            is_extended_id=kind == 2, is_remote_frame=kind == 3, is_error_frame=kind == 4,
            is_fd=kind == 1, bitrate_switch=kind == 1, is_rx=bool(k % 2),
            data=b"" if kind == 3 else data, dlc=8 if kind != 1 else 64, channel=0))
    path = tmp_path / "traffic.blf"
    with can.Logger(str(path)) as log:
        for msg in frames:
            log.on_message_received(msg)
    theirs = list(can.io.blf.BLFReader(str(path)))
    with BlfReader(path) as reader:
        ours = list(reader)
    assert len(theirs) == len(frames) == len(ours)
    assert all(same(a, b) for a, b in zip(theirs, ours, strict=True))


def test_it_reads_a_can_fd_64_object_as_python_can(tmp_path):
    """Vector's own CAN FD object (type 101), which python-can reads but does not write."""
    payload = bytes(range(64))
    fields = CAN_FD_MSG_64_STRUCT.pack(2, 15, 64, 0, 0x8000_0123, 0, 0x3001, 0, 0, 0, 0, 0,
                                       0, 0, 0)
    body = OBJ_HEADER_V1_STRUCT.pack(1, 0, 0, 123_456) + fields + payload
    size = OBJ_HEADER_BASE_STRUCT.size + len(body)
    obj = OBJ_HEADER_BASE_STRUCT.pack(b"LOBJ", 32, 1, size, CAN_FD_MESSAGE_64) + body
    path = write(tmp_path / "fd64.blf", file_header(), container(obj + can_object(), 2))
    theirs = list(can.io.blf.BLFReader(str(path)))
    ours = list(BlfReader(path))
    assert len(ours) == len(theirs) == 2 and all(map(same, theirs, ours))
    assert ours[0].is_fd and ours[0].data == payload and ours[0].arbitration_id == 0x123


def test_an_object_split_over_containers_is_joined(tmp_path):
    """Writers split objects across containers: a 300 kB object of a type it skips, over
    three containers, then a frame."""
    big = OBJ_HEADER_BASE_STRUCT.pack(b"LOBJ", 32, 1, 300_000, 999) + b"\x00" * (300_000 - 16)
    stream = big + can_object(ticks=5)
    parts = [container(stream[i:i + 128_000]) for i in range(0, len(stream), 128_000)]
    path = write(tmp_path / "split.blf", file_header(), *parts)
    with within(10):
        frames = list(BlfReader(path))
    assert [f.timestamp for f in frames] == [5e-9]


# -- files that break a bound --------------------------------------------------------------
BOMB = 80 * 1024 * 1024  # inflated bytes of the zlib bomb: past the 64 MB bound

HOSTILE = {
    "empty": ((b"",), "empty (0 bytes): a BLF file starts with its header"),
    "cut header": ((file_header()[:50],), "50 bytes, shorter than a BLF file's header"),
    "not BLF": ((b"MDF " + b"\x00" * 200,), "not a BLF file, which starts with 'LOGG'"),
    "header of 4 GB": ((file_header(0xFFFF_FFF0),), "its header declares 4294967280 bytes; "
                       "valid is 72 to 65536"),
    "object of size 0": ((file_header(), container(can_object(size=0))),
                         "an object of type 1 of 0 bytes, less than the 48"),
    "object of size 0, unknown header": ((file_header(), container(can_object(size=0,
                                                                               version=9))),
                                         "of 0 bytes, less than the 32"),
    "object smaller than its header": ((file_header(), container(can_object(size=8))),
                                       "of 8 bytes, less than the 48"),
    "container of 4 GB": ((file_header(), OBJ_HEADER_BASE_STRUCT.pack(
        b"LOBJ", 16, 1, 0xFFFF_FFF0, LOG_CONTAINER)),
        "byte 144: an object of 4096 MB; valid is at most 64 MB"),
    "inner object of 4 GB": ((file_header(), container(can_object(size=0xFFFF_FFF0)),
                              container(b"\x00" * 1000)),
                             "the container at byte 144: an object of 4096 MB"),
    "zlib bomb": ((file_header(), container(b"\x00" * BOMB, 2)),
                  "byte 144: a container that inflates beyond 64 MB"),
    "not zlib": ((file_header(), container(b"\x00" * 64)[:16]
                  + struct.pack("<H", 2) + container(b"\x00" * 64)[18:]),
                 "a container that does not inflate"),
    "unknown compression": ((file_header(), container(b"\x00" * 64)[:16]
                             + struct.pack("<H", 7) + container(b"\x00" * 64)[18:]),
                            "compression method 7; valid are 0 (none) and 2 (zlib)"),
    "garbage between objects": ((file_header(), container(can_object() + b"\xff" * 40)),
                                "no object where one should start"),
}


@pytest.mark.parametrize("name", sorted(HOSTILE))
def test_a_file_that_breaks_a_bound_ends_with_a_clear_error(tmp_path, name):
    parts, message = HOSTILE[name]
    path = write(tmp_path / "hostile.blf", *parts)
    with within(10), pytest.raises(BlfError, match=re.escape(message)), \
            BlfReader(path) as reader:
        for _ in reader:
            pass


def test_the_bound_is_the_documented_one():
    assert MAX_CONTAINER_BYTES == 64 * 1024 * 1024 < BOMB


def test_a_file_cut_inside_a_container_ends_with_the_whole_objects_it_holds(tmp_path):
    """A file that ends inside a container is not an error: the whole objects before the
    cut are read, as python-can reads them, and the reading ends (the replay says
    truncated). python-can raises struct.error on a file cut inside a container's header."""
    whole = container(can_object(ticks=1) + can_object(ticks=2))
    for cut, stamps in ((10, [1e-9, 2e-9]), (30, [1e-9, 2e-9]),
                        (len(whole) - 5, [1e-9, 2e-9, 1e-9])):
        path = write(tmp_path / "cut.blf", file_header(), whole, whole[:cut])
        assert [f.timestamp for f in BlfReader(path)] == stamps, cut
    assert [f.timestamp for f in can.io.blf.BLFReader(str(path))] == stamps


# -- through the replay --------------------------------------------------------------------
def test_the_replay_of_a_hostile_file_is_a_clear_log_file_error(tmp_path):
    """The zero-size object that loops python-can's reader forever: ``ReplaySource`` says
    what is wrong and where, at once."""
    path = write(tmp_path / "loop.blf", file_header(), container(can_object(size=0,
                                                                            version=9)))
    with within(10), pytest.raises(LogFileError, match=r"loop.blf: the container at byte "
                                                       r"144: an object of type 1 of 0 bytes"):
        list(ReplaySource(path))


def test_the_replay_keeps_what_comes_before_damage(tmp_path, caplog):
    """A container that breaks a bound after good ones: the frames before it are replayed,
    the log is marked truncated, and the warning says where and why."""
    good = container(b"".join(can_object(ticks=t) for t in range(10)))
    path = write(tmp_path / "late.blf", file_header(), good, container(b"\x00" * BOMB, 2))
    with within(10):
        source = ReplaySource(path)
        list(source)
    assert source.frames == 10 and source.truncated
    assert "inflates beyond 64 MB" in caplog.text
