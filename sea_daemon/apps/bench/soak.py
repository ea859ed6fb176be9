"""``sea-daemon bench soak``: a long run of the whole stack, memory, overruns and log rows.

The daemon's :class:`FixedRateLoop` on the real monotonic clock at ``--rate``, with
:class:`CanopenHardware` against the device model on a virtual CAN bus in **lock-step** (the
plant steps once per SYNC, so a slow cycle slows the simulated arm rather than the physics
running away), a PID tracking a slow sine, the **GP-AKF learning online** from every sample
(LoG-GP with bounded leaves: ``learning.max_points`` per leaf, ``--max-leaves`` leaves, so the
per-cycle work and the memory are bounded), and the measured log written every cycle through
the off-loop :class:`LogWriter` (shared-memory ring, writer process, flush <= 1 s, rotation).

Reported: resident memory (VmRSS of /proc, the loop's process and the writer process) at
start, after the warm-up and at the end, with the LoG-GP's size; cycles, overruns and the
cycle time (from the log's own ``period`` / ``compute`` columns); log rows appended, written
and dropped, and the rows counted back in the rotated files.

A latched fault would stop the estimator (the loop's policy) and is reported; the overrun
streak that would trip it when the host cannot hold the rate is configurable
(``--overrun-streak``; 0 disables it, and LOOP_STALL, for the soak; overruns and skipped
cycles are still counted).
"""
from __future__ import annotations

import dataclasses
import gc
import os
import signal
import tempfile
import time
from pathlib import Path

import numpy as np

from sea_daemon.runtime.logwriter import LogWriter
from sea_daemon.core.log import log_columns
from sea_daemon.runtime.loop import FixedRateLoop
from sea_daemon.runtime.safety import SafetySupervisor
from sea_daemon.runtime.realtime import try_realtime
from sea_daemon.apps.bench import add_json_argument, json_output, machine, summarize
from sea_daemon.apps.bench._rig import SineTracker, bench_config, bench_rig, vm_rss_kb
from sea_daemon.apps.bench.loop import device_model_process
from sea_daemon.core.estimators import make_estimator
from sea_daemon.core.rates import at_rate
from sea_daemon.errors import InputError
from sea_daemon.io.files import check_output_dir
from sea_daemon.core.bounds.akf_bound import theorem_bound
from sea_daemon.runtime.bound_worker import BoundWorker
from sea_daemon.runtime.service import WORKER_PRIORITY_BELOW

DESCRIPTION = __doc__


def add_arguments(p) -> None:
    p.add_argument("--cycles", type=int, default=1000000, help="loop cycles (default 1e6)")
    p.add_argument("--rate", type=float, default=1000.0, help="loop rate [Hz] (default 1000)")
    p.add_argument("--warmup", type=int, default=None,
                   help="cycles of warm-up before the reference memory sample (default: 10%% of --cycles)")
    p.add_argument("--max-leaves", type=int, default=None,
                   help="LoG-GP leaf bound (default: learning.max_leaves of the config)")
    p.add_argument("--overrun-streak", type=int, default=0,
                   help="consecutive overruns that latch the fault (0: neither it nor LOOP_STALL for the soak; counted anyway)")
    p.add_argument("--rotate-mb", type=float, default=64.0, help="log rotation size [MB] (default 64)")
    p.add_argument("--out", default=None, help="directory of the log files (default: a temporary one, removed)")
    p.add_argument("--samples", type=int, default=20, help="memory samples over the run (default 20)")
    add_json_argument(p)
    p.add_argument("--bus", choices=("virtual", "ipc"), default="virtual",
                   help="virtual: the device model in this process; ipc: in its own process (SCHED_FIFO 70) over "
                        "the ipc bus, the loop SCHED_FIFO 80")
    p.add_argument("--learn-cycles", type=int, default=None,
                   help="the GP learns online in the first N cycles, then is frozen (default: all cycles)")
    p.add_argument("--max-missed", type=int, default=3, help="ipc: late TPDOs held in a row (default 3; counted)")
    p.add_argument("--bound", action="store_true",
                   help="publish the Theorem-1 bound rho_k once learning stops (with --learn-cycles; default: the "
                        "filter's own bound)")
    p.add_argument("--bound-in", choices=("worker", "loop"), default="worker",
                   help="with --bound: the bound in a worker process started when learning stops (default, as the "
                        "daemon in real-time pace) or in the loop's estimator step")


