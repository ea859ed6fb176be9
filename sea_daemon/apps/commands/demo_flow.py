"""The demo's flow, shared by ``sea-daemon demo`` (one joint, :mod:`.demo`) and ``demo --robot``
(n joints, :mod:`.demo_robot`): the arguments and the configuration used (:func:`prepare`), one
scenario by the daemon on the virtual CAN bus — calibration, estimation, both logs with the
subject's true torque (:func:`session`) — the GP-AKF's online estimate read from the log
(:func:`online_result`), the plot of a joint (:func:`plot_joint`) and the lines printed after
the table (:func:`print_scenarios`).  :mod:`.demo` describes the flow and the files written.
"""
from __future__ import annotations

import contextlib
import dataclasses
import io
import json
import logging
import math
import time
from pathlib import Path

import numpy as np
import yaml

from sea_daemon.apps.commands import main
from sea_daemon.core.log import MeasuredLog, column_names
from sea_daemon.core.rates import at_rate
from sea_daemon.core.estimators import make_estimator
from sea_daemon.core.replay import ReplayResult, bound_rows, est_columns, replay, summarize
from sea_daemon.errors import InputError, RunFault
from sea_daemon.io.configfile import load_config, load_yaml, save_config, urdf_path
from sea_daemon.io.files import atomic_write_text, check_output_dir
from sea_daemon.io.logcsv import read_log, write_columns, write_log
from sea_daemon.io.scenario import load_scenario
from sea_daemon.runtime.rig import subject_torque

logger = logging.getLogger("sea_daemon.demo")

#: fewest cycles of the held-out session (the torque calibration's ceil((m+1)(1-delta)) rule needs m >= 19)
HELD_OUT_MIN = 120


def plot_joint(path: Path, title: str, est_log, results: dict, j: int, zoom: tuple = ()) -> None:
    """The plot of joint ``j`` (0-based): the true and estimated τ_h,act with each bounded
    estimator's band ±ρ_k, and the joint's load and motor angles.  ``zoom``: the estimators whose
    estimates (with the truth, not the bands) set the torque axis's range; () the matplotlib
    default (every line and band)."""
    # local: matplotlib takes ~0.5 s to import and its backend is a process-wide choice, made here
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = est_log.t - est_log.t[0]
    fig, ax = plt.subplots(2, 1, figsize=(10, 6), sharex=True)
    truth = est_log.tau_h_act[:, j]
    ax[0].plot(t, truth, "k", lw=2, label="true τ_h,act")
    for key, res in results.items():
        line, = ax[0].plot(t, res.tau_h_act_hat[:, j], lw=1, label=key)
        if key != "spring":
            ax[0].fill_between(t, res.tau_h_act_hat[:, j] - res.tau_h_act_bound[:, j],
                               res.tau_h_act_hat[:, j] + res.tau_h_act_bound[:, j], color=line.get_color(), alpha=0.12)
    ax[0].set_ylabel("τ_h,act [N m]")
    ax[0].legend(loc="upper right", fontsize=8)
    if zoom:
        shown = np.concatenate([truth] + [results[k].tau_h_act_hat[:, j] for k in zoom if k in results])
        shown = shown[np.isfinite(shown)]
        lo, hi = float(np.min(shown)), float(np.max(shown))
        pad = max(0.5, 0.25 * (hi - lo))
        ax[0].set_ylim(lo - pad, hi + pad)
        title = f"{title} (axis: the truth and {', '.join(zoom)}; wider lines and bands cut)"
        ax[0].set_title(f"{title}\nestimation phase, daemon on the virtual CAN bus (bands: ±tau_h_act_bound, "
                        "the Theorem-1 bound ρ_k)", fontsize=10)
    else:
        ax[0].set_title(f"{title}: estimation phase, daemon on the virtual CAN bus (bands: ±tau_h_act_bound, the "
                        "Theorem-1 bound ρ_k)")
    ax[1].plot(t, np.degrees(est_log.q[:, j]), label="q (load encoder)")
    ax[1].plot(t, np.degrees(est_log.theta_m[:, j]), "--", label="θ_m (motor encoder / gear)")
    ax[1].set_ylabel("angle [deg]")
    ax[1].set_xlabel("t [s]")
    ax[1].legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def daemon(argv: list[str], command=None) -> dict:
    """Run a daemon command in this process (``command``: the CLI's ``main``, by default
    :func:`sea_daemon.apps.commands.main`); its JSON summary (stdout) is returned."""
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        rc = (command or main)(argv)
    lines = [ln for ln in buf.getvalue().splitlines() if ln.startswith("{")]
    summary = json.loads(lines[-1]) if lines else {}
    if rc == 2:                 # the step refused its input (already said on stderr): the demo's too
        raise InputError(f"sea-daemon {argv[0]} refused its input (above); the demo stops there")
    if rc != 0:                 # the step stopped on a latched fault (said on stderr): not a bug
        fault = summary.get("fault")
        fault = fault if fault and fault != "NONE" else "see the line above"
        if fault == "OVERRUN_STREAK":
            # --pace realtime on a host too slow or too busy for the rate: not the method's fault
            fault += (": the daemon's cycles took longer than their period on this host; --pace lockstep (the "
                      "default) runs the same sessions sample by sample")
        raise RunFault(f"sea-daemon {argv[0]} stopped with exit status {rc} ({fault}); the demo stops there")
    return summary


