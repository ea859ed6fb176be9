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

Paced (a lock-step device model on buses with descriptors, ``period`` given; one bus too): once
the SYNCs have come at that period for :data:`SharedReceiver.PACE_RUN` SYNCs in a row — a master
in real-time pace — the thread does not wait on the buses for the next SYNC: it sleeps on its
own timer until the time by which nine SYNCs in ten have come (their phase after the earliest
one seen, a running quantile), then takes what is queued, and waits on the buses (as unpaced)
only when the SYNC has not come by then.  A real device gets the SYNC over the wire; here the master's SYNC would
otherwise wake this process, and waking a process on another CPU costs the sender (the daemon's
loop) about 15 µs more than a send that wakes nobody on a two-vCPU virtual machine.  The answer
comes a few tens of µs later (the master's TPDO deadline is most of a period); the frames, their
order and the plant's steps are the same.  A SYNC off the pace (a stall, a lock-step master that runs
as fast as it can) ends the pacing until the SYNCs keep the period again.
"""
from __future__ import annotations

import select
import threading
import time

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
    #: paced (module docstring): SYNCs in a row at the period (each interval within ± a quarter of
    #: it) before the timer replaces the wait on the buses; the share of SYNCs that come before
    #: the timer ends, the step of its running quantile (a fraction of the period per SYNC) and
    #: its largest value (a fraction of the period); how fast the earliest phase follows a master
    #: that comes later (a fraction of the period per SYNC)
    PACE_RUN = 8
    PACE_SHARE = 0.9
    PACE_STEP = 0.02
    PACE_LATE_MAX = 0.2
    PACE_CREEP = 0.001
    SYNC_ID = 0x80

    def __init__(self, buses, networks, fds, cycle: float = 0.05, period=None):
        self.buses, self.networks = list(buses), list(networks)
        self.fds = None if fds is None else list(fds)
        self.cycle = cycle                    # the select timeout: a stop is seen within it
        # paced: () -> the SYNCs' period [s] (the drives' interpolation period, which the master sets);
        # None: not paced, or no descriptors to look at after the timer
        self.period = period if self.fds is not None else None
        self._p = 0.0                         # the period at the newest SYNC
        self._last_sync = None                # the newest SYNC's send time (its timestamp, time.time())
        self._expect = None                   # when the next SYNC comes at the earliest phase seen
        self._at_pace = 0                     # SYNCs in a row at the period
        self._late = 0.0                      # the running quantile of the SYNCs' phase after the earliest [s]
        self.paced_waits = 0                  # waits that ended on the timer (statistics)
        self._running = True
        self.exception: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name="device-model-rx", daemon=True)

    @classmethod
    def of(cls, buses, networks, cycle: float = 0.05, period=None) -> "SharedReceiver | None":
        """One receive thread for several buses; for one bus only when paced (``period``: () -> the
        SYNCs' period [s], a lock-step device model; and descriptors to look at), else None
        (canopen's Notifier)."""
        fds = descriptors(buses)
        if len(buses) < 2 and (period is None or fds is None):
            return None
        return cls(buses, networks, fds, cycle, period)

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
            synced = False
            for _, i, msg in batch:
                if not synced and msg.arbitration_id == self.SYNC_ID and self.period is not None:
                    synced = True
                    self._synced(msg.timestamp)
                for listener in self.networks[i].listeners:
                    listener.on_message_received(msg)
            batch.clear()

    def _synced(self, t: float | None) -> None:
        """A cycle's first SYNC, sent at ``t`` (its timestamp): whether the SYNCs keep the period,
        and when the next one comes at the earliest phase they have come at."""
        if not t:
            self._at_pace = 0
            return
        p = self._p = float(self.period())
        last, self._last_sync = self._last_sync, t
        self._at_pace = self._at_pace + 1 if (last is not None and abs(t - last - p) <= 0.25 * p) else 0
        e = self._expect
        if e is not None and self._at_pace:
            # the quantile PACE_SHARE of how late SYNCs come after the earliest phase
            q = self._late + self.PACE_STEP * p * (self.PACE_SHARE - (1.0 if t - e < self._late else 0.0))
            self._late = min(max(q, 0.0), self.PACE_LATE_MAX * p)
        # the earliest phase, following a master that comes later by PACE_CREEP of a period a SYNC
        e = t if (e is None or t < e or not self._at_pace) else e + self.PACE_CREEP * p
        self._expect = e + p

    def _paced_sleep(self) -> None:
        """Paced and at the pace: sleep until the next SYNC's earliest phase plus the running
        quantile of how late they come after it (at most ``cycle``)."""
        if self.period is None or self._at_pace < self.PACE_RUN:
            return
        left = self._expect + self._late - time.time()
        if left > 0.0:
            time.sleep(min(left, self.cycle))
            self.paced_waits += 1

    def _wait(self, batch: list) -> bool:
        """Until a frame is queued on some bus (False after ``cycle`` without one): ``select`` on
        the descriptors, or without them a short wait on the first bus (its frame into ``batch``)
        and a look at the others."""
        if self.fds is not None:
            self._paced_sleep()
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