def _count_rows(files) -> tuple[int, np.ndarray, np.ndarray]:
    """Rows in the rotated CSV files (header excluded) and their period / compute columns."""
    rows = 0
    per, comp = [], []
    for f in files:
        with open(f) as fh:
            cols = fh.readline().strip().split(",")
            ip, ic = cols.index("period"), cols.index("compute")
            for line in fh:
                rows += 1
                parts = line.split(",")
                per.append(float(parts[ip]))
                comp.append(float(parts[ic]))
    return rows, np.asarray(per), np.asarray(comp)


class _SoakProbe:
    """The soak's ``on_cycle``: freezes the GP after ``learn_cycles`` (and starts the bound, in
    its worker or the loop, with ``bound``), and samples the memory every ``stride`` cycles and
    at the end of the warm-up into :attr:`trace`: (cycle, loop RSS kB, writer RSS kB, GP leaves,
    GP points)."""

    def __init__(self, est, log: LogWriter, rt: dict, warmup: int, stride: int, learn_cycles: int | None,
                 bound: bool, bound_in: str, progress):
        self.est, self.log, self.rt, self.warmup, self.stride = est, log, rt, warmup, stride
        self.learn_cycles, self.bound, self.bound_in, self.progress = learn_cycles, bound, bound_in, progress
        self.gp = est.gp.gps[0]
        self.loop: FixedRateLoop | None = None
        self.trace: list = []
        self.marks: dict = {}
        self.links: dict = {}

    def sample(self, k: int) -> tuple:
        return (k, vm_rss_kb(), vm_rss_kb(self.log.writer_pid), self.gp.n_leaves, self.gp.n_points)

    def __call__(self, k, meas, e, tau) -> None:
        if self.learn_cycles is not None and k == self.learn_cycles:
            self._freeze()
        if k % self.stride == 0 or k == self.warmup:
            rec = self.sample(k)
            self.trace.append(rec)
            if k == self.warmup:
                self.marks["warmup"] = rec
            if self.progress and k % self.stride == 0:
                self.progress(rec, self.loop.stats)

    def _freeze(self) -> None:
        est = self.est
        est.learning = False                  # the model frozen from here on (the daemon's run)
        if not self.bound:
            return
        est.bound = theorem_bound(est)
        est.bound.reset(est.est, est.record)  # the set of means starts at a point here
        if self.bound_in == "worker":
            # the GP is frozen now: the worker's copy of it stays the loop's
            prio = 80 - WORKER_PRIORITY_BELOW if self.rt.get("sched", "").startswith("fifo") else 0
            # started from inside the running loop: not waiting for the worker's set-up
            self.loop.bound_link = self.links["worker"] = BoundWorker(est, rt_priority=prio).start(wait=False)


def _soak_rig(cfg, bus: str, out_dir: Path, rate: float, max_missed: int):
    """The device model in this process (virtual) or, started here, in its own (ipc); (cfg, rig,
    device model process or None, what real-time set-up applied)."""
    if bus != "ipc":
        return cfg, bench_rig(cfg), None, {"sched": "other (not asked)"}
    # the TPDO deadline inside the period; a late answer is held for 3 cycles (counted)
    b = dataclasses.replace(cfg.hardware.bus, interface="ipc", channel=f"soak-{os.getpid()}",
                            pdo_timeout_ms=0.6e3 / rate, max_missed_cycles=max_missed)
    cfg = dataclasses.replace(cfg, hardware=dataclasses.replace(cfg.hardware, bus=b))
    dev, rig = device_model_process(cfg, out_dir, ["--q0", "0.6", "--seed", "0"])
    # as the service does: SCHED_FIFO and the memory locked before the hardware starts (locking
    # faults the process in, which must not happen while the drives watch its heartbeat)
    rt = try_realtime(80)
    rig.start()
    return cfg, rig, dev, rt


