"""``sea-daemon demo``: the main job on the embedded default — device model + daemon on a virtual CAN bus.

For each embedded scenario (``configs/scenarios/passive.yaml``: Sec. V-B, PID moves with a
passive subject; ``active.yaml``: Sec. V-C, a subject resisting a cosine torque) the simulated
exoskeleton runs as CANopen devices (drive + load encoder, :mod:`sea_daemon.hw.device_model`, the
scenario's true plant with its hidden effects, lock-step with SYNC) on a fresh virtual CAN bus,
and the daemon talks to it through its own code paths:

1. ``sea-daemon calibrate --fit`` — the training phase (subject passive; the scenario's
   controller moves the joint) from the nominal robot alone (the configuration's model and
   hardware, no estimator settings; the scenario's declared human-torque rate if it declares
   one), then the whole calibration on its log (docs/calibration.md: noise, diagnose's physics,
   residual GP, process noise): ``<name>_model.npz`` and the complete ``<name>_model.yaml``;
2. ``sea-daemon run --model`` — the estimation phase: the GP-AKF on the calibrated model runs
   online in the loop (the scenario's controller drives, the subject acts as the scenario says)
   and publishes the Theorem-1 bound ρ_k (the guaranteed β of Lederer et al. 2019) with every
   estimate.

``--online-gp`` runs the GP learned online on the configured model instead: calibrate,
``calibrate-bound`` on a held-out session (the same moves, the scenario's seed + 1000: it checks
the configured β or calibrates one on that session's torque error, docs/bounds.md §2c), run.

Then the daemon's measured log of the estimation phase, with the subject's true torque added
(known from the device model), is replayed with the AKF and the spring-torque estimate, and the
GP-AKF's own online estimate from the log is scored with them: RMSE table, plots.

``--robot MODEL.yaml`` runs this flow on a robot of n coupled joints (``configs/exo_2dof.yaml``)
with its two-joint scenarios, the oracle AKF, a table and a plot per joint (:mod:`.demo_robot`).

Writes, in ``--out``: ``config.yaml`` (the configuration used), per scenario
``<name>/`` (the daemon's logs: calibration-*.csv, run-*.csv), ``<name>_model.npz``,
``<name>_train.csv`` / ``<name>_est.csv`` (docs/interfaces.md §1, with the truth), ``<name>_<estimator>.csv``
(EST.csv columns), ``<name>.png``; ``summary.json``.  The loops run lock-step (as fast as the
device model answers); ``--pace realtime`` runs them at the configured rate.
"""
from __future__ import annotations

import json
import logging
import time
from pathlib import Path

from sea_daemon.apps.calibration.modelio import jsonable
from sea_daemon.apps.commands import main
from sea_daemon.apps.commands.demo_flow import daemon, fig, plot_joint, prepare, print_scenarios, scored, session
from sea_daemon.errors import InputError
from sea_daemon.io.configfile import data_root
from sea_daemon.io.files import atomic_write_text

DESCRIPTION = __doc__
logger = logging.getLogger("sea_daemon.demo")

SCENARIOS = ("passive", "active")
ESTIMATORS = ("spring", "akf", "gp-akf")


def add_arguments(p) -> None:
    p.add_argument("--out", default="demo_out", help="output directory (default: demo_out)")
    p.add_argument("--online-gp", action="store_true",
                   help="the GP learned online on the configured model (and calibrate-bound's beta) instead of "
                        "the calibration (calibrate --fit from the nominal robot)")
    p.add_argument("--scenario", action="append", choices=SCENARIOS, default=None,
                   help="run only this embedded scenario (repeatable; default: both)")
    p.add_argument("--config", default=None,
                   help="daemon configuration (default: configs/exo_1dof_sim.yaml, the estimator settings "
                        "for the simulated sensors)")
    p.add_argument("--robot", default=None, metavar="MODEL.yaml",
                   help="a robot of n coupled joints (a model YAML with model.urdf, e.g. configs/exo_2dof.yaml): its "
                        "two-joint scenarios (configs/scenarios/two_joint_passive.yaml, two_joint_active.yaml) on "
                        "it, with the oracle AKF (the true plant's model) among the estimators, a table and a "
                        "plot per joint; instead of --config")
    p.add_argument("--samples", type=int, default=None,
                   help="shorten both phases to this many samples each (quick look; the calibration's diagnose "
                        "needs four smoothing windows of the session, --online-gp does not)")
    p.add_argument("--duration", type=float, default=None, metavar="SECONDS",
                   help="shorten both phases to this many seconds each, the same at every --rate (quick look; "
                        "the passive calibration needs 10 s with moves both ways)")
    p.add_argument("--sync-rpdo", action="store_true",
                   help="torque RPDO actuated at the next SYNC (one cycle more delay) instead of on reception")
    p.add_argument("--rate", type=float, default=None, metavar="HZ",
                   help="loop rate of calibration and estimation (default: the configuration's, 100 Hz); the same "
                        "configuration at another rate (sea_daemon.core.rates: kinematics window, R per second), "
                        "the scenarios' phases keep their duration")
    p.add_argument("--pace", choices=("lockstep", "realtime"), default="lockstep",
                   help="lockstep (default): as fast as the device model answers; realtime: at the configured rate")


