"""``sea-daemon bench loop --rate 100|1000 --cycles N --bus virtual|ipc|remote``: the daemon's loop against the device model.

``--joints N`` (2 or 3) runs N joints, a bus per joint (``--one-bus``: one bus), and prints the
load of each bus; two joints are the coupled shoulder–elbow exoskeleton of a URDF
(``configs/exo_2dof.yaml``; ``--uncoupled``: two copies of the one-joint exoskeleton) (:mod:`sea_daemon.apps.bench._loop_rig`); what follows describes one joint.

What runs is ``sea-daemon run``'s service (:func:`sea_daemon.runtime.service.serve`): the GP-AKF
with a residual learned by ``sea-daemon calibrate`` (lock-step on the device model, not timed)
at ``--model-rate`` (default 100 Hz: the model file of the 100 Hz daemon, run at ``--rate``
through :func:`sea_daemon.core.rates.at_rate`), learning frozen, the Theorem-1 bound ρ_k
published every cycle (``--no-bound``: the filter's own bound) — computed in the bound worker
process (``--bound-in worker``, the configuration's default in real-time pace; ρ of an earlier
sample, at most ``--bound-max-age`` cycles old) or in the loop's estimator step (``--bound-in
loop``) — the passive scenario's PID
controller, the off-loop log writer, the loop in real-time pace, SCHED_FIFO / mlockall tried
(what applied is printed).  The device model (the passive scenario's true plant behind a
CANopen drive and load encoder, lock-step with SYNC) runs in this process on a python-can
virtual bus (``--bus virtual``: its SYNC handling and plant step compete with the loop for the
GIL), or in its own process (SCHED_FIFO ``--device-rt-priority``) on the ``ipc`` bus (UNIX
datagram sockets, one hop per frame) or behind ``python -m can_remote`` (``remote``:
websockets through the relay process).  The TPDOs are collected until ``--tpdo-deadline`` of
the period after the SYNC (a deadline inside the period); a cycle whose TPDOs are later holds
the last values in the driver (up to ``--max-missed`` cycles in a row, then the TPDO_MISSING
fault), which the loop passes on as the constant-velocity extrapolation of the two cycles
before; both are counted.

Figures, over the N measured cycles: the loop period (start to start) minus nominal — median,
p99, max of |period − nominal|; overruns (cycles that ended after their deadline) per 10⁵
cycles; the daemon's own CPU time per cycle — the loop thread's (``time.thread_time`` from the
start of the cycle to its log row) plus the CAN receive thread's over the same cycle (its
thread CPU clock), median / p99; the bound worker's process is not part of it and has its own
line: its CPU time per sample (the bound's step and the start-up gate, its thread CPU clock),
median / p99 / max, and its whole process's CPU time per cycle; the bound's age (cycle of the
estimate − cycle of the bound's sample) over the filter steps, median / p99 / max, and the steps
with no bound within the maximum age (the estimate not valid there) — and the cycle's wall time (read → log row, the log's
``compute``) with the part spent in ``hw.read()`` (SYNC → TPDOs, waiting for the devices);
the device model's answer latency (its SYNC frame's send time to its last TPDO handed to the
bus, measured in the device model's process) and its SYNC handler's CPU time; CAN frames per
cycle and the load they are on a 1 Mbit/s bus (every frame the device model sent or received,
start-up included, plus the daemon's published TPDOs, which the devices' acceptance filter keeps
out of the device model; bits per frame 47 + 8·DLC without stuffing, 55 + 10·DLC with worst-case
stuffing); missed and late TPDO cycles; log rows dropped; the page faults of the loop thread over
the cycles after the first tenth and of the device model's SYNC handler from its 100th SYNC on
(a page first written on the real-time path; the memory each process locked is printed: the
loop's and the device model's with their scheduling, the worker's with the bound).  The
machine's load average is printed
before and after: the machine is shared; so is what starting a cycle cold costs on it
(:func:`sea_daemon.apps.bench.host_wake`: a fixed reference workload timed right after sleeping
one period and hot, before and after the run).  The OVERRUN_STREAK fault is off by default here
(``--overrun-fault`` keeps it), so that every measured cycle does the full work; when another fault
latches (the estimator stops), the daemon's CPU is given over the cycles before it too.
"""
from __future__ import annotations

import dataclasses
import json
import os
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from sea_daemon.apps.bench import add_json_argument, describe_host_wake, host_wake, json_output, machine
from sea_daemon.apps.bench._loop_rig import (
    SwayController, bench_rig, describe_bus_load, device_model_process, joints_config, per_bus_load, stop_procs,
    joints_plant, trained_estimator)
