"""systemd notification protocol (sd_notify(3)) over the ``NOTIFY_SOCKET`` datagram socket.

Ten lines of protocol: ``READY=1``, ``WATCHDOG=1`` (at most every 1/40 of systemd's watchdog
period, however often the loop calls it), ``STATUS=…``, ``STOPPING=1``.  Without
``NOTIFY_SOCKET`` (not started by systemd) every call is a no-op.  The socket is opened
once; :meth:`Notifier.send` does not allocate beyond encoding the message.
"""
from __future__ import annotations

import math
import os
import socket
import time


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
        # WATCHDOG=1 at most every 1/40 of that period (50 ms without it): a loop that calls
        # watchdog() every cycle wakes systemd 20-40 times a second, not 1000 times at 1 kHz
        self._wd_every = self.watchdog_s / 40.0 if self.watchdog_s else 0.05
        self._wd_next = -math.inf

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
        """WATCHDOG=1 — sent when the last one is older than 1/40 of systemd's watchdog period
        (50 ms without one); in between a call only reads the clock and returns True."""
        if self._sock is None:
            return False
        now = time.monotonic()
        if now < self._wd_next:
            return True
        self._wd_next = now + self._wd_every
        return self.send("WATCHDOG=1")

    def status(self, text: str) -> bool:
        return self.send(f"STATUS={text}")

    def stopping(self) -> bool:
        return self.send("STOPPING=1")

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None
