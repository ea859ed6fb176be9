"""``sea-daemon bench generalize``: calibrate once, hold everywhere (docs/calibration.md).

A family of random plants (:mod:`._family`: nominal robot ±30 %, hidden effects in and outside
the vocabulary, noise levels, encoder resolutions, 100 Hz and 1 kHz).  Each plant is
calibrated ONCE on a passive session — the calibration excitation over its declared working
range (:func:`sea_daemon.calibration.excitation.excitation`) — with the whole calibration
(:func:`sea_daemon.calibration.pipeline.calibrate`: the nominal robot model and the log are
its only inputs, plus the declared human-torque band), then tested on sessions unlike it
(:func:`._family.sessions`: slower, faster, wider, other shapes, active subjects at 0.1–3 Hz
while moving, still-arm active sessions).  Per session:

* ``gp-akf``     the GP-AKF on the calibrated model (augmented physics + residual GP weighted
                 by its variance; the AKF when the calibration kept no GP);
* ``akf-robot``  the AKF on the nominal robot model alone, with the calibrated noise settings;
* ``akf-aug``    the AKF on the augmented physical model (diagnose's effects), same settings;
* ``oracle``     the AKF on the true plant (every hidden effect declared), same settings;

RMSE of τ̂_h,act, faults (typed EstimatorFault), non-finite outputs, and — with ``--bound`` —
the Theorem-1 bound ρ_k of the GP-AKF with the guaranteed (Lederer et al. 2019) β: coverage
of all samples and of the samples marked valid, the share valid, mean ρ / mean |error|.  Per
rate (:func:`by_rate`): GP-AKF / oracle median and 90th percentile, each session's coverage and
the smallest, the bound's size against :data:`TIGHT`, each target of :data:`TARGETS` met or not.

``--rates``: each plant drawn at each rate given (default the seed's own).  ``--degenerate``:
each plant calibrated instead on degenerate logs by ``sea-daemon fit`` (:mod:`._degenerate`).

``--joints 2``: the two-joint shoulder–elbow family instead (:mod:`._generalize_joints`: the same
options and summary, the figures per joint).

Seeds: ``--seeds`` (default ``420-439``).  The seeds that chose any setting of the calibration
are 0–5, 100–119, 201, 209 and 400–419 (:data:`DEVELOPMENT_SEEDS`); the headline figures use
other seeds, and the output names each seed development or held out.
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

from sea_daemon.apps.bench import choose, machine
from sea_daemon.apps.bench._degenerate import (print_case, run_degenerate_plant, score_replay,
                                                summarize_degenerate)
from sea_daemon.apps.bench._family import DEGENERATE, REFERENCE, calibration_motion, draw_plant, noise_seeds, sessions
from sea_daemon.apps.bench._logcache import load_logs, private_dir, producer, save_logs
from sea_daemon.apps.bench._degenerate_joints import run_degenerate_plant_joints
from sea_daemon.apps.bench._family_joints import DEGENERATE_JOINTS, draw_plant_joints
from sea_daemon.apps.bench._generalize_joints import calibrate_plant, run_joints, seed_roles_joints
from sea_daemon.apps.progress import Progress
from sea_daemon.core.bounds.akf_bound import theorem_bound
from sea_daemon.core.estimators.akf import AKF
from sea_daemon.core.sim.session import run_session
from sea_daemon.errors import InputError
from sea_daemon.io.configfile import data_root
from sea_daemon.io.files import atomic_write_text, check_output_dir

ESTIMATORS = ("gp-akf", "akf-robot", "akf-aug", "oracle")
#: what makes the one-joint family's logs (the cache key's producer, :func:`._logcache.producer`):
#: the family and the session simulator (with every module they import), the family's base model
PRODUCER = ("sea_daemon.apps.bench._family", "sea_daemon.core.sim.session")
PRODUCER_FILES = (data_root() / "configs" / "exo_1dof.yaml",)
#: the plant seeds used while choosing the calibration's settings (not for headline figures):
#: 0–5 for the calibration's steps; 100–119 for the GP weight's reference (plants 101 and 104,
#: 1 kHz, active subject 0.5–3 Hz, inspected; the others' figures looked at); 201 and 209 (inspected
#: after a run of 200–219: the GP's target, and the GP's mean on 209's still_band session);
#: 400–419 (a run whose plants 402 and 403 showed that diagnose must not refuse a spring term
#: whose gain shows on one balance only); the degenerate calibrations (``--degenerate``) were built and
#: first run on 400 and 401
DEVELOPMENT_SEEDS = tuple(range(6)) + tuple(range(100, 120)) + (201, 209) + tuple(range(400, 420))
#: the held-out sessions of every plant (:func:`._family.sessions`)
SESSION_NAMES = tuple(sp.name for sp in sessions(draw_plant(0)))
#: what the held-out seeds must show, per rate: GP-AKF / oracle AKF median and 90th percentile
#: at most; in every session, the bound's coverage of the valid samples and the share valid at least
TARGETS = {"gp_over_oracle_median": 1.5, "gp_over_oracle_p90": 3.0, "coverage": 0.95, "valid_share": 0.95}
#: the largest mean bound over the valid samples [N m] of a passive and of an active session at
#: 100 Hz (rates up to 200 Hz) and at 1 kHz (above); at 1 kHz an active session's is 3 × its RMSE
TIGHT = {("passive", 100): 0.3, ("active", 100): 0.3, ("passive", 1000): 0.1}
TIGHT_RMSE_FACTOR = 3.0


def add_arguments(p) -> None:
    p.add_argument("--seeds", default="420-439", help="plant seeds: 'a-b' or comma list (default 420-439)")
    p.add_argument("--out", default="bench_generalize", help="directory for results.json and the cache")
    p.add_argument("--cal-s", type=float, default=60.0, help="calibration session length [s] (default 60)")
    p.add_argument("--bound", choices=("none", "100hz", "all"), default="100hz",
                   help="Theorem-1 bound (guaranteed beta) of the GP-AKF: on no plant, the 100 Hz plants, all")
    p.add_argument("--estimators", default=",".join(ESTIMATORS), help="comma list of " + ", ".join(ESTIMATORS))
    p.add_argument("--jobs", type=int, default=1, help="plants in parallel (processes)")
    p.add_argument("--no-cache", action="store_true", help="re-simulate even if the cache has the logs")
    p.add_argument("--rates", default=None,
                   help="comma list of rates [Hz] each plant is drawn at (default: the seed's own, 1 kHz for "
                        "seeds = 2 mod 3, else 100 Hz)")
    p.add_argument("--sessions", default=None, help="comma list of the held-out sessions to run (default all: "
                                                    + ", ".join(SESSION_NAMES) + ")")
    p.add_argument("--degenerate", action="store_true",
                   help="calibrate each plant instead on degenerate logs (" + ", ".join(DEGENERATE)
                        + ") with sea-daemon fit, as a user does: refused, or the held-out error and coverage "
                          "next to the AKF on the robot-only model, and the verdict; with --joints 2 the two-joint "
                        "cases (--cases)")
    p.add_argument("--joints", type=int, default=1,
                   help="1 (the one-joint family) or 2 (the two-joint shoulder-elbow family, "
                        "sea_daemon.apps.bench._family_joints; ratios per joint); default 1")
    p.add_argument("--tau-model", choices=("walk", "integrated"), default="walk",
                   help="the filter's model of the subject's torque (estimator.tau_h_act_model): walk (default) or "
                        "integrated (tracks its rate too; docs/bounds.md §6)")
    p.add_argument("--walk-for", choices=("estimate", "bound"), default="estimate",
                   help="what the calibration chooses the subject's torque walk for (calibration.walk_for): estimate "
                        "(default) or bound (the Theorem-1 bound as well; docs/calibration.md step 5)")
    p.add_argument("--cases", default=None,
                   help="with --degenerate: comma list of " + ", ".join(DEGENERATE) + " (default all of them) and "
                        + REFERENCE + " (the calibration excitation for --cal-s s, for comparison); with --joints 2 "
                        "of " + ", ".join(DEGENERATE_JOINTS) + " (default all; one joint held still or moving one "
                        "way only for --cal-s s while the other runs the calibration excitation, a 3 s log) and "
                        + REFERENCE)


def parse_seeds(text: str) -> list[int]:
    out = []
    for part in text.split(","):
        part = part.strip()
        if "-" in part:
            a, b = part.split("-")
            out += list(range(int(a), int(b) + 1))
        elif part:
            out.append(int(part))
    return out


def plant_logs(seed: int, cal_s: float, cache: Path | None, rate_hz: float | None = None,
               calibration: bool = True):
    """(plant, calibration log, {session: log}) of plant ``seed`` (at ``rate_hz``, default the
    seed's own rate), simulated or from the cache (:mod:`._logcache`: numbers only; the plant
    is drawn again from its seed); ``calibration=False``: the held-out sessions only (the
    calibration log None)."""
    pd = draw_plant(seed, rate_hz)
    name = f"plant_{seed}_{int(cal_s)}" if calibration else f"sessions_{seed}"
    if rate_hz is not None:
        name += f"_{rate_hz:g}hz"
    p = None if cache is None else cache / f"{name}.npz"
    specs = sessions(pd)
    seeds = noise_seeds(seed, len(specs))
    key = {"seed": seed, "cal_s": cal_s if calibration else None, "sessions": [s.name for s in specs],
           "noise_seeds": seeds, "producer": producer(PRODUCER, PRODUCER_FILES)}
    if rate_hz is not None:
        key["rate_hz"] = float(rate_hz)
    logs = None if p is None else load_logs(p, key)
    if logs is not None and ("calibration" in logs or not calibration):
        cal = logs.pop("calibration", None)
        return pd, cal, logs
    cal = None
    if calibration:
        cal = run_session(pd.true, cal_s, reference=calibration_motion(pd, cal_s, seed=seed),
                          seed=seeds["calibration"])
    tests = {}
    for s, noise_seed in zip(specs, seeds["sessions"]):
        tests[s.name] = run_session(pd.true, s.duration_s, reference=s.reference, hold_q=s.hold_q, human=s.human,
                                    seed=noise_seed)
    if p is not None:
        save_logs(p, key, ({"calibration": cal} if calibration else {}) | tests)
    return pd, cal, tests


def run_plant(seed: int, cal_s: float, cache: Path | None, estimators, bound_mode: str,
              rate_hz: float | None = None, tau_model: str = "walk", walk_for: str = "estimate") -> dict:
    """Calibrate plant ``seed`` (at ``rate_hz``, default its own; the filter's τ_h,act model
    ``tau_model``, its walk chosen for ``walk_for``) once and run every estimator on every test session."""
    t0 = time.perf_counter()
    pd, cal, tests = plant_logs(seed, cal_s, cache, rate_hz)
    t_sim = time.perf_counter() - t0
    row: dict = {"seed": seed, "rate_hz": pd.nominal.rate_hz, "plant": pd.summary,
                 "session_kinds": {sp.name: sp.kind for sp in sessions(pd)}}
    t0 = time.perf_counter()
    res = calibrate_plant(cal, pd, row, tau_model, walk_for)
    if res is None:
        return row
    row["tau_h_act_model"], row["walk_for"] = tau_model, walk_for
    row["calibration"] = calibration_row(res.report)
    do_bound = bound_mode == "all" or (bound_mode == "100hz" and pd.nominal.rate_hz <= 200)
    row["sessions"] = run_sessions(res, pd.nominal, pd.true, tests, estimators, do_bound)
    row["wall_s"] = time.perf_counter() - t0 + t_sim
    return row


def calibration_row(rep: dict) -> dict:
    """What a calibration report says, for a benchmark's results: the effects diagnose added, the
    identified noise, the GP kept or not and its hyperparameters, the coverage, the expected RMSE."""
    return {
        "effects": [f"{d['type']}({d['side']})" for d in rep.get("diagnose", {}).get("effects_added", [])],
        "q_tau": rep["tau_h_act_walk"].get("q_tau"), "tau_m_noise": rep["tau_m_noise"].get("identified"),
        "R": rep["R"].get("identified"), "gp_kept": rep["gp_kept"], "gp_cv": rep.get("gp_cv"),
        "gp_hyper": rep.get("gp_hyper"), "leftover_rms": rep["leftover"]["rms"], "coverage": rep["coverage"],
        "expected": rep["tau_h_act_walk"].get("chosen")}


def run_sessions(res, nominal, true, tests: dict, estimators, do_bound: bool = False, on_session=None) -> dict:
    """Every estimator of ``estimators`` on every log of ``tests`` ({name: log}) after the
    calibration ``res``: the GP-AKF and the AKF on the calibrated model, the AKF on the nominal
    robot ``nominal`` and on the true plant ``true`` (both with the calibrated noise settings).
    ``on_session(name, result)`` is called after each session.  {name: {estimator: result}}."""
    cfg = res.cfg
    # the robot-only AKF with the health monitor off: its model does not fit any of these logs
    # (NIS divergence would stop it at once), and the comparison wants its estimate
    robot = dataclasses.replace(nominal, estimator=dataclasses.replace(cfg.estimator, nis_scale=1e12),
                                kinematics=cfg.kinematics)
    oracle = dataclasses.replace(true, estimator=cfg.estimator, kinematics=cfg.kinematics)
    out = {}
    for name, log in tests.items():
        r = {}
        for lab in estimators:
            try:
                if lab == "gp-akf":
                    r[lab] = score_replay(log, res.estimator(dt=log.dt, bound=theorem_bound if do_bound else None),
                                  bound=do_bound)
                elif lab == "akf-aug":
                    r[lab] = score_replay(log, res.estimator(dt=log.dt, kind="akf"))
                elif lab == "akf-robot":
                    r[lab] = score_replay(log, AKF(robot, dt=log.dt))
                else:
                    r[lab] = score_replay(log, AKF(oracle, dt=log.dt))
            except Exception as e:
                r[lab] = {"internal_error": f"{type(e).__name__}: {e}", "traceback": traceback.format_exc()[-1500:]}
        out[name] = r
        if on_session is not None:
            on_session(name, r)
    return out


def summarize(rows: list[dict]) -> dict:
    """Ratios to the oracle and to the AKF on the augmented model, counts of faults."""
    ratios_oracle, ratios_aug, rm = [], [], {k: [] for k in ESTIMATORS}
    faults = {k: 0 for k in ESTIMATORS}
    internal = {k: 0 for k in ESTIMATORS}
    nonfinite = {k: 0 for k in ESTIMATORS}
    cover, bratio = [], []
    worst = []
    for row in rows:
        for name, r in row.get("sessions", {}).items():
            for k in ESTIMATORS:
                v = r.get(k)
                if v is None:
                    continue
                if "fault" in v:
                    faults[k] += 1
                elif "internal_error" in v:
                    internal[k] += 1
                else:
                    rm[k].append(v["rmse"])
                    nonfinite[k] += int(not v["finite"])
            g, o, a = r.get("gp-akf", {}), r.get("oracle", {}), r.get("akf-aug", {})
            if "rmse" in g and "rmse" in o:
                ratios_oracle.append(g["rmse"] / o["rmse"])
            if "rmse" in g and "rmse" in a:
                ratios_aug.append(g["rmse"] / a["rmse"])
                worst.append((g["rmse"] / a["rmse"], row["seed"], name))
            if "bound" in g:
                cover.append(g["bound"]["coverage"])
                bratio.append(g["bound"]["ratio"])
    q = lambda a, p: float(np.percentile(a, p)) if len(a) else None
    return {
        "runs": len(ratios_oracle), "plants": len(rows),
        "calibration_errors": sum(1 for r in rows if "calibration_error" in r),
        "gp_over_oracle": {"median": q(ratios_oracle, 50), "p90": q(ratios_oracle, 90), "max": q(ratios_oracle, 100)},
        "gp_over_aug": {"median": q(ratios_aug, 50), "max": q(ratios_aug, 100),
                        "over_1.1": int(sum(1 for x in ratios_aug if x > 1.1)),
                        "worst": sorted(worst, reverse=True)[:5]},
        "rmse_median": {k: q(v, 50) for k, v in rm.items()},
        "rmse_p90": {k: q(v, 90) for k, v in rm.items()},
        "faults": faults, "internal_errors": internal, "non_finite": nonfinite,
        "bound": {"runs": len(cover), "coverage_median": q(cover, 50), "coverage_min": q(cover, 0),
                  "share_cov_0.95": float(np.mean(np.array(cover) >= 0.95)) if cover else None,
                  "ratio_median": q(bratio, 50), "ratio_p90": q(bratio, 90)},
    }


def seed_roles(seeds) -> dict:
    """The seeds of a run named: development (they chose settings) and held out."""
    dev = sorted(set(seeds) & set(DEVELOPMENT_SEEDS))
    return {"development": dev, "held_out": sorted(set(seeds) - set(dev))}


def _session_bound(g: dict, kind: str, rate: float):
    """(coverage, mean bound, its limit) of a GP-AKF session over its valid samples (all when
    none is marked valid); the limit of :data:`TIGHT`, None where it does not apply."""
    b = g["bound"]
    cov = b.get("coverage_valid") if b.get("coverage_valid") is not None else b["coverage"]
    rho = b.get("mean_rho_valid") if b.get("mean_rho_valid") is not None else b["mean_rho"]
    band = 100 if rate <= 200 else 1000
    kind = "passive" if kind == "passive" else "active"
    lim = TIGHT.get((kind, band))
    if lim is None and b.get("rmse_valid") is not None:
        lim = TIGHT_RMSE_FACTOR * b["rmse_valid"]
    return cov, rho, lim


def by_rate(rows: list[dict]) -> dict:
    """Per rate: GP-AKF / oracle AKF median and p90, the bound's coverage per session (of the
    valid samples) and the smallest, the sessions whose mean bound is above :data:`TIGHT`, and
    whether each target of :data:`TARGETS` holds."""
    out: dict = {}
    for row in rows:
        rate = float(row.get("rate_hz", row["plant"]["rate_hz"]))
        d = out.setdefault(f"{rate:g}", {"plants": [], "ratios": [], "coverage": [], "loose": [], "bounded": 0,
                                         "no_estimate": []})
        d["plants"].append(row["seed"])
        for name, r in row.get("sessions", {}).items():
            g, o = r.get("gp-akf", {}), r.get("oracle", {})
            if "rmse" in g and "rmse" in o:
                d["ratios"].append(g["rmse"] / o["rmse"])
            if "gp-akf" in r and "rmse" not in g:
                d["no_estimate"].append([row["seed"], name, "fault" if "fault" in g else "internal error"])
            if "bound" in g:
                cov, rho, lim = _session_bound(g, row.get("session_kinds", {}).get(name, "active"), rate)
                d["bounded"] += 1
                d["coverage"].append([row["seed"], name, cov, g["bound"].get("valid_share", 1.0)])
                if lim is not None and rho > lim:
                    d["loose"].append([row["seed"], name, rho, lim])
    for d in out.values():
        ratios, covs = d.pop("ratios"), d.pop("coverage")
        med, p90 = (float(np.percentile(ratios, 50)), float(np.percentile(ratios, 90))) if ratios else (None, None)
        low = min(covs, key=lambda c: c[2]) if covs else None
        d.update(sessions=len(ratios), gp_over_oracle={"median": med, "p90": p90},
                 coverage={"per_session": covs, "min": None if low is None else low[2],
                           "min_at": None if low is None else f"plant {low[0]} {low[1]}",
                           "below": [c for c in covs if c[2] < TARGETS["coverage"]]},
                 held={"median": None if med is None else med <= TARGETS["gp_over_oracle_median"],
                       "p90": None if p90 is None else p90 <= TARGETS["gp_over_oracle_p90"],
                       "coverage": None if not covs else (all(c[2] >= TARGETS["coverage"] for c in covs)
                                                          and not d["no_estimate"]),
                       "valid": None if not covs else all(c[3] >= TARGETS["valid_share"] for c in covs),
                       "tight": None if not d["bounded"] else not d["loose"]})
    return out


def _job(args):
    seed, cal_s, cache, est, bound, rate, names, tau_model, walk_for = args
    row = run_plant(seed, cal_s, cache, est, bound, rate, tau_model, walk_for)
    if names is not None and "sessions" in row:
        row["sessions"] = {k: v for k, v in row["sessions"].items() if k in names}
    return row


def _degenerate_job(args):
    seed, rate, cal_s, cache, names, cases, work, verbose = args
    pd, _, tests = plant_logs(seed, cal_s, cache, rate, calibration=False)
    tests = {k: v for k, v in tests.items() if names is None or k in names}
    return run_degenerate_plant(pd, tests, work / f"plant_{seed}_{pd.nominal.rate_hz:g}hz", cases, cal_s,
                                on_case=print_case if verbose else None)


def parse_rates(text: str | None) -> list[float | None]:
    """``--rates``: [None] (each seed's own rate) or the rates [Hz], each in 1..100000."""
    if not text:
        return [None]
    try:
        rates = [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise InputError(f"--rates {text}: expected a comma list of rates in Hz, e.g. 100,1000") from None
    bad = [r for r in rates if not 1.0 <= r <= 100000.0]
    if bad or not rates:
        raise InputError(f"--rates {text}: each rate must be in 1..100000 Hz")
    return rates


def run(args) -> int:
    try:
        seeds = parse_seeds(args.seeds)
    except ValueError:
        raise InputError(f"--seeds {args.seeds}: expected 'a-b' or a comma list of integers") from None
    if not seeds:
        raise InputError(f"--seeds {args.seeds}: no seed")
    rates = parse_rates(args.rates)
    names = None if not args.sessions else choose(args.sessions, SESSION_NAMES, "--sessions")
    if args.joints not in (1, 2):
        raise InputError(f"--joints {args.joints}: allowed 1 or 2")
    roles = seed_roles(seeds) if args.joints == 1 else seed_roles_joints(seeds)
    print(f"bench generalize: seeds held out {roles['held_out'] or 'none'}; development seeds (they chose the "
          f"calibration's settings) {roles['development'] or 'none'}", flush=True)
    Path(args.out).mkdir(parents=True, exist_ok=True)
    out = check_output_dir("--out", args.out)
    cache = None if args.no_cache else out / "cache"
    if cache is not None:
        cache.mkdir(mode=0o700, exist_ok=True)
        why = private_dir(cache)
        if why is not None:
            print(f"bench generalize: note: cache {cache} not used: {why}", flush=True)
            cache = None
    if args.degenerate:
        return run_degenerate(args, seeds, rates, names, out, cache)
    est = choose(args.estimators, ESTIMATORS, "--estimators")
    if args.joints != 1:
        return run_joints(args, seeds, rates, names, est, out, cache, summarize, by_rate)
    print(f"bench generalize: {len(seeds)} plants (seeds {args.seeds}), rates "
          f"{args.rates or 'of the seeds'}, calibration {args.cal_s:g} s, estimators {', '.join(est)}, "
          f"bound {args.bound}, tau_h_act model {args.tau_model}, walk for {args.walk_for}; {machine()}", flush=True)
    jobs = [(s, args.cal_s, cache, est, args.bound, r, names, args.tau_model, args.walk_for) for s in seeds for r in rates]
    rows = _pool(jobs, _job, args.jobs, _print_row, out, "plants calibrated and tested")
    rows.sort(key=lambda r: (r["seed"], r.get("rate_hz", 0.0)))
    summary = summarize(rows)
    summary["seeds"] = roles
    summary["by_rate"] = by_rate([r for r in rows if r["seed"] not in DEVELOPMENT_SEEDS])
    if roles["development"]:
        summary["by_rate_development"] = by_rate([r for r in rows if r["seed"] in DEVELOPMENT_SEEDS])
    atomic_write_text(out / "results.json", json.dumps({"summary": summary, "rows": rows}, indent=1, default=float))
    print(json.dumps({k: v for k, v in summary.items() if not k.startswith("by_rate")}, indent=1, default=float))
    for label, key in (("held-out seeds", "by_rate"), ("development seeds", "by_rate_development")):
        for rate, d in summary.get(key, {}).items():
            _print_targets(label, rate, d)
    print(f"results: {out / 'results.json'}  (load average {os.getloadavg()[0]:.2f})")
    return 0


def _pool(jobs, fn, n_jobs: int, show, out: Path, what: str) -> list[dict]:
    """``fn`` over ``jobs`` (``n_jobs`` processes), each row shown as it comes and the rows so
    far kept in ``out/results.json``."""
    rows = []
    with Progress("bench generalize", total=len(jobs), unit="plants", interval=0.0) as progress:
        progress(0, what=what)
        if n_jobs > 1:
            with mp.get_context("fork").Pool(n_jobs) as pool:
                for row in pool.imap_unordered(fn, jobs):
                    rows.append(row)
                    show(row)
                    progress(len(rows), what=what)
        else:
            for j in jobs:
                rows.append(fn(j))
                show(rows[-1])
                atomic_write_text(out / "results.json", json.dumps({"rows": rows}, indent=1, default=float))
                progress(len(rows), what=what)
    return rows


def run_degenerate(args, seeds, rates, names, out: Path, cache) -> int:
    """``--degenerate``: every degenerate calibration of every plant and rate, its verdict
    (``--joints 2``: the two-joint cases of :mod:`._degenerate_joints`)."""
    two = args.joints == 2
    known = (DEGENERATE_JOINTS if two else DEGENERATE) + (REFERENCE,)
    cases = choose(args.cases or ",".join(DEGENERATE_JOINTS if two else DEGENERATE), known, "--cases")
    print(f"bench generalize --degenerate: {len(seeds)} {'two-joint ' if two else ''}plants (seeds {args.seeds}), "
          f"rates {args.rates or 'of the seeds'}, cases {', '.join(cases)}, the calibration by sea-daemon fit, "
          f"held-out sessions {', '.join(names or SESSION_NAMES)}; {machine()}", flush=True)
    work = out / "degenerate"
    verbose = args.jobs <= 1
    jobs = [(s, r, args.cal_s, cache, names, cases, work, verbose) for s in seeds for r in rates]

    def show(row):
        if not verbose:
            for c in row["cases"].values():
                print_case((draw_plant_joints if two else draw_plant)(row["seed"], row["rate_hz"]), c)
    rows = _pool(jobs, _degenerate_joints_job if two else _degenerate_job, args.jobs, show, out,
                 "plants calibrated on degenerate logs")
    rows.sort(key=lambda r: (r["seed"], r["rate_hz"]))
    summary = {"seeds": (seed_roles_joints if two else seed_roles)(seeds), "degenerate": summarize_degenerate(rows)}
    atomic_write_text(out / "results.json", json.dumps({"summary": summary, "degenerate": rows}, indent=1,
                                                       default=float))
    _print_degenerate(summary["degenerate"], cases)
    print(f"results: {out / 'results.json'}, logs and models: {work}  (load average {os.getloadavg()[0]:.2f})")
    return 0


def _degenerate_joints_job(args):
    seed, rate, cal_s, cache, _, cases, work, verbose = args
    return run_degenerate_plant_joints(seed, rate, work / f"joints2_plant_{seed}_{rate or 100:g}hz", cache, cal_s,
                                       cases, on_case=print_case if verbose else None)


def _print_degenerate(d: dict, cases) -> None:
    rates = sorted(d["by_rate"], key=float)
    print("\nverdicts of the degenerate calibrations (plants by seed):")
    print("| case | " + " | ".join(f"{r} Hz" for r in rates) + " |")
    for case in cases:
        cells = []
        for r in rates:
            c = d["by_rate"][r].get(case, {})
            cells.append("; ".join(f"{k} {', '.join(map(str, v))}" for k, v in c.items() if v) or "-")
        print(f"| {case} | " + " | ".join(cells) + " |")
    print(f"{d['ok']} of {d['cases']} as the rule asks ({d['refused']} refused, {d['held']} held, {d['failed']} "
          f"failed); invented effects {d['invented_effects']}, nan/inf printed or written {d['nonfinite_printed']}, "
          f"internal errors {d['internal_errors']}", flush=True)


def _print_targets(label: str, rate: str, d: dict) -> None:
    yes = {True: "yes", False: "NO", None: "not measured"}
    g, c, h = d["gp_over_oracle"], d["coverage"], d["held"]
    f = lambda x: "-" if x is None else f"{x:.3f}"
    print(f"{rate} Hz, {label} {d['plants']}: GP-AKF / oracle median {f(g['median'])} "
          f"(<= {TARGETS['gp_over_oracle_median']:g}: {yes[h['median']]}), p90 {f(g['p90'])} "
          f"(<= {TARGETS['gp_over_oracle_p90']:g}: {yes[h['p90']]}); coverage of the valid samples: smallest "
          f"{f(c['min'])} ({c['min_at'] or '-'}) over {d['bounded']} sessions, >= {TARGETS['coverage']:g} in every "
          f"session: {yes[h['coverage']]}; >= {100 * TARGETS['valid_share']:g} % valid in every session: "
          f"{yes[h['valid']]}; mean bound within the limits: {yes[h['tight']]}"
          + (f" ({len(d['loose'])} sessions above)" if d["loose"] else "")
          + (f"; no estimate in {len(d['no_estimate'])} sessions" if d["no_estimate"] else ""), flush=True)


def _print_row(row: dict) -> None:
    if "calibration_error" in row:
        print(f"plant {row['seed']}: CALIBRATION ERROR {row['calibration_error']}", flush=True)
        return
    c = row["calibration"]
    print(f"plant {row['seed']} ({'development' if row['seed'] in DEVELOPMENT_SEEDS else 'held out'}, "
          f"{row['plant']['rate_hz']:g} Hz, {row['plant']['encoder_bits']} bit, outside "
          f"{row['plant']['outside_vocabulary']}): q_tau {c['q_tau']:.3g}, gp {'kept' if c['gp_kept'] else 'off'}, "
          f"calibration {row['calibration_s']:.0f} s", flush=True)
    for name, r in row["sessions"].items():
        cells = []
        for k in ESTIMATORS:
            v = r.get(k, {})
            cells.append(f"{k} " + (f"{v['rmse']:.3f}" if "rmse" in v else ("FAULT" if "fault" in v else
                                                                               ("ERROR" if "internal_error" in v else "-"))))
        b = r.get("gp-akf", {}).get("bound")
        if b:
            cv = b.get("coverage_valid")
            cells.append(f"bound cov {b['coverage']:.3f}" + ("" if cv is None else f", of the valid {cv:.3f}")
                         + f" ({100 * b.get('valid_share', 1.0):.0f} % valid) ratio {b['ratio']:.1f}")
        print(f"  {name:12s} " + "  ".join(cells), flush=True)