from sea_daemon.hw.busload import measured_load
from sea_daemon.core.log import DaemonColumns
from sea_daemon.apps.bench._loop_stages import stage_timers
from sea_daemon.apps.bench._loop_overruns import describe as describe_overruns, overrun_anatomy
from sea_daemon.io.configfile import save_config
from sea_daemon.io.configfile import load_config, data_root
from sea_daemon.core.rates import at_rate
from sea_daemon.apps.calibration import calibrate
from sea_daemon.core.estimators import make_estimator
from sea_daemon.io.gpmodel import load_gp_model
from sea_daemon.core.buffers import resident_zeros
from sea_daemon.hw.device_model.model import thread_page_faults
from sea_daemon.runtime.realtime import huge_page_state, kernel_preemption
from sea_daemon.io.logcsv import read_log
from sea_daemon.io.scenario import load_scenario
from sea_daemon.runtime.controller import ScenarioController
from sea_daemon.runtime.publish import make_publisher
from sea_daemon.errors import InputError
from sea_daemon.runtime.affinity import parse_cpus
from sea_daemon.runtime.safety import SafetySupervisor
from sea_daemon.runtime.service import serve



def add_arguments(p) -> None:
    p.add_argument("--rate", type=int, default=100, help="loop rate [Hz] (default 100)")
    p.add_argument("--cycles", type=int, default=6000, help="measured cycles (default 6000)")
    p.add_argument("--bus", choices=("virtual", "ipc", "remote"), default="virtual",
                   help="virtual: device model in this process; ipc: device model in its own process over UNIX "
                        "datagram sockets; remote: in its own process behind python -m can_remote")
    p.add_argument("--train", type=int, default=700, help="lock-step calibration cycles before (default 700)")
    p.add_argument("--model-rate", type=int, default=100,
                   help="rate [Hz] the model file is calibrated at (default 100; run at --rate)")
    p.add_argument("--estimator", choices=("gp-akf", "akf"), default="gp-akf",
                   help="estimator in the loop (default gp-akf; akf: without the GP, for comparison)")
    p.add_argument("--no-bound", action="store_true",
                   help="publish the filter's own bound instead of the Theorem-1 rho_k (for comparison)")
    p.add_argument("--bound-in", choices=("auto", "worker", "loop"), default="auto",
                   help="where the Theorem-1 bound is computed: worker (a process of its own, rho_k published "
                        "with its sample's cycle), loop (in the estimator's step); auto (default): the "
                        "configuration's estimator.bound_in, the worker in real-time pace")
    p.add_argument("--bound-max-age", type=int, default=None,
                   help="oldest bound published, in cycles behind the estimate (worker; default: the "
                        "configuration's estimator.bound_max_age)")
    p.add_argument("--rt-priority", type=int, default=80, help="SCHED_FIFO priority tried (0: do not)")
    p.add_argument("--device-rt-priority", type=int, default=70,
                   help="SCHED_FIFO priority of the device model's process (ipc, remote; 0: do not)")
    p.add_argument("--tpdo-deadline", type=float, default=0.6,
                   help="TPDOs collected until this fraction of the period after the SYNC (default 0.6)")
    p.add_argument("--max-missed", type=int, default=None,
                   help="cycles in a row without a sample (a late TPDO held, or deadlines the loop skipped) "
                        "before TPDO_MISSING / LOOP_STALL latches (default: the configuration's missed-cycle "
                        "tolerance, hardware.bus.max_missed_ms: 9 cycles at 1 kHz)")
    p.add_argument("--stages", action="store_true",
                   help="also time each stage of the cycle (read, controller, write, estimator and its bound, "
                        "publication) with the loop thread's CPU clock; the wrappers add about 1 us each")
    p.add_argument("--host-rounds", type=int, default=100,
                   help="rounds of the host's reference workload before and after the run (what starting a "
                        "cycle cold costs on the host; default 100; 0: not measured)")
    p.add_argument("--overrun-fault", action="store_true",
                   help="keep the OVERRUN_STREAK fault (default: off, so that every measured cycle does the full "
                        "work -- a latched fault would stop the estimator and command zero torque)")
    p.add_argument("--joints", type=int, default=1,
                   help="joints (1..3; default 1): more than one runs the simulated exoskeleton with that many "
                        "joints, a bus per joint, a PD per joint around slow sines")
    p.add_argument("--one-bus", action="store_true",
                   help="with --joints > 1: every joint on one bus (default: a bus per joint)")
    p.add_argument("--uncoupled", action="store_true",
                   help="with --joints 2: two copies of the one-joint exoskeleton (default: the shoulder-elbow "
                        "exoskeleton of configs/exo_2dof.yaml, its joints coupled through the URDF's rigid body)")
    p.add_argument("--cpus", metavar="LOOP[,WORKER[,DEVICE_MODEL]]", default=None,
                   help="pin the loop's thread, the bound worker and the device model's process (ipc, remote) "
                        "to these CPUs (as run --cpus, docs/daemon.md \"CPU placement\"; default: not pinned)")
    add_json_argument(p)


