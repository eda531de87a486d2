"""systemd's notification protocol, without a dependency: ``READY=1``, ``WATCHDOG=1``,
``STATUS=...`` and ``STOPPING=1`` as datagrams to the socket named by ``$NOTIFY_SOCKET``.

Outside systemd (no ``NOTIFY_SOCKET``) every call does nothing. ``watchdog_period()`` is half
of ``$WATCHDOG_USEC`` (the unit's ``WatchdogSec``), the interval to feed the watchdog at, or
None if the watchdog is off.
"""

from __future__ import annotations

import os
import socket


class Notifier:
    """Sends state changes to systemd (a no-op outside it)."""

    def __init__(self, environ=None) -> None:
        env = os.environ if environ is None else environ
        address = env.get("NOTIFY_SOCKET", "")
        if address.startswith("@"):  # abstract namespace
            address = "\0" + address[1:]
        self._address = address or None
        self._sock: socket.socket | None = None
        usec = env.get("WATCHDOG_USEC", "")
        pid = env.get("WATCHDOG_PID", "")
        mine = not pid or pid == str(os.getpid())
        self._watchdog = (int(usec) / 2e6) if usec.isdigit() and int(usec) > 0 and mine else None

    @property
    def enabled(self) -> bool:
        return self._address is not None

    def watchdog_period(self) -> float | None:
        return self._watchdog

    def notify(self, message: str) -> bool:
        """Send one notification; returns False (and never raises) if it could not be sent."""
        if self._address is None:
            return False
        try:
            if self._sock is None:
                self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)
            self._sock.sendto(message.encode("utf-8"), self._address)
            return True
        except OSError:
            return False

    def ready(self, status: str = "") -> bool:
        return self.notify("READY=1" + (f"\nSTATUS={status}" if status else ""))

    def watchdog(self) -> bool:
        return self.notify("WATCHDOG=1")

    def status(self, text: str) -> bool:
        return self.notify(f"STATUS={text}")

    def stopping(self) -> bool:
        return self.notify("STOPPING=1")

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None
