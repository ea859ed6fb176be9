"""``sea-daemon bench generalize --joints 2``: calibrate once, hold everywhere, for two coupled joints.

The one-joint benchmark (:mod:`.generalize`) over the two-joint family (:mod:`._family_joints`:
the shoulder–elbow example with every link's mass and length ±30 %, hidden effects per joint,
the SEA part ±30 %): each plant calibrated ONCE on a passive session of the multi-joint
calibration excitation over its declared working ranges
(:func:`~sea_daemon.core.excitation.excitation_joints`) with the whole calibration
(:func:`~sea_daemon.apps.calibration.pipeline.calibrate`), then the same estimators on the
same kinds of held-out sessions, on both joints at once.  Every figure is taken per joint
(``joints`` of each result: RMSE, bound, coverage of that joint's τ̂_h,act), and the summary is
the one-joint summary per joint (``summary.joints["1"]``, ``["2"]``: GP-AKF / oracle AKF
median and p90, coverage, the bound's size) plus the targets of a two-joint arm per joint
(:data:`DONE_WHEN`).

Seeds: the two-joint plants are their own family (plant ``s`` of ``--joints 2`` is not plant
``s`` of one joint).  :data:`DEVELOPMENT_SEEDS` chose settings of the two-joint calibration;
the headline figures use other seeds, and the output names each seed development or held out.
"""
from __future__ import annotations

import dataclasses
import json
import multiprocessing as mp
import os
import time
import traceback
from pathlib import Path

import numpy as np

from sea_daemon.apps.bench import machine
from sea_daemon.apps.bench._family_joints import (HOLD, SESSIONS_REV, calibration_motion_joints, draw_plant_joints,
                                                  sessions_joints)
from sea_daemon.apps.bench._degenerate import timed_replay
from sea_daemon.apps.bench._family import noise_seeds
from sea_daemon.apps.bench._logcache import load_logs, producer, save_logs
from sea_daemon.analysis.passive_noise import passive_noise, walk_for_noise
from sea_daemon.apps.calibration.joints import plant_substep
from sea_daemon.apps.calibration.pipeline import CalibrationOptions, HumanSpec, calibrate
from sea_daemon.core.bounds.akf_bound import theorem_bound
from sea_daemon.core.estimators.akf import AKF
from sea_daemon.core.sim.session import run_session
from sea_daemon.io.configfile import data_root
from sea_daemon.io.files import atomic_write_text

#: the two-joint plant seeds used while building the two-joint calibration (not for headline figures):
#: 2–4, whose first run (diagnose's per-joint stand-ins for wrong link masses, passive sessions up to
#: 1.8 N m) led to correcting the wearer's arm before diagnose, and whose second (an exoskeleton link's
#: length, undeclared friction and tissue bending the arm's factors; one walk for both joints) to
#: correcting every link with the friction and a stiffness fitted beside, and a walk per joint
DEVELOPMENT_SEEDS = (2, 3, 4)
#: what makes the two-joint family's logs (the cache key's producer, :func:`._logcache.producer`):
#: the family and the session simulator (with every module they import), the family's base model and its URDF
PRODUCER_JOINTS = ("sea_daemon.apps.bench._family_joints", "sea_daemon.core.sim.session")
PRODUCER_FILES_JOINTS = tuple(data_root() / "configs" / f for f in ("exo_2dof.yaml", "exo_2dof_arm.urdf"))
#: what the held-out seeds must show per joint: GP-AKF / oracle AKF median and p90 at most, the
#: largest passive RMSE [N m], the bound's coverage of every session at least, and its mean at
#: most this many times the RMSE on active sessions
DONE_WHEN = {"gp_over_oracle_median": 1.5, "gp_over_oracle_p90": 3.0, "passive_rmse": 0.05, "coverage": 0.95,
             "active_bound_over_rmse": 3.0}


