"""One receive thread for the device model's buses (a bus per joint or per limb).

canopen's :meth:`~canopen.Network.connect` gives each network a python-can Notifier, a thread per
bus.  The daemon sends every bus's SYNC at once; with a thread per bus the SYNC of the second bus
wakes a second thread while the first still answers its own (the plant's step, its TPDOs), and
the two take turns at the interpreter and the model's lock before the second bus's TPDOs go out.
:class:`SharedReceiver` waits on every bus's descriptor in one ``select`` and, woken, takes what
each bus has queued in bus order: the second bus's SYNC is answered right after the first's, by
the thread that is already running.  For buses with a file descriptor (``ipc``, SocketCAN);
:meth:`SharedReceiver.of` gives None otherwise (each network keeps its own Notifier).
"""
from __future__ import annotations

import select
import threading

import can


class SharedReceiver:
    """Receives the frames of ``buses`` on one thread and hands each to the listeners of its
    network (``networks[i]``'s, as canopen's Notifier would); :meth:`stop` ends it (the
    Notifier's ``stop(timeout)``: each network's ``notifier``)."""

    def __init__(self, buses, networks, fds, cycle: float = 0.05):
        self.buses, self.networks, self.fds = list(buses), list(networks), list(fds)
        self.cycle = cycle                    # the select timeout: a stop is seen within it
        self._running = True
        self.exception: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name="device-model-rx", daemon=True)

    @classmethod
    def of(cls, buses, networks, cycle: float = 0.05) -> "SharedReceiver | None":
        if len(buses) < 2:
            return None
        fds = []
        for bus in buses:
            try:
                fd = bus.fileno()
            except (NotImplementedError, AttributeError, OSError, ValueError):
                return None
            if not isinstance(fd, int) or fd < 0:
                return None
            fds.append(fd)
        return cls(buses, networks, fds, cycle)

    def start(self) -> "SharedReceiver":
        for net in self.networks:
            net.notifier = self
        self._thread.start()
        return self

    def _run(self) -> None:
        index = {fd: i for i, fd in enumerate(self.fds)}
        while self._running:
            try:
                ready = select.select(self.fds, (), (), self.cycle)[0]
            except (OSError, ValueError):
                if not self._running:
                    return
                raise
            for i in sorted(index[fd] for fd in ready):      # bus order: the first bus's SYNC first
                self._take(i)

    def _take(self, i: int) -> None:
        bus, listeners = self.buses[i], self.networks[i].listeners
        while self._running:
            try:
                msg = bus.recv(0.0)
            except can.CanError as e:
                self.exception = e
                return
            if msg is None:
                return
            for listener in listeners:
                listener.on_message_received(msg)

    def stop(self, timeout: float = 5.0) -> None:
        self._running = False
        if self._thread.is_alive() and self._thread is not threading.current_thread():
            self._thread.join(timeout)
