"""python-can's ``slcan`` interface with a buffered reader.

python-can 4.6.1's ``slcanBus._read`` takes the serial port's bytes one ``read(1)`` call at a
time, about 20 calls for a classic frame and 140 for a 64-byte FD frame: at 1 kHz that is
most of a core, and with the estimator running the plug-in fell behind the 500 cycles per
second of the classic profile, the adapter's buffer filled and frames (acknowledgements
among them) were lost. :class:`BufferedSlcanBus` overrides only that method: it reads what
the port holds in one call and splits it at the protocol's terminators (CR, or BEL for an
error). Everything else, the protocol, the frame parsing and sending, is python-can's own.

It relies on private members of python-can's ``slcanBus`` (``_read``, ``_buffer``,
``serialPortOrig``, ``_OK``, ``_ERROR``), so pyproject.toml pins python-can to 4.6.x and
``tests/firmware_bridge/test_slcan_buffered.py`` fails when a release changes them.
"""

from __future__ import annotations

import serial
from can.exceptions import error_check
from can.interfaces.slcan import slcanBus


class BufferedSlcanBus(slcanBus):
    """``can.interfaces.slcan.slcanBus`` reading the port in blocks, not byte by byte."""

    def _read(self, timeout: float | None) -> str | None:
        deadline = serial.Timeout(timeout)
        buf = self._buffer
        port = self.serialPortOrig
        with error_check("Could not read from serial device"):
            while True:
                line = self._take_line(buf)
                if line is not None:
                    return line
                data = port.read(max(1, port.in_waiting))
                if data:
                    buf.extend(data)
                elif deadline.expired():
                    return None

    def _take_line(self, buf: bytearray) -> str | None:
        """The first complete reply or frame line in ``buf`` (terminator included), removed."""
        ends = [i for i in (buf.find(self._OK), buf.find(self._ERROR)) if i >= 0]
        if not ends:
            return None
        end = min(ends) + 1
        line = bytes(buf[:end]).decode()
        del buf[:end]
        return line