def plant_logs_joints(seed: int, cal_s: float, cache: Path | None, rate_hz: float | None = None):
    """(plant, calibration log, {session: log}) of two-joint plant ``seed``, simulated or from the cache."""
    pd = draw_plant_joints(seed, rate_hz)
    name = f"joints2_plant_{seed}_{int(cal_s)}_{pd.nominal.rate_hz:g}hz"
    p = None if cache is None else cache / f"{name}.npz"
    specs = sessions_joints(pd)
    seeds = noise_seeds(seed, len(specs))
    sub = plant_substep(pd.true, 3e-3, pd.nominal.rate_hz)
    key = {"seed": seed, "joints": 2, "cal_s": cal_s, "rate_hz": pd.nominal.rate_hz,
           "sessions": [s.name for s in specs], "sessions_rev": SESSIONS_REV, "noise_seeds": seeds,
           "substep_hz": sub, "hold": list(HOLD), "producer": producer(PRODUCER_JOINTS, PRODUCER_FILES_JOINTS)}
    logs = None if p is None else load_logs(p, key)
    if logs is not None and "calibration" in logs:
        cal = logs.pop("calibration")
        return pd, cal, logs
    cal = run_session(pd.true, cal_s, reference=calibration_motion_joints(pd, cal_s, seed=seed),
                      seed=seeds["calibration"], substep_hz=sub)
    tests = {}
    for s, noise_seed in zip(specs, seeds["sessions"]):
        tests[s.name] = run_session(pd.true, s.duration_s, reference=s.reference, hold_q=s.hold_q, human=s.human,
                                    seed=noise_seed, substep_hz=sub, hold=HOLD if s.hold_q is not None else None)
    if p is not None:
        save_logs(p, key, {"calibration": cal} | tests)
    return pd, cal, tests


def _joint_stats(e: np.ndarray, rho: np.ndarray, v: np.ndarray, bound: bool) -> dict:
    """The figures of one joint's error ``e`` (and bound ``rho``, valid samples ``v``) as
    :func:`~._degenerate.score_replay` gives them for one joint."""
    out = {"rmse": float(np.sqrt(np.mean(e ** 2))), "mean_abs": float(np.mean(np.abs(e))),
           "max_abs": float(np.max(np.abs(e))), "finite": bool(np.all(np.isfinite(e)))}
    if bound:
        inside = np.abs(e) <= rho
        out["bound"] = {"coverage": float(np.mean(inside)), "mean_rho": float(np.mean(rho)),
                        "ratio": float(np.mean(rho) / max(np.mean(np.abs(e)), 1e-12)),
                        "valid_share": float(np.mean(v)),
                        "coverage_valid": float(np.mean(inside[v])) if v.any() else None,
                        "mean_rho_valid": float(np.mean(rho[v])) if v.any() else None,
                        "rmse_valid": float(np.sqrt(np.mean(e[v] ** 2))) if v.any() else None}
    return out


def score_joints(log, est, bound: bool = False) -> dict:
    """Replay ``est`` over ``log``: the RMSE over all joints, whether every output is finite, µs per
    step, and per joint (``joints``) its own figures (:func:`_joint_stats`); ``{"fault": ...}``
    when the estimator stops on a typed fault."""
    r, base = timed_replay(log, est)
    if r is None:
        return base
    e = r.tau_h_act_hat - log.tau_h_act
    v = r.valid if r.valid is not None else np.ones(len(log), dtype=bool)
    return {"rmse": float(np.sqrt(np.mean(e ** 2))), **base,
            "joints": [_joint_stats(e[:, j], r.tau_h_act_bound[:, j], v, bound) for j in range(e.shape[1])]}


def passive_noise_record(cfg, walk: dict, pd) -> dict | None:
    """The calibrated filter's computed passive noise per joint at its walk and the walk that keeps
    it at :data:`DONE_WHEN`'s passive RMSE (:mod:`sea_daemon.analysis.passive_noise`; the arm at rest
    in the middle of its declared ranges); None for the integrated walk or a filter that does not settle."""
    if cfg.estimator.integrated or "q_tau" not in walk:
        return None
    q = np.array([0.5 * (w.q_min + w.q_max) for w in pd.working_range])
    try:
        p = passive_noise(cfg, walk.get("q_tau_per_joint", walk["q_tau"]), q=q)
        target = DONE_WHEN["passive_rmse"]
        return {**p.to_dict(), "walk_for_target": walk_for_noise(cfg, target, q=q).tolist(), "target": target}
    except ValueError:
        return None


