"""``sea-daemon bench assist``: assistance on robots it has never seen, by the README flow alone.

For each plant ``--seeds`` of the generalisation family (:mod:`._family`: nominal robot ±30 %,
hidden effects in and outside diagnose's vocabulary, encoders of 16–20 bit, gears 50–160), at
``--rate``, the flow of docs/setup.md with nothing tuned by hand:

1. ``calibrate --excitation --fit``: the PID moves the relaxed arm through the calibration
   excitation over the plant's declared working range (``--cal-s`` seconds; the family's
   calibration session, :func:`._family.calibration_motion`, the seeds of ``bench generalize``),
   then the whole calibration on that log with the user's robot file (the nominal model, the
   hardware, the ``calibration`` section: working range and the declared wearer) —
   ``model.yaml`` and ``model.npz`` written as ``calibrate --fit`` writes them;
2. ``model.yaml`` with ``assist.enabled: true`` and nothing else changed, read back as
   ``sea-daemon run`` reads it (the same estimator, the same innovation check, the same
   controller);
3. the tracking task of ``configs/scenarios/assist_track.yaml`` (hold 20°, move to 70°, hold,
   back; a subject with muscle feedback, a sensory delay and a feed-forward it adapts,
   :mod:`sea_daemon.core.sim.subject`) on the plant, in the daemon's fixed-rate loop — three
   times: assisting; with the compensation of the user's nominal robot alone (``robot_only``:
   the exoskeleton carrying only itself); and with the calibrated model's compensation and no
   assistance (gain 0, ``reference``: that compensation also carries what the calibration found
   of the wearer's relaxed arm, its weight and tissue stiffness).

The runs are in-process: the loop over the simulated rig (:class:`sea_daemon.hw.sim_hw.SimHardware`,
what ``sea-daemon run --sim`` runs), lock-step, no CAN bus.

Per plant: ``effort_reduction`` = 1 − RMS(τ_h,act assisted) / RMS(τ_h,act robot_only) after the
first 2 s (what the controller of the README flow does for the wearer, against an exoskeleton
carrying only itself, as ``python -m benchmarks.assist`` measures it), ``effort_reduction_gated``
the same against the reference run (what the estimate-gated assistance adds to the compensation); ``engaged_share`` (the controller's summary, as ``run`` prints it) and why it was
not engaged (``not_engaged``: fault, invalid, ρ̄ above rho_max, the bound certifying no effort);
while the assistance acts (valid rows with τ_assist ≠ 0) the bound's coverage and the estimate's
error; pushes against the subject while the estimate was not valid; ``faults``.
"""
from __future__ import annotations

import dataclasses
import json
import math
import os
import tempfile
import time
import traceback
from pathlib import Path

import numpy as np
import yaml

from sea_daemon.apps.bench import add_json_argument, json_output, machine
from sea_daemon.apps.bench._family import calibration_motion, draw_plant
from sea_daemon.apps.bench._family_joints import calibration_motion_joints, draw_plant_joints
from sea_daemon.apps.bench.generalize import parse_seeds
from sea_daemon.apps.calibration.joints import plant_substep
from sea_daemon.apps.calibration.modelio import save_calibrated
from sea_daemon.apps.calibration.pipeline import CalibrationOptions, HumanSpec, calibrate, calibrate_log
from sea_daemon.apps.commands.run import run_estimator
from sea_daemon.core.assist import BELOW_BOUND, ENGAGED, STATES
from sea_daemon.core.config import CalibrationConfig
from sea_daemon.core.effects import COULOMB, STRIBECK
from sea_daemon.core.model import SEAModel
from sea_daemon.core.sim.plant import Plant
from sea_daemon.core.sim.session import run_session
from sea_daemon.core.sim.subject import TrackingSubject
from sea_daemon.errors import InputError
from sea_daemon.hw.sim_hw import SimHardware
from sea_daemon.io.configfile import data_root, load_config, load_yaml
from sea_daemon.io.files import atomic_write_text
from sea_daemon.io.scenario import load_scenario
from sea_daemon.runtime.controller import AssistController
from sea_daemon.runtime.loop import FixedRateLoop

