"""systemd notification protocol (sd_notify(3)) over the ``NOTIFY_SOCKET`` datagram socket.

Ten lines of protocol: ``READY=1``, ``WATCHDOG=1``, ``STATUS=…``, ``STOPPING=1``.  Without
``NOTIFY_SOCKET`` (not started by systemd) every call is a no-op.  The socket is opened
once; :meth:`Notifier.send` does not allocate beyond encoding the message.
"""
from __future__ import annotations

import os
import socket


class Notifier:
    def __init__(self, path: str | None = None):
        path = path if path is not None else os.environ.get("NOTIFY_SOCKET")
        self._sock = None
        self._addr = None
        if path:
            # abstract namespace sockets are written with a leading '@'
            self._addr = "\0" + path[1:] if path.startswith("@") else path
            self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
            self._sock.setblocking(False)
        wd = os.environ.get("WATCHDOG_USEC")
        #: watchdog period requested by systemd [s], or None
        self.watchdog_s = int(wd) / 1e6 if wd and wd.isdigit() else None

    @property
    def enabled(self) -> bool:
        return self._sock is not None

    def send(self, message: str) -> bool:
        """Send one notification; returns False (never raises) when it cannot be delivered."""
        if self._sock is None:
            return False
        try:
            self._sock.sendto(message.encode(), self._addr)
            return True
        except OSError:
            return False

    def ready(self, status: str = "") -> bool:
        return self.send("READY=1" + (f"\nSTATUS={status}" if status else ""))

    def watchdog(self) -> bool:
        return self.send("WATCHDOG=1")

    def status(self, text: str) -> bool:
        return self.send(f"STATUS={text}")

    def stopping(self) -> bool:
        return self.send("STOPPING=1")

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None
