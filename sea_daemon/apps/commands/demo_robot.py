"""``sea-daemon demo --robot MODEL.yaml``: the demo's flow for a robot of n coupled joints.

The robot is a model YAML with ``model.urdf`` (``configs/exo_2dof.yaml``: the shoulder–elbow
exoskeleton with the wearer's arm).  Its scenarios are the embedded two-joint ones
(``configs/scenarios/two_joint_passive.yaml``: a PID per joint on each joint's own minimum-jerk
moves, passive subject; ``two_joint_active.yaml``: the arm held open loop, the subject resisting
a cosine torque on each joint), each with its model set to the robot: the true plant is the
robot with the scenario's heavier, lighter or longer links and its hidden friction per joint,
behind a CANopen drive and load encoder per joint on the virtual CAN bus (a bus per joint when
the configuration names one).  As for one joint (:mod:`.demo`, the flow of :mod:`.demo_flow`): ``calibrate --fit`` from the
nominal robot, ``run`` with the calibrated GP-AKF and its Theorem-1 bound, then the estimation log
with the subject's true torque scored: the GP-AKF's own online estimate, the AKF on the
nominal robot, the oracle AKF (the true plant's model with the same estimator settings: what a
perfect model would give) and the spring torque — a table row per scenario, joint and
estimator, and a plot per scenario and joint.

Writes, in ``--out``, what the one-joint demo writes (with the per-joint columns of
docs/interfaces.md §1) and ``<name>_scenario.yaml`` (the scenario run, its model the robot),
``<name>_<joint>.png`` per joint (the URDF's joint name), and in ``summary.json`` per scenario and
estimator ``joints``: the one-joint summary of each joint, by the joint's name.
"""
from __future__ import annotations

import dataclasses
import json
import logging
import time
from pathlib import Path

import yaml

from sea_daemon.apps.calibration.joints import joint_names
from sea_daemon.apps.calibration.modelio import jsonable
from sea_daemon.apps.commands.demo_flow import fig, plot_joint, prepare, print_scenarios, scored, session
from sea_daemon.core.rates import at_rate
from sea_daemon.core.replay import ReplayResult, summarize
from sea_daemon.errors import InputError
from sea_daemon.io.configfile import data_root, load_yaml
from sea_daemon.io.files import atomic_write_text

logger = logging.getLogger("sea_daemon.demo")

#: the embedded scenario of each demo scenario name, for a robot of two joints
SCENARIOS = {"passive": "two_joint_passive.yaml", "active": "two_joint_active.yaml"}
#: the estimates that set a joint plot's torque axis (the spring torque, off by the arm's weight, and
#: the bands of a bound far wider than the estimate's error would hide the others)
ZOOM = ("akf", "oracle", "gp-akf")
#: the estimators scored, in the table's order: the one-joint demo's and the oracle AKF
ROBOT_ESTIMATORS = ("spring", "akf", "oracle", "gp-akf")


def run(args) -> int:
    if args.online_gp:
        raise InputError("--online-gp: one joint only (--config); the robot demo calibrates with calibrate --fit")
    out, cfg, cfg_path, cfg_rate = prepare(args, args.robot)
    if cfg.joints < 2 or cfg.model.rigid is None:
        raise InputError(f"--robot {args.robot}: a model of {cfg.joints} joint(s)"
                         f"{'' if cfg.model.rigid is not None else ' without model.urdf'}; allowed: a robot of 2 "
                         "joints with model.urdf (configs/exo_2dof.yaml); one joint: sea-daemon demo --config")
    names = joint_names(cfg)
    summary: dict = {"bus": "virtual", "sync_rpdo": bool(args.sync_rpdo), "robot": str(args.robot),
                     "joints": names, "pace": args.pace, "rate_hz": cfg_rate.rate_hz,
                     "kinematics_window": cfg_rate.kinematics.window, "scenarios": {}}
    rows = []
    t_all = time.perf_counter()
    for name in args.scenario or tuple(SCENARIOS):
        sc_path = robot_scenario(Path(args.robot), name, out / f"{name}_scenario.yaml")
        entry, est_log, sc = session(args, name, str(sc_path), out, cfg, cfg_path, cfg_rate)
        logger.info("demo %s: scoring the estimators per joint and plotting …", name)
        oracle = at_rate(dataclasses.replace(sc.true_config(), estimator=cfg.estimator, kinematics=cfg.kinematics),
                         args.rate)
        rows += score_joints(out, name, est_log, cfg_rate, oracle, names, cfg.model.rigid.joint_names,
                             entry["estimators"])
        summary["scenarios"][name] = entry
    summary["wall_s"] = round(time.perf_counter() - t_all, 2)
    atomic_write_text(out / "summary.json", json.dumps(jsonable(summary), indent=2, allow_nan=False))
    print_table(rows)
    print_scenarios(out, summary)
    return 0