DESCRIPTION = __doc__
TASK = data_root() / "configs" / "scenarios" / "assist_track.yaml"
#: the plant seeds looked at while the assistance's settings were chosen (not for headline figures)
DEVELOPMENT_SEEDS = (600, 601, 602)
#: the same for ``--joints 2``: the two-joint family's development seeds (``bench generalize --joints 2``)
DEVELOPMENT_SEEDS_JOINTS = (2, 3, 4)
SKIP_S = 2.0                 # the task's start (the subject settling with the exoskeleton) is not scored


def add_arguments(p) -> None:
    p.add_argument("--seeds", default="610-614", help="plant seeds: 'a-b' or comma list (default 610-614)")
    p.add_argument("--rate", type=float, default=100.0, help="loop rate [Hz] of every plant (default 100)")
    p.add_argument("--seconds", type=float, default=36.0, help="task duration [s] per run (default 36: four cycles)")
    p.add_argument("--cal-s", type=float, default=60.0, help="calibration excitation [s] (default 60)")
    p.add_argument("--joints", type=int, default=1,
                   help="1: the one-joint family; 2: the two-joint family (shoulder-elbow arm from a URDF; default 1)")
    p.add_argument("--out", default=None, help="directory for the model files and arrays (default: a temp dir)")
    p.add_argument("--reuse-calibration", action="store_true",
                   help="use again the model files a calibration of the same plant left in --out (development)")
    add_json_argument(p, "the per-plant figures")


def _check(args) -> list[int]:
    try:
        seeds = parse_seeds(args.seeds)
    except ValueError:
        raise InputError(f"--seeds {args.seeds}: expected 'a-b' or a comma list of integers >= 0") from None
    if not seeds or min(seeds) < 0:
        raise InputError(f"--seeds {args.seeds}: expected 'a-b' or a comma list of integers >= 0")
    if not (math.isfinite(args.rate) and 50.0 <= args.rate <= 2000.0):
        raise InputError(f"--rate {args.rate:g}: must be in [50, 2000] Hz")
    if not (math.isfinite(args.seconds) and 4.0 <= args.seconds <= 3600.0):
        raise InputError(f"--seconds {args.seconds:g}: must be in [4, 3600] s")
    if not (math.isfinite(args.cal_s) and 2.0 <= args.cal_s <= 600.0):
        raise InputError(f"--cal-s {args.cal_s:g}: must be in [2, 600] s")
    if args.joints not in (1, 2):
        raise InputError(f"--joints {args.joints}: must be 1 or 2")
    return seeds


# ---------------------------------------------------------------------------- the README flow
def save_yaml(d: dict, path: Path) -> None:
    """``d`` as YAML to ``path`` (atomically)."""
    atomic_write_text(path, yaml.safe_dump(d, sort_keys=False, default_flow_style=None))


def robot_file(pd, cal_s: float) -> dict:
    """What the user writes for plant ``pd`` (docs/setup.md §2): the nominal robot, its hardware,
    the rate and the ``calibration`` section — the plant's working range and the excitation's
    length; the wearer as the README's example and the defaults declare it (0.1–1 Hz, 1.5 N m RMS:
    a task of moves of seconds, as the tracking task is)."""
    wr = pd.working_range
    cal = CalibrationConfig(q_min_deg=math.degrees(wr.q_min), q_max_deg=math.degrees(wr.q_max), v_max=wr.v_max,
                            a_max=wr.a_max, duration_s=cal_s, seed=0)
    d = dataclasses.replace(pd.nominal, calibration=cal).to_dict()
    return {k: d[k] for k in ("joints", "rate_hz", "model", "hardware", "calibration")}


