"""The exoskeleton on CANopen: CiA 402 drive (CST, mode 10) + CiA 406 load encoder per joint.

Start-up (:meth:`CanopenHardware.start`), over SDO, after CiA 301 / 402 / 406:

1. NMT pre-operational; per node: device type 0x1000 (profile 402 / 406), identity 0x1018
   (vendor, product as in our EDS), encoder resolution (drive 0x608F = 2^bits per motor turn,
   encoder 0x6501 = 2^bits, 0x6502 turns), gear 0x6091, supported modes 0x6502 (CST), rated
   torque 0x6076 — any difference is a :class:`~drivers.errors.DeviceMismatch` naming node and
   object;
2. interpolation period 0x60C2 = the loop period, max torque 0x6072 from ``torque_limit``;
3. PDO mapping written with canopen's PDO API and read back: drive TPDO1 = statusword 0x6041,
   torque actual 0x6077, position actual 0x6064 (8 bytes, on every SYNC), encoder TPDO1 =
   position value 0x6004 (4 bytes, every SYNC), drive RPDO1 = controlword 0x6040 + target torque
   0x6071 (synchronous); every other PDO disabled;
4. heartbeat producer 0x1017 on every node, first heartbeat awaited;
5. NMT operational; our own heartbeat (node ``master_node``) starts and each drive watches it
   (consumer heartbeat 0x1016 = ``heartbeat_timeout_ms``, reaction 0x6007 = quick stop): the
   heartbeat is sent from ``read()``, so a daemon that dies or stops cycling leaves the drive
   quick-stopped — call ``read()`` within ``heartbeat_timeout_ms`` after ``start()``;
   mode 10 (0x6060, checked on 0x6061), CiA 402 state machine walked to OPERATION_ENABLED
   (fault reset first if needed);
6. one priming cycle (zero torque, or ``start(initial_torque)``) that sets the unwrapping reference (the load encoder's single-turn
   count is centred on (-π, π]).

Cycle — PDOs only: ``write(tau)`` sends the RPDO; ``read()`` sends SYNC and takes that cycle's
TPDOs.  The rx callbacks copy the frame bytes into preallocated buffers under a lock (a
snapshot, no torn reads); ``read()`` copies the snapshot and decodes it with precompiled
structs.  Counts become joint-side radians (gear ratio, multi-turn unwrapping, offsets) and per
mille of rated torque becomes N m.  Detected: missing TPDOs, late frames, heartbeat timeout,
EMCY, drive leaving OPERATION_ENABLED, encoder jumps beyond ``max_joint_speed``, stuck
encoders, failed sends and bus-off.

The synchronous RPDO written in cycle k is actuated by the drive at SYNC k+1 and acts over
[t_k+1, t_k+2]; :attr:`Measurement.tau_m_applied` (0x6077) is the torque that acted over the
cycle ending at the sample time (see :mod:`drivers.interface` for the whole timing).
"""
from __future__ import annotations

import math
import struct
import threading
import time

import can
import canopen
import numpy as np
from canopen.emcy import EmcyError
from canopen.sdo import SdoAbortedError, SdoCommunicationError

from sea_daemon.core.config import ModelConfig
from sea_daemon.io.configfile import repo_root

from drivers import cia402
from drivers.bus import make_bus
from drivers.errors import (
    BusOff, DeviceMismatch, DriveFault, EmcyReceived, EncoderJump, EncoderStuck, HeartbeatLost,
    PdoLengthError, PdoTimeout, SendFailed, WrongDevice)
from drivers.interface import FaultFlag, HardwareInterface, Measurement

EDS_DIR = repo_root() / "configs" / "eds"
DRIVE_EDS = EDS_DIR / "sea_drive.eds"
ENCODER_EDS = EDS_DIR / "sea_load_encoder.eds"

PROFILE_DRIVE, PROFILE_ENCODER = 402, 406
NMT_OPERATIONAL = 0x05
ABORT_QUICK_STOP = 3                    # 0x6007: reaction of the drive to a lost connection

DRIVE_TPDO = struct.Struct("<Hhi")      # 0x6041 statusword, 0x6077 torque actual [‰], 0x6064 position
ENCODER_TPDO = struct.Struct("<I")      # 0x6004 position value
DRIVE_RPDO = struct.Struct("<Hh")       # 0x6040 controlword, 0x6071 target torque [‰]

