"""``sea-daemon demo``: the main job on the embedded default, through the CAN stack.

For each embedded scenario (``configs/scenarios/passive.yaml``: Sec. V-B, PID moves with a
passive subject; ``active.yaml``: Sec. V-C, a subject resisting a cosine torque) the simulated
exoskeleton runs as CANopen devices (drive + load encoder, :mod:`drivers.device_model`) on a
virtual CAN bus, the CANopen driver reads it at 100 Hz and the scenario's controller drives it:

1. calibration — the training phase, passive subject: its log is what the GP learns from;
2. estimation — the AKF runs online in the cycle; afterwards every estimator (spring torque,
   AKF, GP-AKF trained on the calibration log when available) replays the estimation log.

Writes, in ``--out``: per scenario ``<name>_train.csv`` / ``<name>_est.csv`` (contracts §1),
``<name>_<estimator>.csv`` (EST.csv columns) and ``<name>.png``; ``summary.json``; prints the
RMSE table.
"""
from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from ..config import repo_root
from ..errors import InputError

NAME = "demo"
HELP = "simulated exoskeleton on a virtual CAN bus: calibration, estimation, RMSE table and plots"
ORDER = 10
DESCRIPTION = __doc__

SCENARIOS = ("passive", "active")
ESTIMATORS = ("spring", "akf", "gp-akf")


def add_arguments(p) -> None:
    p.add_argument("--out", default="demo_out", help="output directory (default: demo_out)")
    p.add_argument("--scenario", action="append", choices=SCENARIOS, default=None,
                   help="run only this embedded scenario (repeatable; default: both)")
    p.add_argument("--samples", type=int, default=None,
                   help="shorten both phases to this many samples each (quick look)")
    p.add_argument("--sync-rpdo", action="store_true",
                   help="torque RPDO actuated at the next SYNC (one cycle more delay) instead of on reception")


def _plot(path: Path, name: str, est_log, results: dict) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = est_log.t
    fig, ax = plt.subplots(2, 1, figsize=(10, 6), sharex=True)
    truth = est_log.tau_h_act[:, 0]
    ax[0].plot(t, truth, "k", lw=2, label="true τ_h,act")
    for key, res in results.items():
        line, = ax[0].plot(t, res.tau_h_act_hat[:, 0], lw=1, label=key)
        if key != "spring":
            ax[0].fill_between(t, res.tau_h_act_hat[:, 0] - res.tau_h_act_bound[:, 0],
                               res.tau_h_act_hat[:, 0] + res.tau_h_act_bound[:, 0], color=line.get_color(), alpha=0.12)
    ax[0].set_ylabel("τ_h,act [N m]")
    ax[0].legend(loc="upper right", fontsize=8)
    ax[0].set_title(f"{name}: estimation phase over the virtual CAN bus (bands: guaranteed bound)")
    ax[1].plot(t, np.degrees(est_log.q[:, 0]), label="q (load encoder)")
    ax[1].plot(t, np.degrees(est_log.theta_m[:, 0]), "--", label="θ_m (motor encoder / gear)")
    ax[1].set_ylabel("angle [deg]")
    ax[1].set_xlabel("t [s]")
    ax[1].legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def run(args) -> int:
    from drivers.hil_session import run_scenario

    from ..estimators import make_estimator
    from ..logio import write_columns, write_log
    from ..replay import est_columns, replay, summarize
    from ..sim.scenario import load_scenario
    from .replay import build_estimator

    if args.samples is not None and args.samples < 10:
        raise InputError(f"--samples {args.samples}: allowed >= 10")
    out = Path(args.out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise InputError(f"--out {out}: cannot create: {e.strerror or e}") from None
    summary: dict = {"bus": "virtual", "sync_rpdo": bool(args.sync_rpdo), "scenarios": {}}
    rows = []
    for name in args.scenario or SCENARIOS:
        sc = load_scenario(repo_root() / "configs" / "scenarios" / f"{name}.yaml")
        cfg, dt = sc.nominal, sc.nominal.dt
        n_tr = n_est = args.samples
        t0 = time.perf_counter()
        hil = run_scenario(sc, estimator=make_estimator("akf", cfg, dt=dt), sync_rpdo=args.sync_rpdo,
                           training_samples=n_tr, estimation_samples=n_est)
        wall = time.perf_counter() - t0
        write_log(out / f"{name}_train.csv", hil.training)
        write_log(out / f"{name}_est.csv", hil.estimation)
        results = {}
        entry: dict = {"cycles": int(hil.cycle_s.size), "wall_s": round(wall, 2),
                       "cycle_us_median": round(float(np.median(hil.cycle_s)) * 1e6, 1),
                       "cycle_us_p99": round(float(np.percentile(hil.cycle_s, 99)) * 1e6, 1),
                       "startup_ms": round(hil.startup_s * 1e3, 1), "estimators": {}}
        online = hil.estimation.extra["tau_h_act_hat"] - hil.estimation.tau_h_act[:, 0]
        entry["akf_online_rmse"] = float(np.sqrt(np.mean(online ** 2)))
        for est_name in ESTIMATORS:
            try:
                est = build_estimator(est_name, cfg, dt, hil.training)
            except InputError as e:
                entry["estimators"][est_name] = {"skipped": str(e)}
                continue
            res = replay(hil.estimation, est, clock=time.perf_counter)
            res.estimator = est_name
            results[est_name] = res
            write_columns(out / f"{name}_{est_name}.csv", est_columns(res))
            s = summarize(res)
            entry["estimators"][est_name] = s
            rows.append((name, est_name, s["rmse"], s.get("coverage"), s["mean_bound"]))
        _plot(out / f"{name}.png", name, hil.estimation, results)
        summary["scenarios"][name] = entry
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    print(f"{'scenario':<9} {'estimator':<8} {'RMSE [N m]':>10} {'coverage':>9} {'mean bound':>11}")
    for name, est_name, rmse, cov, bound in rows:
        print(f"{name:<9} {est_name:<8} {rmse:>10.4f} {cov if cov is not None else float('nan'):>9.3f} {bound:>11.3f}")
    for name, e in summary["scenarios"].items():
        skipped = [k for k, v in e["estimators"].items() if "skipped" in v]
        print(f"{name}: {e['cycles']} CAN cycles in {e['wall_s']} s (cycle median {e['cycle_us_median']} us, "
              f"p99 {e['cycle_us_p99']} us), start-up {e['startup_ms']} ms, online AKF RMSE "
              f"{e['akf_online_rmse']:.4f} N m" + (f"; not run: {', '.join(skipped)}" if skipped else ""))
    print(f"wrote {out}/summary.json, logs, estimates and plots")
    return 0
