"""The receive side of the CANopen cycle: the cycle's TPDOs as the network's rx thread delivers them.

:class:`TpdoWindow` holds one :class:`TpdoSlot` per TPDO of the cycle.  The rx callbacks (run
by canopen's notifier thread) copy each frame's bytes into the slot's preallocated buffer under
a lock; ``read()`` of :class:`drivers.canopen_hw.CanopenHardware` opens the window before its
SYNC, waits until every TPDO arrived (or the PDO timeout), and closes it, which copies the
buffers into the slots' snapshots — no torn reads, nothing allocated.  Frames that arrive while
the window is closed belong to an earlier cycle: counted as late, never decoded.
:class:`ErrorFrames` watches the bus for the bus-off flag.
"""
from __future__ import annotations

import threading
from typing import Callable

import can


class TpdoSlot:
    """One TPDO of the cycle: the rx callback's buffer and its copy for ``read()``."""

    __slots__ = ("node", "cob_id", "buf", "snap", "count", "snap_count", "missed", "length", "bad_len")

    def __init__(self, node: int, cob_id: int, length: int = 0):
        self.node, self.cob_id = node, cob_id
        self.length = length          # bytes the mapping defines (0: not checked)
        self.bad_len = 0              # length of a frame that did not match, this cycle
        self.buf = bytearray(8)
        self.snap = bytearray(8)
        self.count = 0
        self.snap_count = 0
        self.missed = 0


class TpdoWindow:
    """The TPDOs of one cycle (see the module docstring).

    ``add(node, cob_id, length)`` returns the rx callback to subscribe for that TPDO.  Per cycle:
    :meth:`open` before the SYNC, :meth:`wait`, :meth:`close`; :meth:`abort` when the SYNC
    could not be sent.
    """

    def __init__(self):
        self.slots: list[TpdoSlot] = []
        self._lock = threading.Lock()
        self._all_rx = threading.Event()
        self._arrived = 0
        self._open = False
        self._late_frames = 0

    def add(self, node: int, cob_id: int, length: int) -> Callable[[int, bytes, float], None]:
        slot = TpdoSlot(node, cob_id, length)
        self.slots.append(slot)
        lock, event, slots = self._lock, self._all_rx, self.slots

        def on_tpdo(can_id, data, timestamp):
            with lock:
                if not self._open:             # no SYNC waiting: a frame of an earlier cycle
                    self._late_frames += 1
                    return
                k = min(len(data), 8)
                if slot.length and len(data) != slot.length:
                    slot.bad_len = len(data) or -1        # reported by read(), never decoded
                else:
                    slot.buf[:k] = data[:k]
                slot.count += 1
                if slot.count == 1:
                    self._arrived += 1
                    if self._arrived >= len(slots):
                        event.set()
        return on_tpdo

    def open(self) -> bool:
        """Start a cycle's window; True when frames arrived late since the last one."""
        with self._lock:
            for s in self.slots:
                s.count = 0
                s.bad_len = 0
            self._arrived = 0
            self._all_rx.clear()
            late = self._late_frames > 0
            self._late_frames = 0
            self._open = True
        return late

    def abort(self) -> None:
        self._open = False

    def wait(self, timeout: float) -> None:
        """Until every TPDO of the window arrived, or ``timeout`` [s]."""
        self._all_rx.wait(timeout)

    def close(self) -> None:
        """End the window: each slot's buffer and count to its snapshot."""
        with self._lock:
            self._open = False
            for s in self.slots:
                s.snap[:] = s.buf
                s.snap_count = s.count


class ErrorFrames(can.Listener):
    """Watches error frames for the bus-off flag (SocketCAN: CAN_ERR_BUSOFF = 0x40)."""

    def __init__(self):
        self.bus_off = False

    def on_message_received(self, msg: can.Message) -> None:
        if msg.is_error_frame and msg.arbitration_id & 0x40:
            self.bus_off = True