DRIVE_TPDO_MAP = ((0x6041, 0), (0x6077, 0), (0x6064, 0))
ENCODER_TPDO_MAP = ((0x6004, 0),)
DRIVE_RPDO_MAP = ((0x6040, 0), (0x6071, 0))


def _wrap(delta: int, span: int) -> int:
    """Shortest signed difference of two counters that wrap at ``span``."""
    return (delta + span // 2) % span - span // 2


def interpolation_period(period: float) -> tuple[int, int]:
    """0x60C2 (value, index) with value·10^index = period, value in 1..255, index -6..0."""
    for index in range(-3, -7, -1):
        value = period * 10.0 ** (-index)
        if 1 <= round(value) <= 255 and abs(round(value) - value) < 1e-6 * max(1.0, value):
            return int(round(value)), index
    for index in range(0, -7, -1):
        value = period * 10.0 ** (-index)
        if 1 <= round(value) <= 255:
            return int(round(value)), index
    raise ValueError(f"period {period} s cannot be written to 0x60C2 (1..255 · 10^-6..10^0 s)")


class _Slot:
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


class _ErrorFrames(can.Listener):
    """Watches error frames for the bus-off flag (SocketCAN: CAN_ERR_BUSOFF = 0x40)."""

    def __init__(self):
        self.bus_off = False

    def on_message_received(self, msg: can.Message) -> None:
        if msg.is_error_frame and msg.arbitration_id & 0x40:
            self.bus_off = True


class CanopenHardware(HardwareInterface):
    """:class:`HardwareInterface` on a CANopen bus (see the module docstring for the sequence)."""

    def __init__(self, cfg: ModelConfig, bus: can.BusABC | None = None, *, period: float | None = None,
                 pdo_timeout: float | None = None, clock=time.monotonic):
        hw, b = cfg.hardware, cfg.hardware.bus
        self.cfg, self.bus_cfg = cfg, b
        self.n = cfg.joints
        self.period = float(period or cfg.dt)
        self.gear = hw.gear_ratio
        self.res = 1 << hw.encoder_bits
        self.torque_limit = hw.torque_limit
        self.pdo_timeout = pdo_timeout if pdo_timeout is not None else b.pdo_timeout_ms / 1e3
        #: cycles between write() and the interval the torque acts over (see drivers.interface)
        self.actuation_delay = 1 if b.sync_rpdo else 0
        self.hb_timeout = b.heartbeat_timeout_ms / 1e3
        self.clock = clock
        self._bus, self._owns_bus = bus, bus is None
        self.drive_ids, self.encoder_ids = list(b.drive_node), list(b.encoder_node)
        self.network: canopen.Network | None = None
        self.drives: list = []
        self.encoders: list = []
        n = self.n
        # conversions (joint side)                     counts → rad
        self.k_q = 2 * math.pi / self.res                                  # load encoder
        self.k_m = 2 * math.pi / (self.res * self.gear)                    # motor encoder through the gear
        self.nm_per_permille = b.rated_torque / 1e6 * self.gear            # 1 ‰ of 0x6076 on the joint side
        self.max_permille = min(32767, int(math.ceil(self.torque_limit / self.nm_per_permille)))
        self.q_offset = np.array(b.q_offset, dtype=float)
        self.theta_m_offset = np.array(b.theta_m_offset, dtype=float)
        self.enc_range = [self.res] * n
        # cycle state
        self.meas = Measurement(n)
        self._slots: list[_Slot] = []
        self._rx_lock = threading.Lock()
        self._all_rx = threading.Event()
        self._arrived = 0
        self._window_open = False
        self._late_frames = 0
        self._hb_last = {}
        self._hb_state = {}
        self._emcy: dict[int, tuple[int, int, bytes] | None] = {}
        self._errors = _ErrorFrames()
        self._rpdo_msgs: list[can.Message] = []
        self._sync_msg = can.Message(arbitration_id=0x80, data=b"", is_extended_id=False)
        self._hb_msg = can.Message(arbitration_id=0x700 + b.master_node, data=bytes([NMT_OPERATIONAL]),
                                   is_extended_id=False)
        self._hb_period = b.heartbeat_ms / 1e3
        self._hb_next = 0.0
        self._hb_on = False
        self._cw = cia402.CW_ENABLE_OPERATION
        self._quick_stopped = False
        self._u_q = [0] * n            # unwrapped load counts
        self._u_m = [0] * n            # unwrapped motor counts (int32 wraps undone)
        self._raw_q = [0] * n
        self._raw_m = [0] * n
        self._primed = False
        self._stuck_q = [[0, 0.0] for _ in range(n)]   # [unchanged cycles, other angle at run start]
        self._stuck_m = [[0, 0.0] for _ in range(n)]
        self._prev_q = [0] * n         # raw counts of the last cycle (stuck detection)
        self._prev_m = [0] * n
        self._cycle = -1
        self._started = False

    # ================================================================== start-up (SDO)
    def start(self, initial_torque: np.ndarray | None = None) -> None:
        """Start-up sequence; the priming cycle commands ``initial_torque`` [N m] (default 0)."""
        if self._started:
            return
        self._initial_torque = np.zeros(self.n) if initial_torque is None else \
            np.asarray(initial_torque, dtype=float).reshape(self.n)
        bus = self._bus if self._bus is not None else make_bus(self.bus_cfg)
        self._bus = bus
        net = canopen.Network(bus)
        net.NOTIFIER_CYCLE = 0.05          # bounded shutdown: the rx thread wakes every 50 ms
        net.listeners.append(self._errors)
        net.connect()
        self.network = net
        try:
            self._startup()
        except BaseException:
            self._release()
            raise
        self._started = True

    def _startup(self) -> None:
        net = self.network
        for j in range(self.n):
            self.drives.append(net.add_node(self.drive_ids[j], str(DRIVE_EDS)))
            self.encoders.append(net.add_node(self.encoder_ids[j], str(ENCODER_EDS)))
        for node in self.drives + self.encoders:
            node.sdo.RESPONSE_TIMEOUT = self.bus_cfg.sdo_timeout_ms / 1e3
            self._hb_last[node.id] = None
            self._hb_state[node.id] = None
            self._emcy[node.id] = None
            net.subscribe(0x700 + node.id, self._on_heartbeat)
            net.subscribe(0x80 + node.id, self._on_emcy)
        net.nmt.state = "PRE-OPERATIONAL"                                 # broadcast
        for j in range(self.n):
            self._check_drive(self.drives[j])
            self.enc_range[j] = self._check_encoder(self.encoders[j])
        for j in range(self.n):
            self._configure_drive(self.drives[j])
            self._configure_encoder(self.encoders[j])
        for node in self.drives + self.encoders:
            self._sdo_write(node, 0x1017, 0, self.bus_cfg.heartbeat_ms, "producer heartbeat time")
        self._await_heartbeats()
        for node in self.drives + self.encoders:
            node.nmt.state = "OPERATIONAL"
        self._await_heartbeats(NMT_OPERATIONAL)
        for drive in self.drives:
            # the drive watches our heartbeat; losing it means quick stop (the daemon died or hangs)
            self._sdo_write(drive, 0x6007, 0, ABORT_QUICK_STOP, "abort connection option code")
            self._sdo_write(drive, 0x1016, 1, (self.bus_cfg.master_node << 16) | self.bus_cfg.heartbeat_timeout_ms,
                            "consumer heartbeat time")
        self._send_master_heartbeat(force=True)        # the drives' watch starts with this one
        self._hb_on = True
        for drive in self.drives:
            self._sdo_write(drive, 0x6060, 0, cia402.MODE_CST, "modes of operation")
            mode = self._sdo_read(drive, 0x6060 + 1, 0, "modes of operation display")
            if mode != cia402.MODE_CST:
                raise WrongDevice(drive.id, "0x6061 modes of operation display",
                                     f"is {mode}, expected {cia402.MODE_CST} (cyclic synchronous torque)")
            self._enable(drive)
        self._prime()

    # ---------------------------------------------------------------- SDO helpers
    def _sdo_read(self, node, index: int, sub: int, what: str) -> int:
        if self._hb_on:
            self._send_master_heartbeat()            # keep the drives' watch happy during SDO sequences
        try:
            var = node.sdo[index] if sub == 0 and not isinstance(node.sdo[index], canopen.sdo.SdoRecord) \
                else node.sdo[index][sub]
            return var.raw
        except SdoAbortedError as e:
            raise WrongDevice(node.id, f"0x{index:04X}:{sub:02X} {what}", f"SDO read aborted: {e}") from None
        except SdoCommunicationError as e:
            raise DeviceMismatch(node.id, f"0x{index:04X}:{sub:02X} {what}", f"no SDO answer: {e}") from None

    def _sdo_write(self, node, index: int, sub: int, value: int, what: str) -> None:
        if self._hb_on:
            self._send_master_heartbeat()
        try:
            obj = node.sdo[index]
            (obj[sub] if isinstance(obj, (canopen.sdo.SdoRecord, canopen.sdo.SdoArray)) else obj).raw = value
        except SdoAbortedError as e:
            raise WrongDevice(node.id, f"0x{index:04X}:{sub:02X} {what}",
                                 f"SDO write of {value} aborted: {e}") from None
        except SdoCommunicationError as e:
            raise DeviceMismatch(node.id, f"0x{index:04X}:{sub:02X} {what}", f"no SDO answer: {e}") from None

    def _check_identity(self, node, profile: int, kind: str) -> None:
        dtype = self._sdo_read(node, 0x1000, 0, "device type")
        if dtype & 0xFFFF != profile:
            raise WrongDevice(node.id, "0x1000 device type",
                                 f"is 0x{dtype:08X} (profile {dtype & 0xFFFF}), expected profile {profile} ({kind})")
        info = node.object_dictionary.device_information
        for sub, what, expected in ((1, "vendor-ID", info.vendor_number), (2, "product code", info.product_number)):
            got = self._sdo_read(node, 0x1018, sub, what)
            if expected is not None and got != expected:
                raise WrongDevice(node.id, f"0x1018:{sub:02X} {what}",
                                     f"is 0x{got:08X}, expected 0x{expected:08X} ({kind} of our EDS)")

    def _check_drive(self, d) -> None:
        self._check_identity(d, PROFILE_DRIVE, "CiA 402 drive")
        inc = self._sdo_read(d, 0x608F, 1, "position encoder resolution, encoder increments")
        rev = self._sdo_read(d, 0x608F, 2, "position encoder resolution, motor revolutions")
        if rev == 0 or inc != self.res * rev:
            raise WrongDevice(d.id, "0x608F position encoder resolution",
                                 f"is {inc} increments per {rev} motor revolution(s), expected {self.res} per 1 "
                                 f"(hardware.encoder_bits = {self.res.bit_length() - 1})")
        motor = self._sdo_read(d, 0x6091, 1, "gear ratio, motor revolutions")
        shaft = self._sdo_read(d, 0x6091, 2, "gear ratio, shaft revolutions")
        if shaft == 0 or abs(motor / shaft - self.gear) > 1e-9 * self.gear:
            raise WrongDevice(d.id, "0x6091 gear ratio",
                                 f"is {motor}:{shaft}, expected {self.gear:g}:1 (hardware.gear_ratio)")
        modes = self._sdo_read(d, 0x6502, 0, "supported drive modes")
        if not modes & cia402.SUPPORTED_MODE_BIT[cia402.MODE_CST]:
            raise WrongDevice(d.id, "0x6502 supported drive modes",
                                 f"is 0x{modes:08X}, needs bit 9 (cyclic synchronous torque, mode 10)")
        rated = self._sdo_read(d, 0x6076, 0, "motor rated torque")
        if abs(rated - self.bus_cfg.rated_torque) > 1e-9 * self.bus_cfg.rated_torque:
            raise WrongDevice(d.id, "0x6076 motor rated torque",
                                 f"is {rated} mN m, expected {self.bus_cfg.rated_torque:g} mN m "
                                 f"(hardware.bus.rated_torque)")

    def _check_encoder(self, e) -> int:
        self._check_identity(e, PROFILE_ENCODER, "CiA 406 encoder")
        res = self._sdo_read(e, 0x6501, 0, "singleturn resolution")
        if res != self.res:
            raise WrongDevice(e.id, "0x6501 singleturn resolution",
                                 f"is {res}, expected {self.res} (hardware.encoder_bits = {self.res.bit_length() - 1})")
        turns = self._sdo_read(e, 0x6502, 0, "number of distinguishable revolutions")
        if not 1 <= turns <= (1 << 32) // res:
            raise WrongDevice(e.id, "0x6502 number of distinguishable revolutions",
                                 f"is {turns}, allowed 1..{(1 << 32) // res}")
        return res * turns

    # ---------------------------------------------------------------- PDO configuration
    def _map(self, node, pdo, number: int, entries, cob_id: int, expected_bytes: int | None,
             trans_type: int = 1) -> None:
        """Write one PDO's communication and mapping parameters; read the mapping back."""
        m = pdo[number]
        what = f"0x{m.map_array.od.index:04X} {'TPDO' if m.map_array.od.index >= 0x1A00 else 'RPDO'}{number} mapping"
        m.clear()
        for index, sub in entries:
            m.add_variable(index, sub)
        m.cob_id = cob_id
        m.trans_type = trans_type             # 1: synchronous, every SYNC; 255: on event / reception
        m.enabled = bool(entries)
        try:
            m.save()
        except SdoAbortedError as e:
            raise WrongDevice(node.id, what, f"rejected by the device: {e}") from None
        except SdoCommunicationError as e:
            raise DeviceMismatch(node.id, what, f"no SDO answer: {e}") from None
        if m.enabled:
            self.network.unsubscribe(cob_id, m.on_message)       # we snapshot frames ourselves
        if expected_bytes is None:
            return
        count = self._sdo_read(node, m.map_array.od.index, 0, "number of mapped objects")
        bits = sum(self._sdo_read(node, m.map_array.od.index, s, "mapping entry") & 0xFF for s in range(1, count + 1))
        if count != len(entries) or bits != 8 * expected_bytes:
            raise WrongDevice(node.id, what, f"reads back {count} objects, {bits // 8} bytes; "
                                                f"expected {len(entries)} objects, {expected_bytes} bytes")

    def _configure_drive(self, d) -> None:
        value, index = interpolation_period(self.period)
        self._sdo_write(d, 0x60C2, 1, value, "interpolation time period value")
        self._sdo_write(d, 0x60C2, 2, index, "interpolation time index")
        self._sdo_write(d, 0x6072, 0, self.max_permille, "max torque")
        self._map(d, d.tpdo, 1, DRIVE_TPDO_MAP, 0x180 + d.id, DRIVE_TPDO.size)
        self._map(d, d.tpdo, 2, (), 0x280 + d.id, None)
        self._map(d, d.rpdo, 1, DRIVE_RPDO_MAP, 0x200 + d.id, DRIVE_RPDO.size,
                  1 if self.bus_cfg.sync_rpdo else 255)
        self._map(d, d.rpdo, 2, (), 0x300 + d.id, None)
        self._slots.append(_Slot(d.id, 0x180 + d.id, DRIVE_TPDO.size))
        self.network.subscribe(0x180 + d.id, self._rx_callback(self._slots[-1]))
        self._rpdo_msgs.append(can.Message(arbitration_id=0x200 + d.id, data=bytearray(DRIVE_RPDO.size),
                                           is_extended_id=False))

    def _configure_encoder(self, e) -> None:
        self._map(e, e.tpdo, 1, ENCODER_TPDO_MAP, 0x180 + e.id, ENCODER_TPDO.size)
        self._map(e, e.tpdo, 2, (), 0x280 + e.id, None)
        self._slots.append(_Slot(e.id, 0x180 + e.id, ENCODER_TPDO.size))
        self.network.subscribe(0x180 + e.id, self._rx_callback(self._slots[-1]))

    def _await_heartbeats(self, state: int | None = None) -> None:
        """Wait for a heartbeat of every node (reporting ``state`` when given)."""
        for node in self.drives + self.encoders:
            self._hb_last[node.id] = None
        deadline = self.clock() + self.hb_timeout
        for node in self.drives + self.encoders:
            while self._hb_last[node.id] is None or (state is not None and self._hb_state[node.id] != state):
                if self.clock() > deadline:
                    raise HeartbeatLost(node.id, self.hb_timeout, self.hb_timeout, self._hb_state[node.id])
                time.sleep(0.001)

    def _enable(self, d) -> None:
        """Walk the CiA 402 state machine to OPERATION_ENABLED over SDO."""
        state = None
        for _ in range(8):
            sw = self._sdo_read(d, 0x6041, 0, "statusword")
            state = cia402.state_of(sw)
            if state is cia402.State.OPERATION_ENABLED:
                return
            cw = cia402.command_towards(state)
            if cw is None:
                time.sleep(self.period)
                continue
            self._sdo_write(d, 0x6040, 0, cw, "controlword")
        raise DeviceMismatch(d.id, "0x6041 statusword",
                             f"drive did not reach OPERATION_ENABLED, stays in {state.name if state else 'invalid state'}")

    def _prime(self) -> None:
        """First cycle (at the initial torque): sets the unwrapping reference."""
        self._primed = False
        self.write(getattr(self, "_initial_torque", np.zeros(self.n)))
        self.read()

    def actuated(self, tau_m: np.ndarray) -> np.ndarray:
        """The joint-side torque the drive applies for a ``write(tau_m)``: per-mille steps, max torque."""
        tau = np.nan_to_num(np.asarray(tau_m, dtype=float).reshape(self.n), nan=0.0, posinf=0.0, neginf=0.0)
        pm = np.clip(np.round(tau / self.nm_per_permille), -self.max_permille, self.max_permille)
        return pm * self.nm_per_permille

    # ================================================================== rx callbacks
    def _rx_callback(self, slot: _Slot):
        lock, event, slots = self._rx_lock, self._all_rx, self._slots

        def on_tpdo(can_id, data, timestamp):
            with lock:
                if not self._window_open:      # no SYNC waiting: a frame of an earlier cycle
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

    def _on_heartbeat(self, can_id, data, timestamp) -> None:
        node = can_id - 0x700
        self._hb_last[node] = self.clock()
        self._hb_state[node] = data[0] & 0x7F if data else None

    def _on_emcy(self, can_id, data, timestamp) -> None:
        if len(data) < 3:
            return
        code = data[0] | data[1] << 8
        if code == 0:                      # "error reset / no error"
            return
        self._emcy[can_id - 0x80] = (code, data[2], bytes(data[3:8]))

    # ================================================================== the cycle (PDO only)
    def write(self, tau_m: np.ndarray) -> None:
        """Target torque [N m, joint side] → ‰ of 0x6076 in the drives' RPDOs."""
        if self.network is None:
            raise RuntimeError("CanopenHardware: call start() before read() / write()")
        tau = np.asarray(tau_m, dtype=float)
        for j, msg in enumerate(self._rpdo_msgs):
            t = float(tau[j])
            permille = int(round(t / self.nm_per_permille)) if math.isfinite(t) else 0
            permille = max(-self.max_permille, min(self.max_permille, permille))
            DRIVE_RPDO.pack_into(msg.data, 0, self._cw, permille)
            self._send(msg, "RPDO1 (controlword, target torque)")

    def _send_master_heartbeat(self, force: bool = False) -> None:
        """Our heartbeat, from the cycle itself: it stops when the loop stops calling read()."""
        now = self.clock()
        if force or now >= self._hb_next:
            self._hb_next = now + self._hb_period
            self._send(self._hb_msg, "master heartbeat")

    def _send(self, msg: can.Message, what: str) -> None:
        if self._errors.bus_off:
            raise BusOff("error frame with the bus-off flag received")
        try:
            with self.network.send_lock:
                self._bus.send(msg)
        except (can.CanError, OSError) as e:
            if "bus-off" in str(e).lower() or "bus off" in str(e).lower():
                raise BusOff(f"sending {what}: {e}") from None
            raise SendFailed(msg.arbitration_id, what, e) from None

    def read(self) -> Measurement:
        """SYNC → this cycle's TPDOs → joint-side measurement (reused object)."""
        if self.network is None:
            raise RuntimeError("CanopenHardware: call start() before read() / write()")
        m = self.meas
        m.faults = 0
        self._check_async()
        self._send_master_heartbeat()
        with self._rx_lock:
            for s in self._slots:
                s.count = 0
                s.bad_len = 0
            self._arrived = 0
            self._all_rx.clear()
            if self._late_frames:
                m.faults |= FaultFlag.FRAME_LATE
                self._late_frames = 0
            self._window_open = True
        t_sync = self.clock()
        try:
            self._send(self._sync_msg, "SYNC")
        except BaseException:
            self._window_open = False
            raise
        self._all_rx.wait(self.pdo_timeout)
        with self._rx_lock:
            self._window_open = False
            for s in self._slots:
                s.snap[:] = s.buf
                s.snap_count = s.count
        self._cycle += 1
        self._check_emcy()                 # an EMCY sent before the TPDOs has arrived before them
        m.cycle = self._cycle
        m.t = self._cycle * self.period
        m.t_mono = t_sync
        m.valid = True
        missing = None
        for s in self._slots:
            if s.bad_len:
                m.faults |= FaultFlag.PDO_MISSING
                m.valid = False
                raise PdoLengthError(s.node, s.cob_id, max(s.bad_len, 0), s.length, self._cycle)
            if s.snap_count == 0:
                s.missed += 1
                m.faults |= FaultFlag.PDO_MISSING
                m.valid = False
                if missing is None or s.missed > missing.missed:
                    missing = s
            else:
                s.missed = 0
                if s.snap_count > 1:
                    m.faults |= FaultFlag.FRAME_LATE
        if missing is not None:
            if missing.missed > self.bus_cfg.max_missed_cycles or not self._primed:
                raise PdoTimeout(missing.node, missing.cob_id, self._cycle, self.pdo_timeout, missing.missed)
            return m                                   # values held from the last cycle
        self._decode(m)
        return m

    def _check_emcy(self) -> None:
        for node, e in self._emcy.items():
            if e is not None:
                self._emcy[node] = None
                self.meas.faults |= FaultFlag.EMCY
                raise EmcyReceived(node, e[0], e[1], e[2], EmcyError(e[0], e[1], e[2], 0.0).get_desc())

    def _check_async(self) -> None:
        """Faults that arrive between cycles: EMCY, heartbeat, bus-off."""
        if self._errors.bus_off:
            raise BusOff("error frame with the bus-off flag received")
        self._check_emcy()
        now = self.clock()
        for node, last in self._hb_last.items():
            if last is None or now - last > self.hb_timeout:
                self.meas.faults |= FaultFlag.HEARTBEAT_LOST
                raise HeartbeatLost(node, now - (last or 0.0), self.hb_timeout)
            state = self._hb_state[node]
            if self._primed and state is not None and state != NMT_OPERATIONAL:
                self.meas.faults |= FaultFlag.HEARTBEAT_LOST
                raise HeartbeatLost(node, now - last, self.hb_timeout, state)

    def _decode(self, m: Measurement) -> None:
        n = self.n
        for j in range(n):
            ds, es = self._slots[2 * j], self._slots[2 * j + 1]
            sw, torque, pos = DRIVE_TPDO.unpack_from(ds.snap, 0)
            (qc,) = ENCODER_TPDO.unpack_from(es.snap, 0)
            m.statusword[j] = sw
            m.q_counts[j] = qc
            m.theta_m_counts[j] = pos
            m.tau_m_applied[j] = torque * self.nm_per_permille
            if sw & 0x6F != cia402.State.OPERATION_ENABLED.bits and self._primed:
                m.faults |= FaultFlag.DRIVE_STATE
                st = cia402.state_of(sw)
                if not (self._quick_stopped and st is not cia402.State.FAULT):
                    raise DriveFault(ds.node, sw, st.name if st else "invalid")
                # after safe_stop() a quick-stopped / disabled drive is what was asked for: flag only
            rng = self.enc_range[j]
            if not self._primed:
                # load: single-turn absolute, centred on (-range/2, range/2]
                self._u_q[j] = qc - rng if qc >= rng // 2 else qc
                # motor: multi-turn count (single-turn count + 2^bits per shaft turn), int32
                self._u_m[j] = pos
            else:
                dq = _wrap(qc - self._raw_q[j], rng)
                dm = _wrap(pos - self._raw_m[j], 1 << 32)
                allowed_q = self.bus_cfg.max_joint_speed * self.period + 2 * self.k_q
                allowed_m = self.bus_cfg.max_joint_speed * self.period + 2 * self.k_m
                if abs(dq * self.k_q) > allowed_q:
                    m.faults |= FaultFlag.ENCODER_JUMP
                    raise EncoderJump(es.node, "0x6004 load position value", dq * self.k_q, allowed_q, self._cycle)
                if abs(dm * self.k_m) > allowed_m:
                    m.faults |= FaultFlag.ENCODER_JUMP
                    raise EncoderJump(ds.node, "0x6064 motor position actual value", dm * self.k_m, allowed_m,
                                      self._cycle)
                self._u_q[j] += dq
                self._u_m[j] += dm
            self._raw_q[j], self._raw_m[j] = qc, pos
            m.q[j] = self._u_q[j] * self.k_q - self.q_offset[j]
            m.theta_m[j] = self._u_m[j] * self.k_m - self.theta_m_offset[j]
            if self._primed:
                self._check_stuck(m, j, es.node, ds.node)
            else:
                self._stuck_q[j][:] = [0, m.theta_m[j]]
                self._stuck_m[j][:] = [0, m.q[j]]
                self._prev_q[j], self._prev_m[j] = int(qc), int(pos)
        self._primed = True

    def _check_stuck(self, m: Measurement, j: int, enc_node: int, drive_node: int) -> None:
        b = self.bus_cfg
        for run, changed, other, node, obj, count in (
                (self._stuck_q[j], m.q_counts[j] != self._prev_q[j], m.theta_m[j], enc_node,
                 "0x6004 load position value", int(m.q_counts[j])),
                (self._stuck_m[j], m.theta_m_counts[j] != self._prev_m[j], m.q[j], drive_node,
                 "0x6064 motor position actual value", int(m.theta_m_counts[j]))):
            if changed:
                run[0], run[1] = 0, other
                continue
            run[0] += 1
            moved = abs(other - run[1])
            if run[0] >= b.stuck_cycles and moved > b.stuck_motion:
                m.faults |= FaultFlag.ENCODER_STUCK
                raise EncoderStuck(node, obj, count, run[0], moved, b.stuck_motion)
        self._prev_q[j], self._prev_m[j] = int(m.q_counts[j]), int(m.theta_m_counts[j])

    # ================================================================== stopping
    def safe_stop(self) -> None:
        """Quick stop with zero torque in the RPDO, latched by a SYNC; never raises."""
        if self.network is None:
            return
        self._cw = cia402.CW_QUICK_STOP
        self._quick_stopped = True
        try:
            for msg in self._rpdo_msgs:
                DRIVE_RPDO.pack_into(msg.data, 0, cia402.CW_QUICK_STOP, 0)
                with self.network.send_lock:
                    self._bus.send(msg)
            with self.network.send_lock:
                self._bus.send(self._sync_msg)
        except Exception:  # noqa: BLE001 - the bus may be gone; nothing more can be done here
            pass

    def reset_fault(self) -> None:
        """Operator reset: clear the drive's fault, re-enable, reset the unwrapping reference."""
        for k in self._emcy:
            self._emcy[k] = None
        self._errors.bus_off = False
        self._cw = cia402.CW_ENABLE_OPERATION
        self._quick_stopped = False
        for drive in self.drives:
            self._enable(drive)
        self._prime()

    def stop(self) -> None:
        """Zero torque, disable the drives, pre-operational, release the bus; idempotent."""
        if self.network is None:
            return
        self.safe_stop()
        for drive in self.drives:
            drive.sdo.RESPONSE_TIMEOUT = min(drive.sdo.RESPONSE_TIMEOUT, 0.2)   # do not hang on the way out
            try:
                drive.sdo[0x6040].raw = cia402.CW_DISABLE_VOLTAGE
                drive.sdo[0x1016][1].raw = 0           # a clean stop: stop watching our heartbeat
            except Exception:  # noqa: BLE001 - best effort on the way out
                pass
        self._hb_on = False
        try:
            self.network.nmt.state = "PRE-OPERATIONAL"
        except Exception:  # noqa: BLE001
            pass
        self._release()

    def _release(self) -> None:
        net, self.network = self.network, None
        self._started = False
        self._hb_on = False
        if net is not None and net.notifier is not None:
            net.notifier.stop(2.0)
        if self._owns_bus and self._bus is not None:
            self._bus.shutdown()
            self._bus = None
