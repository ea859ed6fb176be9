"""The receive side of the CANopen cycle: the cycle's TPDOs, received by the loop thread itself.

:class:`TpdoWindow` holds one :class:`TpdoSlot` per TPDO of the cycle and a bus handle of its
own (:meth:`TpdoWindow.bind`), filtered to the TPDOs' COB-IDs (a kernel filter on SocketCAN,
an id check before decoding on the ``ipc`` bus; on ``virtual`` and ``remote`` every frame comes
and the others are skipped here).  The
loop thread receives them directly in ``read()`` of :class:`sea_daemon.hw.canopen_hw.CanopenHardware`:
:meth:`TpdoWindow.drain` before the SYNC (frames that arrived since the last window belong to an
earlier cycle: counted as late, never decoded), :meth:`TpdoWindow.collect` after it until every
TPDO arrived or the deadline — no receive thread, no lock, no hand-over between threads on the
cycle's path, nothing allocated beyond python-can's message object per frame (none on the
``ipc`` bus, whose :meth:`~sea_daemon.hw.ipc_bus.IpcBus.recv_frame` gives id and data from its own
buffer).  canopen's own
receive thread keeps the rest of the traffic (SDO, NMT; its handle is filtered to those).  Once
the cycle runs, the devices' EMCY and heartbeats are the loop thread's too: a few µs of Python in
the loop thread instead of a wake-up of canopen's thread inside the cycle.  Where the handles
filter below python-can (SocketCAN, ``ipc``), the EMCY come on the TPDO handle (its filter takes
them, :meth:`TpdoWindow.watch`) and the heartbeats on a third handle that the loop thread reads
in ``read()`` (:class:`FrameTap`); on ``virtual`` and ``remote``, whose TPDO handle sees every
frame anyway, the window hands both over as it meets them.  Either way an EMCY queued before
``read()`` — or before the cycle's TPDOs — is seen by that ``read()``, whatever the scheduler
does with canopen's thread.  The devices answer a SYNC with a burst of TPDOs: after a frame the
window reads on before it waits (:meth:`TpdoWindow.collect`), one wake-up for the burst.
A heartbeat counts from its arrival on the bus
(:func:`arrival`), not from when a thread took it.  :class:`ErrorFrames` watches the bus for the
bus-off flag.
"""
from __future__ import annotations

import select
import time

import can

from sea_daemon.hw.bus import descriptors, set_controller_filters

#: accept filters of the canopen network's handle: everything but the TPDO range 0x180..0x4FF
#: (NMT, SYNC/EMCY, SDO both ways, heartbeats; error frames pass on every interface)
NETWORK_FILTERS = [{"can_id": cid, "can_mask": 0x780, "extended": False}
                   for cid in (0x000, 0x080, 0x500, 0x580, 0x600, 0x680, 0x700)]
#: the same without SYNC/EMCY and the heartbeats, once a :class:`FrameTap` takes them
CYCLE_NETWORK_FILTERS = [f for f in NETWORK_FILTERS if f["can_id"] not in (0x080, 0x700)]
#: frames per TPDO slot that :meth:`TpdoWindow.collect` still takes from the queue past its
#: deadline (a handle that sees other frames too, ``virtual`` or ``remote``, is bounded by it)
LATE_TAKE = 4


def arrival(now: float, timestamp: float | None) -> float:
    """When a frame arrived, on the clock that reads ``now``: ``now`` minus the frame's age by
    its bus timestamp (``can.Message.timestamp``: the kernel's reception time on SocketCAN, the
    sender's ``time.time()`` on ``virtual``, ``ipc`` and ``remote``).  A frame a thread takes late
    is dated when it came, not when it was taken; no timestamp, or one from the future (the wall
    clock stepped back), dates it ``now``."""
    if timestamp:
        age = time.time() - timestamp
        if age > 0.0:
            return now - age
    return now


