"""One receive thread for the device model's buses (a bus per joint or per limb).

canopen's :meth:`~canopen.Network.connect` gives each network a python-can Notifier, a thread per
bus.  The daemon sends every bus's SYNC at once; with a thread per bus the SYNC of the second bus
wakes a second thread while the first still answers its own (the plant's step, its TPDOs), and
the two take turns at the interpreter and the model's lock before the second bus's TPDOs go out.
:class:`SharedReceiver` waits on every bus's descriptor in one ``select`` and, woken, takes what
every bus has queued and hands it over in the order it was sent (the frames' timestamps): the
second bus's SYNC is answered right after the first's, by the thread that is already running,
and a torque command sent on one bus before the SYNC of another is in force when that SYNC
steps the plant (with a thread per bus, whichever thread ran first decided: in a lock-step run
one joint's step often acted with its previous command).  On buses with file descriptors
(``ipc``, SocketCAN) it waits in ``select``; on python-can's ``virtual`` bus (in-process, no
descriptor) it waits on the first bus at most :data:`SharedReceiver.POLL` at a time and looks at
the others in between.
"""
from __future__ import annotations

import select
import threading

import can

from sea_daemon.hw.bus import descriptors


def _sent(item) -> float:
    return item[0]


class SharedReceiver:
    """Receives the frames of ``buses`` on one thread and hands each to the listeners of its
    network (``networks[i]``'s, as canopen's Notifier would); :meth:`stop` ends it (the
    Notifier's ``stop(timeout)``: each network's ``notifier``)."""

    #: without descriptors (python-can ``virtual``): the longest wait on the first bus before the
    #: others are looked at again [s] (a frame on another bus waits at most this long)
    POLL = 0.0005

    def __init__(self, buses, networks, fds, cycle: float = 0.05):
        self.buses, self.networks = list(buses), list(networks)
        self.fds = None if fds is None else list(fds)
        self.cycle = cycle                    # the select timeout: a stop is seen within it
        self._running = True
        self.exception: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name="device-model-rx", daemon=True)

    @classmethod
    def of(cls, buses, networks, cycle: float = 0.05) -> "SharedReceiver | None":
        if len(buses) < 2:
            return None
        return cls(buses, networks, descriptors(buses), cycle)

    def start(self) -> "SharedReceiver":
        for net in self.networks:
            net.notifier = self
        self._thread.start()
        return self

    def _run(self) -> None:
        batch: list = []
        while self._running:
            if not self._wait(batch):
                continue
            # every bus's queue, in the order the frames were sent (their timestamps; a bus's own
            # order for equal ones): the daemon's torque RPDO on the second bus, sent before the
            # first bus's SYNC, is in force when that SYNC steps the plant
            for i in range(len(self.buses)):
                self._take(i, batch)
            batch.sort(key=_sent)
            for _, i, msg in batch:
                for listener in self.networks[i].listeners:
                    listener.on_message_received(msg)
            batch.clear()

    def _wait(self, batch: list) -> bool:
        """Until a frame is queued on some bus (False after ``cycle`` without one): ``select`` on
        the descriptors, or without them a short wait on the first bus (its frame into ``batch``)
        and a look at the others."""
        if self.fds is not None:
            try:
                return bool(select.select(self.fds, (), (), self.cycle)[0])
            except (OSError, ValueError):
                if not self._running:
                    return False
                raise
        try:
            msg = self.buses[0].recv(self.POLL)
        except can.CanError as e:
            self.exception = e
            return False
        if msg is not None:
            batch.append((msg.timestamp or 0.0, 0, msg))
        return True

    def _take(self, i: int, batch: list) -> None:
        bus = self.buses[i]
        while self._running:
            try:
                msg = bus.recv(0.0)
            except can.CanError as e:
                self.exception = e
                return
            if msg is None:
                return
            batch.append((msg.timestamp or 0.0, i, msg))

    def stop(self, timeout: float = 5.0) -> None:
        self._running = False
        if self._thread.is_alive() and self._thread is not threading.current_thread():
            self._thread.join(timeout)
