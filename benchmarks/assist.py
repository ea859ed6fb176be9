"""``python -m benchmarks.assist``: what assistance does in the device model's tracking task (docs/assist.md).

For each rate (``--rates``, default 100 and 1000 Hz), on the device model (``configs/scenarios/
assist_track.yaml``: the hypertonic elbow tracking 20–70 deg with muscle torque) behind the CAN
stack, in lock-step, the daemon's own workflow:

1. calibration (``sea_daemon.apps.calibration.calibrate``: the PID moves the passive arm, the GP
   learns) — ``--calibration excitation`` (default): ``calibrate --excitation`` over the working
   range the configuration declares (``calibration``: angles, speeds and accelerations the assisted
   arm reaches); ``task``: the task's own moves — then a held-out session of the task's passive
   moves (another noise seed) and β of the bound on it (``--target torque``);
2. the task with the exoskeleton only compensating itself (assist gain 0) and with assistance
   (the configuration's gain), GP-AKF with its bound in the loop, on ``--seeds`` noise seeds:
   the subject's active torque RMS, the tracking error, the estimate's error and the bound's
   coverage, and the settling of every hold (peak-to-peak of the angle and of the assistance
   over its last second: a limit cycle would keep them up);
3. at the first rate, corrupted estimates during the assisted task: an estimator fault (the
   filter's state set to NaN) and load-encoder biases below the driver's jump detector (device
   model ``jump`` faults): cycles from the corruption to the latched fault, the torque from
   then on, and the subject's torque before and after;
4. ``--can``: the publication over python-can-remote — a ``sea-daemon run`` with assistance in
   its own process against ``sea-daemon device-model`` in another, TPDO1/TPDO2 received here
   (a third process) and compared with the run's log.

Prints what it measured, on what, with how many runs; ``--out DIR`` keeps the arrays and logs.
"""
from __future__ import annotations

import csv
import dataclasses
import json
import math
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import can
import numpy as np
import yaml

from sea_daemon.apps.bench import machine
from sea_daemon.apps.bench.can_cycle import remote_relay
from sea_daemon.apps.calibration import calibrate
from sea_daemon.client import tpdo_cob_ids, tpdo_cycles
from sea_daemon.core.assist import InnovationGuard
from sea_daemon.core.bounds.torque_beta import torque_calibrated_beta
from sea_daemon.core.estimators import make_estimator
from sea_daemon.hw.device_model import parse_fault
from sea_daemon.io.configfile import data_root, import_root, save_config
from sea_daemon.io.gpmodel import load_gp_model
from sea_daemon.io.logcsv import read_log
from sea_daemon.io.scenario import load_scenario
from sea_daemon.runtime.controller import AssistController
from sea_daemon.runtime.loop import FixedRateLoop
from sea_daemon.runtime.rig import make_rig

NAME = "assist"
HELP = "assist-as-needed in the device model's tracking task: effort, tracking, stability, corrupted estimates"
SCENARIO = data_root() / "configs" / "scenarios" / "assist_track.yaml"
#: the calibration's motion (``--calibration``): the working-range excitation, or the task's moves
CALIBRATIONS = ("excitation", "task")


def add_arguments(p) -> None:
    p.add_argument("--scenario", default=str(SCENARIO), help="a human: track scenario (default assist_track.yaml)")
    p.add_argument("--rates", default="100,1000", help="loop rates [Hz] (default 100,1000)")
    p.add_argument("--seeds", default="3,4,5", help="noise seeds of the task runs at the first rate (default 3,4,5)")
    p.add_argument("--seeds-other", default="3", help="noise seeds at the other rates (default 3)")
    p.add_argument("--seconds", type=float, default=36.0, help="task duration [s] (default 36: four cycles)")
    p.add_argument("--gain", type=float, default=None, help="assist gain (default: the configuration's)")
    p.add_argument("--calibration", choices=CALIBRATIONS, default="excitation",
                   help="the calibration's motion: the excitation over the configuration's working range "
                        "(calibrate --excitation; default) or the task's own moves")
    p.add_argument("--no-faults", action="store_true", help="skip the corrupted-estimate runs")
    p.add_argument("--can", action="store_true", help="also the publication check over python-can-remote")
    p.add_argument("--out", default=None, help="directory for models, logs and arrays (default: a temp dir)")