def calibrated_files(seed: int, rate: float, cal_s: float, out: Path, reuse: bool = False):
    """``calibrate --excitation --fit`` on plant ``seed``, then ``assist.enabled: true`` in the
    model YAML: (plant, path of the assist YAML, path of the model file, calibration figures).
    ``reuse``: the files a calibration of the same robot file left in ``out`` are used again."""
    pd = draw_plant(seed, rate_hz=rate)
    out.mkdir(parents=True, exist_ok=True)
    robot = yaml.safe_dump(robot_file(pd, cal_s), sort_keys=False, default_flow_style=None)
    kept = out / "model_assist.yaml", out / "model.npz", out / "calibration.json"
    if reuse and all(f.is_file() for f in kept) and (out / "robot.yaml").read_text() == robot:
        return pd, kept[0], kept[1], {**json.loads(kept[2].read_text()), "reused": True}
    atomic_write_text(out / "robot.yaml", robot)
    cfg = load_config(out / "robot.yaml")
    t0 = time.perf_counter()
    log = run_session(pd.true, cal_s, reference=calibration_motion(pd, cal_s, seed=seed), seed=1000 + seed)
    res = calibrate_log(log, cfg, load_yaml(out / "robot.yaml"))
    return (pd, *assist_files(res, out, seed, t0))


def calibrated_files_joints(seed: int, rate: float, cal_s: float, out: Path, reuse: bool = False):
    """:func:`calibrated_files` for two-joint plant ``seed`` (:mod:`._family_joints`: the coupled
    shoulder-elbow arm of ``configs/exo_2dof.yaml``, link masses and lengths ±30 %, hidden effects
    per joint): its calibration excitation over each joint's working range, then the n-joint
    calibration with the declared subject and working range, as ``bench generalize --joints 2``."""
    pd = draw_plant_joints(seed, rate_hz=rate)
    out.mkdir(parents=True, exist_ok=True)
    key = json.dumps({"seed": seed, "joints": 2, "rate_hz": pd.nominal.rate_hz, "cal_s": cal_s})
    kept = out / "model_assist.yaml", out / "model.npz", out / "calibration.json"
    if reuse and all(f.is_file() for f in kept) and (out / "plant.json").read_text() == key:
        return pd, kept[0], kept[1], {**json.loads(kept[2].read_text()), "reused": True}
    atomic_write_text(out / "plant.json", key)
    t0 = time.perf_counter()
    log = run_session(pd.true, cal_s, reference=calibration_motion_joints(pd, cal_s, seed=seed), seed=1000 + seed,
                      substep_hz=plant_substep(pd.true, 3e-3, pd.nominal.rate_hz))
    res = calibrate(log, pd.nominal, opts=CalibrationOptions(human=HumanSpec(pd.human_band_hz, pd.human_rms),
                                                             working_range=pd.working_range))
    return (pd, *assist_files(res, out, seed, t0))


def assist_files(res, out: Path, seed: int, t0: float):
    """The calibration ``res`` written as ``calibrate --fit`` writes it, then its model YAML with
    ``assist.enabled: true`` and nothing else changed: (assist YAML, model file, calibration figures)."""
    yaml_path, npz_path = save_calibrated(out / "model", res, {"command": "bench assist", "seed": seed})
    d = load_yaml(yaml_path)
    d.setdefault("assist", {})["enabled"] = True
    save_yaml(d, out / "model_assist.yaml")
    rep = res.report
    info = {"calibration_s": round(time.perf_counter() - t0, 1), "gp_kept": bool(rep.get("gp_kept")),
            "effects": [f"{e['type']}({e['side']})" + (f"[{e['joint']}]" if "joint" in e else "")
                        for e in rep.get("diagnose", {}).get("effects_added", [])],
            "q_tau": rep.get("tau_h_act_walk", {}).get("q_tau")}
    atomic_write_text(out / "calibration.json", json.dumps(info))
    return out / "model_assist.yaml", npz_path, info


