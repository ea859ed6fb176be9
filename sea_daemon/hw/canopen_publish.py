"""The daemon's own CANopen node publishes its estimate: TPDOs on the driver's bus (docs/can.md).

Node ``hardware.bus.master_node`` (127 by default, the node whose heartbeat the drives watch)
sends, every cycle right after the estimate (transmission type 254, event-driven by the
daemon's cycle), little-endian, described by ``configs/eds/sea_daemon.eds``:

| TPDO | COB-ID | bytes |
|---|---|---|
| 1 | 0x180 + node | 0–3 τ̂_h,act joint 1 (REAL32, N m), 4–7 ρ_k joint 1 (REAL32, N m; +inf while not valid) |
| 3 | 0x380 + node | the same for joint 2 |
| 4 | 0x480 + node | the same for joint 3 |
| 2 | 0x280 + node | 0–3 cycle (UNSIGNED32), 4–5 fault code (UNSIGNED16), 6 valid bits (bit j−1: joint j), 7 flags |

in that order: TPDO2 closes a cycle's frames.  With a bus per joint or per limb
(:class:`sea_daemon.hw.canopen_buses.CanopenBuses`) each bus carries the TPDOs of its own joints
(the same COB-IDs: joint 2 is TPDO3 on its bus too) and a TPDO2 of its own that closes them
(:func:`make_tpdo_publisher`).  The frames are preallocated and packed in place;
a send that fails (a full transmit queue, the bus gone) is counted in :attr:`TpdoPublisher.dropped`
and never raises into the cycle — the drive's RPDO of the same cycle is what the fault policy
watches.
"""
from __future__ import annotations

import can

from sea_daemon.client import JOINT_FUNCTIONS, STATUS_FUNCTION, TPDO_JOINT, TPDO_STATUS


class TpdoPublisher:
    """TPDOs of node ``node`` for ``n`` joints (1..3) on the bus of ``hw`` (a started
    :class:`sea_daemon.hw.canopen_hw.CanopenHardware`: its canopen network's bus and send lock);
    ``joints``: the joints (0-based) whose TPDOs go on this bus (default all ``n``)."""

    def __init__(self, hw, node: int, n: int, joints=None):
        if not 1 <= n <= len(JOINT_FUNCTIONS):
            raise ValueError(f"the daemon's node publishes 1..{len(JOINT_FUNCTIONS)} joints, got {n}")
        if not 1 <= node <= 127:
            raise ValueError(f"node id {node}: allowed 1..127")
        self.hw, self.node, self.n = hw, int(node), int(n)
        self.joints = tuple(range(n)) if joints is None else tuple(joints)
        self._joint = [can.Message(arbitration_id=JOINT_FUNCTIONS[j] + node, data=bytearray(TPDO_JOINT.size),
                                   is_extended_id=False) for j in self.joints]
        self._status = can.Message(arbitration_id=STATUS_FUNCTION + node, data=bytearray(TPDO_STATUS.size),
                                   is_extended_id=False)
        self._frames = (*self._joint, self._status)    # the order on the bus: TPDO2 closes the cycle
        self.sent = 0
        self.sent_bytes = 0
        self.dropped = 0

    def send(self, cycle: int, hat, bound, valid_mask: int, fault: int, flags: int) -> None:
        """One cycle's frames: ``hat``/``bound`` per joint [N m] (``bound`` +inf where not valid)."""
        net = getattr(self.hw, "network", None)
        if net is None:                               # not started, or stopped
            self.dropped += len(self._joint) + 1
            return
        for j, msg in zip(self.joints, self._joint):
            TPDO_JOINT.pack_into(msg.data, 0, hat[j], bound[j])
        TPDO_STATUS.pack_into(self._status.data, 0, cycle & 0xFFFFFFFF, fault & 0xFFFF, valid_mask & 0xFF,
                              flags & 0xFF)
        bus = net.bus
        with net.send_lock:                           # one hold of the lock for the cycle's frames
            for msg in self._frames:
                try:
                    bus.send(msg, timeout=0.0)
                    self.sent += 1
                    self.sent_bytes += msg.dlc
                except Exception:  # noqa: BLE001 - a publication never stops the cycle: counted
                    self.dropped += 1


class BusesPublisher:
    """The TPDOs of :class:`TpdoPublisher` on each bus of a
    :class:`sea_daemon.hw.canopen_buses.CanopenBuses`: each bus its joints' and a TPDO2."""

    def __init__(self, hw, node: int, n: int):
        self.parts = [TpdoPublisher(sub, node, n, joints) for sub, joints in zip(hw.subs, hw.joints)]

    def send(self, cycle: int, hat, bound, valid_mask: int, fault: int, flags: int) -> None:
        for p in self.parts:
            p.send(cycle, hat, bound, valid_mask, fault, flags)

    @property
    def sent(self) -> int:
        return sum(p.sent for p in self.parts)

    @property
    def sent_bytes(self) -> int:
        return sum(p.sent_bytes for p in self.parts)

    @property
    def dropped(self) -> int:
        return sum(p.dropped for p in self.parts)


def make_tpdo_publisher(hw, node: int, n: int):
    """The daemon's TPDOs on the bus (or buses) of ``hw``."""
    if hasattr(hw, "subs"):
        return BusesPublisher(hw, node, n)
    return TpdoPublisher(hw, node, n)