def scenario_copy(src: Path, dest: Path, **changes) -> Path:
    d = yaml.safe_load(src.read_text())
    d["model"] = str((src.parent / d["model"]).resolve())
    d.update(changes)
    dest.write_text(yaml.safe_dump(d, sort_keys=False))
    return dest


def rms(x) -> float:
    return float(np.sqrt(np.mean(np.square(x)))) if len(x) else float("nan")


# ---------------------------------------------------------------------------- calibration
def task_config(sc, rate: float):
    """The scenario's model at ``rate`` with the assistance on and what the scenario declares about
    its subject (``tau_h_act_rate``: the Theorem-1 bound's term for the subject's torque changes,
    docs/bounds.md §6)."""
    return sc.declared(dataclasses.replace(sc.nominal, rate_hz=rate,
                                           assist=dataclasses.replace(sc.nominal.assist, enabled=True)))


def calibrated(sc, cfg, rate: float, out: Path, motion: str = "excitation") -> tuple[object, float, dict]:
    """(GP residual, β, info) for ``cfg`` at ``rate``: calibration (``motion``: the working-range
    excitation of ``cfg.calibration``, or the task's moves), held-out session of the task's passive
    moves, torque β."""
    src = Path(sc.source)
    excitation = motion == "excitation"
    task_s = sc.training_samples * sc.nominal.dt
    n_cal = int(round((cfg.calibration.duration_s if excitation else task_s) * rate))
    n_held = min(int(round(task_s * rate)), int(round(12.0 * rate)))   # 12 s: the β replays are the cost
    model = out / f"model_{rate:g}.npz"
    t0 = time.perf_counter()
    code, summ, msg = calibrate(cfg, str(src), model, out / f"calibration_{rate:g}.csv", device_model=str(src),
                                realtime=False, cycles=n_cal, excitation=excitation)
    if code:
        raise RuntimeError(f"calibration at {rate:g} Hz: {msg}")
    held = scenario_copy(src, out / "heldout.yaml", seed=sc.seed + 1000)
    code, _, msg = calibrate(cfg, str(held), out / f"heldout_{rate:g}.npz", out / f"heldout_{rate:g}.csv",
                             device_model=str(held), realtime=False, cycles=n_held)
    if code:
        raise RuntimeError(f"held-out calibration at {rate:g} Hz: {msg}")
    residual, _ = load_gp_model(model, cfg)
    log = read_log(out / f"heldout_{rate:g}.csv", n=cfg.joints)
    est = make_estimator("gp-akf", cfg, dt=log.dt, residual=residual, learning=False, bound=False)
    b = torque_calibrated_beta(est, log, cfg.estimator.delta, truth=np.zeros((len(log), cfg.joints)))
    info = {"calibration": motion, "calibration_cycles": n_cal, "gp_points": summ["gp_points"], "heldout_cycles": n_held,
            "beta": b["beta"], "beta_coverage": b["coverage"], "wall_s": round(time.perf_counter() - t0, 1)}
    return residual, float(b["beta"]), info


