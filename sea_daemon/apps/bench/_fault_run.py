"""One run of ``sea-daemon bench faults``: the loop against the device model with injections of one kind.

:class:`FaultRun` builds the rig (:func:`~sea_daemon.apps.bench._rig.bench_rig`), the AKF behind
a NaN hook, the :class:`~sea_daemon.apps.bench._rig.DriveProbe` and the daemon's
:class:`~sea_daemon.runtime.loop.FixedRateLoop` on a virtual clock; from the loop's ``on_cycle``
it injects the faults, removes their causes and asks for the operator reset, and afterwards
evaluates each :class:`Injection` against what the probe saw at the drive (the measures are
described in :mod:`sea_daemon.apps.bench.faults`).

The heartbeat timeout runs on the real clock, and a lock-step cycle otherwise takes whatever the
machine gives it (0.5–4 ms on a 2-vCPU virtual machine): while a heartbeat loss is pending the
run paces its cycles to one period of wall time each (:meth:`FaultRun._pace`), as the loop runs
in production, so the timeout is a number of cycles that does not depend on the machine's load.
"""
from __future__ import annotations

import dataclasses
import time

import can
import numpy as np

from sea_daemon.core.log import DaemonColumns
from sea_daemon.hw.bus import make_bus
from sea_daemon.hw.device_model import FaultSpec

from sea_daemon.errors import Fault
from sea_daemon.runtime.logwriter import LogWriter
from sea_daemon.core.log import log_columns
from sea_daemon.runtime.loop import FixedRateLoop
from sea_daemon.runtime.safety import SafetySupervisor
from sea_daemon.apps.bench._rig import DriveProbe, HeartbeatSniffer, SineTracker, VirtualClock, bench_config, bench_rig
from sea_daemon.core.estimators import make_estimator
from sea_daemon.io.logcsv import read_log

FAULTS = {
    "tpdo_missing": Fault.TPDO_MISSING,
    "heartbeat_lost": Fault.HEARTBEAT_LOST,
    "emcy": Fault.EMCY,
    "encoder_jump": Fault.ENCODER_JUMP,
    "encoder_stuck": Fault.ENCODER_STUCK,
    "bus_off": Fault.BUS_OFF,
    "send_failed": Fault.SEND_FAILED,
    "estimator_nonfinite": Fault.ESTIMATOR_NONFINITE,
    "covariance_not_pd": Fault.COVARIANCE_NOT_PD,
    "overrun_streak": Fault.OVERRUN_STREAK,
}

# bus settings of the runs: a lock-step run on a shared machine needs a generous PDO wait
BUS = dict(pdo_timeout_ms=100.0, max_missed_cycles=2, heartbeat_ms=50, heartbeat_timeout_ms=200,
           stuck_cycles=20, stuck_motion=0.05, sdo_timeout_ms=1000)
OVERRUN_STREAK = 5
HOLD = 5                 # cycles a latched fault is held before the cause is removed and reset asked


class _Estimator:
    """The AKF behind a hook that can replace one measurement by NaN."""

    def __init__(self, akf):
        self.akf = akf
        self.nan_next = False

    def update(self, q, theta_m, tau_m, dt=None):
        if self.nan_next:
            self.nan_next = False
            q = q * np.nan
        return self.akf.update(q, theta_m, tau_m, dt)

    def reset(self, q=None, theta_m=None, tau_m=None):
        return self.akf.reset(q, theta_m, tau_m)


@dataclasses.dataclass
class Injection:
    kind: str
    cycle: int                 # first cycle the fault is present in
    cond: int = -1             # cycle in which the fault's condition is met
    latched: str = ""
    latched_cycle: int = -1
    zero_cycle: int = -1
    held: int = 0
    note: str = ""

    @property
    def detected(self) -> bool:
        return self.latched == FAULTS[self.kind].name and self.latched_cycle >= self.cycle

    @property
    def latency(self) -> int:
        return self.latched_cycle - self.cycle if self.latched_cycle >= 0 else -1

    @property
    def reaction(self) -> int:
        return self.zero_cycle - self.cond if self.zero_cycle >= 0 and self.cond >= 0 else -1


