"""The device model: the exoskeleton's CANopen devices around the simulator's true plant.

One :class:`DeviceModel` holds, per joint, a CiA 402 drive (:class:`DriveNode`) and a CiA 406
load encoder (:class:`EncoderNode`) on one canopen Network per bus (one bus, or a bus per joint
or per limb: ``joint_bus``), and a plant with the API of
:class:`sea_daemon.core.sim.plant.Plant` (``step(tau_m, dt, tau_h_act)``, ``t, q, theta_m, dq,
dtheta_m``).  On every SYNC it (CiA 301 synchronous semantics):

1. in **lock-step** mode steps the plant over the interval since the previous SYNC (the drive's
   interpolation period 0x60C2) with the torque set-point in force — actuated at that SYNC
   for a synchronous RPDO, on reception for an asynchronous one (transmission type 255) — and
   reports it as torque actual 0x6077;
2. writes the buffered synchronous RPDOs into the dictionaries (controlword, target torque);
3. samples the encoders at the plant's state and sends the synchronous TPDOs.

With several buses the plant steps once per cycle, at the first of the cycle's SYNCs on any bus
(the k-th SYNC of each bus is cycle k), and each bus's SYNC samples its joints and sends their
TPDOs.  So the TPDOs of SYNC k show the state at t_k; a torque written after SYNC k acts over
[t_k+1, t_k+2] with a synchronous RPDO and over [t_k, t_k+1] with an asynchronous one.  In
**free-running** mode a thread steps the plant in real time with the set-point in force, and
SYNC only samples.
Faults (:mod:`.faults`) can be injected now or scheduled at a device time.
"""
from __future__ import annotations

import math
import threading
import time
from typing import Callable, Sequence

import numpy as np

from sea_daemon.hw.bus import set_controller_filters
from sea_daemon.hw.ipc_bus import IpcBus
from sea_daemon.hw.device_model.drive import DriveNode
from sea_daemon.hw.device_model.encoder import EncoderNode
from sea_daemon.hw.device_model.faults import FaultSpec
from sea_daemon.hw.device_model.receiver import SharedReceiver
from sea_daemon.hw.device_model.slave import DeviceNetwork
from sea_daemon.core.buffers import resident_zeros

TPDO_FUNCTIONS = (0x180, 0x280, 0x380, 0x480)
#: the SYNC from which the handler's page faults are counted (after its start-up)
_FAULTS_FROM_SYNC = 100


def thread_page_faults() -> tuple[int, int]:
    """The calling thread's (minor, major) page faults so far."""
    import resource
    r = resource.getrusage(resource.RUSAGE_THREAD)
    return r.ru_minflt, r.ru_majflt