def _online_gp(out: Path, name: str, sc, sc_path: str, cfg, cfg_path: Path, model: Path, common, logs: Path,
               n_tr: int, per: float):
    """``--online-gp``: calibrate (the GP learned online), calibrate-bound on a held-out session,
    the run's configuration.  Returns (calibrate's JSON, calibrate-bound's JSON, run config)."""
    cal = daemon(["calibrate", *common(cfg_path, sc_path, logs), "--out", str(model), "--cycles", str(n_tr)])
    held = _held_out_scenario(sc_path, out / f"{name}_heldout.yaml")
    hcal = daemon(["calibrate", *common(cfg_path, held, logs / "heldout"),
                    "--out", str(out / f"{name}_heldout_model.npz"), "--cycles", str(max(n_tr, int(HELD_OUT_MIN * per)))])
    run_cfg = out / f"{name}_config.yaml"
    base_cfg = cfg_path
    if sc.tau_h_act_rate is not None:
        # what the experimenter declares about the subject: the bound's human-torque rate
        base_cfg = out / f"{name}_declared.yaml"
        save_config(sc.declared(cfg), base_cfg, header=f"sea-daemon demo: {cfg_path} with what {name} declares")
    if isinstance(cfg.estimator.gp_beta, float):
        # the configured β: the held-out session checks it, the run uses it
        bound = daemon(["calibrate-bound", hcal["log"], "--config", str(base_cfg), "--model", str(model)])
        run_cfg = base_cfg
    else:
        bound = daemon(["calibrate-bound", hcal["log"], "--config", str(base_cfg), "--model", str(model),
                         "--target", "torque", "--write", str(run_cfg)])
    return cal, bound, run_cfg


def _robot_config(cfg, sc, path: Path) -> None:
    """The nominal robot a user starts from: the configuration's model and hardware, no
    estimator, kinematics or learning settings (the calibration identifies them), and the
    scenario's declared human-torque rate when it declares one."""
    d = cfg.to_dict()
    for key in ("estimator", "kinematics", "learning"):
        d.pop(key, None)
    if cfg.model.rigid is not None:           # the robot description where the configuration's names it
        d["model"]["urdf"] = str(urdf_path(cfg.source, cfg.model.urdf).resolve())
    if sc.tau_h_act_rate is not None:
        d["estimator"] = {"tau_h_act_rate": float(sc.tau_h_act_rate)}
    atomic_write_text(path, "# sea-daemon demo: the nominal robot the calibration starts from\n"
                      + yaml.safe_dump(json.loads(json.dumps(d)), sort_keys=False))


def _beta_summary(bound: dict) -> dict:
    """What the run's β is and what the held-out session said about it (calibrate-bound's JSON)."""
    if bound.get("lederer"):
        return {"beta": "lederer", "source": "guaranteed (Lederer et al. 2019)",
                "text": "guaranteed beta (Lederer et al. 2019) of the calibrated residual GP"}
    c = bound.get("configured")
    if c is not None:
        return {"beta": c["beta"], "source": "configured", "held_out_coverage": c["coverage"],
                "held_out_steps": c["steps"], "log": bound["log"],
                "text": f"beta {c['beta']:.3g} (configured) covers {c['coverage']:.3f} of a held-out session's "
                        f"{c['steps']} steps"}
    # calibrate-bound --target torque
    return {"beta": bound["beta"], "source": "torque", "held_out_coverage": bound["coverage"],
            "held_out_steps": bound["steps"], "log": bound["log"],
            "text": f"beta {bound['beta']:.3g} calibrated on a held-out session's torque error (covers "
                    f"{bound['coverage']:.3f} of {bound['steps']} steps)"}