# ---------------------------------------------------------------------------- one task run
def task_run(pd, cfg, model_path: Path, task, seconds: float, gain: float | None, seed: int,
             compensation=None) -> dict:
    """The tracking task on plant ``pd`` in the daemon's loop over the simulated rig, with the
    estimator and controller ``run`` builds from ``cfg`` and ``model_path`` (``gain`` 0: no
    assistance; ``compensation``: the configuration whose model the compensation uses, default
    ``cfg``).  The recorded arrays, the fault and the controller's summary."""
    n, dt = cfg.joints, cfg.dt
    ccfg = cfg if compensation is None else dataclasses.replace(cfg, model=compensation.model)
    q0 = np.full(n, math.radians(task.q_deg[0]))
    z = np.zeros(n)
    comp = SEAModel.from_config(ccfg).load_torque(q0, z, z)
    # 1 kHz or the rate, finer where the plant has a stiffer mode (a light distal link)
    kw = dict(seed=seed, substep_hz=plant_substep(pd.true, 3e-3, cfg.rate_hz), sign_eps=3e-3)
    tau0 = Plant(pd.true, q0=q0, **kw).hold_torque - comp        # the subject holds what compensation does not
    plant = Plant(pd.true, q0=q0, tau_h_act0=tau0, **kw)
    subject = TrackingSubject(task, plant, dt, tau0=tau0)
    hw = SimHardware(plant, dt, torque_limit=cfg.hardware.torque_limit, tau_h_act=subject)
    est = run_estimator(cfg, model_path)
    ctl = AssistController(ccfg, gain=gain, subject=subject.tau)
    N = int(round(seconds * cfg.rate_hz))
    # per cycle; per cycle and joint (one column a joint, squeezed for one joint)
    rec = {k: np.zeros(N) for k in ("t", "valid", "hold")}
    rec.update({k: np.zeros((N, n)) for k in ("q", "q_target", "tau_h_act", "hat", "rho", "tau_assist", "state")})
    box = {}

    def on(k, m, e, tau):
        if k >= N:
            return
        t = m.t if m is not None else k * dt
        rec["t"][k] = t
        rec["q"][k] = m.q if m is not None else np.nan
        rec["tau_h_act"][k] = subject(t)          # what the subject applies over [t_k, t_k+1]
        rec["q_target"][k] = subject.q_target
        rec["hold"][k] = float(task.target(t)[1] == 0.0)    # the task holds its target (else a move)
        ok = e is not None and bool(e.valid) and box["loop"].supervisor.ok
        rec["valid"][k] = float(ok)
        rec["hat"][k] = e.tau_h_act_hat if ok else 0.0
        rec["rho"][k] = e.tau_h_act_bound if ok else math.inf
        rec["tau_assist"][k] = ctl.tau_assist if box["loop"].supervisor.ok else 0.0
        rec["state"][k] = ctl.law.state
    t0 = time.perf_counter()
    hw.start(initial_torque=plant.hold_torque)
    try:
        loop = box["loop"] = FixedRateLoop(hw, est, ctl, n, dt, realtime=False, on_cycle=on,
                                           initial_torque=plant.hold_torque)
        loop.run(N)
    finally:
        hw.stop()
    sup = loop.supervisor
    if n == 1:
        rec.update({k: v[:, 0] for k, v in rec.items() if v.ndim == 2})
    rec.update(fault=sup.latched.name, fault_cycle=int(sup.latched_cycle), detail=sup.latched_detail,
               wall_s=time.perf_counter() - t0, summary=ctl.summary(N))
    return rec


def _rms(x) -> float:
    return float(np.sqrt(np.mean(np.square(x)))) if len(x) else 0.0


def joint_view(r: dict, j: int) -> dict:
    """The record of joint ``j`` of :func:`task_run`'s record ``r`` (per-joint arrays as columns)."""
    return {k: v[:, j] if isinstance(v, np.ndarray) and v.ndim == 2 else v for k, v in r.items()}


def run_metrics(r: dict, dt: float) -> dict:
    """The figures of one run after :data:`SKIP_S`: effort, estimate error and coverage overall and
    while the assistance acts, pushes against the subject (while valid and while not)."""
    m = r["t"] >= SKIP_S
    tau_h, ta, valid = r["tau_h_act"][m], r["tau_assist"][m], r["valid"][m] > 0
    # the controller of cycle k acts on the estimate of cycle k - 1
    used = np.concatenate([[False], r["valid"][:-1] > 0])[m]
    err = r["hat"][m] - tau_h
    acts = valid & (ta != 0.0)
    against = (ta * tau_h < 0.0) & (np.abs(ta) > 0.05) & (np.abs(tau_h) > 0.05)
    cover = np.abs(err) <= r["rho"][m]

    def share(mask, of):
        return float(np.mean(mask[of])) if of.any() else None
    return {"tau_h_rms": _rms(tau_h), "assist_rms": _rms(ta), "valid_share": float(np.mean(valid)),
            "acting_share": float(np.mean(acts)),
            "est_rmse_valid": _rms(err[valid]) if valid.any() else None,
            "est_rmse_acting": _rms(err[acts]) if acts.any() else None,
            "coverage_valid": share(cover, valid), "coverage_acting": share(cover, acts),
            "rho_mean_acting": float(np.mean(r["rho"][m][acts])) if acts.any() else None,
            "track_rms_deg": _rms(np.degrees(r["q"][m] - r["q_target"][m])),
            "against_share": float(np.mean(against)),
            "pushes_while_invalid": int(np.sum((~used) & (ta != 0.0))),
            "pushes_against_while_invalid": int(np.sum((~used) & (ta * tau_h < 0.0))),
            "by_phase": {name: phase_metrics(r, m & (r["hold"] == flag)) for name, flag in (("hold", 1.0), ("move", 0.0))},
            "fault": r["fault"], "fault_cycle": r["fault_cycle"], "wall_s": round(r["wall_s"], 1)}