# ---------------------------------------------------------------------------- one task run
def task_run(scenario: Path, cfg, residual, gain: float, seconds: float, *, inject=None) -> dict:
    """The task on the device model with the daemon's loop; ``inject(k, rig, estimator)`` is called
    at the end of every cycle (corruptions).  Returns the recorded arrays and the fault."""
    rig = make_rig(cfg, device_model=str(scenario), phase="estimation")
    subject = rig.tau_h_act
    est = InnovationGuard(make_estimator("gp-akf", rig.cfg, dt=cfg.dt, residual=residual, learning=False),
                          cfg.assist.innovation_max)
    ctl = AssistController(rig.cfg, gain=gain)
    N = int(round(seconds * cfg.rate_hz))
    keys = ("t", "q", "theta_m", "q_target", "tau_h_act", "hat", "rho", "valid", "tau_assist", "tau_m", "nis")
    rec = {k: np.full(N, np.nan) for k in keys}
    loop = None

    def on(k, m, e, tau):
        if k >= N:
            return
        t = m.t if m is not None else k * cfg.dt
        rec["t"][k] = t
        if m is not None:
            rec["q"][k] = m.q[0]
            rec["theta_m"][k] = m.theta_m[0]
        rec["q_target"][k] = subject.q_target[0]
        rec["tau_h_act"][k] = subject(t)[0]
        rec["valid"][k] = 0.0
        if e is not None:
            rec["hat"][k] = e.tau_h_act_hat[0]
            rec["rho"][k] = e.tau_h_act_bound[0]
            rec["valid"][k] = float(e.valid)
        rec["tau_assist"][k] = ctl.tau_assist[0] if loop.supervisor.ok else 0.0
        rec["tau_m"][k] = tau[0]
        rec["nis"][k] = getattr(est.estimator, "nis", np.nan)
        if inject is not None:
            inject(k, rig, est)
    t0 = time.perf_counter()
    try:
        rig.start()
        loop = FixedRateLoop(rig.hw, est, ctl, cfg.joints, cfg.dt, realtime=False, on_cycle=on,
                             initial_torque=rig.initial_torque, clock=time.perf_counter)
        loop.run(N)
    finally:
        rig.stop()
    sup = loop.supervisor
    rec.update(fault=sup.latched.name, fault_cycle=sup.latched_cycle, detail=sup.latched_detail,
               max_nis=est.max_seen, wall_s=time.perf_counter() - t0)
    return rec


