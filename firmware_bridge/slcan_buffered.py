"""python-can's ``slcan`` interface with a buffered reader.

python-can 4.6.1's ``slcanBus._read`` takes the serial port's bytes one ``read(1)`` call at a
time, about 20 calls for a classic frame and 140 for a 64-byte FD frame: at 1 kHz that is
most of a core, and with the estimator running the plug-in fell behind the 500 cycles per
second of the classic profile, the adapter's buffer filled and frames (acknowledgements
among them) were lost. :class:`BufferedSlcanBus` overrides only that method: it reads what
the port holds in one call and splits it at the protocol's terminators (CR, or BEL for an
error). Everything else, the protocol, the frame parsing and sending, is python-can's own.

On a POSIX serial device (a USB adapter's tty, a pty) it waits on the port's descriptor itself
and takes everything the kernel holds in one ``os.read``: through pyserial's ``read`` each
frame took two calls (one blocking for the first byte, one for the rest), each a select, an
``ioctl`` for ``in_waiting`` and pyserial's timeout bookkeeping. Same errors as pyserial's
``read``: a device ready with no data is disconnected (``SerialException``), and EAGAIN and
the like are retried. Ports without a descriptor (``loop://`` and other URL handlers) go
through pyserial's ``read`` as before.

It relies on private members of python-can's ``slcanBus`` (``_read``, ``_buffer``,
``serialPortOrig``, ``_OK``, ``_ERROR``), so pyproject.toml pins python-can to 4.6.x and
``tests/firmware_bridge/test_slcan_buffered.py`` fails when a release changes them.
"""

from __future__ import annotations

import errno
import os
import select
import time

import serial
from can.exceptions import CanOperationError
from can.interfaces.slcan import slcanBus

READ_SIZE = 4096
"""Most bytes taken from the descriptor in one read (about 30 FD frames' lines)."""


class BufferedSlcanBus(slcanBus):
    """``can.interfaces.slcan.slcanBus`` reading the port in blocks, not byte by byte."""

    def _read(self, timeout: float | None) -> str | None:
        port = self.serialPortOrig
        fd = getattr(port, "fd", None)
        if isinstance(fd, int) and fd >= 0:
            def more(wait):
                return _read_ready(fd, wait)
        else:  # a URL handler: pyserial's read, with the port's own timeout
            def more(wait):
                return port.read(max(1, port.in_waiting))
        buf = self._buffer
        deadline = None if timeout is None else time.monotonic() + timeout
        try:  # python-can's error_check, without a context manager per frame
            line = self._take_line(buf) if buf else None  # an earlier read's next line
            while line is None:
                data = more(None if deadline is None else max(0.0, deadline - time.monotonic()))
                if data:
                    buf.extend(data)
                    line = self._take_line(buf)
                elif deadline is not None and time.monotonic() >= deadline:
                    return None
            return line
        except Exception as error:
            raise CanOperationError("Could not read from serial device") from error

    def _take_line(self, buf: bytearray) -> str | None:
        """The first complete reply or frame line in ``buf`` (terminator included), removed."""
        end = buf.find(self._OK)
        error = buf.find(self._ERROR)
        if error >= 0 and (end < 0 or error < end):
            end = error
        if end < 0:
            return None
        end += 1
        line = bytes(buf[:end]).decode()
        del buf[:end]
        return line


def _read_ready(fd: int, wait: float | None) -> bytes:
    """What a POSIX descriptor holds, once it is readable within ``wait`` s (b"" if it is
    not, or if the read would block); pyserial's errors for a failed read or a vanished
    device."""
    ready, _, _ = select.select([fd], [], [], wait)
    if not ready:
        return b""
    try:
        data = os.read(fd, READ_SIZE)
    except OSError as exc:
        if exc.errno in (errno.EAGAIN, errno.EWOULDBLOCK, errno.EINTR):
            return b""
        raise serial.SerialException(f"read failed: {exc}") from exc
    if not data:
        raise serial.SerialException("device reports readiness to read but returned no data "
                                     "(device disconnected or multiple access on port?)")
    return data
