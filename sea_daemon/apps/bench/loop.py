"""``sea-daemon bench loop --rate 100|1000 --cycles N``: the daemon's fixed-rate loop against the device model.

What runs is ``sea-daemon run``'s service (:func:`sea_daemon.runtime.service.serve`): the GP-AKF
with a residual learned by ``sea-daemon calibrate`` at the same rate (lock-step on the device
model, not timed), the passive scenario's PID controller, the off-loop log writer, the loop in
real-time pace (sleep to the absolute deadline), SCHED_FIFO / mlockall tried (what applied is
printed).  The device model (the passive scenario's true plant behind a CANopen drive and load
encoder, lock-step with SYNC) runs either in this process on a python-can virtual bus
(``--bus virtual``: its SYNC handling and plant step compete with the loop for the GIL) or in a
separate process behind a ``python -m can_remote`` server (``--bus remote``: websockets).

Figures: the loop period (start to start of consecutive cycles) minus nominal — median, p99 and
max of |period − nominal|; overruns (cycles that ended after their deadline) per 10⁵ cycles over
the N measured cycles; the cycle's compute (read → log row, the log's ``compute`` column); CAN
frames per cycle counted by a listener on the bus over the measured cycles (SYNC, RPDO, TPDOs,
heartbeats: everything on the bus), and the load they would be on a 1 Mbit/s bus.  Bits per
frame: CAN 2.0A data frame with 11-bit identifier, 47 + 8·DLC bits (SOF … IFS, no stuffing) —
the "typical" figure — and with the worst-case stuff bits, ⌊(34 + 8·DLC − 1)/4⌋ over SOF … CRC.
The load average is printed before and after: the machine is shared.  The OVERRUN_STREAK fault is
off by default here (``--overrun-fault`` keeps it), so that every measured cycle does the full work.
"""
from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from sea_daemon.apps.bench import add_json_argument, json_output, machine

NAME = "loop"
HELP = "fixed-rate loop jitter, overruns and CAN bus load against the device model (100 Hz / 1 kHz)"


def add_arguments(p) -> None:
    p.add_argument("--rate", type=int, choices=(100, 1000), default=100, help="loop rate [Hz] (default 100)")
    p.add_argument("--cycles", type=int, default=6000, help="measured cycles (default 6000)")
    p.add_argument("--bus", choices=("virtual", "remote"), default="virtual",
                   help="virtual: device model in this process; remote: device model in its own process "
                        "behind python -m can_remote")
    p.add_argument("--train", type=int, default=700, help="lock-step calibration cycles before (default 700)")
    p.add_argument("--estimator", choices=("gp-akf", "akf"), default="gp-akf",
                   help="estimator in the loop (default gp-akf; akf: without the GP, for comparison)")
    p.add_argument("--rt-priority", type=int, default=80, help="SCHED_FIFO priority tried (0: do not)")
    p.add_argument("--overrun-fault", action="store_true",
                   help="keep the OVERRUN_STREAK fault (default: off, so that every measured cycle does the full "
                        "work -- a latched fault would stop the estimator and command zero torque)")
    add_json_argument(p)


def _loadavg() -> str:
    try:
        return " ".join(f"{x:.2f}" for x in os.getloadavg())
    except OSError:
        return "n/a"


def _wait_line(proc, text: str, timeout: float) -> None:
    import selectors
    sel = selectors.DefaultSelector()
    sel.register(proc.stdout, selectors.EVENT_READ)
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if proc.poll() is not None:
            raise RuntimeError(f"process exited with {proc.returncode} before printing {text!r}")
        if sel.select(0.2):
            line = proc.stdout.readline()
            if text in line:
                return
    raise RuntimeError(f"no {text!r} within {timeout} s")