def _held_out_scenario(sc_path: str, dest: Path) -> Path:
    """A copy of the scenario with another noise seed (seed + 1000) and its model path made
    absolute: a calibration session the GP never learned, for calibrate-bound."""
    src = Path(sc_path)
    d = load_yaml(src)
    d["seed"] = int(d.get("seed", 0)) + 1000
    d["model"] = str((src.parent / d["model"]).resolve())
    atomic_write_text(dest, yaml.safe_dump(d, sort_keys=False))
    return dest


def _with_truth(log_path: str, tau_h, n: int):
    """The daemon's log as a MeasuredLog with the subject's true torque over each row's interval."""
    log = read_log(log_path, n=n)
    truth = np.array([np.array(tau_h(t), dtype=float).reshape(n) for t in log.t])
    return MeasuredLog(t=log.t, q=log.q, theta_m=log.theta_m, tau_m=log.tau_m, tau_h_act=truth, extra=log.extra)


def prepare(args, config: str):
    """The arguments checked, ``--out`` created and the configuration ``config`` used written
    there: (out directory, configuration, its copy's path, the configuration at ``--rate``)."""
    if args.samples is not None and args.samples < 10:
        raise InputError(f"--samples {args.samples}: allowed >= 10")
    if args.duration is not None:
        if args.samples is not None:
            raise InputError("--samples and --duration: give one (--duration is in seconds)")
        if not (math.isfinite(args.duration) and 0.1 <= args.duration <= 3600.0):
            raise InputError(f"--duration {args.duration:g}: allowed 0.1..3600 s")
    out = check_output_dir("--out", args.out, [config])
    cfg = load_config(config)
    if args.sync_rpdo:
        cfg = dataclasses.replace(cfg, hardware=dataclasses.replace(
            cfg.hardware, bus=dataclasses.replace(cfg.hardware.bus, sync_rpdo=True)))
    cfg_path = out / "config.yaml"
    save_config(cfg, cfg_path, header="configuration used by sea-daemon demo")
    if args.rate is not None and not 1.0 <= args.rate <= 100000.0:
        raise InputError(f"--rate {args.rate:g}: allowed 1..100000 Hz")
    return out, cfg, cfg_path, at_rate(cfg, args.rate)


def session(args, name: str, sc_path: str, out: Path, cfg, cfg_path: Path, cfg_rate) -> tuple[dict, MeasuredLog, object]:
    """The scenario ``sc_path`` by the daemon on the virtual bus: calibration (``calibrate
    --fit`` from the nominal robot; or ``--online-gp``), the
    estimation phase (``run``), both logs with the subject's true torque written to ``out``.
    Returns (its entry of summary.json, estimators still empty; the estimation log; the scenario)."""
    n = cfg.joints
    per = cfg_rate.rate_hz / cfg.rate_hz                # samples per scenario sample
    rate_args = ["--rate", f"{cfg_rate.rate_hz:g}"] if args.rate is not None else []
    sc = load_scenario(sc_path)
    n_tr = args.samples or int(round(sc.training_samples * per))
    n_est = args.samples or int(round(sc.estimation_samples * per))
    if args.duration is not None:
        # seconds at the loop's rate: the same session at 100 Hz and 1 kHz
        n_tr = n_est = max(10, int(round(args.duration * cfg_rate.rate_hz)))
    logs = out / name
    model = out / f"{name}_model.npz"

    def common(config, scenario, log_dir):
        return ["--config", str(config), "--device-model", str(scenario), "--log-dir", str(log_dir),
                "--pace", args.pace, "--scenario", str(scenario), *rate_args]
    t0 = time.perf_counter()
    logger.info("demo %s: the calibration phase on the device model, then the calibration of its log …", name)
    if args.online_gp:
        cal, bound, run_cfg = _online_gp(out, name, sc, sc_path, cfg, cfg_path, model, common, logs, n_tr, per)
    else:
        # the calibration from the nominal robot alone: calibrate --fit writes the model file
        # and the complete configuration beside it
        robot_cfg = out / f"{name}_robot.yaml"
        _robot_config(cfg, sc, robot_cfg)
        cal = daemon(["calibrate", *common(robot_cfg, sc_path, logs), "--out", str(model), "--cycles", str(n_tr),
                       "--fit", "--no-progress"])
        run_cfg = Path(cal["config_calibrated"])
        bound = {"lederer": True}
    t1 = time.perf_counter()
    logger.info("demo %s: the estimation phase (sea-daemon run, %d cycles) …", name, n_est)
    est = daemon(["run", *common(run_cfg, sc_path, logs), "--model", str(model), "--cycles", str(n_est)])
    t2 = time.perf_counter()
    # the device model's subject: passive in calibration, the scenario's in estimation
    train_log = _with_truth(cal["log"], subject_torque(sc, "training"), n)
    est_log = _with_truth(est["log"], subject_torque(sc, "estimation"), n)
    write_log(out / f"{name}_train.csv", train_log)
    write_log(out / f"{name}_est.csv", est_log)
    x = est_log.extra
    entry: dict = {"cycles": int(cal["cycles"] + est["cycles"]), "wall_s": round(t2 - t0, 2),
                   "calibrate": {k: cal[k] for k in ("cycles", "gp_points", "overruns", "wall_s", "log", "model")},
                   "calibration": cal.get("calibration"),
                   "run": {k: est[k] for k in ("cycles", "overruns", "wall_s", "log", "rows_written")},
                   "calibrate_wall_s": round(t1 - t0, 2), "run_wall_s": round(t2 - t1, 2),
                   "gp_beta": _beta_summary(bound),
                   "cycle_compute_us_median": round(float(np.median(x["compute"])) * 1e6, 1),
                   "cycle_compute_us_p99": round(float(np.percentile(x["compute"], 99)) * 1e6, 1),
                   "estimators": {}}
    return entry, est_log, sc