def _plot(path: Path, name: str, est_log, results: dict) -> None:
    plot_joint(path, name, est_log, results, 0)


def _daemon(argv: list[str]) -> dict:
    """A daemon command run in this process (this module's ``main``); its JSON summary."""
    return daemon(argv, main)




def run(args) -> int:
    if args.robot is not None:
        if args.config is not None:
            raise InputError("--robot and --config: give one (--robot: a robot of n joints, --config: one joint)")
        # local import: the robot's flow (n joints) is loaded only when asked for
        from sea_daemon.apps.commands import demo_robot
        return demo_robot.run(args)
    args.config = args.config or str(data_root() / "configs" / "exo_1dof_sim.yaml")
    out, cfg, cfg_path, cfg_rate = prepare(args, args.config)
    summary: dict = {"bus": "virtual", "sync_rpdo": bool(args.sync_rpdo), "config": str(args.config),
                     "pace": args.pace, "rate_hz": cfg_rate.rate_hz,
                     "kinematics_window": cfg_rate.kinematics.window, "scenarios": {}}
    rows = []
    t_all = time.perf_counter()
    for name in args.scenario or SCENARIOS:
        summary["scenarios"][name], scenario_rows = _scenario(args, name, out, cfg, cfg_path, cfg_rate)
        rows += scenario_rows
    summary["wall_s"] = round(time.perf_counter() - t_all, 2)
    atomic_write_text(out / "summary.json", json.dumps(jsonable(summary), indent=2, allow_nan=False))
    _print_summary(out, summary, rows)
    return 0


def _scenario(args, name: str, out: Path, cfg, cfg_path: Path, cfg_rate) -> tuple[dict, list]:
    """One embedded scenario: calibration and estimation by the daemon on the virtual bus, its
    logs with the subject's true torque, the estimators scored on the estimation log.
    Returns (its entry of summary.json, its rows of the table)."""
    sc_path = str(data_root() / "configs" / "scenarios" / f"{name}.yaml")
    entry, est_log, _ = session(args, name, sc_path, out, cfg, cfg_path, cfg_rate)
    logger.info("demo %s: scoring the estimators and plotting …", name)
    rows = _score(out, name, est_log, cfg_rate, cfg.joints, entry["estimators"])
    return entry, rows


def _score(out: Path, name: str, est_log, cfg_rate, n: int, summaries: dict) -> list:
    """The estimators on the estimation log of ``n`` joints (the GP-AKF's online estimate, the
    others replayed at ``cfg_rate``): their EST.csv files, their summaries into ``summaries``,
    the plot; the table's rows."""
    done = scored(out, name, est_log, n, {e: None if e == "gp-akf" else (e, cfg_rate) for e in ESTIMATORS})
    rows = []
    for est_name, (_, s) in done.items():
        summaries[est_name] = s
        rows.append((name, est_name, s["rmse"], s.get("coverage"), s["mean_bound"]))
    _plot(out / f"{name}.png", name, est_log, {k: r for k, (r, _) in done.items()})
    return rows


def _print_summary(out: Path, summary: dict, rows: list) -> None:
    """The RMSE table and one line per scenario on stdout."""
    print(f"{'scenario':<9} {'estimator':<8} {'RMSE [N m]':>10} {'coverage':>9} {'mean bound':>11}")
    for name, est_name, rmse, cov, bound in rows:
        print(f"{name:<9} {est_name:<8} {fig(rmse, '.4f'):>10} {fig(cov, '.3f'):>9} {fig(bound, '.3f'):>11}")
    print_scenarios(out, summary)