def phase_metrics(r: dict, mask) -> dict:
    """The controller's states (:data:`~sea_daemon.core.assist.STATES`) over the scored cycles of one
    phase of the task (``mask``: its holds or its moves), the published bound's median there (valid
    rows) and the subject's torque there: where the engaged time is lost, and against what."""
    n = int(mask.sum())
    if not n:
        return {"share": 0.0}
    st = np.bincount(r["state"][mask].astype(np.int64), minlength=len(STATES))
    ok = mask & (r["valid"] > 0)
    return {"share": n / float(np.sum(r["t"] >= SKIP_S)),
            "engaged_share": float(st[ENGAGED] / n), "available_share": float((st[ENGAGED] + st[BELOW_BOUND]) / n),
            "states": {name: int(st[i]) for i, name in enumerate(STATES)},
            "rho_median": float(np.median(r["rho"][ok])) if ok.any() else None,
            "tau_h_rms": _rms(r["tau_h_act"][mask])}


def friction_at_rest(cfg, j: int = 0) -> float:
    """The declared load-side friction's magnitude at rest on joint ``j`` (Coulomb F_c plus Stribeck
    F_s) [N m]: at standstill the subject's torque is known only up to it, whatever the estimator."""
    return float(sum(abs(e.vector[0]) for e in cfg.model.effects
                     if e.side == "load" and e.joint == j and e.code in (COULOMB, STRIBECK)))


def run_plant(seed: int, args, task, out: Path) -> dict:
    """The README flow and the three task runs on plant ``seed``: its row of the JSON (with two
    joints, the figures of each joint under ``joints`` and at the top the smallest of them)."""
    row: dict = {"seed": seed, "rate_hz": args.rate, "effort_reduction": None, "engaged_share": None, "faults": []}
    files = calibrated_files_joints if args.joints == 2 else calibrated_files
    try:
        pd, yaml_path, npz_path, info = files(seed, args.rate, args.cal_s, out / f"plant_{seed}",
                                              reuse=args.reuse_calibration)
    except Exception as e:        # a calibration that refuses or fails is this plant's result
        row.update(calibration_error=f"{type(e).__name__}: {e}"[:400], faults=["calibration: refused or failed"])
        return row
    row.update(plant=pd.summary, calibration=info)
    cfg = load_config(yaml_path)
    robot = pd.nominal if args.joints == 2 else load_config(yaml_path.parent / "robot.yaml")
    n = cfg.joints
    runs, per = {}, {}
    for name, gain, comp in (("reference", 0.0, None), ("assisted", None, None), ("robot_only", 0.0, robot)):
        try:
            r = task_run(pd, cfg, npz_path, task, args.seconds, gain, seed=3000 + seed, compensation=comp)
        except Exception as e:    # an internal error of a run is a benchmark result, with its trace
            row["faults"].append(f"{name}: internal error {type(e).__name__}: {e}"[:300])
            row.setdefault("traceback", traceback.format_exc()[-1500:])
            return row
        per[name] = [run_metrics(joint_view(r, j), cfg.dt) for j in range(n)]
        runs[name] = {**per[name][0], "controller": r["summary"]} if n == 1 else \
            {"joints": per[name], "controller": r["summary"]}
        if r["fault"] != "NONE":
            row["faults"].append(f"{name}: {r['fault']} at cycle {r['fault_cycle']}: {r['detail']}"[:300])
        if args.out:
            np.savez(out / f"plant_{seed}" / f"{name}.npz", **{k: v for k, v in r.items() if isinstance(v, np.ndarray)})
    s = runs["assisted"]["controller"]
    rows = [joint_row(per["assisted"][j], per["reference"][j], per["robot_only"][j], friction_at_rest(cfg, j))
            for j in range(n)]
    row.update(engaged_share=s["engaged_share"], available_share=s["available_share"], not_engaged=s["not_engaged"],
               rho_avg_mean=s["rho_avg_mean"])
    if n == 1:
        row.update(rows[0])
    else:
        for j, jr in enumerate(rows):
            sj = s["joints"][j]
            jr.update(joint=j + 1, engaged_share=sj["engaged_share"], available_share=sj["available_share"],
                      not_engaged=sj["not_engaged"], rho_avg_mean=sj["rho_avg_mean"])
        row.update({k: _least([jr[k] for jr in rows]) for k in ("effort_reduction", "effort_reduction_gated",
                                                                 "coverage_acting")},
                   pushes_against_while_invalid=sum(jr["pushes_against_while_invalid"] for jr in rows), joints=rows)
    row["runs"] = runs
    return row