def calibrate_plant(cal, pd, row: dict, tau_model: str | None = None, walk_for: str = "estimate"):
    """The calibration of plant ``pd`` on its log ``cal`` (its declared subject and working range)
    with the filter's τ_h,act model ``tau_model`` (``estimator.tau_h_act_model``; None: the plant's
    configured one), its walk chosen for ``walk_for`` (``calibration.walk_for``);
    ``row["calibration_s"]`` its time, or, for an internal error (a benchmark result), None and
    ``row["calibration_error"]``."""
    nom = pd.nominal
    if tau_model is not None:
        pd = dataclasses.replace(pd, nominal=dataclasses.replace(
            nom, estimator=nom.estimator.with_tau_model(tau_model, nom.joints)))
    try:
        t0 = time.perf_counter()
        res = calibrate(cal, pd.nominal, opts=CalibrationOptions(human=HumanSpec(pd.human_band_hz, pd.human_rms),
                                                                 working_range=pd.working_range, walk_for=walk_for))
        row["calibration_s"] = time.perf_counter() - t0
        return res
    except Exception as e:        # an internal error of the calibration is a benchmark result
        row["calibration_error"] = f"{type(e).__name__}: {e}"
        row["traceback"] = traceback.format_exc()[-2000:]
        return None


def run_plant_joints(seed: int, cal_s: float, cache: Path | None, estimators, bound_mode: str,
                     rate_hz: float | None = None, names=None, tau_model: str = "walk",
                     walk_for: str = "estimate") -> dict:
    """Calibrate two-joint plant ``seed`` once and run every estimator on every test session."""
    t0 = time.perf_counter()
    pd, cal, tests = plant_logs_joints(seed, cal_s, cache, rate_hz)
    if names is not None:
        tests = {k: v for k, v in tests.items() if k in names}
    row: dict = {"seed": seed, "joints": 2, "rate_hz": pd.nominal.rate_hz, "plant": pd.summary, "tau_h_act_model": tau_model,
                 "walk_for": walk_for, "session_kinds": {sp.name: sp.kind for sp in sessions_joints(pd)}, "simulation_s": time.perf_counter() - t0}
    t0 = time.perf_counter()
    res = calibrate_plant(cal, pd, row, tau_model, walk_for)
    if res is None:
        return row
    rep = res.report
    row["calibration"] = {"effects": [f"{d['type']}({d['side']})[{d.get('joint', 1)}]"
                                      for d in rep.get("diagnose", {}).get("effects_added", [])],
                          "nominal_joints": rep.get("diagnose", {}).get("nominal_joints", []),
                          "q_tau": rep["tau_h_act_walk"].get("q_tau"), "gp_kept": rep["gp_kept"],
                          "gp_cv": rep.get("gp_cv"), "leftover": rep["leftover"], "coverage": rep["coverage"],
                          "passive_noise": passive_noise_record(res.cfg, rep["tau_h_act_walk"], pd)}
    do_bound = bound_mode == "all" or (bound_mode == "100hz" and pd.nominal.rate_hz <= 200)
    cfg = res.cfg
    robot = dataclasses.replace(pd.nominal, estimator=dataclasses.replace(cfg.estimator, nis_scale=1e12),
                                kinematics=cfg.kinematics)
    oracle = dataclasses.replace(pd.true, estimator=cfg.estimator, kinematics=cfg.kinematics)
    make = {"gp-akf": lambda dt: res.estimator(dt=dt, bound=theorem_bound if do_bound else None),
            "akf-aug": lambda dt: res.estimator(dt=dt, kind="akf"),
            "akf-robot": lambda dt: AKF(robot, dt=dt), "oracle": lambda dt: AKF(oracle, dt=dt)}
    row["sessions"] = {}
    for name, log in tests.items():
        r = {}
        for lab in estimators:
            try:
                r[lab] = score_joints(log, make[lab](log.dt), bound=do_bound and lab == "gp-akf")
            except Exception as e:     # an internal error of an estimator is a benchmark result
                r[lab] = {"internal_error": f"{type(e).__name__}: {e}", "traceback": traceback.format_exc()[-1500:]}
        row["sessions"][name] = r
    row["wall_s"] = time.perf_counter() - t0 + row["simulation_s"]
    return row