def online_result(est_log, n: int) -> ReplayResult:
    """The GP-AKF's own online estimate of ``n`` joints, read from the daemon's estimation log."""
    x = est_log.extra

    def per_joint(base):            # the log's column of each joint (docs/interfaces.md §1)
        return np.stack([x[c] for c in column_names(base, n)], axis=1)
    return ReplayResult(t=est_log.t, tau_h_act_hat=per_joint("tau_h_act_hat"),
                        tau_h_act_sigma=per_joint("tau_h_act_sigma"), tau_h_act_bound=per_joint("tau_h_act_bound"),
                        x_hat=np.zeros((len(est_log), 5 * n)), tau_h_act=est_log.tau_h_act,
                        step_time_s=x["compute"], estimator="gp-akf", valid=x["valid"] > 0.5,
                        bound_of=bound_rows(x["cycle"], x["bound_cycle"]))


def scored(out: Path, name: str, est_log, n: int, estimators: dict) -> dict:
    """The estimators on the estimation log of ``n`` joints, in the order of ``estimators`` (its
    name → (estimator kind, configuration) replayed on the log, or None: the GP-AKF's own online
    estimate from the log): each one's EST.csv ``<name>_<estimator>.csv``; {estimator:
    (ReplayResult, its summary)}."""
    done = {}
    for est_name, spec in estimators.items():
        if spec is None:
            res = online_result(est_log, n)           # the daemon's own online estimate
        else:
            kind, cfg = spec
            res = replay(est_log, make_estimator(kind, cfg, dt=cfg.dt), clock=time.perf_counter)
            res.estimator = est_name
        write_columns(out / f"{name}_{est_name}.csv", est_columns(res))
        s = summarize(res)
        if spec is None:
            s["source"] = "online, in the daemon's loop (step_time_us: whole cycle compute)"
        done[est_name] = (res, s)
    return done


def fig(v, spec: str) -> str:
    """A table figure; "-" for one that is not measurable (None, nan or inf)."""
    return format(v, spec) if v is not None and math.isfinite(v) else "-"


def print_scenarios(out: Path, summary: dict) -> None:
    """One line per scenario (cycles, time, compute, the bound's β) and the files written."""
    for name, e in summary["scenarios"].items():
        print(f"{name}: {e['cycles']} CAN cycles in {e['wall_s']} s (calibrate {e['calibrate']['cycles']} cycles, "
              f"GP {e['calibrate']['gp_points']} points; run {e['run']['cycles']} cycles; cycle compute median "
              f"{e['cycle_compute_us_median']} us, p99 {e['cycle_compute_us_p99']} us; overruns "
              f"{e['calibrate']['overruns'] + e['run']['overruns']}); bound: {e['gp_beta']['text']}")
        g = e["estimators"]["gp-akf"]
        if g.get("bound_age_max", 0) > 0:
            # the bound worker (real-time pace): ρ of an earlier sample is published with the estimate
            print(f"{name}: the GP-AKF's bound came from the worker, up to {g['bound_age_max']} cycles behind its "
                  f"estimate: each rho against its own sample's error covers {g['coverage_own_sample']:.3f} of the "
                  f"valid rows (the table's coverage: against the estimate published with it)")
    print(f"wrote {out}/summary.json, logs, model files, estimates and plots ({summary['wall_s']} s)")