def joint_row(ass: dict, ref: dict, rob: dict, friction: float) -> dict:
    """One joint's figures of a plant from its metrics in the three runs (:func:`run_metrics`)."""
    return {"effort_reduction": 1.0 - ass["tau_h_rms"] / rob["tau_h_rms"] if rob["tau_h_rms"] > 0 else None,
            "effort_reduction_gated": 1.0 - ass["tau_h_rms"] / ref["tau_h_rms"] if ref["tau_h_rms"] > 0 else None,
            "coverage_acting": ass["coverage_acting"], "pushes_against_while_invalid": ass["pushes_against_while_invalid"],
            "by_phase": ass["by_phase"], "friction_at_rest": friction}


def _least(xs):
    """The smallest of the figures that exist (None if none does)."""
    xs = [x for x in xs if x is not None]
    return min(xs) if xs else None


# ---------------------------------------------------------------------------- main
def run(args) -> int:
    seeds = _check(args)
    write = json_output(args)
    out = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="bench-assist-"))
    out.mkdir(parents=True, exist_ok=True)
    task = load_scenario(TASK).task
    dev = DEVELOPMENT_SEEDS_JOINTS if args.joints == 2 else DEVELOPMENT_SEEDS
    used = sorted(set(seeds) & set(dev))
    print(f"bench assist: {len(seeds)} {'two-joint ' if args.joints == 2 else ''}plant(s) (seeds {args.seeds}) at "
          f"{args.rate:g} Hz, calibration "
          f"{args.cal_s:g} s, task {args.seconds:g} s x 3 runs, in-process (the loop over the simulated rig, no "
          f"CAN); {machine()}; output {out}", flush=True)
    if used:
        print(f"bench assist: note: seeds {used} were looked at while choosing the assistance's settings", flush=True)
    rows = []
    for seed in seeds:
        row = run_plant(seed, args, task, out)
        rows.append(row)
        print(describe_row(row), flush=True)
        write(_report(args, rows))
    report = _report(args, rows)
    write(report)
    print(describe_summary(report["summary"]))
    print(f"(load average {os.getloadavg()[0]:.2f})")
    return 0


def _report(args, rows: list[dict]) -> dict:
    red = [r["effort_reduction"] for r in rows if r["effort_reduction"] is not None]
    gated = [r["effort_reduction_gated"] for r in rows if r.get("effort_reduction_gated") is not None]
    eng = [r["engaged_share"] for r in rows if r["engaged_share"] is not None]
    avail = [r["available_share"] for r in rows if r.get("available_share") is not None]
    cov = [r["coverage_acting"] for r in rows if r.get("coverage_acting") is not None]
    summary = {"plants": len(rows), "effort_reduction_min": min(red) if red else None,
               "effort_reduction_gated_min": min(gated) if gated else None,
               "engaged_share_min": min(eng) if eng else None, "available_share_min": min(avail) if avail else None,
               "coverage_acting_min": min(cov) if cov else None,
               "plants_with_faults": sum(1 for r in rows if r["faults"]),
               "pushes_against_while_invalid": sum(r.get("pushes_against_while_invalid", 0) for r in rows)}
    return {"benchmark": "assist", "joints": args.joints, "rate_hz": args.rate, "seconds": args.seconds, "cal_s": args.cal_s,
            "seeds": args.seeds, "machine": machine(),
            "development_seeds": list(DEVELOPMENT_SEEDS_JOINTS if args.joints == 2 else DEVELOPMENT_SEEDS),
            "rig": "in-process: the daemon's loop over the simulated rig (SimHardware), lock-step, no CAN",
            "summary": summary, "plants": rows}