def joint_view(rows: list[dict], j: int) -> list[dict]:
    """The rows with each estimator's result replaced by joint ``j``'s (a fault or an error stays as
    it is): what the one-joint summaries read."""
    out = []
    for row in rows:
        v = {k: x for k, x in row.items() if k != "sessions"}
        if "sessions" in row:
            v["sessions"] = {name: {lab: (res["joints"][j] if "joints" in res else res) for lab, res in r.items()}
                             for name, r in row["sessions"].items()}
        out.append(v)
    return out


def done_when(view: list[dict]) -> dict:
    """One joint's figures against :data:`DONE_WHEN`: the largest passive RMSE of the GP-AKF, the
    smallest coverage (of the valid samples) and the largest mean bound / RMSE on active sessions."""
    passive, cover, ratio = [], [], []
    for row in view:
        kinds = row.get("session_kinds", {})
        for name, r in row.get("sessions", {}).items():
            g = r.get("gp-akf", {})
            if "rmse" not in g:
                continue
            if kinds.get(name) == "passive":
                passive.append(g["rmse"])
            b = g.get("bound")
            if b:
                cover.append(b["coverage_valid"] if b.get("coverage_valid") is not None else b["coverage"])
                if kinds.get(name) != "passive" and b.get("rmse_valid"):
                    ratio.append(b["mean_rho_valid"] / b["rmse_valid"])
    worst = {"passive_rmse_max": max(passive, default=None), "coverage_min": min(cover, default=None),
             "active_bound_over_rmse_max": max(ratio, default=None),
             "active_bound_over_rmse_median": float(np.median(ratio)) if ratio else None}
    held = {"passive_rmse": None if not passive else worst["passive_rmse_max"] <= DONE_WHEN["passive_rmse"],
            "coverage": None if not cover else worst["coverage_min"] >= DONE_WHEN["coverage"],
            "active_bound_over_rmse": None if not ratio else
            worst["active_bound_over_rmse_max"] <= DONE_WHEN["active_bound_over_rmse"]}
    return {**worst, "held": held}


def _job(a) -> dict:
    return run_plant_joints(*a)


def summarize_joints(rows: list[dict], summarize, by_rate) -> dict:
    """The one-joint summary (``summarize``, ``by_rate`` of :mod:`.generalize`) per joint, each with
    its :func:`done_when` on the held-out seeds."""
    out: dict = {"plants": len(rows), "calibration_errors": sum(1 for r in rows if "calibration_error" in r),
                 "seeds": seed_roles_joints([r["seed"] for r in rows]), "joints": {}}
    held = [r for r in rows if r["seed"] not in DEVELOPMENT_SEEDS]
    dev = [r for r in rows if r["seed"] in DEVELOPMENT_SEEDS]
    for j in range(2):
        d = summarize(joint_view(rows, j))
        d["by_rate"] = by_rate(joint_view(held, j))
        d["done_when"] = done_when(joint_view(held, j))
        if dev:
            d["by_rate_development"] = by_rate(joint_view(dev, j))
            d["done_when_development"] = done_when(joint_view(dev, j))
        out["joints"][str(j + 1)] = d
    return out


def seed_roles_joints(seeds) -> dict:
    """The seeds of a two-joint run named: development (they chose settings) and held out."""
    dev = sorted(set(seeds) & set(DEVELOPMENT_SEEDS))
    return {"development": dev, "held_out": sorted(set(seeds) - set(dev))}


