"""A CANopen slave on canopen's :class:`~canopen.LocalNode` with the pieces LocalNode lacks.

canopen's LocalNode answers SDO, follows NMT commands and produces heartbeats, but it neither
sends TPDOs on SYNC nor copies received RPDOs into its object dictionary.  :class:`SlaveNode`
adds, after CiA 301:

* PDO configuration read from its own dictionary (0x1400/0x1600, 0x1800/0x1A00) when the node
  enters OPERATIONAL; mapping entries are checked when written (abort 0x06040041 / 0x06040042);
* synchronous TPDOs (transmission type 1..240: every n-th SYNC) built from the mapped objects;
* synchronous RPDOs buffered on reception and written into the dictionary at the next SYNC
  (transmission type 0..240) or at once (254/255), firing the write callbacks;
* EMCY with the error register (0x1001) kept up to date;
* device-side faults: heartbeat loss, bus-off (the node goes silent and deaf).
"""
from __future__ import annotations

import struct
import threading
from dataclasses import dataclass, field
from pathlib import Path

import can
import canopen
from canopen.nmt import NmtSlave
from canopen.sdo import SdoAbortedError

from sea_daemon.io.configfile import data_root

EDS_DIR = data_root() / "configs" / "eds"
PDO_INVALID = 0x80000000


@dataclass
class PdoConfig:
    cob_id: int
    trans_type: int
    entries: list = field(default_factory=list)     # [(index, subindex, n_bytes)]
    counter: int = 0
    length: int = 0
    # fast path (every mapped object has a getter / setter of the node): the frame's struct and
    # the getters (TPDO) or setters (RPDO), in mapping order; None: through the dictionary
    codec: struct.Struct | None = None
    access: tuple = ()
    msg: can.Message | None = None                   # the TPDO's frame, reused (fast path)


#: struct codes of the mappable integer types, by (signed, bytes)
_INT_CODES = {(False, 1): "B", (False, 2): "H", (False, 4): "I", (True, 1): "b", (True, 2): "h", (True, 4): "i"}


class DeviceNetwork(canopen.Network):
    """canopen Network of the device model: outgoing frames pass a gate (drop / delay / mute)."""

    def __init__(self, bus):
        super().__init__(bus)
        self.gate = None           # callable(can_id, data) -> bool: True = send now (gate may send later)
        self.deaf: set[int] = set()   # node ids that ignore what they receive (bus-off)
        # every frame this network sent or received, and their data bytes (bus load: with the
        # master as the only other member, everything on the bus but the frames the devices'
        # acceptance filter rejects — the master's published TPDOs, counted by their sender)
        self.frames = 0
        self.data_bytes = 0

    def send_message(self, can_id: int, data: bytes, remote: bool = False) -> None:
        if self.gate is not None and not self.gate(can_id, bytes(data)):
            return
        super().send_message(can_id, data, remote)
        self.frames += 1
        self.data_bytes += len(data)

    def send_pdo(self, msg: can.Message, data: bytes) -> None:
        """A PDO through the gate in a message object of its own, reused (the cycle's frames:
        no canopen Message per frame; the bus copies the data when it sends)."""
        if self.gate is not None and not self.gate(msg.arbitration_id, data):
            return
        msg.data[:] = data                          # the mapping's length: the frame's length
        with self.send_lock:
            self.bus.send(msg)
        self.frames += 1
        self.data_bytes += len(data)

    def send_now(self, can_id: int, data: bytes) -> None:
        """Bypass the gate (used by the gate itself for delayed frames)."""
        try:
            super().send_message(can_id, data)
        except Exception:  # noqa: BLE001 - the bus may have been closed meanwhile
            pass

    def notify(self, can_id: int, data: bytearray, timestamp: float) -> None:
        self.frames += 1
        self.data_bytes += len(data)
        if self.deaf:
            node = can_id & 0x7F
            if node in self.deaf and can_id & 0x780 in (0x200, 0x300, 0x400, 0x500, 0x600):
                return
        super().notify(can_id, data, timestamp)