__all__ = ["add_arguments", "run", "device_model_process"]


def _loadavg() -> str:
    try:
        return " ".join(f"{x:.2f}" for x in os.getloadavg())
    except OSError:
        return "n/a"


def _pcts(a) -> dict:
    a = np.asarray(a, dtype=float)
    return {"median": float(np.median(a) * 1e6), "p99": float(np.percentile(a, 99) * 1e6),
            "max": float(a.max() * 1e6)}


class ReceiveThreadsCpu:
    """CPU clocks of the driver's CAN receive threads (python-can Notifier threads) on every bus
    (a driver of several buses: each one's)."""

    def __init__(self, hw):
        self.clocks = []
        for sub in getattr(hw, "subs", None) or [hw]:
            notifier = getattr(getattr(sub, "network", None), "notifier", None)
            for t in getattr(notifier, "_readers", []) or []:
                ident = getattr(t, "ident", None)
                if ident:
                    try:
                        self.clocks.append(time.pthread_getcpuclockid(ident))
                    except (OSError, AttributeError):
                        pass

    def now(self) -> float:
        return sum(time.clock_gettime(c) for c in self.clocks)


@dataclasses.dataclass
class _Measured:
    """What one bench run measured (:func:`_measure`), for the figures and the report."""

    res: Any                       # the service's ServeResult
    rig: Any
    n_cycles: int
    k_faults: int                  # the loop thread's page faults counted from this cycle on
    rx_cpu: np.ndarray             # the receive threads' CPU clock at each cycle's end [s]
    probe: dict                    # cycle -> the loop thread's (minor, major) page faults
    dev_stats: dict | None         # the device model's answer statistics
    stages: Any                    # Stages, or None
    max_age: int                   # the worker's oldest bound [cycles]
    compute: np.ndarray            # the log's compute column [s]
    read_s: np.ndarray             # the log's read column [s]
    publisher: Any = None          # the run's publisher (its TPDOs per bus)


def _bad_args(args) -> str | None:
    if args.cycles < 100:
        return "--cycles must be >= 100"
    if args.max_missed is not None and not 0 <= args.max_missed <= 1000:
        return f"--max-missed must be in 0..1000, got {args.max_missed}"
    if not 0.05 <= args.tpdo_deadline <= 50:
        return "--tpdo-deadline must be in 0.05..50 (fraction of the period)"
    if args.host_rounds < 0:
        return "--host-rounds must be >= 0"
    if not 1 <= args.joints <= 3:
        return f"--joints must be in 1..3, got {args.joints}"
    if args.joints > 1 and args.bus == "remote":
        return "--joints > 1 runs on --bus virtual or ipc (a bus per joint)"
    try:
        args.cpus = parse_cpus(args.cpus, "--cpus", ("loop", "worker", "device model"))
    except InputError as e:
        return str(e)
    if args.cpus and len(args.cpus) > 2 and args.bus == "virtual":
        return f"--cpus {','.join(map(str, args.cpus))}: a device model's CPU needs --bus ipc or remote (its own process)"
    return None


def run(args) -> int:

    save = json_output(args)
    problem = _bad_args(args)
    if problem is not None:
        print(f"sea-daemon bench loop: {problem}", file=sys.stderr)
        return 2
    root = data_root()
    scen = str(root / "configs" / "scenarios" / "passive.yaml")
    base = (load_config(root / "configs" / "exo_1dof_sim.yaml") if args.joints == 1 else
            joints_config(args.joints, args.one_bus, args.uncoupled))
    cfg_model = at_rate(base, args.model_rate)
    cfg = at_rate(base, args.rate)
    load_before = _loadavg()
    wake_before = host_wake(cfg.dt, args.host_rounds) if args.host_rounds else None
    with tempfile.TemporaryDirectory(prefix="bench-loop-") as tmp:
        tmp = Path(tmp)
        calibrated = (_calibrated_estimator(args, cfg_model, cfg, scen, tmp) if args.joints == 1 else
                      trained_estimator(cfg_model, cfg, args.train, args.estimator, not args.no_bound))
        if calibrated is None:
            return 1
        estimator, residual = calibrated
        thp_before = huge_page_state()
        m = _measure(args, cfg, scen, tmp, estimator)
        thp_after = huge_page_state()
    load_after = _loadavg()
    wake_after = host_wake(cfg.dt, args.host_rounds) if args.host_rounds else None
    out = _figures(args, cfg, m, {"loadavg_before": load_before, "loadavg_after": load_after,
                                  "huge_pages": _huge_pages(thp_before, thp_after),
                                  "kernel_preemption": kernel_preemption(),
                                  "host_wake_before": wake_before, "host_wake_after": wake_after})
    _report(args, cfg, m, out, residual)
    save(out)
    return 0