def soak(cycles: int, rate: float, warmup: int, max_leaves: int | None, overrun_streak: int, rotate_bytes: int,
         out_dir: Path, samples: int = 20, progress=None, bus: str = "virtual", learn_cycles: int | None = None,
         bound: bool = False, max_missed: int = 3, bound_in: str = "worker") -> dict:
    cfg = bench_config(pdo_timeout_ms=200.0, heartbeat_ms=50, heartbeat_timeout_ms=1000, sdo_timeout_ms=1000)
    cfg = at_rate(cfg, float(rate))
    if max_leaves:
        cfg = dataclasses.replace(cfg, learning=dataclasses.replace(cfg.learning, max_leaves=int(max_leaves)))
    rss = {"start": vm_rss_kb()}
    # the Theorem-1 bound needs a GP with data (its constants): it starts when learning stops
    est = make_estimator("gp-akf", cfg, bound=False)
    cfg, rig, dev, rt = _soak_rig(cfg, bus, out_dir, rate, max_missed)
    log = LogWriter(out_dir / "soak.csv", log_columns(cfg.joints), rotate_bytes=rotate_bytes, flush_interval=0.5)
    sup = SafetySupervisor.with_streak(overrun_streak)
    probe = _SoakProbe(est, log, rt, warmup, max(1, cycles // max(1, samples)), learn_cycles, bound, bound_in,
                       progress)
    loop = probe.loop = FixedRateLoop(rig.hw, est, SineTracker(cfg), n=cfg.joints, period=cfg.dt, log=log,
                                      supervisor=sup, realtime=True, on_cycle=probe)
    rss["after_start"] = vm_rss_kb()
    gc.collect()
    # SIGTERM / SIGINT end the soak early and cleanly: the figures are of the cycles run
    old_handlers = {sig: signal.signal(sig, lambda *_: loop.request_stop()) for sig in (signal.SIGTERM, signal.SIGINT)}
    t0 = time.monotonic()
    try:
        st = loop.run(cycles)
    finally:
        for sig, h in old_handlers.items():
            signal.signal(sig, h)
        wall = time.monotonic() - t0
        probe.trace.append(probe.sample(loop.stats.cycles))
        closed = log.close()
        if "worker" in probe.links:
            probe.links["bound"] = probe.links["worker"].close()
        rig.stop()
        if dev is not None:
            dev.terminate()
            dev.communicate(timeout=20)
    return _soak_summary(cfg, rig, est, sup, st, probe, rss, rt, closed, wall, rate=rate, bus=bus, bound=bound,
                         bound_in=bound_in, learn_cycles=learn_cycles)


def _soak_summary(cfg, rig, est, sup, st, probe: _SoakProbe, rss: dict, rt: dict, closed: dict, wall: float, *,
                  rate: float, bus: str, bound: bool, bound_in: str, learn_cycles: int | None) -> dict:
    rows, per, comp = _count_rows(closed["files"])
    end = probe.trace[-1]
    w = probe.marks.get("warmup", probe.trace[0])
    growth = (end[1] - w[1]) / w[1] * 100.0 if w[1] > 0 else float("nan")
    wgrowth = (end[2] - w[2]) / w[2] * 100.0 if w[2] > 0 else float("nan")
    return {
        "cycles": st.cycles, "rate_hz": rate, "bus": bus, "realtime": rt, "bound": bound,
        "bound_in": (bound_in if bound else None), "bound_worker": probe.links.get("bound"),
        "learn_cycles": learn_cycles, "hardware": getattr(rig, "description", ""),
        "missed_tpdo_cycles": int(getattr(rig.hw, "missed_cycles", 0)), "late_tpdo_cycles": int(getattr(rig.hw, "late_cycles", 0)), "wall_s": wall, "achieved_hz": st.cycles / wall if wall else 0.0,
        "overruns": st.overruns, "max_late_s": st.max_late_s,
        "fault": sup.latched.name, "fault_detail": sup.latched_detail, "fault_cycle": sup.latched_cycle,
        "rss_kb": {"process_start": rss["start"], "after_start": rss["after_start"], "warmup": w[1], "end": end[1],
                   "writer_warmup": w[2], "writer_end": end[2]},
        "rss_growth_after_warmup_pct": growth, "writer_rss_growth_after_warmup_pct": wgrowth,
        "warmup_cycles": w[0], "gp_warmup": {"leaves": w[3], "points": w[4]},
        "gp_end": {"leaves": end[3], "points": end[4]}, "max_leaves": cfg.learning.max_leaves,
        "learned": est.n_learned,
        "log": {"appended": closed["rows_appended"], "written": closed["rows_written"],
                "dropped": closed["rows_dropped"], "counted_in_files": rows, "files": len(closed["files"])},
        "period": summarize(per[1:], 1e3, "ms") if len(per) > 1 else "-",
        "compute": summarize(comp, 1e3, "ms") if len(comp) else "-",
        "trace": probe.trace,
    }


def run(args) -> int:
    save = json_output(args)
    if args.cycles < 100 or args.rate <= 0:
        raise InputError(f"--cycles {args.cycles} (>= 100), --rate {args.rate} (> 0)")
    warmup = args.warmup if args.warmup is not None else args.cycles // 10
    if args.bound and args.learn_cycles is None:
        raise InputError("--bound needs --learn-cycles (the bound's GP constants need the learned data)")
    if not 0 <= warmup < args.cycles:
        raise InputError(f"--warmup {warmup}: must be in 0..{args.cycles - 1}")
    if args.overrun_streak < 0:
        raise InputError(f"--overrun-streak {args.overrun_streak}: allowed >= 0 (0: never)")
    print(f"# sea-daemon bench soak on {machine()}")
    print(f"# FixedRateLoop (real clock, {args.rate:g} Hz) + CanopenHardware + device model ({args.bus} bus, lock-step) "
          f"+ GP-AKF learning online + LogWriter; {args.cycles} cycles, warm-up {warmup}", flush=True)

    def progress(rec, st):
        print(f"#   cycle {rec[0]:>8}: RSS {rec[1] / 1024:.1f} MB (writer {rec[2] / 1024:.1f} MB), "
              f"GP {rec[3]} leaves / {rec[4]} points, overruns {st.overruns}", flush=True)
    tmp = None
    if args.out:
        out = check_output_dir("--out", args.out)
    else:
        tmp = tempfile.TemporaryDirectory(prefix="sea-soak-")
        out = Path(tmp.name)
    try:
        r = soak(args.cycles, args.rate, warmup, args.max_leaves, args.overrun_streak,
                 int(args.rotate_mb * 1e6), out, args.samples, progress, bus=args.bus, learn_cycles=args.learn_cycles,
                 bound=args.bound, max_missed=args.max_missed, bound_in=args.bound_in)
    finally:
        if tmp is not None:
            tmp.cleanup()
    m = r["rss_kb"]
    lg = r["log"]
    if r["cycles"] < args.cycles:
        print(f"# stopped by a signal after {r['cycles']} of {args.cycles} cycles")
    print(f"hardware            {r['hardware']}; loop {r['realtime']['sched']}; GP learning "
          f"{'all cycles' if r['learn_cycles'] is None else 'first %d cycles, then frozen' % r['learn_cycles']}; "
          f"bound {'Theorem-1 rho_k' if r['bound'] else 'the filter own'}"
          + (f" in {'a worker process' if r['bound_in'] == 'worker' else 'the loop'}" if r['bound'] else ""))
    bw = r.get("bound_worker")
    if bw:
        print(f"bound worker        sched {bw['sched']}; {bw['samples_done']} samples, {bw['stale']} of {bw['steps']} filter steps with no "
              f"bound within {bw['max_age']} cycles; ring full: {bw['broken']}; fault: {bw['fault']}; its CPU "
              f"{bw['worker_cpu_process_s']:.1f} s")
    print(f"cycles run          {r['cycles']} in {r['wall_s']:.0f} s ({r['achieved_hz']:.0f} Hz achieved, "
          f"{r['rate_hz']:g} Hz asked)")
    print(f"overruns            {r['overruns']} (max late {r['max_late_s'] * 1e3:.1f} ms); TPDO cycles missed at "
          f"the deadline {r['missed_tpdo_cycles']}, late {r['late_tpdo_cycles']}")
    print(f"cycle period        {r['period']}")
    print(f"cycle compute       {r['compute']}")
    print(f"fault latched       {r['fault']}" + (f" at cycle {r['fault_cycle']}: {r['fault_detail']}"
                                                 if r['fault'] != 'NONE' else ""))
    print(f"RSS loop process    start {m['process_start'] / 1024:.1f} MB, rig up {m['after_start'] / 1024:.1f} MB, "
          f"after warm-up ({r['warmup_cycles']} cycles) {m['warmup'] / 1024:.1f} MB, end {m['end'] / 1024:.1f} MB "
          f"-> growth after warm-up {r['rss_growth_after_warmup_pct']:+.2f} %")
    print(f"RSS writer process  after warm-up {m['writer_warmup'] / 1024:.1f} MB, end {m['writer_end'] / 1024:.1f} MB "
          f"-> {r['writer_rss_growth_after_warmup_pct']:+.2f} %")
    print(f"LoG-GP              warm-up {r['gp_warmup']['leaves']} leaves / {r['gp_warmup']['points']} points, "
          f"end {r['gp_end']['leaves']} / {r['gp_end']['points']} (max_leaves {r['max_leaves']}), "
          f"{r['learned']} samples learned")
    print(f"log rows            appended {lg['appended']}, written {lg['written']}, dropped {lg['dropped']}, "
          f"counted in {lg['files']} file(s) {lg['counted_in_files']}; cycles - rows = "
          f"{r['cycles'] - lg['counted_in_files']}")
    save(r)
    return 0