class _Nmt(NmtSlave):
    """NmtSlave that reports state changes to its node and produces the heartbeat itself.

    The heartbeat is sent by a small thread through the network's gate (so a bus-off node
    falls silent) instead of the bus's periodic-send task: python-can-remote's task cannot
    change its data (heartbeat state) and stops with the client.  Once :meth:`stop_heartbeat`
    returns, no heartbeat of that thread is sent any more (one it was sending is on the bus)."""

    def __init__(self, node_id: int, local_node):
        super().__init__(node_id, local_node)
        self.node = local_node
        self._hb_stop: tuple[threading.Event, threading.Lock] | None = None

    # canopen 2.4's NMT classes keep the numeric state in their private ``_state`` and offer
    # only the name (``state``), whose setter sends an NMT command.  The device model needs
    # the number (the heartbeat byte, the PDO gate) and must set it without a command (at
    # boot and on a reset): this property is the one place that touches ``_state``.
    # (:meth:`start_heartbeat` keeps NmtSlave's ``_heartbeat_time_ms`` as the method it
    # replaces does.)
    @property
    def code(self) -> int:
        """The NMT state as its number (0 INITIALISING, 4 STOPPED, 5 OPERATIONAL,
        127 PRE-OPERATIONAL); setting it changes the state without a command."""
        return self._state

    @code.setter
    def code(self, value: int) -> None:
        self._state = value

    def on_command(self, can_id, data, timestamp):
        old = self.code
        super().on_command(can_id, data, timestamp)
        if self.code != old or self.code == 0:
            self.node.on_nmt_state(old, self.code)

    def start_heartbeat(self, heartbeat_time_ms: int):
        self._heartbeat_time_ms = heartbeat_time_ms
        self.stop_heartbeat()
        if heartbeat_time_ms <= 0 or self.node.heartbeat_suppressed:
            return
        stop, sending = threading.Event(), threading.Lock()
        self._hb_stop = (stop, sending)
        period = heartbeat_time_ms / 1000.0

        def produce():
            while not stop.wait(period):
                with sending:
                    if stop.is_set():
                        return
                    try:
                        self.network.send_message(0x700 + self.id, [self.code])
                    except Exception:  # noqa: BLE001 - bus closed: the node is gone
                        return
        threading.Thread(target=produce, name=f"heartbeat-{self.id}", daemon=True).start()

    def stop_heartbeat(self):
        if self._hb_stop is not None:
            stop, sending = self._hb_stop
            self._hb_stop = None
            stop.set()
            with sending:                  # a heartbeat being sent now has gone out
                pass

    def update_heartbeat(self):
        pass                               # the producer reads the current state every period