class FaultRun:
    """One loop run with injections of one kind (or none)."""

    def __init__(self, kind: str | None, cycles: int, seed: int, gap: tuple[int, int], max_wait: int = 400,
                 warmup: int = 200, log_path=None):
        self.kind, self.cycles = kind, cycles
        self.rng = np.random.default_rng(seed)
        self.gap, self.max_wait = gap, max_wait
        cfg = bench_config(**BUS)
        self.cfg = cfg
        # the estimator first: its construction loads the compiled kernels (~0.6 s in a fresh
        # process), and the drive watches the daemon's heartbeat from the rig's start on
        self.est = _Estimator(make_estimator("akf", cfg, bound=False))
        self.rig = bench_rig(cfg)
        self.sniffer = HeartbeatSniffer(make_bus(cfg.hardware.bus))
        self.probe = DriveProbe(self.rig, cycles)
        self.clock = VirtualClock()
        self.sup = SafetySupervisor(overrun_streak=OVERRUN_STREAK)
        # the daemon's measured log through the off-loop writer: checked after the run (_check_log)
        self.log_path = log_path
        self.log = None if log_path is None else LogWriter(log_path, log_columns(cfg.joints))
        self.log_check: dict | None = None
        self.loop = FixedRateLoop(self.probe, self.est, SineTracker(cfg), n=cfg.joints, period=cfg.dt,
                                  supervisor=self.sup, clock=self.clock.now, sleep=self.clock.sleep,
                                  realtime=True, on_cycle=self._on_cycle, log=self.log)
        n = cycles + 1
        self.qc = np.zeros(n, dtype=np.int64)
        self.mc = np.zeros(n, dtype=np.int64)
        self.qa = np.zeros(n)
        self.ma = np.zeros(n)
        self.latched_at = np.zeros(n, dtype=bool)
        self.injections: list[Injection] = []
        self.false_alarms: list[tuple[int, str]] = []
        self.reset_failed: list[tuple[int, str]] = []     # an operator reset that did not take
        # the drive's quick stop on the daemon's heartbeat missing while the loop itself stalled
        # longer than the timeout (a loaded host): the watch doing its job, not a false alarm
        self.host_stalls: list[tuple[int, str]] = []
        self.cur: Injection | None = None
        self.next_at = warmup + int(self.rng.integers(*gap))
        self.reset_at = -1
        self._restore = None
        self._pending_cond = None
        self._slow: list[float] = []          # injected slowness still to come, one entry per cycle

    # ------------------------------------------------------------------ injection
    def _inject(self, k: int) -> None:
        """Called in on_cycle(k): the fault is present from cycle k + 1 on (the stall: in k)."""
        inj = Injection(self.kind, k + 1)
        target = "drive" if self.rng.random() < 0.5 else "encoder"
        node = self.rig.drive if target == "drive" else self.rig.encoder
        getattr(self, f"_inject_{self.kind}")(inj, k, target, node)
        self.injections.append(inj)
        self.cur = inj

    def _inject_tpdo_missing(self, inj: Injection, k: int, target: str, node) -> None:
        kk = self.cfg.hardware.bus.max_missed_cycles + 1
        self.rig.device_model.inject(FaultSpec("drop", target=target, params={"count": kk}))
        inj.cond = k + kk
        inj.note = f"{kk} cycles"

    def _inject_heartbeat_lost(self, inj: Injection, k: int, target: str, node) -> None:
        node.suppress_heartbeat()
        inj.cond = -2                     # from the sniffer, once the latch is seen
        self._restore = lambda: self._restore_heartbeat(node)
        inj.note = target

    def _restore_heartbeat(self, node) -> None:
        hw = self.rig.hw
        node.heartbeat_suppressed = False
        node.nmt.start_heartbeat(self.cfg.hardware.bus.heartbeat_ms)
        # the loop waits here: the daemon's own heartbeat goes on meanwhile (keepalive), as it
        # would from a loop that keeps cycling
        t0 = time.monotonic()
        seen = self.sniffer.hb_seen.get(node.id, 0.0)
        while self.sniffer.hb_seen.get(node.id, 0.0) <= seen and time.monotonic() - t0 < 2.0:
            hw.keepalive()
            time.sleep(0.002)
        while hw.heartbeat_arrival(node.id) is None or time.monotonic() - hw.heartbeat_arrival(node.id) > 0.05:
            hw.keepalive()                 # the heartbeats come on the cycle's handles
            time.sleep(0.002)

    def _inject_emcy(self, inj: Injection, k: int, target: str, node) -> None:
        code = int(self.rng.choice([0x2310, 0x4210, 0x7305, 0x5530]))
        self.rig.device_model.inject(FaultSpec("emcy", target=target, params={"code": code}))
        inj.cond = k + 1
        inj.note = f"{target} 0x{code:04X}"

    def _inject_encoder_jump(self, inj: Injection, k: int, target: str, node) -> None:
        rng = self.rng
        rad = float(rng.uniform(0.3, 1.0) * rng.choice([-1, 1]))
        before = node.jump_counts
        self.rig.device_model.inject(FaultSpec("jump", target=target, params={"rad": rad}))
        delta = node.jump_counts - before

        def restore(node=node, delta=delta):
            node.jump_counts -= delta
        self._restore = restore
        inj.cond = k + 1
        inj.note = f"{target} {rad:+.2f} rad"

    def _inject_encoder_stuck(self, inj: Injection, k: int, target: str, node) -> None:
        self.rig.device_model.inject(FaultSpec("stuck", target=target))

        def restore(node=node):
            node.frozen = None
        self._restore = restore
        inj.cond = -3                     # recomputed from the recorded counts
        inj.note = target

    def _inject_bus_off(self, inj: Injection, k: int, target: str, node) -> None:
        self.rig.dev_bus.send(can.Message(arbitration_id=0x40, is_error_frame=True, is_extended_id=False,
                                          data=bytes(8)))
        t0 = time.monotonic()
        while not self.rig.hw.bus_off and time.monotonic() - t0 < 2.0:   # controller state known
            time.sleep(0.0005)
        inj.cond = k + 1

    def _inject_send_failed(self, inj: Injection, k: int, target: str, node) -> None:
        self.probe.fail_sends = 1
        inj.cond = k + 1

    def _inject_estimator_nonfinite(self, inj: Injection, k: int, target: str, node) -> None:
        rng = self.rng
        if rng.random() < 0.5:
            self.est.akf.x[int(rng.integers(0, self.est.akf.d))] = np.nan
            inj.note = "state x"
        else:
            self.est.nan_next = True
            inj.note = "measurement q"
        inj.cond = k + 1

    def _inject_covariance_not_pd(self, inj: Injection, k: int, target: str, node) -> None:
        rng, P = self.rng, self.est.akf.P
        i = int(rng.integers(0, self.est.akf.d))
        P[i, i] = -float(rng.uniform(1.0, 100.0)) * max(1.0, abs(P[i, i]))
        inj.cond = k + 1
        inj.note = f"P[{i},{i}] < 0"

    def _inject_overrun_streak(self, inj: Injection, k: int, target: str, node) -> None:
        # the loop turns slow: each of m >= streak consecutive cycles (from this one on) takes
        # 1.1..3 periods (the loop re-phases after a single long stall, so one stall alone is
        # one overrun; a streak needs consecutive slow cycles)
        rng = self.rng
        m = OVERRUN_STREAK + int(rng.integers(0, 4))
        self._slow = [float(x) * self.cfg.dt for x in rng.uniform(1.1, 3.0, size=m)]
        slow = list(self._slow)
        self._slow_cycle()                # this cycle is the first slow one
        inj.cycle = k
        inj.cond = k + OVERRUN_STREAK - 1
        inj.note = f"{m} cycles of {min(slow) * 1e3:.0f}-{max(slow) * 1e3:.0f} ms"

    def _host_stall(self, k: int, fault: Fault, detail: str) -> bool:
        """A latch without an injection that the heartbeat watches rightly raised because a
        thread of this host stalled past ``heartbeat_timeout_ms``: the drive's EMCY 0x8130 (its
        watch of the daemon's heartbeat, sent from read()) when two read() starts within the last
        second of cycles lie further apart than the timeout, or the bus (the sniffer) carried no
        heartbeat of the daemon for longer since the previous latch; HEARTBEAT_LOST when the bus
        had no heartbeat of a device for longer than the timeout before this read()."""
        timeout = self.cfg.hardware.bus.heartbeat_timeout_ms / 1e3
        if fault == Fault.EMCY and "EMCY 0x8130" in detail:
            t = self.probe.read_t[max(0, k - int(round(1.0 / self.cfg.dt))):k + 1]
            t = t[t > 0]
            master = self.cfg.hardware.bus.master_node
            gap = max(self.sniffer.hb_gap_max.pop(master, 0.0),
                      self.probe.read_t[k] - self.sniffer.hb_seen.get(master, self.probe.read_t[k]))
            return gap > timeout or (len(t) > 1 and float(np.max(np.diff(t))) > timeout)
        if fault == Fault.HEARTBEAT_LOST:
            nodes = (self.rig.drive.id, self.rig.encoder.id)
            return any(self.probe.read_t[k] - self.sniffer.hb_seen.get(n, self.probe.read_t[k]) > timeout
                       for n in nodes)
        return False

    def _slow_cycle(self) -> None:
        """Injected slowness of this cycle (advances the loop's virtual clock)."""
        if self._slow:
            self.clock.t += self._slow.pop(0)

    def _pace(self, k: int) -> None:
        """While a heartbeat loss is pending: the next read() starts one period of wall time
        after this one started (the loop's virtual clock does not see it)."""
        left = self.probe.read_t[k] + self.cfg.dt - time.monotonic()
        if left > 0:
            time.sleep(left)

    def _on_cycle(self, k, meas, est, tau) -> None:
        self._slow_cycle()                    # an injected slowdown in progress
        m = self.rig.hw.meas
        self.qc[k], self.mc[k] = m.q_counts[0], m.theta_m_counts[0]
        self.qa[k], self.ma[k] = m.q[0], m.theta_m[0]
        sup = self.sup
        latched = not sup.ok
        self.latched_at[k] = latched
        inj = self.cur
        if inj is not None:
            if latched and inj.latched_cycle < 0:
                inj.latched = sup.latched.name
                inj.latched_cycle = sup.latched_cycle
                self.reset_at = k + HOLD
            elif not latched and k - inj.cycle > self.max_wait:
                inj.note += " (not detected)"
                self.reset_at = k
            if k >= self.reset_at >= 0:
                if self._restore is not None:
                    self._restore()
                    self._restore = None
                self.loop.request_reset()
                self.sniffer.hb_gap_max.clear()      # stalls count from here
                self.reset_at = -1
                self.cur = None
                self.next_at = k + 1 + int(self.rng.integers(*self.gap))
            elif inj.kind == "heartbeat_lost" and inj.latched_cycle < 0:
                self._pace(k)
            return
        if latched:                           # no injection pending: a false alarm (or a failed reset)
            if self.reset_at < 0:
                rec = (k, f"{sup.latched.name}: {sup.latched_detail}")
                if self.probe.reset_failures and self.probe.reset_failures[-1] in sup.latched_detail:
                    self.reset_failed.append(rec)
                elif self._host_stall(k, sup.latched, sup.latched_detail):
                    self.host_stalls.append(rec)
                else:
                    self.false_alarms.append(rec)
            if self.reset_at < 0:
                self.reset_at = k + HOLD
            if k >= self.reset_at:
                self.loop.request_reset()
                self.sniffer.hb_gap_max.clear()      # stalls count from here
                self.reset_at = -1
            return
        if self.kind is not None and k >= self.next_at and k + self.max_wait + HOLD + 2 < self.cycles:
            self._inject(k)
            if self.kind == "heartbeat_lost":
                self._pace(k)

    # ------------------------------------------------------------------ evaluation
    def run(self) -> "FaultRun":
        try:
            self.loop.run(self.cycles)
            self.probe.observe(self.cycles - 1)
        finally:
            try:
                self.rig.stop()
            finally:
                self.sniffer.close()
                closed = self.log.close() if self.log is not None else None
        self._evaluate()
        if closed is not None:
            self._check_log(closed)
        return self

    def _check_log(self, closed: dict) -> None:
        """The log has a row for every cycle (cycle column 0..N−1, time increasing), its fault
        column is non-zero exactly in the cycles the loop was latched, valid is 0 there, and the
        commanded torque of those rows is zero."""
        log = read_log(self.log_path, n=1, units=False)   # its own log: never a unit error
        ex = DaemonColumns.of(log)
        fault = ex.fault != 0
        n = self.loop.stats.cycles
        self.log_check = {
            "cycles": n, "rows": len(log), "rows_lost": closed["rows_lost"],
            "every_cycle": bool(len(log) == n and np.array_equal(ex.cycle, np.arange(n))
                                and np.all(np.diff(log.t) > 0)),
            "fault_rows": int(fault.sum()),
            "fault_rows_match": bool(np.array_equal(fault, self.latched_at[:n])),
            "no_valid_while_latched": bool(not np.any(ex.valid[fault])),
            "zero_torque_while_latched": bool(np.all(log.tau_m[fault] == 0)),
            "placeholder_rows": int(np.count_nonzero(ex.measured == 0)),
        }
        self.log_check["ok"] = all(v for k, v in self.log_check.items() if isinstance(v, bool)) \
            and closed["rows_lost"] == 0

    def _stuck_cond(self, inj: Injection) -> int:
        """The cycle in which the driver's stuck condition is met for joint 0 (the joint the run
        records): a count unchanged for ``stuck_cycles`` while the other encoder moved by more
        than joint 0's ``stuck_motion``; -1 if never."""
        b = self.cfg.hardware.bus
        limit = float(b.stuck_motions(self.cfg.joints)[0])
        end = inj.latched_cycle if inj.latched_cycle >= 0 else self.cycles
        for counts, other in ((self.qc, self.ma), (self.mc, self.qa)):
            run, ref = 0, other[inj.cycle - 1]
            for k in range(inj.cycle, end + 1):
                if counts[k] != counts[k - 1]:
                    run, ref = 0, other[k]
                    continue
                run += 1
                if run >= b.stuck_cycles and abs(other[k] - ref) > limit:
                    if counts[inj.cycle:k + 1].min() == counts[inj.cycle:k + 1].max():
                        return k
                    break
        return -1

    def _evaluate(self) -> None:
        timeout = self.cfg.hardware.bus.heartbeat_timeout_ms / 1e3
        applied = self.probe.applied
        for inj in self.injections:
            if inj.cond == -3:
                inj.cond = self._stuck_cond(inj)
            if inj.cond == -2:
                # first cycle whose read() started later than the last heartbeat seen + timeout:
                # the sniffer's last heartbeat before the latch is the one before the outage
                inj.cond = -1
            if inj.latched_cycle < 0:
                continue
            # the latch record ends HOLD cycles later (then reset): zero torque from then on?
            end = inj.latched_cycle + HOLD
            start = max(inj.cond, inj.cycle) if inj.cond >= 0 else inj.cycle
            for k in range(start, end + 1):
                if np.all(applied[k:end + 1] == 0):
                    inj.zero_cycle = k
                    break
            inj.held = int(np.count_nonzero(applied[inj.latched_cycle:end + 1]))
        # heartbeat: condition cycle from the read() start times and the sniffer's record
        for inj in self.injections:
            if inj.kind == "heartbeat_lost" and inj.latched_cycle >= 0:
                last = inj.hb_last if hasattr(inj, "hb_last") else None
                if last is not None:
                    later = np.nonzero(self.probe.read_t[inj.cycle:inj.latched_cycle + 2] > last + timeout)[0]
                    if len(later):
                        inj.cond = inj.cycle + int(later[0])
                        inj.zero_cycle = -1
                        end = inj.latched_cycle + HOLD
                        for k in range(inj.cond, end + 1):
                            if np.all(applied[k:end + 1] == 0):
                                inj.zero_cycle = k
                                break


def record_heartbeats(run: FaultRun) -> None:
    """Record, for heartbeat injections, the sniffer's last heartbeat of the silenced node
    before the latch (read in on_cycle of the latch cycle: nothing has been restored yet)."""
    orig = run.loop.on_cycle

    def on_cycle(k, meas, est, tau):
        inj = run.cur
        if inj is not None and inj.kind == "heartbeat_lost" and not run.sup.ok and inj.latched_cycle < 0:
            node = run.rig.drive if inj.note == "drive" else run.rig.encoder
            inj.hb_last = run.sniffer.hb_seen.get(node.id)
        orig(k, meas, est, tau)
    run.loop.on_cycle = on_cycle
