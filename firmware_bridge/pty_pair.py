"""A pseudo-terminal owned by this process: it keeps the master, a client opens the slave.

The slave is put in raw mode at once (no echo, no CR/LF translation) and its descriptor is
kept open here, so the master never sees a hang-up when a client closes and reopens it.
Writes never block the owner: bytes the client does not read yet wait in a backlog of at
most ``max_backlog`` bytes; a write that does not fit is dropped whole (so line or message
framing stays intact) and counted in ``dropped_writes``.

It offers the small part of pyserial's interface the serial link needs (``read``,
``write``, ``in_waiting``, ``close``), so the controller side can use it in place of a
``serial.Serial``.
"""

from __future__ import annotations

import errno
import fcntl
import os
import select
import struct
import termios
import tty


class PtyPair:
    def __init__(self, max_backlog: int = 1 << 16) -> None:
        master, slave = os.openpty()
        tty.setraw(slave)
        os.set_blocking(master, False)
        self.master = master
        self._slave = slave
        self.slave_path = os.ttyname(slave)
        self.max_backlog = max_backlog
        self._out = bytearray()
        self.dropped_writes = 0
        self.closed = False

    def fileno(self) -> int:
        return self.master

    # -- output ----------------------------------------------------------------------------
    def write(self, data: bytes) -> int:
        """Queue ``data`` for the client and push what the pty takes; 0 if dropped."""
        if len(self._out) + len(data) > self.max_backlog:
            self.dropped_writes += 1
            self.flush()
            return 0
        self._out += data
        self.flush()
        return len(data)

    def flush(self) -> None:
        while self._out:
            try:
                n = os.write(self.master, self._out)
            except BlockingIOError:
                return
            except OSError as exc:
                if exc.errno == errno.EIO:
                    return
                raise
            del self._out[:n]

    @property
    def backlog(self) -> int:
        return len(self._out)

    # -- input -----------------------------------------------------------------------------
    def read(self, size: int = 1 << 16) -> bytes:
        """What the client wrote (up to ``size`` bytes), without blocking."""
        try:
            return os.read(self.master, size)
        except BlockingIOError:
            return b""
        except OSError as exc:
            if exc.errno == errno.EIO:  # no client has the slave open
                return b""
            raise

    @property
    def in_waiting(self) -> int:
        """Bytes the client wrote that are waiting to be read."""
        try:
            buf = fcntl.ioctl(self.master, termios.FIONREAD, b"\0\0\0\0")
        except OSError:
            return 0
        return struct.unpack("I", buf)[0]

    def wait_readable(self, timeout: float) -> bool:
        r, _, _ = select.select([self.master], [], [], max(0.0, timeout))
        return bool(r)

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            os.close(self.master)
            os.close(self._slave)