def frame_receiver(bus: can.BusABC, stamped: bool = False):
    """``recv(timeout, ready=False) -> (arbitration id, data[, timestamp]) | None`` on ``bus``:
    the bus's own frame path where it has one (the ipc bus: no can.Message per frame, and no
    wait before a read when ``ready`` says a frame is probably queued, the rest of a burst; the
    timestamp only when ``stamped``), else python-can's ``recv`` (always with the frame's
    timestamp; ``ready`` changes nothing)."""
    fast = getattr(bus, "recv_frame", None)
    if fast is not None:
        if not stamped:
            return fast
        stamp = bus.frame_timestamp

        def recv_stamped(timeout: float, ready: bool = False):
            frame = fast(timeout, ready)
            return None if frame is None else (frame[0], frame[1], stamp())
        return recv_stamped

    def recv(timeout: float, ready: bool = False):
        msg = bus.recv(timeout)
        return None if msg is None else (msg.arbitration_id, msg.data, msg.timestamp)
    return recv


def exact_filters(cob_ids) -> list[dict]:
    """python-can ``can_filters`` accepting exactly these 11-bit COB-IDs."""
    return [{"can_id": i, "can_mask": 0x7FF, "extended": False} for i in cob_ids]


class TpdoSlot:
    """One TPDO of the cycle: the last frame's bytes (``snap``) and this cycle's frame count."""

    __slots__ = ("node", "cob_id", "snap", "count", "snap_count", "missed", "length", "bad_len")

    def __init__(self, node: int, cob_id: int, length: int = 0):
        self.node, self.cob_id = node, cob_id
        self.length = length          # bytes the mapping defines (0: not checked)
        self.bad_len = 0              # length of a frame that did not match, this cycle
        self.snap = bytearray(8)
        self.count = 0
        self.snap_count = 0
        self.missed = 0


class TpdoWindow:
    """The TPDOs of one cycle (see the module docstring).

    ``add(node, cob_id, length)`` declares a TPDO; :meth:`bind` gives the window its bus handle
    (and sets the handle's filters).  Per cycle: :meth:`drain` before the SYNC, :meth:`collect`
    after it.
    """

    def __init__(self):
        self.slots: list[TpdoSlot] = []
        self._by_cob: dict[int, TpdoSlot] = {}
        self.bus: can.BusABC | None = None
        self._recv = None
        #: whether the handle's filters apply below python-can (SocketCAN, ipc)
        self.filtered = False
        self._other: frozenset = frozenset()     # COB-IDs handed to _on_other (see watch())
        self._on_other = None

    def add(self, node: int, cob_id: int, length: int) -> TpdoSlot:
        slot = TpdoSlot(node, cob_id, length)
        self.slots.append(slot)
        self._by_cob[cob_id] = slot
        return slot

    def bind(self, bus: can.BusABC) -> None:
        """Receive the TPDOs on ``bus``; its filters are set where the bus applies them below
        python-can (SocketCAN's kernel filter, the ipc bus): python-can's software filter would
        end ``recv(0)`` at the first other frame and leave TPDOs queued behind it."""
        self.bus = bus
        self._recv = frame_receiver(bus)
        self.filtered = set_controller_filters(bus, exact_filters(s.cob_id for s in self.slots))

    def watch(self, cob_ids, on_frame) -> None:
        """Hand the frames of ``cob_ids`` met while draining or collecting to ``on_frame(cob_id,
        data, timestamp)`` (timestamp None where the handle's own frame path has none), taken by
        the loop thread in the order they came with the TPDOs.  On a handle that sees every
        frame (``virtual``, ``remote``) the devices' heartbeats and EMCY; on one filtered below
        python-can (SocketCAN, ipc) the filter takes ``cob_ids`` too (the devices' EMCY: an EMCY
        sent before the cycle's TPDOs is queued before them, on the same handle)."""
        self._other = frozenset(cob_ids)
        self._on_other = on_frame
        if self.filtered:
            ids = [s.cob_id for s in self.slots] + sorted(self._other)
            self.filtered = set_controller_filters(self.bus, exact_filters(ids))

    def drain(self, queued: bool = True) -> bool:
        """Before the SYNC: take what arrived since the last window (late frames) and reset the
        slots; True when there were any.  ``queued=False``: the caller knows that the handle has
        nothing queued (:class:`Queued`), only the slots are reset."""
        late = False
        recv = self._recv
        by_cob, other = self._by_cob, self._other
        while queued:
            frame = recv(0.0)
            if frame is None:
                break
            if frame[0] in by_cob:                 # a bus that ignores filters (python-can-remote)
                late = True
            elif frame[0] in other:
                self._on_other(frame[0], frame[1], frame[2] if len(frame) > 2 else None)
        for s in self.slots:
            s.count = 0
            s.bad_len = 0
        return late

    def collect(self, deadline: float, clock) -> None:
        """After the SYNC: receive until every TPDO arrived or ``clock() >= deadline``; each
        slot's ``snap`` gets its frame's bytes (a slot without a frame keeps the last ones),
        ``snap_count`` the number of frames.  The deadline bounds the wait, not the taking: a
        thread that comes to its TPDOs late (preempted after its SYNC) still takes the frames
        already queued (at most :data:`LATE_TAKE` per slot past the deadline, without waiting).
        The devices answer a SYNC with their TPDOs in a burst: after a frame the next is read
        before waiting for one (one wake-up for the burst, not one per frame)."""
        recv = self._recv
        need = len(self.slots)
        arrived = 0
        late_take = LATE_TAKE * need
        by_cob, other = self._by_cob, self._other
        ready = False
        while arrived < need:
            left = deadline - clock()
            if left <= 0.0:
                if late_take == 0:
                    break
                late_take -= 1
                left = 0.0
            frame = recv(left, ready)
            if frame is None:
                break
            ready = True
            s = by_cob.get(frame[0])
            if s is None:
                if frame[0] in other:
                    self._on_other(frame[0], frame[1], frame[2] if len(frame) > 2 else None)
                continue
            data = frame[1]
            k = len(data)
            if s.length and k != s.length:
                s.bad_len = k or -1                      # reported by read(), never decoded
            else:
                s.snap[:k] = data
            s.count += 1
            if s.count == 1:
                arrived += 1
        for s in self.slots:
            s.snap_count = s.count