def holds(r: dict, task, dt: float) -> tuple[float, float]:
    """Largest peak-to-peak of q [deg] and of τ_assist [N m] over the last second of the holds."""
    t = r["t"]
    period = task.period_s
    ptp_q = ptp_a = 0.0
    for start in (task.hold_s - 1.0, period / 2 + task.hold_s - 1.0):
        for c in range(int(t[-1] // period) + 1):
            a = c * period + start
            m = (t >= a) & (t < a + 1.0 - 1e-9) & np.isfinite(r["q"])
            if m.sum() < 0.9 / dt or a < 2.0:
                continue
            ptp_q = max(ptp_q, float(np.degrees(np.ptp(r["q"][m]))))
            ptp_a = max(ptp_a, float(np.ptp(r["tau_assist"][m])))
    return ptp_q, ptp_a


def metrics(r: dict, task, dt: float, skip_s: float = 2.0) -> dict:
    m = r["t"] >= skip_s
    err = np.degrees(r["q"][m] - r["q_target"][m])
    tau_h = r["tau_h_act"][m]
    ok = (r["valid"][m] > 0) & np.isfinite(r["rho"][m])
    e = (r["hat"][m] - tau_h)[ok]
    ta = r["tau_assist"][m]
    against = (ta * tau_h < 0) & (np.abs(ta) > 0.05) & (np.abs(tau_h) > 0.05)
    pq, pa = holds(r, task, dt)
    return {"tau_h_rms": rms(tau_h), "tau_h_max": float(np.max(np.abs(tau_h))), "assist_rms": rms(ta),
            "assist_max": float(np.max(np.abs(ta))), "err_rms_deg": rms(err), "err_max_deg": float(np.max(np.abs(err))),
            "est_rmse": rms(e), "coverage": float(np.mean(np.abs(e) <= r["rho"][m][ok])) if ok.any() else float("nan"),
            "rho_mean": float(np.mean(r["rho"][m][ok])) if ok.any() else float("nan"),
            "against_fraction": float(np.mean(against)), "hold_ptp_q_deg": pq, "hold_ptp_assist": pa,
            "max_nis": r["max_nis"], "fault": r["fault"], "wall_s": round(r["wall_s"], 1), "cycles": int(m.size)}


# ---------------------------------------------------------------------------- corruptions
def corrupted(scenario: Path, cfg, residual, gain: float, seconds: float, base_max: float, at: float = 10.0):
    """Runs with an estimator fault and with load-encoder biases at ``at`` s; returns rows."""
    rows = []
    k_at = int(round(at * cfg.rate_hz))

    def nan_state(k, rig, est):
        if k == k_at - 1:
            est.estimator.x[0] = float("nan")          # the filter's state: the next step is not finite

    kinds = [("estimator state NaN", nan_state, None)]
    for rad in (0.001, 0.005, 0.02, 0.1):
        kinds.append((f"load encoder bias {rad * 1e3:g} mrad (K_s x bias = {110 * rad:.2f} N m)", None, rad))
    for label, inj, rad in kinds:
        def inject(k, rig, est, inj=inj, rad=rad):
            if inj is not None:
                inj(k, rig, est)
            elif k == 0:
                rig.device_model.schedule(parse_fault(f"jump:target=encoder,rad={rad},at={at}"))
        r = task_run(scenario, cfg, residual, gain, min(seconds, at + 5.0), inject=inject)
        kf = r["fault_cycle"]
        after = slice(kf, None) if kf >= 0 else slice(k_at, None)     # undetected: the rest of the run
        zero_from = bool(kf >= 0 and np.all(r["tau_m"][after] == 0.0) and np.all(r["tau_assist"][after] == 0.0))
        before = r["tau_h_act"][int(2 * cfg.rate_hz):k_at]
        rows.append({"corruption": label, "at_cycle": k_at, "fault": r["fault"], "fault_cycle": kf,
                     "reaction_cycles": (kf - k_at) if kf >= 0 else None, "zero_torque_from_fault": zero_from,
                     "assist_before_max": float(np.nanmax(np.abs(r["tau_assist"][:k_at]))),
                     "tau_h_before_max": float(np.max(np.abs(before))),
                     "tau_h_after_max": float(np.nanmax(np.abs(r["tau_h_act"][after]))),
                     "assist_after_max": float(np.nanmax(np.abs(r["tau_assist"][after]))),
                     "unassisted_task_max": base_max})
    return rows


# ---------------------------------------------------------------------------- publication over CAN
def _real32_equal(frame: float, logged: str) -> bool:
    """The frame's REAL32 is the log's value to REAL32 precision: within one REAL32 step (the log
    keeps 10 significant digits, so its value can sit on the other side of a REAL32 rounding edge)."""
    x = np.float32(float(logged))
    return abs(frame - float(x)) <= abs(float(np.spacing(x)))


def can_check(scenario: Path, cfg, model: Path, beta: float, out: Path, cycles: int = 3000) -> dict:
    """``sea-daemon run`` (assist on) and ``sea-daemon device-model`` in their own processes on a
    python-can-remote bus; TPDO1/TPDO2 received in this process, compared with the run's log."""
    env = dict(os.environ, PYTHONPATH=str(import_root()) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    server, url = remote_relay()
    dev = listener_bus = None
    frames: list = []
    stop = threading.Event()
    try:
        dev = _device_model_process(scenario, url, env)
        listener_bus = can.Bus(interface="remote", channel=url)
        ids = set(tpdo_cob_ids(cfg.hardware.bus.master_node, 1).values())

        def listen():
            while not stop.is_set():
                m = listener_bus.recv(0.1)
                if m is not None and m.arbitration_id in ids:
                    frames.append((m.arbitration_id, bytes(m.data)))
        th = threading.Thread(target=listen, daemon=True)
        th.start()
        r = _daemon_run(cfg, beta, model, url, out, cycles, env)
        time.sleep(1.0)
        stop.set()
        th.join(5)
    finally:
        stop.set()
        if listener_bus is not None:
            listener_bus.shutdown()
        for p in (dev, server):
            if p is not None and p.poll() is None:
                p.terminate()
                try:
                    p.wait(10)
                except subprocess.TimeoutExpired:
                    p.kill()
    summary = json.loads(r.stdout.strip().splitlines()[-1])
    with open(summary["log"]) as f:
        log = {int(float(row["cycle"])): row for row in csv.DictReader(f)}
    return {**_frames_against_log(tpdo_cycles(frames, cfg.hardware.bus.master_node), log),
            "run_fault": summary["fault"], "overruns": summary["overruns"], "run_wall_s": summary["wall_s"],
            "publish": summary["publish"]}


def _device_model_process(scenario: Path, url: str, env: dict) -> subprocess.Popen:
    """``sea-daemon device-model`` on the remote bus ``url`` in its own process, once ready."""
    dev = subprocess.Popen([sys.executable, "-m", "sea_daemon", "device-model", "--bus", "remote", "--channel", url,
                            "--config", str(data_root() / "configs" / "exo_1dof_assist.yaml"),
                            "--scenario", str(scenario), "--duration", "900"],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    line = dev.stdout.readline()
    if "device-model ready" not in line:
        dev.terminate()
        raise RuntimeError(f"device model did not start: {line!r}")
    return dev


def _daemon_run(cfg, beta: float, model: Path, url: str, out: Path, cycles: int, env: dict):
    """``sea-daemon run`` of ``cycles`` cycles on the remote bus ``url`` (the configuration with
    ``gp_beta`` = ``beta``, written to ``out/can_run.yaml``), in its own process: its result."""
    bus = dataclasses.replace(cfg.hardware.bus, pdo_timeout_ms=200.0, max_missed_cycles=2,
                              heartbeat_timeout_ms=2000, sdo_timeout_ms=3000)
    run_cfg = dataclasses.replace(cfg, hardware=dataclasses.replace(cfg.hardware, bus=bus),
                                  estimator=dataclasses.replace(cfg.estimator, gp_beta=beta))
    save_config(run_cfg, out / "can_run.yaml")
    logs = Path(tempfile.mkdtemp(prefix="sea-can-"))
    return subprocess.run([sys.executable, "-m", "sea_daemon", "run", "--config", str(out / "can_run.yaml"),
                           "--model", str(model), "--bus", "remote", "--channel", url, "--log-dir", str(logs),
                           "--cycles", str(cycles), "--overrun-streak", "0", "--rt-priority", "0"],
                          capture_output=True, text=True, env=env, timeout=3600)


def _frames_against_log(by_cycle: dict, log: dict) -> dict:
    """The published TPDOs (``by_cycle``: cycle -> (TPDO1 fields, status)) against the run's log
    rows (``log``: cycle -> row): counts of equal, +inf while not valid, and mismatches."""
    got = [k for k in log if k in by_cycle]
    equal = inf_invalid = mismatch = 0
    examples: list = []                        # the first mismatches, to say what differed
    for k in got:
        j1, st = by_cycle[k]
        row = log[k]
        hat_ok = _real32_equal(j1["tau_h_act_hat"], row["tau_h_act_hat"])
        if j1["valid"]:
            ok = hat_ok and _real32_equal(j1["tau_h_act_bound"], row["tau_h_act_bound"])
            equal += ok
        else:                                  # +inf exactly where the log says not valid or faulted
            ok = j1["tau_h_act_bound"] == math.inf and (float(row["valid"]) == 0 or float(row["fault"]) != 0)
            inf_invalid += ok
        mismatch += not ok
        if not ok and len(examples) < 5:
            examples.append({"cycle": k, "frame": j1, "status": st, "log": {c: row[c] for c in
                             ("t", "tau_h_act_hat", "tau_h_act_bound", "valid", "fault")}})
    return {"examples": examples, "log_rows": len(log), "cycles_with_tpdo1": len(got), "equal_to_log": equal,
            "inf_while_invalid": inf_invalid, "mismatch": mismatch}


# ---------------------------------------------------------------------------- main
def run(args) -> int:
    out = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="bench-assist-"))
    out.mkdir(parents=True, exist_ok=True)
    src = Path(args.scenario)
    sc = load_scenario(src)
    rates = [float(x) for x in args.rates.split(",")]
    print(f"assist benchmark on {machine()}")
    print(f"scenario {src} ({sc.description}); model {sc.model_path.name}; {args.seconds:g} s per run; "
          f"output {out}")
    report: dict = {"scenario": str(src), "rates": {}}
    for i, rate in enumerate(rates):
        cfg = task_config(sc, rate)
        gain = cfg.assist.gain if args.gain is None else args.gain
        residual, beta, info = calibrated(sc, cfg, rate, out, args.calibration)
        cfg = dataclasses.replace(cfg, estimator=dataclasses.replace(cfg.estimator, gp_beta=beta))
        print(f"\n{rate:g} Hz: calibration ({info['calibration']}) {info['calibration_cycles']} cycles ({info['gp_points']} GP points), "
              f"held-out {info['heldout_cycles']} cycles, torque beta {beta:.3g} (coverage {info['beta_coverage']:.3f}); "
              f"{info['wall_s']} s")
        seeds = [int(s) for s in (args.seeds if i == 0 else args.seeds_other).split(",")]
        rows = []
        for seed in seeds:
            scen = scenario_copy(src, out / f"task_seed{seed}.yaml", seed=seed)
            for g in (0.0, gain):
                r = task_run(scen, cfg, residual, g, args.seconds)
                np.savez(out / f"run_{rate:g}Hz_seed{seed}_gain{g:g}.npz",
                         **{k: v for k, v in r.items() if isinstance(v, np.ndarray)})
                m = metrics(r, sc.task, cfg.dt)
                m.update(seed=seed, gain=g)
                rows.append(m)
        hdr = (f"  {'seed':>4} {'gain':>4} {'tau_h RMS':>9} {'max':>5} {'assist RMS':>10} {'track RMS/max [deg]':>19} "
               f"{'est RMSE':>8} {'cover':>5} {'mean rho':>8} {'hold ptp q [deg] / assist [N m]':>31} "
               f"{'against':>7} {'max NIS':>7} {'fault':>6} {'wall':>6}")
        print(hdr)
        for m in rows:
            print(f"  {m['seed']:>4} {m['gain']:>4g} {m['tau_h_rms']:>9.3f} {m['tau_h_max']:>5.2f} {m['assist_rms']:>10.3f} "
                  f"{m['err_rms_deg']:>9.2f} / {m['err_max_deg']:<7.2f} {m['est_rmse']:>8.3f} {m['coverage']:>5.3f} "
                  f"{m['rho_mean']:>8.3f} {m['hold_ptp_q_deg']:>15.3f} / {m['hold_ptp_assist']:<13.3f} "
                  f"{m['against_fraction']:>7.3f} {m['max_nis']:>7.1f} {m['fault']:>6} {m['wall_s']:>5.0f}s")
        red = []
        for seed in seeds:
            b = next(m for m in rows if m["seed"] == seed and m["gain"] == 0.0)
            a = next(m for m in rows if m["seed"] == seed and m["gain"] == gain)
            red.append(1.0 - a["tau_h_rms"] / b["tau_h_rms"])
        print(f"  effort reduction (1 - RMS assisted / RMS unassisted), gain {gain:g}: "
              + ", ".join(f"seed {s} {100 * x:.1f} %" for s, x in zip(seeds, red))
              + f"; mean {100 * float(np.mean(red)):.1f} % over {len(seeds)} seed(s)")
        entry = {"calibration": info, "runs": rows, "reduction": red}
        if i == 0 and not args.no_faults:
            base_max = max(m["tau_h_max"] for m in rows if m["gain"] == 0.0)
            scen = out / f"task_seed{seeds[0]}.yaml"
            fr = corrupted(scen, cfg, residual, gain, args.seconds, base_max)
            print(f"  corrupted estimates during the assisted task (seed {seeds[0]}), injected at cycle "
                  f"{fr[0]['at_cycle']}:")
            for f in fr:
                print(f"    {f['corruption']:<48} fault {f['fault']:<20} reaction {f['reaction_cycles']} cycle(s); "
                      f"zero torque from the fault on: {f['zero_torque_from_fault']}; assistance before <= "
                      f"{f['assist_before_max']:.2f} N m; subject |tau_h| before <= {f['tau_h_before_max']:.2f}, "
                      f"after <= {f['tau_h_after_max']:.2f} N m (unassisted task <= {f['unassisted_task_max']:.2f} N m); "
                      f"assistance after <= {f['assist_after_max']:.2f} N m")
            entry["corruptions"] = fr
        if i == 0 and args.can:
            c = can_check(src, cfg, out / f"model_{rate:g}.npz", beta, out)
            print(f"  publication over python-can-remote (run, device model and this listener in 3 processes): "
                  f"{c['cycles_with_tpdo1']} of {c['log_rows']} log rows have their TPDO1+TPDO2 "
                  f"({100 * c['cycles_with_tpdo1'] / c['log_rows']:.2f} %); equal to the log (REAL32) "
                  f"{c['equal_to_log']}, +inf while not valid {c['inf_while_invalid']}, mismatch {c['mismatch']}; "
                  f"run fault {c['run_fault']}, {c['overruns']} overruns in {c['run_wall_s']} s")
            entry["can"] = c
        report["rates"][f"{rate:g}"] = entry
    (out / "report.json").write_text(json.dumps(report, indent=2, default=float))
    print(f"\nwrote {out}/report.json")
    return 0


if __name__ == "__main__":
    from benchmarks._cli import main
    sys.exit(main(sys.modules[__name__]))
