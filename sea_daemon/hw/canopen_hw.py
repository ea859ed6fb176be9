"""The exoskeleton on CANopen: CiA 402 drive (CST, mode 10) + CiA 406 load encoder per joint.

Start-up (:meth:`CanopenHardware.start`), after CiA 301 / 402 / 406; what it asks of each node
over SDO is :class:`sea_daemon.hw.canopen_setup.NodeSetup`:

1. NMT pre-operational; per node: device type 0x1000 (profile 402 / 406), identity 0x1018
   (vendor, product as in our EDS), encoder resolution (drive 0x608F = 2^bits per motor turn,
   encoder 0x6501 = 2^bits, 0x6502 turns), gear 0x6091, supported modes 0x6502 (CST), rated
   torque 0x6076 — any difference is a :class:`~sea_daemon.hw.errors.DeviceMismatch` naming node and
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
6. one priming cycle (zero torque, or ``start(initial_torque)``) that sets the unwrapping
   reference (the load encoder's single-turn count is centred on (-π, π]); its sample is
   :attr:`CanopenHardware.meas` until the first ``read()``.

Cycle — PDOs only, pipelined as a CANopen master does: the loop calls ``read()`` at its deadline;
``read()`` sends SYNC first, takes and checks heartbeats / EMCY / bus-off and sends the master
heartbeat
while the devices answer, then collects that cycle's TPDOs until ``pdo_timeout_ms`` after the
SYNC (at 1 kHz a deadline inside the period, e.g. 0.6 ms; a TPDO later than that is missing in
this cycle — held within the missed-cycle tolerance, ``max_missed_ms`` / ``max_missed_cycles`` — and late in the next); ``write(tau)`` sends the
RPDO before the next SYNC, and the estimator runs after it, off the bus's critical path.  ``read()`` takes the cycle's
TPDOs (:class:`sea_daemon.hw.canopen_rx.TpdoWindow`: received by the loop thread on a bus handle of
its own filtered to the TPDOs, no receive thread on the cycle's path; decoded with precompiled
structs; the devices' heartbeats and EMCY too, once cycling: on SocketCAN and ``ipc`` the EMCY on
the TPDO handle, in the order they came with the TPDOs, and the heartbeats on a third handle,
taken after the SYNC; on ``virtual`` and ``remote`` both on the TPDO handle, which sees every
frame there).  A heartbeat counts from its arrival on the bus (the frame's timestamp,
:func:`sea_daemon.hw.canopen_rx.arrival`): the timeout does not grow by the time a thread took to get to it.
Counts become joint-side radians (:class:`sea_daemon.hw.canopen_positions.Positions`: gear ratio,
multi-turn unwrapping, offsets) and per mille of rated torque becomes N m.  Detected: missing
TPDOs, late frames, heartbeat timeout, EMCY, drive leaving OPERATION_ENABLED, encoder jumps
beyond ``max_joint_speed``, stuck encoders, failed sends and bus-off.

The synchronous RPDO written in cycle k is actuated by the drive at SYNC k+1 and acts over
[t_k+1, t_k+2]; :attr:`Measurement.tau_m_applied` (0x6077) is the torque that acted over the
cycle ending at the sample time (see :mod:`sea_daemon.hw.interface` for the whole timing).
"""
from __future__ import annotations

import dataclasses
import math
import time

import can
import canopen
import numpy as np
from canopen.emcy import EmcyError

from sea_daemon.core.config import ModelConfig

from sea_daemon.hw import cia402
from sea_daemon.hw.canopen_positions import Positions
from sea_daemon.hw.bus import make_bus
from sea_daemon.hw.canopen_rx import (
    CYCLE_NETWORK_FILTERS, NETWORK_FILTERS, ErrorFrames, FrameTap, Queued, TpdoWindow, arrival)
from sea_daemon.hw.canopen_setup import (
    ABORT_QUICK_STOP, DRIVE_EDS, DRIVE_RPDO, DRIVE_TPDO, ENCODER_EDS, ENCODER_TPDO, NodeSetup)
from sea_daemon.errors import Fault
from sea_daemon.hw.errors import (
    BusOff, DriveFault, EmcyReceived, HeartbeatLost, PdoLengthError, PdoTimeout, SendFailed, WrongDevice)
from sea_daemon.hw.interface import HardwareInterface, Measurement

NMT_OPERATIONAL = 0x05