def _huge_pages(before: dict | None, after: dict | None) -> dict | None:
    """The machine's transparent huge pages mode and the huge pages ``khugepaged`` collapsed
    during the measured run, in any process (None where the kernel does not tell)."""
    if before is None or after is None:
        return None
    return {"mode": after["mode"], "collapsed_during_run": after["collapsed"] - before["collapsed"]}


def _calibrated_estimator(args, cfg_model, cfg, scen: str, tmp: Path):
    """The residual learned by the calibration at --model-rate (lock-step, not timed) and the
    estimator of the run on it; None (after one line on stderr) when the calibration failed."""
    cfg_path = tmp / "config.yaml"
    save_config(cfg_model, cfg_path)
    rc, summary, message = calibrate(cfg_model, scen, tmp / "model.npz", tmp / "calibration.csv",
                                     cycles=args.train, device_model=scen, realtime=False,
                                     config_name=str(cfg_path))
    if rc != 0:
        print(f"sea-daemon bench loop: calibration failed: {message} {json.dumps(summary)}", file=sys.stderr)
        return None
    residual, _ = load_gp_model(tmp / "model.npz", cfg)
    bound = not args.no_bound
    if args.estimator == "gp-akf":
        estimator = make_estimator("gp-akf", cfg, dt=cfg.dt, residual=residual, learning=False, bound=bound)
    else:
        estimator = make_estimator("akf", cfg, dt=cfg.dt, bound=bound)
    return estimator, residual