def _pct(x) -> str:
    return "n/a" if x is None else f"{100 * x:.1f} %"


def _f3(x) -> str:
    return "n/a" if x is None else f"{x:.3f}"


def describe_row(row: dict) -> str:
    if "runs" not in row:
        return f"plant {row['seed']}: " + "; ".join(row["faults"])
    runs = row["runs"]
    ne = ", ".join(f"{k} {v}" for k, v in row["not_engaged"].items() if v) or "none"
    head = (f"plant {row['seed']}: effort reduction {_pct(row['effort_reduction'])} (the gated assistance's part "
            f"{_pct(row['effort_reduction_gated'])}), engaged {_pct(row['engaged_share'])}, available "
            f"{_pct(row['available_share'])} (not engaged, cycles: {ne}; mean averaged bound "
            f"{_f3(row['rho_avg_mean'])} N m); ")
    tail = f"; faults: {'; '.join(row['faults']) or 'none'}"
    if "joints" not in row:
        return head + _describe_acting(runs["assisted"], runs["reference"]) + tail + describe_phases(row)
    lines = [head.rstrip("; ") + tail]
    for j, jr in enumerate(row["joints"]):
        lines.append(f"  joint {jr['joint']}: effort reduction {_pct(jr['effort_reduction'])} (gated part "
                     f"{_pct(jr['effort_reduction_gated'])}), engaged {_pct(jr['engaged_share'])}, available "
                     f"{_pct(jr['available_share'])}; "
                     + _describe_acting(runs["assisted"]["joints"][j], runs["reference"]["joints"][j])
                     + describe_phases(jr).replace("\n  ", "\n    "))
    return "\n".join(lines)


def _describe_acting(a: dict, ref: dict) -> str:
    """While assisting and in the reference run: coverage and error of one joint."""
    return (f"while assisting: coverage {_f3(a['coverage_acting'])}, RMSE {_f3(a['est_rmse_acting'])}, mean rho "
            f"{_f3(a['rho_mean_acting'])} N m; reference run: RMSE {_f3(ref['est_rmse_valid'])}, coverage "
            f"{_f3(ref['coverage_valid'])}; pushes against the subject while invalid {a['pushes_against_while_invalid']}")


def describe_phases(row: dict) -> str:
    """The holds' and the moves' part of :func:`describe_row`: where the engaged time went."""
    parts = []
    for name, label in (("hold", "holds"), ("move", "moves")):
        p = row.get("by_phase", {}).get(name, {})
        if p.get("share"):
            parts.append(f"{label} ({_pct(p['share'])} of the task): engaged {_pct(p['engaged_share'])}, available "
                         f"{_pct(p['available_share'])}, median rho {_f3(p['rho_median'])} N m, the subject's torque "
                         f"{_f3(p['tau_h_rms'])} N m RMS")
    if not parts:
        return ""
    return f"\n  {'; '.join(parts)}; declared load friction at rest {_f3(row.get('friction_at_rest'))} N m"


def describe_summary(s: dict) -> str:
    return (f"{s['plants']} plant(s): effort reduction min {_pct(s['effort_reduction_min'])} (the gated assistance's "
            f"part min {_pct(s['effort_reduction_gated_min'])}), engaged share min "
            f"{_pct(s['engaged_share_min'])}, available share min {_pct(s.get('available_share_min'))}, coverage while "
            f"assisting min {_f3(s['coverage_acting_min'])}, plants with "
            f"faults {s['plants_with_faults']}, pushes against the subject while invalid "
            f"{s['pushes_against_while_invalid']}")