class DeviceModel:
    """Drives + load encoders + plant on a bus.  ``start()`` boots the nodes, ``stop()`` leaves."""

    STATS_CAP = 1 << 21
    #: answer_stats' slow answers: longer than this [s], at most this many
    SLOW_ANSWER_S = 4e-4
    SLOW_KEPT = 5000

    def __init__(self, bus, plant, *, drive_nodes: Sequence[int] = (1,), encoder_nodes: Sequence[int] = (2,),
                 tau_h_act: Callable[[float], np.ndarray] | None = None, lock_step: bool = True,
                 position_preset: int = 0, owns_bus: bool = False, joint_bus: Sequence[int] | None = None):
        """``bus``: one bus handle, or a list of them with ``joint_bus`` the index of each
        joint's bus in it (default: every joint on the first)."""
        if len(drive_nodes) != len(encoder_nodes):
            raise ValueError(f"one load encoder per drive: got {len(drive_nodes)} drives, "
                             f"{len(encoder_nodes)} encoders")
        self.buses = list(bus) if isinstance(bus, (list, tuple)) else [bus]
        self.bus, self.plant, self.owns_bus = self.buses[0], plant, owns_bus
        self.n = len(drive_nodes)
        self.joint_bus = tuple(joint_bus) if joint_bus is not None else (0,) * self.n
        if len(self.joint_bus) != self.n or not all(0 <= i < len(self.buses) for i in self.joint_bus):
            raise ValueError(f"joint_bus {self.joint_bus}: one index in 0..{len(self.buses) - 1} per joint")
        self.lock_step = lock_step
        self.tau_h_act = tau_h_act or (lambda t, _z=np.zeros(self.n): _z)
        self.networks = [DeviceNetwork(b) for b in self.buses]
        self.network = self.networks[0]
        self.drives = [DriveNode(i, position_preset=position_preset) for i in drive_nodes]
        if lock_step:
            # the drives' RPDO deadline on the device's time (SYNCs x period): the plant moves only
            # with SYNCs, so a master that stops (no SYNC, no RPDO) holds it still, not its torque
            for d in self.drives:
                d.rpdo_clock = self._device_time
        self.encoders = [EncoderNode(i) for i in encoder_nodes]
        self._configured_hardware(getattr(plant, "cfg", None))
        #: the nodes on each bus, and each node's network
        self.bus_nodes = [[] for _ in self.buses]
        self._net_of: dict[int, DeviceNetwork] = {}
        for j in range(self.n):
            for node in (self.drives[j], self.encoders[j]):
                self.networks[self.joint_bus[j]].add_node(node)
                self.bus_nodes[self.joint_bus[j]].append(node)
                self._net_of[node.id] = self.networks[self.joint_bus[j]]
        for i, net in enumerate(self.networks):
            net.NOTIFIER_CYCLE = 0.05            # bounded shutdown
            net.gate = self._gate
            net.subscribe(0x80, lambda can_id, data, timestamp, _i=i: self._on_sync(can_id, data, timestamp, _i))
        self._bus_syncs = [0] * len(self.buses)  # SYNCs seen on each bus (the k-th of each: cycle k)
        self._steps = 0                          # plant steps (lock-step: one per cycle)
        self._sampled_at = -1                    # the plant step the devices were last sampled at
        self.handled = 0                         # SYNCs handled on all buses
        self._lock = threading.RLock()
        self._tau = np.zeros(self.n)
        self._offsets = None                     # the plant's encoder offsets as floats (_sample)
        self._scheduled: list[FaultSpec] = []
        self._drop: dict[int, int] = {}          # node id -> TPDO frames still to drop
        self._delay: dict[int, tuple[int, float]] = {}
        self._timers: list[threading.Timer] = []
        self._thread: threading.Thread | None = None
        self._monitor: threading.Thread | None = None
        self._running = False
        self.syncs = 0
        self._synced = False
        self.last_tau_h_act = np.zeros(self.n)
        self.error: BaseException | None = None
        # answer latency per SYNC (ring of the last STATS_CAP): SYNC frame's timestamp (the
        # sender's time.time()) to the last TPDO handed to the bus, and the handler's CPU time;
        # resident now: a page first written in the SYNC handler (one every 512 SYNCs) stalled
        # the answer by milliseconds on a virtual machine (sea_daemon.core.buffers)
        self.answer_s = resident_zeros(self.STATS_CAP)
        self.handler_cpu_s = resident_zeros(self.STATS_CAP)
        self._faults0: tuple | None = None        # (thread id, its faults) at SYNC _FAULTS_FROM_SYNC
        self._faults_final: dict | None = None    # handler_page_faults() when stopped (the thread ends)
        # lock-step on ipc: each bus's RPDOs on a handle of their own that nobody waits on (one
        # per bus, None where not), taken in the SYNC handler (:meth:`_take_rpdos`)
        self._rpdo_taps: list = [None] * len(self.buses)

    # ------------------------------------------------------------------ life cycle
    def _configured_hardware(self, cfg) -> None:
        """Each joint's drive and load encoder as the plant's configuration ``cfg`` has them (gear
        ratio, encoder counts, rated torque per joint; docs/configuration.md), where they differ
        from the EDS's (a plant without a configuration of these joints: the EDS's)."""
        if cfg is None or getattr(cfg, "joints", None) != self.n:
            return
        n, hw = self.n, cfg.hardware
        gear = hw.gear_ratios(n)
        load, motor = hw.encoder_counts(n)
        rated = hw.bus.rated_torques(n)
        for j, (d, e) in enumerate(zip(self.drives, self.encoders)):
            r = float(rated[j])
            if (d.increments, d.gear, d.rated_mNm) != (int(motor[j]), float(gear[j]), r):
                d.set_hardware(int(motor[j]), float(gear[j]), r)
            if e.resolution != int(load[j]):
                e.set_resolution(int(load[j]))

    def acceptance_filters(self, bus: int = 0, rpdos: bool = True) -> list[dict]:
        """What the CAN controllers of the devices on ``bus`` (an index) accept (python-can
        ``can_filters``): NMT, SYNC, their own RPDOs (``rpdos``) and SDO requests, heartbeats
        (the master's, watched by the drives).  Other nodes' PDOs — the daemon's published TPDOs
        among them — never reach the model."""
        ids = [0x000, 0x080]
        for node in self.bus_nodes[bus]:
            ids += [f + node.id for f in ((0x200, 0x300, 0x400, 0x500, 0x600) if rpdos else (0x600,))]
        out = [{"can_id": i, "can_mask": 0x7FF, "extended": False} for i in ids]
        out.append({"can_id": 0x700, "can_mask": 0x780, "extended": False})
        return out

    def _rpdo_ids(self, bus: int) -> list[int]:
        return [f + node.id for node in self.bus_nodes[bus] for f in (0x200, 0x300, 0x400, 0x500)]

    def _open_rpdo_taps(self) -> None:
        """Lock-step on the ``ipc`` bus: each bus's RPDOs go to a handle of the model's own that
        no thread waits on, and the SYNC handler takes them before it steps the plant
        (:meth:`_take_rpdos`).  A lock-step device acts on a torque command only at the next
        SYNC, and the master sends that SYNC after the command, so the commands are the same
        ones; but the master's RPDO no longer wakes the model's receive thread between two
        SYNCs (on a virtual machine waking a task on another CPU costs the sender about 18 µs
        of CPU, the model a wake-up of its own)."""
        for i, bus in enumerate(self.buses):
            if self.lock_step and isinstance(bus, IpcBus):
                ids = self._rpdo_ids(i)
                self._rpdo_taps[i] = IpcBus(channel=bus.channel, can_filters=[
                    {"can_id": c, "can_mask": 0x7FF, "extended": False} for c in ids])

    def _take_rpdos(self) -> None:
        """The RPDOs queued on every bus's tap, to their network's subscribers as canopen's
        receive thread would hand them (every bus's: the first SYNC of a cycle steps the plant
        of all joints)."""
        for net, tap in zip(self.networks, self._rpdo_taps):
            if tap is None:
                continue
            while True:
                frame = tap.recv_frame(0.0)
                if frame is None:
                    break
                can_id, data = frame
                if can_id & 0x780 in (0x200, 0x300, 0x400, 0x500):   # an RPDO (error frames pass every filter)
                    net.notify(can_id, bytearray(data), tap.frame_timestamp())

    def start(self) -> "DeviceModel":
        # the controllers' acceptance filter where the bus applies one below python-can (the
        # RPDOs on their taps first, then off the receiving handle)
        self._open_rpdo_taps()
        for i, bus in enumerate(self.buses):
            set_controller_filters(bus, self.acceptance_filters(i, rpdos=self._rpdo_taps[i] is None))
        # several buses with descriptors: one receive thread for all of them (SharedReceiver: the
        # cycle's SYNCs answered in bus order by one thread), else canopen's Notifier per network
        shared = SharedReceiver.of(self.buses, self.networks, self.networks[0].NOTIFIER_CYCLE)
        if shared is not None:
            shared.start()
        else:
            for net in self.networks:
                net.connect()
        self._sample()
        for node in self.drives + self.encoders:
            node.boot()
        self._running = True
        self._monitor = threading.Thread(target=self._watch_master, name="device-model-consumer-hb", daemon=True)
        self._monitor.start()
        if not self.lock_step:
            self._thread = threading.Thread(target=self._free_run, name="device-model-physics", daemon=True)
            self._thread.start()
        return self

    @property
    def running(self) -> bool:
        """Started and not stopped since."""
        return self._running

    def stop(self) -> None:
        self._running = False
        self._faults_final = self.handler_page_faults()   # while the handler's thread is there
        if self._thread is not None:
            self._thread.join(2.0)
        if self._monitor is not None:
            self._monitor.join(2.0)
        for t in self._timers:
            t.cancel()
        for node in self.drives + self.encoders:
            node.nmt.stop_heartbeat()
        for net in self.networks:
            if net.notifier is not None:
                net.notifier.stop(2.0)
        for i, tap in enumerate(self._rpdo_taps):
            if tap is not None:
                tap.shutdown()
                self._rpdo_taps[i] = None
        if self.owns_bus:
            for bus in self.buses:
                bus.shutdown()

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.stop()

    @property
    def period(self) -> float:
        return self.drives[0].period

    # ------------------------------------------------------------------ physics
    def _counts(self) -> tuple[np.ndarray, np.ndarray]:
        """Total encoder counts (load, motor shaft) of the plant's current state.

        The simulator's encoders (``plant.encoders``, with offsets and floor quantisation) when
        the plant has them, else floor quantisation at the devices' resolutions."""
        p = self.plant
        q, th = np.atleast_1d(p.q), np.atleast_1d(p.theta_m)
        enc = getattr(p, "encoders", None)
        if enc is not None:
            return enc.counts(q, th)
        d, e = self.drives[0], self.encoders[0]
        return (np.floor(q / (2 * np.pi) * e.resolution).astype(np.int64),
                np.floor(th * d.gear / (2 * np.pi) * d.increments).astype(np.int64))

    def _sample(self) -> None:
        p = self.plant
        enc = getattr(p, "encoders", None)
        y = getattr(p, "_y", None)
        if enc is not None and y is not None:
            # the simulator's encoders (Encoders.counts: floor((angle + offset) / quantum)) on
            # its state vector [q, θ_m, q̇, θ̇_m], in float arithmetic: the same counts (the
            # offsets, one or one per joint, as floats once)
            n = self.n
            off = self._offsets
            if off is None or off[0] is not enc:
                # the offsets and each joint's quanta as floats, once
                off = self._offsets = (enc, np.broadcast_to(enc.offset_load, (n,)).tolist(),
                                       np.broadcast_to(enc.offset_motor, (n,)).tolist(),
                                       enc.q_loads.tolist(), enc.q_motors.tolist())
            _, ol, om, ql, qm = off
            for j in range(n):
                self.drives[j].set_motor_counts(math.floor((float(y[n + j]) + om[j]) / qm[j]), float(y[3 * n + j]))
                self.encoders[j].set_counts(math.floor((float(y[j]) + ol[j]) / ql[j]))
            return
        cq, cm = self._counts()
        dth = np.atleast_1d(self.plant.dtheta_m)
        for j in range(self.n):
            self.drives[j].set_motor_counts(int(cm[j]), float(dth[j]))
            self.encoders[j].set_counts(int(cq[j]))

    def _latch_torque(self) -> None:
        for j, d in enumerate(self.drives):
            self._tau[j] = d.torque_command()

    def _step(self, dt: float) -> None:
        tau_h = np.asarray(self.tau_h_act(self.plant.t), dtype=float).reshape(self.n)
        self.last_tau_h_act = tau_h
        self.plant.step(self._tau.copy(), dt, tau_h)

    def _device_time(self) -> float:
        """The lock-step device's time [s]: its cycles (SYNCs) times the interpolation period."""
        return self.syncs * self.period

    def answer_stats(self) -> dict:
        """The device's answer to SYNC over the SYNCs seen (at most the last STATS_CAP): latency
        from the SYNC's send time (frame timestamp) to the last TPDO sent, and the SYNC
        handler's CPU time, median / p99 / max in µs; the handler's page faults
        (:meth:`handler_page_faults`)."""
        k = min(self.handled, self.STATS_CAP)
        out = {"syncs": int(self._bus_syncs[0]), "frames": int(sum(n.frames for n in self.networks)),
               "data_bytes": int(sum(n.data_bytes for n in self.networks)),
               "handler_page_faults": self.handler_page_faults()}
        if len(self.networks) > 1:
            out["buses"] = [{"syncs": int(c), "frames": int(n.frames), "data_bytes": int(n.data_bytes)}
                            for c, n in zip(self._bus_syncs, self.networks)]
        for key, a in (("answer_us", self.answer_s[:k]), ("handler_cpu_us", self.handler_cpu_s[:k])):
            a = a[1:] if k > 1 else a                # the first SYNC (start-up) is not a cycle
            out[key] = ({"median": float(np.median(a) * 1e6), "p99": float(np.percentile(a, 99) * 1e6),
                         "max": float(a.max() * 1e6)} if a.size else None)
        # the slow answers, each with its cycle (the SYNCs of a cycle are handled one bus after
        # the other; before the ring wrapped): [cycle, answer µs, handler CPU µs]
        if self.handled <= self.STATS_CAP:
            slow = np.flatnonzero(self.answer_s[:k] > self.SLOW_ANSWER_S)[:self.SLOW_KEPT]
            nb = len(self.buses)
            out["slow_answers"] = [[int(i // nb + 1), float(self.answer_s[i] * 1e6), float(self.handler_cpu_s[i] * 1e6)]
                                   for i in slow]
        return out

    def _on_sync(self, can_id, data, timestamp, bus: int = 0) -> None:
        c0 = time.thread_time()
        try:
            self._take_rpdos()
            self._sync(timestamp, bus)
        finally:
            i = (self.handled - 1) % self.STATS_CAP
            self.answer_s[i] = time.time() - timestamp if timestamp else 0.0
            self.handler_cpu_s[i] = time.thread_time() - c0
            if self.handled == _FAULTS_FROM_SYNC:
                self._faults0 = (threading.get_native_id(), thread_page_faults())

    def handler_page_faults(self) -> dict | None:
        """Page faults of the thread that handles the SYNCs from its :data:`_FAULTS_FROM_SYNC`-th
        SYNC on (``{"minor", "major"}``; None before it, or where /proc cannot tell); after
        :meth:`stop`, the count at the stop."""
        if self._faults_final is not None or self._faults0 is None:
            return self._faults_final
        tid, (mi0, ma0) = self._faults0
        try:
            with open(f"/proc/self/task/{tid}/stat") as f:
                s = f.read()
        except OSError:
            return None
        r = s[s.rindex(")") + 2:].split()              # fields from 3 on: minflt is 10, majflt 12
        return {"minor": int(r[7]) - mi0, "major": int(r[9]) - ma0}

    def _sync(self, timestamp, bus: int = 0) -> None:
        try:
            with self._lock:
                self.handled += 1
                self._bus_syncs[bus] += 1
                cycle = self._bus_syncs[bus]
                if cycle > self.syncs:                  # the first SYNC of a cycle on any bus
                    self.syncs = cycle
                    self._run_scheduled()
                    if self.lock_step:
                        now = self._device_time()
                        for d in self.drives:
                            d.check_rpdo(now)           # RPDO deadline on the device's time
                while self.lock_step and self._steps < cycle - 1:
                    # the interval since the last SYNC, with the set-point in force now: a synchronous
                    # RPDO was actuated at that SYNC, an asynchronous one when it arrived
                    self._latch_torque()                # 0x6077 = the torque over [t_k-1, t_k]
                    self._step(self.period)
                    self._steps += 1
                self._synced = True
                nodes = self.bus_nodes[bus]
                for node in nodes:
                    node.apply_pending_rpdos()          # synchronous RPDOs take effect now
                if not (self.lock_step and self._sampled_at == self._steps):
                    self._sample()                      # lock-step: once per plant step (every bus's)
                    self._sampled_at = self._steps
                for node in nodes:
                    node.transmit_sync_tpdos()
        except Exception as e:  # noqa: BLE001 - keep the notifier alive, report via .error
            self.error = e

    def _watch_master(self) -> None:
        """The drives' consumer heartbeat (0x1016), checked every 5 ms in real time, and, in
        free-running mode, their RPDO deadline (0x1400:5), checked at it (or every 5 ms, whichever
        comes first; lock-step: at each SYNC, on the device's time)."""
        while self._running:
            wait = 0.005
            now = time.monotonic()
            real_time = not self.lock_step        # lock-step: the deadline is checked at each SYNC
            for d in self.drives:
                due = d.rpdo_deadline() if real_time else None
                if due is not None:
                    wait = min(wait, max(due - now, 0.0) + 1e-4)
            time.sleep(wait)
            now = time.monotonic()
            with self._lock:
                for d in self.drives:
                    try:
                        d.check_master(now)
                        if real_time:
                            d.check_rpdo(now)
                    except Exception as e:  # noqa: BLE001 - bus gone while stopping
                        self.error = self.error or e

    def _free_run(self) -> None:
        next_t = time.monotonic()
        while self._running:
            dt = self.period
            with self._lock:
                self._latch_torque()
                self._step(dt)
            next_t += dt
            delay = next_t - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            else:
                next_t = time.monotonic()

    # ------------------------------------------------------------------ faults
    def schedule(self, fault: FaultSpec) -> None:
        """Inject ``fault`` now, or at device time ``fault.at`` (checked at every SYNC)."""
        with self._lock:
            if fault.at is None or fault.at <= self.plant.t:
                self.inject(fault)
            else:
                self._scheduled.append(fault)

    def _run_scheduled(self) -> None:
        if self._scheduled:
            due = [f for f in self._scheduled if f.at <= self.plant.t + 1e-12]
            for f in due:
                self._scheduled.remove(f)
                self.inject(f)

    def inject(self, fault: FaultSpec) -> None:
        """Apply a fault at once."""
        if not 0 <= fault.joint < self.n:
            raise ValueError(f"fault joint {fault.joint}: allowed 0..{self.n - 1}")
        node = (self.drives if fault.target == "drive" else self.encoders)[fault.joint]
        k = fault.kind
        with self._lock:
            self._sampled_at = -1                      # the next SYNC samples anew (stuck, jump)
            if k == "drop":
                self._drop[node.id] = self._drop.get(node.id, 0) + int(fault["count"])
            elif k == "delay":
                self._delay[node.id] = (int(fault["count"]), float(fault["seconds"]))
            elif k == "stuck":
                node.frozen = node.position
            elif k == "jump":
                res = node.increments * node.gear if isinstance(node, DriveNode) else node.resolution
                node.jump_counts += int(round(fault["rad"] / (2 * np.pi) * res))
                self._sample()
            elif k == "emcy":
                if isinstance(node, DriveNode):
                    node.drive_fault(int(fault["code"]))
                else:
                    node.emergency(int(fault["code"]))
            elif k == "heartbeat":
                node.suppress_heartbeat()
            elif k == "busoff":
                node.go_bus_off()

    def _gate(self, can_id: int, data: bytes) -> bool:
        """Outgoing frames of the model: drop / delay TPDOs, silence bus-off nodes."""
        node = can_id & 0x7F
        if can_id != 0x80 and any(n.id == node and n.muted for n in self.drives + self.encoders):
            return False
        if can_id & 0x780 in TPDO_FUNCTIONS:
            left = self._drop.get(node, 0)
            if left:
                self._drop[node] = left - 1
                return False
            count, seconds = self._delay.get(node, (0, 0.0))
            if count:
                self._delay[node] = (count - 1, seconds)
                t = threading.Timer(seconds, self._net_of[node].send_now, args=(can_id, data))
                t.daemon = True
                self._timers.append(t)
                t.start()
                return False
        return True
