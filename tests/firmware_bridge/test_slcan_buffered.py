"""slcan_buffered.py overrides private members of python-can's slcan bus; this test fails as
soon as a python-can release changes or drops them (pyproject.toml pins the versions)."""

from __future__ import annotations

import contextlib
import inspect
import os
import queue
import re
import time
from importlib.metadata import version
from pathlib import Path

import can
import pytest
import serial
from can.interfaces.slcan import slcanBus

from firmware_bridge.slcan_buffered import BufferedSlcanBus

PYPROJECT = Path(__file__).resolve().parents[2] / "pyproject.toml"


def test_the_installed_python_can_is_within_the_pin():
    pin = re.search(r'"python-can>=([\d.]+),<([\d.]+)"', PYPROJECT.read_text())
    assert pin, "pyproject.toml must pin python-can to a range (slcan_buffered.py)"
    lo, hi = (tuple(int(x) for x in v.split(".")) for v in pin.groups())
    installed = tuple(int(x) for x in version("python-can").split(".")[:3])
    assert lo <= installed < hi, (installed, lo, hi)


def test_the_private_members_it_overrides_or_uses_are_there():
    # _read(self, timeout) is what python-can's own receive and commands call
    assert list(inspect.signature(slcanBus._read).parameters) == ["self", "timeout"]
    for method in ("_recv_internal", "get_version", "get_serial_number"):
        assert "self._read(" in inspect.getsource(getattr(slcanBus, method)), method
    init = inspect.getsource(slcanBus.__init__)
    assert "self._buffer = bytearray()" in init
    assert "self.serialPortOrig = serial.serial_for_url(" in init
    assert (slcanBus._OK, slcanBus._ERROR) == (b"\r", b"\a")
    assert callable(can.exceptions.error_check)
    assert BufferedSlcanBus._read is not slcanBus._read


class FakePort:
    def __init__(self, chunks):
        self.chunks = list(chunks)

    @property
    def in_waiting(self):
        return len(self.chunks[0]) if self.chunks else 0

    def read(self, size=1):
        return self.chunks.pop(0) if self.chunks else b""


def test_read_takes_whole_lines_from_blocks_as_python_can_expects():
    """What python-can's ``_read`` returns: one reply or frame line, terminator included."""
    bus = BufferedSlcanBus.__new__(BufferedSlcanBus)
    bus._buffer = bytearray()
    bus.serialPortOrig = FakePort([b"t1230\rt12", b"31AA\r\a"])
    assert bus._read(0.1) == "t1230\r"
    assert bus._read(0.1) == "t1231AA\r"
    assert bus._read(0.1) == "\a"
    assert bus._read(0.01) is None


@pytest.fixture()
def pty_port():
    """A pyserial port on a pty's slave (a POSIX descriptor, as a USB adapter's tty) and the
    master's descriptor to write into it."""
    master, slave = os.openpty()
    port = serial.Serial(os.ttyname(slave), timeout=0)
    os.close(slave)
    yield port, master
    port.close()
    with contextlib.suppress(OSError):
        os.close(master)


def test_on_a_descriptor_it_returns_the_same_lines_as_through_pyserial(pty_port):
    """The descriptor path (select, one ``os.read``): whole lines however the bytes arrive,
    None after the timeout, and python-can's own ``_recv_internal`` parses its frames."""
    port, master = pty_port
    bus = BufferedSlcanBus.__new__(BufferedSlcanBus)
    bus._buffer = bytearray()
    bus.serialPortOrig = port
    os.write(master, b"t1230\rt12")
    assert bus._read(0.5) == "t1230\r"
    t0 = time.monotonic()
    assert bus._read(0.05) is None  # half a line: not a line
    assert 0.04 < time.monotonic() - t0 < 1.0
    os.write(master, b"31AA\r\a")
    assert bus._read(0.5) == "t1231AA\r"
    assert bus._read(0.5) == "\a"
    assert bus._read(0.0) is None
    bus._queue = queue.SimpleQueue()  # what slcanBus.__init__ sets up for its replies
    os.write(master, b"t1232BEEF\r")
    msg, _ = bus._recv_internal(0.5)
    assert msg.arbitration_id == 0x123 and bytes(msg.data) == b"\xbe\xef"


def test_on_a_descriptor_a_vanished_device_is_an_error_not_a_silence(pty_port):
    port, master = pty_port
    bus = BufferedSlcanBus.__new__(BufferedSlcanBus)
    bus._buffer = bytearray()
    bus.serialPortOrig = port
    os.close(master)  # the adapter unplugged: the slave reads fail
    with pytest.raises(can.CanOperationError, match="serial device"):
        bus._read(0.5)