#: the statusword bits (mask 0x6F) of a drive in OPERATION ENABLED (read in every cycle)
_OPERATION_ENABLED = cia402.State.OPERATION_ENABLED.bits


class CanopenHardware(HardwareInterface):
    """:class:`HardwareInterface` on a CANopen bus (see the module docstring for the sequence)."""

    #: receive timeout [s] of canopen's thread once heartbeats and EMCY come on the loop thread
    IDLE_CYCLE = 0.25

    def __init__(self, cfg: ModelConfig, bus: can.BusABC | None = None, *, period: float | None = None,
                 pdo_timeout: float | None = None, clock=time.monotonic, bus_cfg=None, joints=None):
        """``bus_cfg``: one bus of ``cfg.hardware.bus`` (:meth:`BusConfig.for_joints`) for a driver
        of those joints alone (:class:`sea_daemon.hw.canopen_buses.CanopenBuses`), ``joints`` their
        0-based indices in the model (the hardware's per-joint values); default all of it."""
        hw, b = cfg.hardware, (bus_cfg or cfg.hardware.bus)
        self.cfg, self.bus_cfg = cfg, b
        self.n = len(b.drive_node)
        js = list(range(self.n)) if joints is None else list(joints)
        if len(js) != self.n:
            raise ValueError(f"joints {js}: one per drive of the bus ({self.n})")
        #: called by keepalive(): the other buses' drivers of a CanopenBuses (their heartbeats)
        self.peer_keepalive = None
        self.period = float(period or cfg.dt)
        # per joint of this bus: gear ratio, the encoders' counts per turn, torque limit [N m]
        self.gear = [float(hw.gear_ratios(cfg.joints)[j]) for j in js]
        counts_load, counts_motor = hw.encoder_counts(cfg.joints)
        self.res_load = [int(counts_load[j]) for j in js]
        self.res_motor = [int(counts_motor[j]) for j in js]
        self.torque_limit = [float(hw.torque_limits(cfg.joints)[j]) for j in js]
        self.pdo_timeout = pdo_timeout if pdo_timeout is not None else b.pdo_timeout_ms / 1e3
        if pdo_timeout is not None:
            b = dataclasses.replace(b, pdo_timeout_ms=pdo_timeout * 1e3)
            self.bus_cfg = b
        #: the missed-cycle tolerance at this period (BusConfig.missed_cycles): missing TPDOs held, and
        #: the deadlines the loop may skip in a row (FixedRateLoop's LOOP_STALL)
        self.max_missed = self.stall_cycles = b.missed_cycles(self.period)
        #: the drives' RPDO deadline [s] written to 0x1400:5 (0: off); InputError when too short
        self.rpdo_timeout = b.rpdo_timeout_s(self.period)
        #: cycles between write() and the interval the torque acts over (see sea_daemon.hw.interface)
        self.actuation_delay = 1 if b.sync_rpdo else 0
        self.hb_timeout = b.heartbeat_timeout_ms / 1e3
        self.clock = clock
        self._bus, self._owns_bus = bus, bus is None
        self._tpdo_bus = None
        self._hb_tap: FrameTap | None = None     # the heartbeats on the loop thread (once cycling)
        self._queued: Queued | None = None       # one poll: the TPDO handle (bit 1), the heartbeats' (bit 2)
        self.drive_ids, self.encoder_ids = list(b.drive_node), list(b.encoder_node)
        self.network: canopen.Network | None = None
        self.drives: list = []
        self.encoders: list = []
        n = self.n
        rated = b.rated_torques(n)
        # 1 ‰ of 0x6076 on the joint side, and the max torque 0x6072 [‰], per joint
        self.nm_per_permille = [float(rated[j]) / 1e6 * self.gear[j] for j in range(n)]
        self.max_permille = [min(32767, int(math.ceil(self.torque_limit[j] / self.nm_per_permille[j])))
                             for j in range(n)]
        self.setup = NodeSetup(b, res_load=self.res_load, res_motor=self.res_motor, gear=self.gear,
                               period=self.period, max_permille=self.max_permille,
                               keepalive=self.keepalive)
        self.positions = Positions(n, self.res_load, self.res_motor, self.gear, b, self.period)
        # cycle state
        self.meas = Measurement(n)
        self._act = np.zeros(n)             # actuated()'s result
        self._rx = TpdoWindow()
        self._hb_last = {}
        self._watching = False               # the TPDO window hands over heartbeats and EMCY
        self._loop_takes_async = False       # heartbeats and EMCY: the loop thread's, not canopen's
        self._late_pending = False           # late TPDOs found by receive_pending()
        self._hb_state = {}
        self._emcy: dict[int, tuple[int, int, bytes] | None] = {}
        self._emcy_any = False               # an EMCY in _emcy not yet raised
        self._errors = ErrorFrames()
        self._rpdo_msgs: list[can.Message] = []
        self._sync_msg = can.Message(arbitration_id=0x80, data=b"", is_extended_id=False)
        self._hb_msg = can.Message(arbitration_id=0x700 + b.master_node, data=bytes([NMT_OPERATIONAL]),
                                   is_extended_id=False)
        self._hb_period = b.heartbeat_ms / 1e3
        self._hb_next = 0.0
        self._hb_on = False
        self._cw = cia402.CW_ENABLE_OPERATION
        self._quick_stopped = False
        self._initial_torque = np.zeros(n)   # commanded by the priming cycle (start())
        self._primed = False
        self._cycle = -1
        self._cycle_decoded = -1        # the cycle of the last decoded sample and its SYNC's time
        self._t_decoded = 0.0
        self._started = False
        self.missed_cycles = 0          # cycles with a TPDO missing at the deadline (held or faulted)
        self.late_cycles = 0            # cycles that found frames of an earlier cycle (FRAME_LATE)

    # ================================================================== start-up (SDO)
    def start(self, initial_torque: np.ndarray | None = None) -> None:
        """Start-up sequence; the priming cycle commands ``initial_torque`` [N m] (default 0)."""
        if self._started:
            return
        self._initial_torque = np.zeros(self.n) if initial_torque is None else \
            np.asarray(initial_torque, dtype=float).reshape(self.n)
        bus = self._bus if self._bus is not None else make_bus(self.bus_cfg)
        self._bus = bus
        # the loop thread's own handle for the cycle's TPDOs (canopen_rx), the network's handle
        # for the rest of the traffic
        self._tpdo_bus = make_bus(self.bus_cfg)
        bus.set_filters(NETWORK_FILTERS)
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
            net.subscribe(0x80 + node.id, self._on_net_emcy)
        net.nmt.state = "PRE-OPERATIONAL"                                 # broadcast
        setup = self.setup
        for j in range(self.n):
            setup.check_drive(self.drives[j], j)
            self.positions.enc_range[j] = setup.check_encoder(self.encoders[j], j)
        for j in range(self.n):
            self._configure_drive(self.drives[j], j)
            self._configure_encoder(self.encoders[j])
        self._rx.bind(self._tpdo_bus)
        for node in self.drives + self.encoders:
            setup.write(node, 0x1017, 0, self.bus_cfg.heartbeat_ms, "producer heartbeat time")
        self._await_heartbeats()
        for node in self.drives + self.encoders:
            node.nmt.state = "OPERATIONAL"
        self._await_heartbeats(NMT_OPERATIONAL)
        for drive in self.drives:
            # the drive watches our heartbeat; losing it means quick stop (the daemon died or hangs)
            setup.write(drive, 0x6007, 0, ABORT_QUICK_STOP, "abort connection option code")
            setup.write(drive, 0x1016, 1, (self.bus_cfg.master_node << 16) | self.bus_cfg.heartbeat_timeout_ms,
                        "consumer heartbeat time")
        self._send_master_heartbeat(force=True)        # the drives' watch starts with this one
        self._hb_on = True
        self._async_in_cycle()
        for drive in self.drives:
            setup.write(drive, 0x6060, 0, cia402.MODE_CST, "modes of operation")
            mode = setup.read(drive, 0x6060 + 1, 0, "modes of operation display")
            if mode != cia402.MODE_CST:
                raise WrongDevice(drive.id, "0x6061 modes of operation display",
                                  f"is {mode}, expected {cia402.MODE_CST} (cyclic synchronous torque)")
            setup.enable(drive)
        self._prime()

    def _async_in_cycle(self) -> None:
        """From here on the loop thread takes the devices' heartbeats and EMCY in ``read()``,
        and the network's handle stops taking them: canopen's receive thread does not wake for
        them inside the cycle, and an EMCY queued before ``read()`` (or before the cycle's
        TPDOs) is raised by that ``read()``, whatever the scheduler does with canopen's thread.
        Where the handles filter below python-can (SocketCAN, ipc) the heartbeats come on a
        handle of their own (:class:`~sea_daemon.hw.canopen_rx.FrameTap`: heartbeats filling a
        queue nobody takes — the ipc bus queues 10 frames — cannot crowd out a TPDO or an EMCY)
        and the EMCY on the TPDO handle, which takes them with the TPDOs in the order they came
        (an EMCY sent before the cycle's TPDOs is taken before them, no poll of its own); on
        ``virtual`` and ``remote`` the TPDO handle sees every frame anyway and hands both over
        (``TpdoWindow.watch``)."""
        nodes = self.drives + self.encoders
        hb_ids = [0x700 + node.id for node in nodes]
        emcy_ids = [0x80 + node.id for node in nodes]
        if self._rx.filtered:
            bus = make_bus(self.bus_cfg)
            try:
                self._hb_tap = FrameTap(bus, hb_ids, self._hb_frame)
            except BaseException:
                bus.shutdown()
                raise
            self._rx.watch(emcy_ids, self._on_emcy)
            self._queued = Queued.of([self._rx.bus, self._hb_tap.bus])
        else:
            self._rx.watch(hb_ids + emcy_ids, self._tap_frame)
        self._watching = True
        # canopen's thread ignores them from now on (a bus that ignores filters — python-can-remote —
        # still brings them to it: taken twice, one EMCY would latch again after its reset)
        self._loop_takes_async = True
        self._bus.set_filters(CYCLE_NETWORK_FILTERS)
        # nothing periodic left on the network's handle: its thread wakes every IDLE_CYCLE for
        # its stop flag, in < 1 % of the cycles at 1 kHz (a stop waits for it up to that long)
        if self.network.notifier is not None:
            self.network.notifier.timeout = self.IDLE_CYCLE

    def receive_pending(self) -> None:
        """Take the heartbeats and EMCY waiting now (on the loop thread's handle, where there is
        one): for a caller that waits for a heartbeat between cycles."""
        if self._hb_tap is not None:
            self._hb_tap.take()
        if self._watching:
            # the TPDO handle: frames of an earlier cycle found here are reported by the next read()
            if self._rx.drain():
                self._late_pending = True

    def keepalive(self) -> None:
        """Between cycles (SDO sequences, a caller that waits): keep the drives' watch of our
        heartbeat happy (once it runs), and take the devices' heartbeats and EMCY off the loop
        thread's handle (its queue would fill while no ``read()`` takes it)."""
        self.keepalive_own()
        if self.peer_keepalive is not None:
            self.peer_keepalive(self)

    def keepalive_own(self) -> None:
        """:meth:`keepalive` of this bus alone (not its peers)."""
        if self._hb_on:
            self._send_master_heartbeat()
        self.receive_pending()

    def heartbeat_arrival(self, node: int) -> float | None:
        """When the newest heartbeat of ``node`` arrived (this driver's clock [s]); None before
        the first one since start-up (read-only, for a caller that waits for a heartbeat)."""
        return self._hb_last.get(node)

    @property
    def bus_off(self) -> bool:
        """Whether an error frame with the bus-off flag has been seen (until :meth:`reset_fault`)."""
        return self._errors.bus_off

    # ---------------------------------------------------------------- PDOs of the cycle
    def _configure_drive(self, d, j: int) -> None:
        self.setup.configure_drive(self.network, d, j)
        self._rx.add(d.id, 0x180 + d.id, DRIVE_TPDO.size)
        self._rpdo_msgs.append(can.Message(arbitration_id=0x200 + d.id, data=bytearray(DRIVE_RPDO.size),
                                           is_extended_id=False))

    def _configure_encoder(self, e) -> None:
        self.setup.configure_encoder(self.network, e)
        self._rx.add(e.id, 0x180 + e.id, ENCODER_TPDO.size)

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
                if self.peer_keepalive is not None:
                    self.peer_keepalive(self)

    def _prime(self) -> None:
        """First cycle (at the initial torque): sets the unwrapping reference."""
        self._primed = False
        self.write(self._initial_torque)
        self.read()

    def actuated(self, tau_m: np.ndarray) -> np.ndarray:
        """The joint-side torque the drive applies for a ``write(tau_m)``: per-mille steps, max torque
        (the array is reused by the next call)."""
        out = self._act
        for j in range(self.n):
            out[j] = self._permille(float(tau_m[j]), j) * self.nm_per_permille[j]
        return out

    def _permille(self, t: float, j: int) -> int:
        """Joint ``j``'s torque [N m] → ‰ of its 0x6076 as the drive gets it (non-finite → 0, clipped)."""
        if not math.isfinite(t):
            return 0
        pm = round(t / self.nm_per_permille[j])
        mx = self.max_permille[j]
        return -mx if pm < -mx else (mx if pm > mx else pm)

    # ================================================================== rx callbacks (heartbeat, EMCY)
    def _on_heartbeat(self, can_id, data, timestamp) -> None:
        if not self._loop_takes_async:
            self._hb_frame(can_id, data, timestamp)

    def _on_net_emcy(self, can_id, data, timestamp) -> None:
        if not self._loop_takes_async:
            self._on_emcy(can_id, data, timestamp)

    def _hb_frame(self, can_id, data, timestamp) -> None:
        """A node's heartbeat: dated by its arrival on the bus (a frame taken late is not younger)."""
        node = can_id - 0x700
        t = arrival(self.clock(), timestamp)
        last = self._hb_last.get(node)
        self._hb_last[node] = t if last is None or t > last else last
        self._hb_state[node] = data[0] & 0x7F if len(data) else None

    def _tap_frame(self, can_id, data, timestamp) -> None:
        """A frame the TPDO window hands over (``virtual``, ``remote``): a heartbeat or an EMCY."""
        if can_id >= 0x700:
            self._hb_frame(can_id, data, timestamp)
        else:
            self._on_emcy(can_id, data, timestamp)

    def _on_emcy(self, can_id, data, timestamp) -> None:
        if len(data) < 3:
            return
        code = data[0] | data[1] << 8
        if code == 0:                      # "error reset / no error"
            return
        self._emcy[can_id - 0x80] = (code, data[2], bytes(data[3:8]))
        self._emcy_any = True

    # ================================================================== the cycle (PDO only)
    def write(self, tau_m: np.ndarray) -> None:
        """Target torque [N m, joint side] → ‰ of 0x6076 in the drives' RPDOs."""
        if self.network is None:
            raise RuntimeError("CanopenHardware: call start() before read() / write()")
        for j, msg in enumerate(self._rpdo_msgs):
            DRIVE_RPDO.pack_into(msg.data, 0, self._cw, self._permille(float(tau_m[j]), j))
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
        t_sync = self.begin_read()
        return self.end_read(t_sync)

    def begin_read(self) -> float:
        """The first half of :meth:`read`: late frames, SYNC, heartbeats, EMCY, bus-off and the
        daemon's heartbeat; the SYNC's time (a driver of several buses sends every SYNC first)."""
        if self.network is None:
            raise RuntimeError("CanopenHardware: call start() before read() / write()")
        m = self.meas
        m.faults = 0
        m.late = False
        if self._errors.bus_off:
            raise BusOff("error frame with the bus-off flag received")
        # which handles have frames queued: one poll for the TPDO handle and the two taps
        queued = self._queued
        mask = queued.mask() if queued is not None else 7
        if self._rx.drain(bool(mask & 1)) or self._late_pending:
            self._late_pending = False
            m.late = True
            self.late_cycles += 1
        # SYNC first (the loop calls read() at its deadline): the devices sample now and answer
        # while this thread checks what arrived between cycles and sends its heartbeat (what
        # came after the poll is taken at the next cycle; an EMCY before the TPDOs, below)
        t_sync = self.clock()
        self._send(self._sync_msg, "SYNC")
        if self._hb_tap is not None and mask & 2:
            self._hb_tap.take()
        self._check_async()
        self._send_master_heartbeat()
        return t_sync

    def end_read(self, t_sync: float) -> Measurement:
        """The second half of :meth:`read`: this cycle's TPDOs until ``pdo_timeout`` after
        ``t_sync``, checked and decoded."""
        m = self.meas
        self._rx.collect(t_sync + self.pdo_timeout, self.clock)   # an EMCY sent before the TPDOs: taken too
        self._cycle += 1
        self._check_emcy()
        m.cycle = self._cycle
        m.t = self._cycle * self.period
        m.t_mono = t_sync
        m.valid = True
        missing = None
        for s in self._rx.slots:
            if s.bad_len:
                m.faults |= Fault.TPDO_MISSING.bit
                m.valid = False
                raise PdoLengthError(s.node, s.cob_id, max(s.bad_len, 0), s.length, self._cycle)
            if s.snap_count == 0:
                s.missed += 1
                m.faults |= Fault.TPDO_MISSING.bit
                m.valid = False
                if missing is None or s.missed > missing.missed:
                    missing = s
            else:
                s.missed = 0
                if s.snap_count > 1:
                    m.late = True
        if missing is not None:
            self.missed_cycles += 1
            if missing.missed > self.max_missed or not self._primed:
                raise PdoTimeout(missing.node, missing.cob_id, self._cycle, self.pdo_timeout, missing.missed)
            return m                                   # values held from the last cycle
        self._decode(m)
        return m

    def _check_emcy(self) -> None:
        if not self._emcy_any:                 # none since the last look (twice a cycle)
            return
        self._emcy_any = False                 # set again below while another one is left
        for node, e in self._emcy.items():
            if e is not None:
                self._emcy[node] = None
                self._emcy_any = any(v is not None for v in self._emcy.values())
                self.meas.faults |= Fault.EMCY.bit
                raise EmcyReceived(node, e[0], e[1], e[2], EmcyError(e[0], e[1], e[2], 0.0).get_desc())

    def _check_async(self) -> None:
        """Faults that arrive between cycles: EMCY, heartbeat, bus-off."""
        if self._errors.bus_off:
            raise BusOff("error frame with the bus-off flag received")
        self._check_emcy()
        now = self.clock()
        for node, last in self._hb_last.items():
            if last is None or now - last > self.hb_timeout:
                self.meas.faults |= Fault.HEARTBEAT_LOST.bit
                raise HeartbeatLost(node, now - (last or 0.0), self.hb_timeout)
            state = self._hb_state[node]
            if self._primed and state is not None and state != NMT_OPERATIONAL:
                self.meas.faults |= Fault.HEARTBEAT_LOST.bit
                raise HeartbeatLost(node, now - last, self.hb_timeout, state)

    def _decode(self, m: Measurement) -> None:
        n = self.n
        # periods since the sample before: cycles held in between, or a stall of the loop that
        # sent no SYNC (the arm moved for that long: the jump check allows for it)
        periods = max(self._cycle - self._cycle_decoded, (m.t_mono - self._t_decoded) / self.period)
        self._cycle_decoded, self._t_decoded = self._cycle, m.t_mono
        slots, primed = self._rx.slots, self._primed
        for j in range(n):
            ds, es = slots[2 * j], slots[2 * j + 1]
            sw, torque, pos = DRIVE_TPDO.unpack_from(ds.snap, 0)
            (qc,) = ENCODER_TPDO.unpack_from(es.snap, 0)
            m.statusword[j] = sw
            m.q_counts[j] = qc
            m.theta_m_counts[j] = pos
            m.tau_m_applied[j] = torque * self.nm_per_permille[j]
            if sw & 0x6F != _OPERATION_ENABLED and primed:
                m.faults |= Fault.DEVICE_FAULT.bit
                st = cia402.state_of(sw)
                if not (self._quick_stopped and st is not cia402.State.FAULT):
                    raise DriveFault(ds.node, sw, st.name if st else "invalid")
                # after safe_stop() a quick-stopped / disabled drive is what was asked for: flag only
            if primed:
                self.positions.update(m, j, qc, pos, es.node, ds.node, self._cycle, periods)
            else:
                self.positions.reference(m, j, qc, pos)
        self._primed = True

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
        """Operator reset: clear the drive's fault, re-enable, reset the unwrapping reference.
        The EMCY that arrived before the reset is what it clears."""
        self.receive_pending()
        for k in self._emcy:
            self._emcy[k] = None
        self._errors.bus_off = False
        self._cw = cia402.CW_ENABLE_OPERATION
        self._quick_stopped = False
        for drive in self.drives:
            self.setup.enable(drive)
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
        self._watching = False
        self._loop_takes_async = False
        if net is not None and net.notifier is not None:
            net.notifier.stop(2.0)
        if self._tpdo_bus is not None:
            self._tpdo_bus.shutdown()
            self._tpdo_bus = None
        if self._hb_tap is not None:
            self._hb_tap.bus.shutdown()
        self._hb_tap = None
        self._queued = None
        if self._owns_bus and self._bus is not None:
            self._bus.shutdown()
            self._bus = None