def run_joints(args, seeds, rates, names, est, out: Path, cache, summarize, by_rate) -> int:
    """``bench generalize --joints 2``: every two-joint plant and rate calibrated and tested; results.json
    with the per-joint summary (:func:`summarize_joints`)."""
    roles = seed_roles_joints(seeds)
    print(f"bench generalize --joints 2: seeds held out {roles['held_out'] or 'none'}; development seeds "
          f"{roles['development'] or 'none'}; {len(seeds)} plants, rates {args.rates or '100 Hz'}, calibration "
          f"{args.cal_s:g} s, estimators {', '.join(est)}, bound {args.bound}; {machine()}", flush=True)
    jobs = [(s, args.cal_s, cache, est, args.bound, r, names, args.tau_model, args.walk_for) for s in seeds for r in rates]
    rows = []
    with mp.get_context("fork").Pool(max(1, min(args.jobs, len(jobs)))) as pool:
        for row in pool.imap_unordered(_job, jobs):
            rows.append(row)
            print_row_joints(row)
            atomic_write_text(out / "results.json", json.dumps({"rows": rows}, indent=1, default=float))
    rows.sort(key=lambda r: (r["seed"], r["rate_hz"]))
    summary = summarize_joints(rows, summarize, by_rate)
    atomic_write_text(out / "results.json", json.dumps({"summary": summary, "rows": rows}, indent=1, default=float))
    for j, d in summary["joints"].items():
        for key, label in (("done_when", "held-out seeds"), ("done_when_development", "development seeds")):
            if key not in d:
                continue
            w = d[key]
            rates_key = "by_rate" if key == "done_when" else "by_rate_development"
            for rate, b in d[rates_key].items():
                g = b["gp_over_oracle"]
                print(f"joint {j}, {rate} Hz, {label} {b['plants']}: GP-AKF / oracle median {_f(g['median'])} "
                      f"(<= 1.5), p90 {_f(g['p90'])} (<= 3)", flush=True)
            print(f"joint {j}, {label}: passive RMSE max {_f(w['passive_rmse_max'])} N m (<= 0.05); coverage min "
                  f"{_f(w['coverage_min'])} (>= 0.95); active mean bound / RMSE max "
                  f"{_f(w['active_bound_over_rmse_max'])} (<= 3), median {_f(w['active_bound_over_rmse_median'])}",
                  flush=True)
    print(f"results: {out / 'results.json'}  (load average {os.getloadavg()[0]:.2f})")
    return 0


def _f(x) -> str:
    return "-" if x is None else f"{x:.3f}"


def print_row_joints(row: dict) -> None:
    """One plant's line and, per session, each estimator's RMSE per joint and the GP-AKF's bound."""
    if "calibration_error" in row:
        print(f"plant {row['seed']} (2 joints): CALIBRATION ERROR {row['calibration_error']}", flush=True)
        return
    c = row["calibration"]
    print(f"plant {row['seed']} (2 joints, {'development' if row['seed'] in DEVELOPMENT_SEEDS else 'held out'}, "
          f"{row['rate_hz']:g} Hz): effects {', '.join(c['effects']) or 'none'}; q_tau {c['q_tau']:.3g}, gp "
          f"{'kept' if c['gp_kept'] else 'off'}, calibration {row['calibration_s']:.0f} s", flush=True)
    pn = c.get("passive_noise")
    if pn:
        print(f"  computed passive noise at the walk {'/'.join(f'{v:.3f}' for v in pn['rms'])} N m; walk for <= "
              f"{pn['target']:g} N m: {'/'.join(f'{v:.3g}' for v in pn['walk_for_target'])}", flush=True)
    for name, r in row["sessions"].items():
        cells = []
        for k, v in r.items():
            cells.append(f"{k} " + ("/".join(f"{x['rmse']:.3f}" for x in v["joints"]) if "joints" in v else
                                    ("FAULT" if "fault" in v else "ERROR")))
        g = r.get("gp-akf", {})
        if "joints" in g and "bound" in g["joints"][0]:
            cells.append("bound cov " + "/".join(f"{x['bound']['coverage']:.3f}" for x in g["joints"]) + " mean "
                         + "/".join(f"{x['bound']['mean_rho']:.3f}" for x in g["joints"]))
        print(f"  {name:12s} " + "  ".join(cells), flush=True)