def robot_scenario(robot: Path, name: str, dest: Path) -> Path:
    """The embedded two-joint scenario ``name`` with its model set to ``robot`` (an absolute path):
    the true plant is the robot with the scenario's links and hidden effects."""
    src = data_root() / "configs" / "scenarios" / SCENARIOS[name]
    d = load_yaml(src)
    d["model"] = str(robot.resolve())
    atomic_write_text(dest, f"# sea-daemon demo --robot: {src.name} on {robot}\n" + yaml.safe_dump(d, sort_keys=False))
    return dest


def joint_result(res: ReplayResult, j: int) -> ReplayResult:
    """Joint ``j`` (0-based) of an n-joint result as a one-joint result."""
    n = res.n
    cut = slice(j, j + 1)
    return ReplayResult(t=res.t, tau_h_act_hat=res.tau_h_act_hat[:, cut], tau_h_act_sigma=res.tau_h_act_sigma[:, cut],
                        tau_h_act_bound=res.tau_h_act_bound[:, cut], x_hat=res.x_hat[:, j::n],
                        tau_h_act=None if res.tau_h_act is None else res.tau_h_act[:, cut],
                        step_time_s=res.step_time_s, estimator=res.estimator, valid=res.valid,
                        bound_of=res.bound_of, reason=res.reason)


def score_joints(out: Path, name: str, est_log, cfg_rate, oracle_cfg, names: list[str], files: tuple,
                 summaries: dict) -> list:
    """The estimators on the estimation log (the GP-AKF's online estimate; the spring torque and
    the AKF on ``cfg_rate``, the oracle AKF on ``oracle_cfg`` replayed): their EST.csv files, their
    summaries (with ``joints``, one per joint by its name in ``names``) into ``summaries``, a plot
    per joint (``<name>_<files[j]>.png``); the table's rows (scenario, joint, estimator, RMSE,
    coverage, mean bound)."""
    specs = {"spring": ("spring", cfg_rate), "akf": ("akf", cfg_rate), "oracle": ("akf", oracle_cfg), "gp-akf": None}
    done = scored(out, name, est_log, len(names), {e: specs[e] for e in ROBOT_ESTIMATORS})
    results = {}
    for est_name, (res, s) in done.items():
        if est_name == "oracle":
            s["source"] = "AKF on the true plant's model (links and hidden effects), the configuration's estimator"
        s["joints"] = {jn: summarize(joint_result(res, j)) for j, jn in enumerate(names)}
        summaries[est_name] = s
        results[est_name] = res
    rows = []
    for j, jn in enumerate(names):
        for est_name in ROBOT_ESTIMATORS:
            s = summaries[est_name]["joints"][jn]
            rows.append((name, jn, est_name, s["rmse"], s.get("coverage"), s["mean_bound"]))
        plot_joint(out / f"{name}_{files[j]}.png", f"{name}, {jn}", est_log, results, j, zoom=ZOOM)
    return rows


def print_table(rows: list) -> None:
    """The RMSE table per scenario, joint and estimator on stdout."""
    w = max(len(r[1]) for r in rows) if rows else 5
    print(f"{'scenario':<9} {'joint':<{w}} {'estimator':<9} {'RMSE [N m]':>10} {'coverage':>9} {'mean bound':>11}")
    for name, jn, est_name, rmse, cov, bound in rows:
        print(f"{name:<9} {jn:<{w}} {est_name:<9} {fig(rmse, '.4f'):>10} {fig(cov, '.3f'):>9} {fig(bound, '.3f'):>11}")