class FrameTap:
    """Frames of a few COB-IDs on a handle of the loop thread's own, filtered to them below
    python-can (SocketCAN, ipc): :meth:`take` hands each queued frame to ``on_frame(cob_id,
    data, timestamp)`` (``data`` valid during the call, ``timestamp`` the frame's bus timestamp;
    other frames that pass every filter — error frames — are skipped).  The devices' heartbeats
    and EMCY: taken in every cycle, no receive thread.  The handle's queue is the socket's (on
    ``ipc`` ``net.unix.max_dgram_qlen`` frames): while nobody takes them, the oldest stay and
    newer ones are lost."""

    def __init__(self, bus: can.BusABC, cob_ids, on_frame):
        self.bus = bus
        self.on_frame = on_frame
        self.cob_ids = frozenset(cob_ids)
        self._recv = frame_receiver(bus, stamped=True)
        if not set_controller_filters(bus, exact_filters(self.cob_ids)):
            raise ValueError(f"{type(bus).__name__} filters in python-can only: a FrameTap would queue "
                             "every frame of the bus")

    def take(self) -> None:
        recv, on_frame, ids = self._recv, self.on_frame, self.cob_ids
        while True:
            frame = recv(0.0)
            if frame is None:
                return
            if frame[0] in ids:
                on_frame(frame[0], frame[1], frame[2])


class Queued:
    """Which of a few receive handles have frames queued, in one ``poll`` for all of them: the
    cycle asks once instead of once per handle.  :meth:`of` gives None when a handle has no file
    descriptor to poll (``virtual``, python-can-remote): every handle is then read as before."""

    def __init__(self, fds):
        self._poll = select.poll()
        self._bit = {}
        for i, fd in enumerate(fds):
            self._poll.register(fd, select.POLLIN)
            self._bit[fd] = 1 << i

    @classmethod
    def of(cls, buses) -> "Queued | None":
        fds = descriptors(buses)
        return None if fds is None else cls(fds)

    def mask(self) -> int:
        """Bit i set: handle i (in the order given) has a frame queued, or an error pending."""
        m = 0
        bit = self._bit
        for fd, _ in self._poll.poll(0):
            m |= bit.get(fd, 0)
        return m


class ErrorFrames(can.Listener):
    """Watches error frames for the bus-off flag (SocketCAN: CAN_ERR_BUSOFF = 0x40)."""

    def __init__(self):
        self.bus_off = False

    def on_message_received(self, msg: can.Message) -> None:
        if msg.is_error_frame and msg.arbitration_id & 0x40:
            self.bus_off = True
