"""The receive side of the CANopen cycle: the cycle's TPDOs, received by the loop thread itself.

:class:`TpdoWindow` holds one :class:`TpdoSlot` per TPDO of the cycle and a bus handle of its
own (:meth:`TpdoWindow.bind`), filtered to the TPDOs' COB-IDs (a kernel filter on SocketCAN,
an id check before decoding on the ``ipc`` bus; on ``virtual`` and ``remote`` every frame comes
and the others are skipped here).  The
loop thread receives them directly in ``read()`` of :class:`drivers.canopen_hw.CanopenHardware`:
:meth:`TpdoWindow.drain` before the SYNC (frames that arrived since the last window belong to an
earlier cycle: counted as late, never decoded), :meth:`TpdoWindow.collect` after it until every
TPDO arrived or the deadline — no receive thread, no lock, no hand-over between threads on the
cycle's path, nothing allocated beyond python-can's message object per frame (none on the
``ipc`` bus, whose :meth:`~drivers.ipc_bus.IpcBus.recv_frame` gives id and data from its own
buffer).  canopen's own
receive thread keeps the rest of the traffic (SDO, heartbeats, EMCY; its handle is filtered to
those).  :class:`ErrorFrames` watches the bus for the bus-off flag.
"""
from __future__ import annotations

import can

#: accept filters of the canopen network's handle: everything but the TPDO range 0x180..0x4FF
#: (NMT, SYNC/EMCY, SDO both ways, heartbeats; error frames pass on every interface)
NETWORK_FILTERS = [{"can_id": cid, "can_mask": 0x780, "extended": False}
                   for cid in (0x000, 0x080, 0x500, 0x580, 0x600, 0x680, 0x700)]


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
        self._recv = self._recv_message

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
        # the bus's own frame path where it has one (the ipc bus: no can.Message per frame)
        self._recv = getattr(bus, "recv_frame", None) or self._recv_message
        from drivers.ipc_bus import IpcBus
        if isinstance(bus, IpcBus) or type(bus).__name__ == "SocketcanBus":
            bus.set_filters([{"can_id": s.cob_id, "can_mask": 0x7FF, "extended": False} for s in self.slots])

    def _recv_message(self, timeout: float):
        """``(arbitration id, data)`` of the next frame from python-can's ``recv``, or None."""
        msg = self.bus.recv(timeout)
        return None if msg is None else (msg.arbitration_id, msg.data)

    def drain(self) -> bool:
        """Before the SYNC: take what arrived since the last window (late frames) and reset the
        slots; True when there were any."""
        late = False
        recv = self._recv
        by_cob = self._by_cob
        while True:
            frame = recv(0.0)
            if frame is None:
                break
            if frame[0] in by_cob:                 # a bus that ignores filters (python-can-remote)
                late = True
        for s in self.slots:
            s.count = 0
            s.bad_len = 0
        return late

    def collect(self, deadline: float, clock) -> None:
        """After the SYNC: receive until every TPDO arrived or ``clock() >= deadline``; each
        slot's ``snap`` gets its frame's bytes (a slot without a frame keeps the last ones),
        ``snap_count`` the number of frames."""
        recv = self._recv
        need = len(self.slots)
        arrived = 0
        by_cob = self._by_cob
        while arrived < need:
            left = deadline - clock()
            if left <= 0.0:
                break
            frame = recv(left)
            if frame is None:
                break
            s = by_cob.get(frame[0])
            if s is None:
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


class ErrorFrames(can.Listener):
    """Watches error frames for the bus-off flag (SocketCAN: CAN_ERR_BUSOFF = 0x40)."""

    def __init__(self):
        self.bus_off = False

    def on_message_received(self, msg: can.Message) -> None:
        if msg.is_error_frame and msg.arbitration_id & 0x40:
            self.bus_off = True