def _measure(args, cfg, scen: str, tmp: Path, estimator) -> _Measured:
    """The service on the bench rig for --cycles + 1 cycles, with the receive threads' CPU and
    the loop thread's page faults probed from its progress callback, and the log read back."""
    procs: list = []
    rig, dev = bench_rig(args, cfg, scen, tmp, procs)
    if cfg.joints == 1:
        controller = ScenarioController(load_scenario(scen), cfg, rig.hold_torque, delay=rig.hw.actuation_delay,
                                        estimation_from=0)
    else:
        hold = joints_plant(cfg).hold_torque
        rig.initial_torque = hold
        controller = SwayController(cfg.joints, hold)
    n_cycles = args.cycles + 1                         # one more: the first period starts at cycle 0
    # the receive threads' CPU clock at each cycle's end (resident: no page first written in the loop)
    rx_cpu = resident_zeros(n_cycles)
    probe = {}
    # the loop thread's page faults over the cycles after the first tenth (its start-up:
    # the first filter steps, the bound worker's first results)
    k_faults = max(1, n_cycles // 10)

    def progress(k, est):
        if k == 0:
            probe["rx"] = ReceiveThreadsCpu(rig.hw)
        if k < n_cycles:
            rx_cpu[k] = probe["rx"].now()
        if k == k_faults or k == n_cycles - 1:
            probe[k] = thread_page_faults()
    dev_stats = None
    # the estimate and its bound published every cycle as the daemon does: the TPDOs of its
    # node on the bus and the datagram socket for local readers (none subscribed here)
    publisher = make_publisher(rig, cfg, controller, socket_path=tmp / "sea-daemon.sock")
    bound_in = cfg.estimator.bound_in if args.bound_in == "auto" else args.bound_in
    max_age = cfg.estimator.bound_max_age if args.bound_max_age is None else args.bound_max_age
    in_worker = bound_in in ("auto", "worker") and not args.no_bound
    stages = stage_timers(n_cycles, rig, controller, estimator, publisher, in_worker) if args.stages else None
    try:
        res = serve(rig, estimator, controller, cfg.joints, cfg.dt, tmp / "run.csv", cycles=n_cycles, realtime=True,
                    progress=progress, rt_priority=args.rt_priority, record_periods=True, label="bench",
                    supervisor=None if args.overrun_fault else SafetySupervisor(overrun_streak=2 ** 62),
                    publisher=publisher, bound_in=bound_in, bound_max_age=max_age, bound_record=n_cycles + 10,
                    cpus=args.cpus)
        if rig.device_model is not None:
            dev_stats = rig.device_model.answer_stats()
    finally:
        dev_stats = stop_procs(procs, dev) or dev_stats
    log = read_log(tmp / "run.csv", n=cfg.joints, units=False)   # its own log: never a unit error
    cols = DaemonColumns.of(log)
    return _Measured(res, rig, n_cycles, k_faults, rx_cpu, probe, dev_stats, stages, max_age,
                     cols.compute, cols.read, publisher)


def _bus_load(args, dev_stats: dict | None, pub_can: dict) -> tuple[float, float, float]:
    """CAN frames per cycle and the bus load at 1 Mbit/s without / with worst-case stuffing:
    the device model's frames (sent or accepted by its nodes) and the daemon's published TPDOs,
    which the devices' acceptance filter keeps out of the model."""
    if not (dev_stats and dev_stats.get("syncs")):
        return float("nan"), float("nan"), float("nan")
    return measured_load(dev_stats["frames"] + pub_can.get("frames_sent", 0),
                         dev_stats["data_bytes"] + pub_can.get("bytes_sent", 0), dev_stats["syncs"], args.rate)


def rt_budget() -> dict | None:
    """The kernel's budget for real-time tasks: ``sched_rt_runtime_us`` of every
    ``sched_rt_period_us`` on each CPU ({"runtime_us", "period_us"}; None where /proc does not
    tell, runtime −1: no limit).  A SCHED_FIFO task that keeps a CPU busy past it has every
    real-time task on that CPU stopped for the rest of the period (≈ 50 ms a second), so that the
    other tasks run."""
    try:
        with open("/proc/sys/kernel/sched_rt_runtime_us") as f:
            runtime = int(f.read())
        with open("/proc/sys/kernel/sched_rt_period_us") as f:
            period = int(f.read())
    except (OSError, ValueError):
        return None
    return {"runtime_us": runtime, "period_us": period}


def _worker_figures(res, n_cycles: int, dt: float) -> dict | None:
    """The bound worker's figures at the period ``dt`` (None: the bound ran in the loop)."""
    bound_where = res.extra.get("bound") or {}
    link = res.extra.get("bound_link")
    if link is None:
        return None
    steps = min(link.steps, link.record)
    ages = link.ages[:steps]
    have = ages[ages >= 0]
    wcpu = link.cpu_per_sample[np.isfinite(link.cpu_per_sample)]
    return {
        "pid": bound_where.get("pid"), "sched": bound_where.get("sched"), "counts": bound_where.get("counts"),
        "heads": bound_where.get("heads"),
        "memory_locked": bound_where.get("memory_locked"),
        # times the worker gave SCHED_FIFO up for being behind (runtime/bound_serve.py)
        "rt_yields": bound_where.get("rt_yields"),
        "max_age_cycles": link.max_age,
        "filter_steps": link.steps,
        "samples_done": bound_where.get("samples_done"),
        "cycles_without_bound_within_max_age": bound_where.get("stale"),
        "without_bound_before_first_result": int(np.argmax(ages >= 0)) if have.size else steps,
        "broken": bound_where.get("broken"),
        "age_cycles": ({"median": float(np.median(have)), "p99": float(np.percentile(have, 99)),
                        "max": int(have.max())} if have.size else None),
        "cpu_per_sample_us": _pcts(wcpu) if wcpu.size else None,
        # the share of one CPU the worker's samples take at this rate (mean CPU per sample ÷ period)
        "cpu_share": float(np.mean(wcpu) / dt) if wcpu.size else None,
        "process_cpu_s": bound_where.get("worker_cpu_process_s"),
        "process_cpu_per_cycle_us": (bound_where.get("worker_cpu_process_s") or 0.0) / n_cycles * 1e6,
    }


def _rpdo_ms(hw) -> float:
    """The drives' RPDO deadline the driver wrote [ms] (0: off)."""
    sub = (getattr(hw, "subs", None) or [hw])[0]
    return float(getattr(sub, "rpdo_timeout", 0.0)) * 1e3


def _figures(args, cfg, m: _Measured, host: dict) -> dict:
    """The JSON summary's figures of the run; ``host``: the machine's load and wake-up figures
    before and after it."""
    res, st, n_cycles, dt = m.res, m.res.stats, m.n_cycles, cfg.dt
    periods = np.asarray(st.periods, dtype=float)
    loop_cpu = np.asarray(st.cpu, dtype=float)[:n_cycles]
    rx = np.diff(m.rx_cpu, prepend=m.rx_cpu[0])[1:]            # receive threads' CPU between cycle ends
    own_cpu = loop_cpu[1:] + rx
    fpc, load_typ, load_worst = _bus_load(args, m.dev_stats, (res.extra.get("publish") or {}).get("can") or {})
    hw, probe, k_faults = m.rig.hw, m.probe, m.k_faults
    return {
        "machine": machine(), "rate_hz": args.rate, "estimator": args.estimator, "bus": args.bus,
        "hardware": m.rig.description, "cycles_measured": periods.size, "realtime": res.realtime,
        "fault": res.supervisor.latched.name,
        "bound": "theorem-1 rho_k" if not args.no_bound else "filter's own", "model_rate_hz": args.model_rate,
        "bound_in": (res.extra.get("bound") or {}).get("where", "loop"),
        "bound_worker": _worker_figures(res, n_cycles, dt), "rt_budget": rt_budget(),
        "kinematics_window": cfg.kinematics.window, "tpdo_deadline_us": args.tpdo_deadline * dt * 1e3 * 1e3,
        "missed_cycle_tolerance": {"cycles": int(getattr(hw, "max_missed", -1)),
                                   "rpdo_timeout_ms": _rpdo_ms(hw)},
        **host,
        "jitter_us": _pcts(np.abs(periods - dt)),
        "daemon_cpu_us": _pcts(own_cpu), "loop_thread_cpu_us": _pcts(loop_cpu), "rx_thread_cpu_us": _pcts(rx),
        # a latched fault stops the estimator: the cycles before it are the ones doing the full work
        "daemon_cpu_before_fault_us": (_pcts(own_cpu[:res.supervisor.latched_cycle - 1])
                                       if res.supervisor.latched_cycle > 100 else None),
        "device_model": m.dev_stats,
        "missed_tpdo_cycles": int(getattr(hw, "missed_cycles", 0)), "late_tpdo_cycles": int(getattr(hw, "late_cycles", 0)),
        "extrapolated_samples": int(getattr(st, "extrapolated", 0)),
        "period_us": {"median": float(np.median(periods) * 1e6), "p99": float(np.percentile(periods, 99) * 1e6),
                      "max": float(periods.max() * 1e6)},
        "overruns": st.overruns, "overruns_per_1e5": st.overruns / n_cycles * 1e5, "skipped_deadlines": st.skipped,
        "max_late_us": st.max_late_s * 1e6,
        "compute_us": _pcts(m.compute), "read_us": _pcts(m.read_s),
        "frames_per_cycle": fpc, "bus_load_1mbit_typical": load_typ, "bus_load_1mbit_worst_stuffing": load_worst,
        "joints": cfg.joints, "bus_load_per_bus": per_bus_load(m.rig.cfg or cfg, args.rate, m.dev_stats, m.publisher),
        "log_rows_dropped": res.log["rows_dropped"], "publish": res.extra.get("publish"),
        "loop_thread_page_faults": ({"cycles": n_cycles - 1 - k_faults,
                                     "minor": probe[n_cycles - 1][0] - probe[k_faults][0],
                                     "major": probe[n_cycles - 1][1] - probe[k_faults][1]}
                                    if k_faults in probe and n_cycles - 1 in probe else None),
        # the start-up's priming read and the first cycle not counted
        "stages_cpu_us": m.stages.summary(2) if m.stages is not None else None,
        "overrun_causes": _anatomy(st, m, loop_cpu, dt),
    }


def _anatomy(st, m: _Measured, loop_cpu: np.ndarray, dt: float) -> dict:
    """Where the time of each overrun went (:mod:`._loop_overruns`), the first cycle (the
    start-up) left out."""
    ds = m.dev_stats or {}
    device = None
    if ds.get("slow_answers") is not None and ds.get("answer_us") and ds.get("handler_cpu_us"):
        device = {"slow": {int(c): (a * 1e-6, h * 1e-6) for c, a, h in ds["slow_answers"]},
                  "answer": ds["answer_us"]["median"] * 1e-6, "cpu": ds["handler_cpu_us"]["median"] * 1e-6}
    return overrun_anatomy(np.asarray(st.late), np.asarray(st.wake), m.compute, m.read_s, loop_cpu, dt, device=device)


def _report(args, cfg, m: _Measured, out: dict, residual) -> None:
    """The printed report: the run, the loop's timing, the worker, the bus and the log."""
    res, st, n_cycles, dt = m.res, m.res.stats, m.n_cycles, cfg.dt
    worker, bound_where = out["bound_worker"], res.extra.get("bound") or {}
    print(f"bench loop on {out['machine']}")
    print(f"load average before {out['loadavg_before']}, after {out['loadavg_after']} (1/5/15 min; shared machine, "
          f"{os.cpu_count()} cores)")
    if out["host_wake_before"] is not None:
        print(f"host: a fixed reference workload (not the daemon's code) costs, in thread CPU, before the run "
              f"{describe_host_wake(out['host_wake_before'])}; after the run "
              f"{describe_host_wake(out['host_wake_after'])} -- a cycle starts after such a sleep")
    thp = out["huge_pages"]
    if thp is not None:
        print(f"transparent huge pages (the host's setting): {thp['mode']}; khugepaged collapsed "
              f"{thp['collapsed_during_run']} during the run, in any process (each collapse holds a CPU for "
              f"milliseconds on a kernel without full preemption; this run's processes have huge pages off)")
    print(f"kernel preemption: {out['kernel_preemption']} (with none or voluntary, a real-time thread woken while "
          f"another task runs kernel code on its CPU waits for a preemption point: a late wake-up below)")
    what = (f"GP-AKF ({residual.n_points} GP points, learned by {'calibrate' if cfg.joints == 1 else 'a lock-step run'} at {args.model_rate} Hz, {args.train} "
            f"lock-step cycles; learning frozen)" if args.estimator == "gp-akf" else "AKF (no GP)")
    heads = ("polled by it in shared memory" if worker and worker.get("heads") == "memory" else
             "through a pipe that wakes it")
    where = (f"computed in a worker process (sched {worker['sched'] if worker else ''}, memory "
             f"{'locked' if worker and worker.get('memory_locked') else 'not locked'}, its counts of samples "
             f"done through {'shared memory' if worker and worker.get('counts') == 'memory' else 'a pipe'}, "
             f"the loop's heads {heads}), "
             f"published with its "
             f"sample's cycle, at most {m.max_age} cycles old"
             if worker is not None else "computed in the loop's estimator step"
             + (f" ({bound_where['why_not_worker']})" if bound_where.get("why_not_worker") else ""))
    ctl = "passive-scenario PID" if cfg.joints == 1 else f"{cfg.joints} joints, a PD per joint"
    print(f"{args.rate} Hz (kinematics window {cfg.kinematics.window}), {out['hardware']}; {what}; bound: "
          f"{out['bound']} every cycle, {where}; {ctl}; real-time pace; {res.realtime}")
    tol = out["missed_cycle_tolerance"]
    print(f"measured {n_cycles} cycles ({out['cycles_measured']} periods), TPDO deadline "
          f"{out['tpdo_deadline_us']:.0f} us after SYNC, missed-cycle tolerance {tol['cycles']} cycles, "
          f"drives' RPDO deadline {tol['rpdo_timeout_ms']:g} ms, "
          f"OVERRUN_STREAK fault {'on' if args.overrun_fault else 'off'}, fault state at the end: {out['fault']}"
          + (f" (latched at cycle {res.supervisor.latched_cycle}: the cycles after it do not estimate)"
             if out['fault'] != 'NONE' else ""))
    j, pr, c = out["jitter_us"], out["period_us"], out["compute_us"]
    print(f"overruns: {st.overruns} in {n_cycles} cycles = {out['overruns_per_1e5']:.0f} per 1e5 cycles "
          f"(max late {out['max_late_us']:.0f} us, deadlines skipped {st.skipped})")
    print(f"|period - {dt * 1e6:.0f} us|: median {j['median']:.1f} us, p99 {j['p99']:.1f} us, max {j['max']:.1f} us"
          f"  (period median {pr['median']:.1f}, p99 {pr['p99']:.1f}, max {pr['max']:.1f} us)")
    _report_cpu(out, res)
    print(f"cycle wall time (read .. log row): median {c['median']:.0f} us, p99 {c['p99']:.0f} us, max {c['max']:.0f} us")
    _report_bus(cfg, m, out)
    for line in describe_overruns(out["overrun_causes"]):
        print(line)


def _report_cpu(out: dict, res) -> None:
    worker = out["bound_worker"]
    dc, lc, xc = out["daemon_cpu_us"], out["loop_thread_cpu_us"], out["rx_thread_cpu_us"]
    print("daemon CPU per cycle (loop thread + CAN receive thread"
          + ("; the bound worker's process is not included, see below" if worker is not None else "")
          + f"): median {dc['median']:.0f} us, p99 "
          f"{dc['p99']:.0f} us, max {dc['max']:.0f} us  (loop thread median {lc['median']:.0f} / p99 {lc['p99']:.0f}; "
          f"receive thread median {xc['median']:.0f} / p99 {xc['p99']:.0f})")
    bf = out["daemon_cpu_before_fault_us"]
    if bf is not None:
        print(f"  over the {res.supervisor.latched_cycle - 1} cycles before the fault latched: median "
              f"{bf['median']:.0f} us, p99 {bf['p99']:.0f} us, max {bf['max']:.0f} us")
    if worker is not None:
        wc, ag = worker["cpu_per_sample_us"], worker["age_cycles"]
        if wc is not None:
            print(f"bound worker CPU per sample (its bound step and start-up gate, thread CPU): median "
                  f"{wc['median']:.0f} us, p99 {wc['p99']:.0f} us, max {wc['max']:.0f} us; its whole process "
                  f"{worker['process_cpu_per_cycle_us']:.0f} us per cycle ({worker['samples_done']} samples)")
        budget = out.get("rt_budget")
        if wc is not None and worker.get("cpu_share") is not None and budget and budget["runtime_us"] > 0:
            print(f"bound worker's share of one CPU at this rate: {worker['cpu_share'] * 100:.0f} % (mean CPU per "
                  f"sample / period); the kernel lets real-time tasks use {budget['runtime_us']} us of every "
                  f"{budget['period_us']} us of a CPU: a worker that keeps its CPU busy past that has every "
                  f"real-time task on that CPU (the loop's, the device model's) stopped for the rest of the period; "
                  f"the worker gave SCHED_FIFO up for being behind {worker.get('rt_yields') or 0} times")
        if ag is not None:
            print(f"bound age (cycle of the estimate - cycle of the bound's sample): median {ag['median']:.0f}, "
                  f"p99 {ag['p99']:.0f}, max {ag['max']} cycles; filter steps with no bound within "
                  f"{worker['max_age_cycles']} cycles: {worker['cycles_without_bound_within_max_age']} of "
                  f"{worker['filter_steps']} ({worker['without_bound_before_first_result']} before the first "
                  f"result){'; ring full: bound lost' if worker['broken'] else ''}")


def _report_bus(cfg, m: _Measured, out: dict) -> None:
    r = out["read_us"]
    print(f"  of which hw.read() (SYNC -> TPDOs, waiting for the devices): median {r['median']:.0f} us, "
          f"p99 {r['p99']:.0f} us, max {r['max']:.0f} us")
    ds = out["device_model"]
    if ds and ds.get("answer_us"):
        a, h = ds["answer_us"], ds["handler_cpu_us"]
        print(f"device model answer latency (SYNC sent -> its last TPDO sent, in its process): median "
              f"{a['median']:.0f} us, p99 {a['p99']:.0f} us, max {a['max']:.0f} us; its SYNC handler CPU median "
              f"{h['median']:.0f} us, p99 {h['p99']:.0f} us ({ds['syncs']} SYNCs)")
    print(f"TPDO cycles missed at the deadline: {out['missed_tpdo_cycles']}, late: {out['late_tpdo_cycles']}; "
          f"samples the loop extrapolated over them: {out['extrapolated_samples']}")
    fpc, load_typ, load_worst = out["frames_per_cycle"], out["bus_load_1mbit_typical"], out["bus_load_1mbit_worst_stuffing"]
    buses = out["bus_load_per_bus"]
    if len(buses) > 1:
        print(f"CAN frames per cycle, every frame the device model sent or received (start-up included) and the "
              f"daemon's published TPDOs, {fpc:.2f} on {len(buses)} buses; per bus: " + "; ".join(describe_bus_load(buses)))
    else:
        print(f"CAN frames per cycle {fpc:.2f} (every frame the device model sent or received, start-up included, "
              f"and the daemon's published TPDOs); "
              f"at 1 Mbit/s: bus load {load_typ * 100:.2f} % without stuffing, {load_worst * 100:.2f} % with "
              f"worst-case stuffing")
    pub = out["publish"] or {}
    can_pub = pub.get("can") or {}
    print(f"published every cycle: {pub.get('published', 0)} cycles; TPDOs of node {cfg.hardware.bus.master_node} "
          f"sent {can_pub.get('frames_sent', 0)}, dropped {can_pub.get('frames_dropped', 0)}; local socket "
          f"(no reader subscribed)")
    print(f"log rows dropped: {out['log_rows_dropped']}")
    pf = out["loop_thread_page_faults"]
    if pf is not None:
        dpf = (ds or {}).get("handler_page_faults")
        print(f"page faults of the loop thread over cycles {m.k_faults}..{m.n_cycles - 1}: {pf['minor']} minor, "
              f"{pf['major']} major" + (f"; of the device model's SYNC handler from its 100th SYNC on: "
                                        f"{dpf['minor']} minor, {dpf['major']} major" if dpf else ""))
    if out["stages_cpu_us"]:
        print("loop thread CPU per stage (median / p99; a wrapper around each adds about 1 us): " + "; ".join(
            f"{k} {v['median']:.0f} / {v['p99']:.0f} us" for k, v in out["stages_cpu_us"].items()))
