"""slcan_buffered.py overrides private members of python-can's slcan bus; this test fails as
soon as a python-can release changes or drops them (pyproject.toml pins the versions)."""

from __future__ import annotations

import inspect
import re
from importlib.metadata import version
from pathlib import Path

import can
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