def run(args) -> int:
    from drivers.canopen_hw import CanopenHardware

    save = json_output(args)
    from sea_daemon.io.configfile import load_config, repo_root, save_config
    from sea_daemon.io.gpmodel import load_gp_model
    from drivers.bus import make_bus
    from sea_daemon.runtime.controller import ScenarioController
    from sea_daemon.runtime.rig import Rig, make_rig
    from sea_daemon.runtime.safety import SafetySupervisor
    from sea_daemon.runtime.service import serve
    from sea_daemon.apps.bench._rig import FrameCounter
    from sea_daemon.core.estimators import make_estimator
    from sea_daemon.io.scenario import load_scenario
    from sea_daemon.apps.bench.can_cycle import _server

    if args.cycles < 100:
        print("sea-daemon bench loop: --cycles must be >= 100", file=sys.stderr)
        return 2
    root = repo_root()
    scen = str(root / "configs" / "scenarios" / "passive.yaml")
    cfg = load_config(root / "configs" / "exo_1dof_sim.yaml")
    cfg = dataclasses.replace(cfg, rate_hz=args.rate)
    dt = cfg.dt
    load_before = _loadavg()
    procs = []
    with tempfile.TemporaryDirectory(prefix="bench-loop-") as tmp:
        tmp = Path(tmp)
        cfg_path = tmp / "config.yaml"
        save_config(cfg, cfg_path)
        # the residual, learned by the calibration at this rate (lock-step, not timed)
        from sea_daemon.apps.calibration import calibrate
        rc, summary, message = calibrate(cfg, scen, tmp / "model.npz", tmp / "calibration.csv", cycles=args.train,
                                         device_model=scen, realtime=False, config_name=str(cfg_path))
        if rc != 0:
            print(f"sea-daemon bench loop: calibration failed: {message} {json.dumps(summary)}", file=sys.stderr)
            return 1
        residual, _ = load_gp_model(tmp / "model.npz", cfg)
        if args.estimator == "gp-akf":
            estimator = make_estimator("gp-akf", cfg, dt=dt, residual=residual, learning=False, bound=False)
        else:
            estimator = make_estimator("akf", cfg, dt=dt)
        if args.bus == "virtual":
            rig = make_rig(cfg, device_model=scen, phase="estimation")
        else:
            server, url = _server()
            procs.append(server)
            cfg_r = dataclasses.replace(cfg, hardware=dataclasses.replace(cfg.hardware, bus=dataclasses.replace(
                cfg.hardware.bus, interface="remote", channel=url, pdo_timeout_ms=1000.0, heartbeat_timeout_ms=2000,
                sdo_timeout_ms=3000)))
            save_config(cfg_r, cfg_path)
            dev = subprocess.Popen([sys.executable, "-m", "sea_daemon", "device-model", "--bus", "remote",
                                    "--channel", url, "--config", str(cfg_path), "--scenario", scen],
                                   stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
                                   env=dict(os.environ, PYTHONPATH=str(root)))
            procs.append(dev)
            _wait_line(dev, "device-model ready", 60)
            rig = Rig(CanopenHardware(cfg_r), f"device model process behind can_remote {url}", np.zeros(cfg.joints),
                      cfg=cfg_r)
        frames = FrameCounter(make_bus(rig.cfg.hardware.bus))          # every frame on the rig's bus
        sc = load_scenario(scen)
        controller = ScenarioController(sc, cfg, rig.hold_torque, delay=rig.hw.actuation_delay, estimation_from=0)
        snaps = {}
        n_cycles = args.cycles + 1                         # one more: the first period starts at cycle 0

        def progress(k, est):
            if k == 0:
                snaps["start"] = (frames.snapshot(), time.monotonic())
            elif k == n_cycles - 1:
                snaps["end"] = (frames.snapshot(), time.monotonic())
        try:
            res = serve(rig, estimator, controller, cfg.joints, dt, tmp / "run.csv", cycles=n_cycles, realtime=True,
                        progress=progress, rt_priority=args.rt_priority, record_periods=True, label="bench",
                        supervisor=None if args.overrun_fault else SafetySupervisor(overrun_streak=2 ** 62))
        finally:
            frames.close()
            for p in reversed(procs):
                p.terminate()
                try:
                    p.wait(10)
                except subprocess.TimeoutExpired:
                    p.kill()
        from sea_daemon.io.logcsv import read_log
        log = read_log(tmp / "run.csv", n=cfg.joints)
        compute = log.extra["compute"]
        read_s = log.extra["read"]
    load_after = _loadavg()
    st = res.stats
    periods = np.asarray(st.periods, dtype=float)
    dev = np.abs(periods - dt)
    measured = periods.size
    (f0, b0, w0), _ = snaps["start"]
    (f1, b1, w1), _ = snaps["end"]
    cyc = n_cycles - 1
    fpc = (f1 - f0) / cyc
    load_typ = (b1 - b0) / cyc * args.rate / 1e6
    load_worst = (w1 - w0) / cyc * args.rate / 1e6
    out = {
        "machine": machine(), "rate_hz": args.rate, "estimator": args.estimator, "bus": args.bus, "hardware": rig.description,
        "cycles_measured": measured, "realtime": res.realtime, "fault": res.supervisor.latched.name,
        "loadavg_before": load_before, "loadavg_after": load_after,
        "jitter_us": {"median": float(np.median(dev) * 1e6), "p99": float(np.percentile(dev, 99) * 1e6),
                      "max": float(dev.max() * 1e6)},
        "period_us": {"median": float(np.median(periods) * 1e6), "p99": float(np.percentile(periods, 99) * 1e6),
                      "max": float(periods.max() * 1e6)},
        "overruns": st.overruns, "overruns_per_1e5": st.overruns / n_cycles * 1e5, "skipped_deadlines": st.skipped,
        "max_late_us": st.max_late_s * 1e6,
        "compute_us": {"median": float(np.median(compute) * 1e6), "p99": float(np.percentile(compute, 99) * 1e6),
                       "max": float(compute.max() * 1e6)},
        "read_us": {"median": float(np.median(read_s) * 1e6), "p99": float(np.percentile(read_s, 99) * 1e6),
                    "max": float(read_s.max() * 1e6)},
        "frames_per_cycle": fpc, "bus_load_1mbit_typical": load_typ, "bus_load_1mbit_worst_stuffing": load_worst,
        "log_rows_dropped": res.log["rows_dropped"],
    }
    print(f"bench loop on {out['machine']}")
    print(f"load average before {load_before}, after {load_after} (1/5/15 min; shared machine)")
    what = (f"GP-AKF ({residual.n_points} GP points, learned by calibrate, {args.train} lock-step cycles)"
            if args.estimator == "gp-akf" else "AKF (no GP)")
    print(f"{args.rate} Hz, {out['hardware']}; {what} + passive-scenario PID; real-time pace; {res.realtime}")
    print(f"measured {n_cycles} cycles ({measured} periods), OVERRUN_STREAK fault "
          f"{'on' if args.overrun_fault else 'off'}, fault state at the end: {out['fault']}")
    j, pr, c = out["jitter_us"], out["period_us"], out["compute_us"]
    print(f"|period - {dt * 1e6:.0f} us|: median {j['median']:.1f} us, p99 {j['p99']:.1f} us, max {j['max']:.1f} us"
          f"  (period median {pr['median']:.1f}, p99 {pr['p99']:.1f}, max {pr['max']:.1f} us)")
    print(f"overruns: {st.overruns} in {n_cycles} cycles = {out['overruns_per_1e5']:.0f} per 1e5 cycles "
          f"(max late {out['max_late_us']:.0f} us, deadlines skipped {st.skipped})")
    print(f"cycle compute (read .. log row): median {c['median']:.0f} us, p99 {c['p99']:.0f} us, max {c['max']:.0f} us")
    r = out["read_us"]
    print(f"  of which hw.read() (SYNC -> TPDOs, incl. the device model's answer): median {r['median']:.0f} us, "
          f"p99 {r['p99']:.0f} us, max {r['max']:.0f} us")
    print(f"CAN frames per cycle {fpc:.2f} (all frames on the bus over the measured cycles); at 1 Mbit/s: "
          f"bus load {load_typ * 100:.2f} % without stuffing, {load_worst * 100:.2f} % with worst-case stuffing")
    print(f"log rows dropped: {out['log_rows_dropped']}")
    save(out)
    return 0