class SlaveNode(canopen.LocalNode):
    """LocalNode + SYNC-triggered TPDOs, RPDO → dictionary, EMCY register, device faults."""

    EDS: str = ""

    def __init__(self, node_id: int, eds: str | Path | None = None):
        od = canopen.import_od(str(eds or EDS_DIR / self.EDS), node_id)
        super().__init__(node_id, od)
        # LocalNode registers its own NmtSlave's callback and has no public way to remove it
        self._write_callbacks.remove(self.nmt.on_write)
        self.nmt = _Nmt(node_id, self)
        self.add_write_callback(self.nmt.on_write)
        self.add_write_callback(self._check_mapping)
        self.heartbeat_suppressed = False
        self.muted = False
        self.tpdos: list[PdoConfig] = []
        self.rpdos: dict[int, PdoConfig] = {}
        self._rpdo_pending: dict[int, bytes] = {}
        self._lock = threading.RLock()
        self.error_register = 0

    # ---------------------------------------------------------------- NMT
    def boot(self) -> None:
        """Power-up: boot-up message, PRE-OPERATIONAL, heartbeat from 0x1017."""
        self.nmt.code = 0
        self.nmt.send_command(0x80)     # INITIALISING -> PRE-OPERATIONAL (sends boot-up first)

    def on_nmt_state(self, old: int, new: int) -> None:
        if new == 0:                    # reset node / reset communication: reboot
            for index in list(self.data_store):
                if 0x1000 <= index < 0x2000:
                    del self.data_store[index]
            self.nmt.code = 0
            self.network.send_message(0x700 + self.id, [0])
            self.nmt.code = 127
            self.nmt.start_heartbeat(self.sdo[0x1017].raw)
            self._stop_pdos()
            return
        if new == 5:                    # OPERATIONAL: PDOs from the dictionary
            self.load_pdo_config()
        elif old == 5:
            self._stop_pdos()

    # ---------------------------------------------------------------- PDO engine
    def _raw(self, index: int, subindex: int) -> int:
        obj = self._find_object(index, subindex)
        return obj.decode_raw(self.get_data(index, subindex))

    def _check_mapping(self, index: int, subindex: int, od, data: bytes) -> None:
        """Mapping entries (0x1600.., 0x1A00..): object must exist, be mappable, size must match."""
        if not (0x1600 <= index <= 0x17FF or 0x1A00 <= index <= 0x1BFF) or subindex == 0:
            return
        value = struct.unpack_from("<I", data)[0]
        if value == 0:
            return
        idx, sub, bits = value >> 16, (value >> 8) & 0xFF, value & 0xFF
        try:
            obj = self._find_object(idx, sub)
        except SdoAbortedError:
            raise SdoAbortedError(0x06040041) from None          # object cannot be mapped
        if not obj.pdo_mappable:
            raise SdoAbortedError(0x06040041)
        if bits != len(obj) or bits % 8:
            raise SdoAbortedError(0x06040042)                   # PDO length exceeded / mismatch

    def _read_pdo(self, com: int, mapping: int, fast: dict) -> PdoConfig | None:
        cob = self._raw(com, 1)
        if cob & PDO_INVALID:
            return None
        cfg = PdoConfig(cob_id=cob & 0x7FF, trans_type=self._raw(com, 2))
        for sub in range(1, self._raw(mapping, 0) + 1):
            value = self._raw(mapping, sub)
            idx, s, bits = value >> 16, (value >> 8) & 0xFF, value & 0xFF
            if idx:
                cfg.entries.append((idx, s, bits // 8))
                cfg.length += bits // 8
        codes, access = [], []
        for idx, s, nbytes in cfg.entries:
            obj = self._find_object(idx, s)
            code = _INT_CODES.get((obj.data_type in (2, 3, 4), nbytes))
            if code is None or idx not in fast:
                return cfg
            codes.append(code)
            access.append(fast[idx])
        cfg.codec = struct.Struct("<" + "".join(codes))
        cfg.access = tuple(access)
        cfg.msg = can.Message(arbitration_id=cfg.cob_id, data=bytearray(cfg.length), is_extended_id=False)
        return cfg

    def fast_getters(self) -> dict:
        """index → () -> int for the objects a TPDO may map without the dictionary (subclasses)."""
        return {}

    def fast_setters(self) -> dict:
        """index → (int) -> None for the objects an RPDO may map without the dictionary (subclasses):
        the same effect as the dictionary's write callbacks for that object."""
        return {}

    def load_pdo_config(self) -> None:
        with self._lock:
            self._stop_pdos()
            od = self.object_dictionary
            for i in range(512):
                if 0x1800 + i in od:
                    cfg = self._read_pdo(0x1800 + i, 0x1A00 + i, self.fast_getters())
                    if cfg is not None:
                        self.tpdos.append(cfg)
                if 0x1400 + i in od:
                    cfg = self._read_pdo(0x1400 + i, 0x1600 + i, self.fast_setters())
                    if cfg is not None:
                        self.rpdos[cfg.cob_id] = cfg
                        self.network.subscribe(cfg.cob_id, self._on_rpdo)

    def _stop_pdos(self) -> None:
        with self._lock:
            for cob in self.rpdos:
                try:
                    self.network.unsubscribe(cob, self._on_rpdo)
                except (KeyError, ValueError):
                    pass
            self.tpdos = []
            self.rpdos = {}
            self._rpdo_pending = {}

    def _on_rpdo(self, can_id: int, data: bytearray, timestamp: float) -> None:
        if self.muted or self.nmt.code != 5:
            return
        cfg = self.rpdos.get(can_id)
        if cfg is None or len(data) < cfg.length:
            return
        if cfg.trans_type <= 240:
            self._rpdo_pending[can_id] = bytes(data)      # actuated at the next SYNC
        else:
            self._apply_rpdo(cfg, bytes(data))

    def _apply_rpdo(self, cfg: PdoConfig, data: bytes) -> None:
        if cfg.codec is not None:
            # fast path: the setters do what the write callbacks would; the raw bytes are kept
            # in the dictionary for SDO reads
            off = 0
            for (idx, sub, nbytes), setter, value in zip(cfg.entries, cfg.access, cfg.codec.unpack_from(data)):
                setter(value)
                self.data_store.setdefault(idx, {})[sub] = data[off:off + nbytes]
                off += nbytes
            return
        off = 0
        for idx, sub, nbytes in cfg.entries:
            self.set_data(idx, sub, data[off:off + nbytes])
            off += nbytes

    def apply_pending_rpdos(self) -> None:
        """SYNC: write the buffered synchronous RPDOs into the dictionary."""
        with self._lock:
            pending, self._rpdo_pending = self._rpdo_pending, {}
            for cob, data in pending.items():
                cfg = self.rpdos.get(cob)
                if cfg is not None:
                    self._apply_rpdo(cfg, data)

    def transmit_sync_tpdos(self) -> None:
        """SYNC: build and send every synchronous TPDO that is due."""
        if self.muted or self.nmt.code != 5:
            return
        with self._lock:
            for cfg in self.tpdos:
                if cfg.trans_type > 240:
                    continue
                cfg.counter += 1
                if cfg.trans_type and cfg.counter < cfg.trans_type:
                    continue
                cfg.counter = 0
                if cfg.codec is not None:
                    self.network.send_pdo(cfg.msg, cfg.codec.pack(*[get() for get in cfg.access]))
                    continue
                payload = b"".join(self.get_data(i, s)[:n] for i, s, n in cfg.entries)
                self.network.send_message(cfg.cob_id, payload)

    # ---------------------------------------------------------------- EMCY and faults
    def emergency(self, code: int, register_bits: int = 0x01, data: bytes = b"") -> None:
        """Send an EMCY frame and set the error register (0x1001)."""
        self.error_register |= register_bits
        self.emcy.send(code, self.error_register, data)

    def suppress_heartbeat(self) -> None:
        self.heartbeat_suppressed = True
        self.nmt.stop_heartbeat()

    def go_bus_off(self) -> None:
        """The node's controller leaves the bus: it sends nothing and hears nothing."""
        self.muted = True
        self.nmt.stop_heartbeat()
        self.network.deaf.add(self.id)

    def get_data(self, index: int, subindex: int, check_readable: bool = False) -> bytes:
        if index == 0x1001:
            return bytes([self.error_register])
        return super().get_data(index, subindex, check_readable)
