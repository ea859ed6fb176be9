"""Degenerate calibrations of ``sea-daemon bench generalize --degenerate``, run as a user runs them.

For each plant and rate, each calibration log of :data:`._family.DEGENERATE` (the arm holding
still, a short log, one direction only, the motor torque at its limit, a log at another rate)
is written as a CSV log with the user's configuration (the nominal robot and its
``calibration`` section) and calibrated by ``python -m sea_daemon fit LOG --config MODEL.yaml
--out PREFIX`` in a child process — the command, its exit status, what it prints and writes.
Then:

* exit 2: **refused**, with its one line;
* exit 0: the calibrated model (``PREFIX.yaml`` + ``PREFIX.npz``, loaded as ``replay --model``
  loads them, with the Theorem-1 bound) on the plant's held-out sessions
  (:func:`._family.sessions`), next to the AKF on the robot-only model (the nominal
  configuration as the user wrote it, its health monitor off) on the same sessions: RMSE of
  τ̂_h,act, coverage of the bound over the samples marked valid, the share marked valid;
* anything else: an internal error (or a time-out).

:func:`verdict` applies the rule: no nan/inf printed or written, no internal error, no effect
added on a log without the motion that reveals it (:func:`invented_effects`), and either
refused, or on every held-out session the estimate no worse than the robot-only AKF's and the
bound holding (coverage ≥ :data:`COVERAGE_MIN` of the valid samples).

:func:`score_replay` is how every estimator of ``bench generalize`` is scored on a log.
"""
from __future__ import annotations

import dataclasses
import json
import math
import os
import re
import subprocess
import sys
import time
import traceback
from pathlib import Path

import numpy as np
import yaml

from sea_daemon.apps.bench._family import (
    DEGENERATE,
    DegenerateLog,
    degenerate_calibration,
    user_config,
)
from sea_daemon.apps.commands.replay import build_estimator
from sea_daemon.core.estimators.akf import AKF
from sea_daemon.core.log import MeasuredLog
from sea_daemon.core.replay import replay
from sea_daemon.errors import EstimatorFault, InputError
from sea_daemon.io.configfile import config_text, import_root, load_config
from sea_daemon.io.files import atomic_write_text
from sea_daemon.io.logcsv import write_log

#: the coverage the bound must reach over the valid samples of every held-out session
COVERAGE_MIN = 0.95
#: a log "moves" when its angle spans at least this [rad] (3 deg)
MOVE_RAD = math.radians(3.0)
#: a log "reverses" when its speed reaches this [rad/s] in both directions
REVERSE_SPEED = 0.05
#: effects whose torque depends on the direction of motion: a log that never reverses cannot
#: tell them from an offset or from gravity
DIRECTIONAL = ("coulomb", "stribeck", "spring_backlash")
#: a nan or an infinity as a printed figure (json NaN/Infinity, Python nan/inf, YAML .nan/.inf)
_NONFINITE = re.compile(r"(?i)(?<![a-z0-9_])[-+]?\.?(nan|inf|infinity)(?![a-z0-9_])")
#: seconds a calibration may take before it counts as an internal error
FIT_TIMEOUT_S = 1800.0


# --------------------------------------------------------------- what a log shows, what a run prints


def motion_of(log: MeasuredLog) -> dict:
    """The motion a log shows (joint 0): the angle range [rad] and the speed reached in each
    direction [rad/s] (the 1st/99th percentiles of the true velocity when the log carries it
    in ``extra['dq_true']``, else of the angle's derivative smoothed over 50 ms)."""
    q = np.asarray(log.q[:, 0], dtype=float)
    if "dq_true" in log.extra:
        v = np.asarray(log.extra["dq_true"], dtype=float).reshape(len(log), -1)[:, 0]
    else:
        w = max(round(0.05 / max(log.dt, 1e-9)), 1)
        v = np.convolve(np.gradient(q, log.t), np.ones(w) / w, mode="same") if len(q) > 1 else np.zeros(1)
    up, down = (float(np.percentile(v, 99)), float(np.percentile(v, 1))) if v.size else (0.0, 0.0)
    rng = float(q.max() - q.min()) if q.size else 0.0
    return {"q_range": rng, "v_up": max(up, 0.0), "v_down": max(-down, 0.0),
            "moves": rng >= MOVE_RAD, "reverses": rng >= MOVE_RAD and min(up, -down) >= REVERSE_SPEED}


def invented_effects(effects, motion: dict) -> list[str]:
    """The effects (``type(side)`` labels) added on a log without the motion that reveals
    them: every effect on a log that does not move; the direction-dependent ones
    (:data:`DIRECTIONAL`) on a log that never reverses."""
    if not motion["moves"]:
        return list(effects)
    if not motion["reverses"]:
        return [e for e in effects if e.split("(")[0] in DIRECTIONAL]
    return []


def nonfinite_tokens(text: str) -> list[str]:
    """The nan/inf figures in ``text``, each with a little of its context."""
    return [text[max(m.start() - 30, 0):m.end() + 10].replace("\n", " ") for m in _NONFINITE.finditer(text)]


# --------------------------------------------------------------- scoring an estimator on a log


def timed_replay(log: MeasuredLog, est):
    """Replay ``est`` over ``log``: (the result, ``{"finite": every estimate, state and bound
    finite, "us_per_step": wall time per sample}``), or (None, ``{"fault": ...}``) when the
    estimator stops on a typed fault."""
    try:
        t0 = time.perf_counter()
        r = replay(log, est)
        wall = time.perf_counter() - t0
    except EstimatorFault as e:
        return None, {"fault": str(e)[:300]}
    fin = bool(np.all(np.isfinite(r.tau_h_act_hat)) and np.all(np.isfinite(r.x_hat))
               and np.all(np.isfinite(r.tau_h_act_bound)))
    return r, {"finite": fin, "us_per_step": 1e6 * wall / len(log)}


def score_replay(log: MeasuredLog, est, bound: bool = False) -> dict:
    """Replay ``est`` over ``log`` (which has the truth ``tau_h_act``): RMSE, mean and largest
    |error|, whether every output is finite, µs per step, the share outside the calibration's
    coverage; ``bound``: the Theorem-1 ρ_k the estimator carries (built with
    ``bound=theorem_bound``), its coverage over all samples and over the samples it marks
    valid, the valid share, mean ρ over all and over the valid samples, mean ρ / mean |error|.
    ``{"fault": ...}`` when the estimator stops on a typed fault."""
    r, base = timed_replay(log, est)
    if r is None:
        return base
    hat = r.tau_h_act_hat
    e = hat - log.tau_h_act
    out = {"rmse": float(np.sqrt(np.mean(e ** 2))), "mean_abs": float(np.mean(np.abs(e))),
           "max_abs": float(np.max(np.abs(e))), **base}
    if hasattr(est, "n_outside"):
        out["outside_share"] = est.n_outside / max(len(log) - 1, 1)
    if bound:
        rho = r.tau_h_act_bound
        inside = np.abs(e) <= rho
        v = r.valid if r.valid is not None else np.ones(len(log), dtype=bool)
        out["bound"] = {"coverage": float(np.mean(inside)), "mean_rho": float(np.mean(rho)),
                        "ratio": float(np.mean(rho) / max(np.mean(np.abs(e)), 1e-12)),
                        "gp_box_violations": int(getattr(est.bound, "gp_box_violations_", 0)),
                        "saturated_share": int(getattr(est.bound, "saturated_", 0)) / len(log),
                        "valid_share": float(np.mean(v)),
                        "coverage_valid": float(np.mean(inside[v])) if v.any() else None,
                        "mean_rho_valid": float(np.mean(rho[v])) if v.any() else None,
                        "rmse_valid": float(np.sqrt(np.mean(e[v] ** 2))) if v.any() else None}
    return out


def guarded(fn) -> dict:
    """``fn()``; a refusal of the input (what ``replay`` exits 2 on) as ``{"refused": line}``,
    any other exception as ``{"internal_error": ...}``."""
    try:
        return fn()
    except InputError as e:
        return {"refused": str(e)[:300]}
    except Exception as e:       # an internal error of the estimator is a benchmark result
        return {"internal_error": f"{type(e).__name__}: {e}", "traceback": traceback.format_exc()[-1500:]}


def robot_akf_runs(pd, tests: dict) -> dict:
    """The AKF on the robot-only model (the user's nominal configuration as written, its
    health monitor off so that it gives its estimate) on every held-out log."""
    cfg = user_config(pd)
    cfg = dataclasses.replace(cfg, estimator=dataclasses.replace(cfg.estimator, nis_scale=1e12))
    return {name: guarded(lambda log=log: score_replay(log, AKF(cfg, dt=log.dt))) for name, log in tests.items()}


# --------------------------------------------------------------- the user's calibration: sea-daemon fit


#: the hardware keys a user's file gives (the drive and the encoders); the rest is simulation
USER_HARDWARE = ("gear_ratio", "encoder_bits", "torque_limit")


def user_yaml(cfg) -> dict:
    """The model configuration a user writes for a robot (as ``configs/scenarios/newrobot/
    robot.yaml``): joints, rate, the nominal robot model, the drive's gear, encoder resolution
    and torque limit, the ``calibration`` section — nothing the calibration identifies (a key
    the file gives is kept as given)."""
    d = yaml.safe_load(config_text(cfg, "<user>"))
    return {"joints": d["joints"], "rate_hz": d["rate_hz"], "model": d["model"],
            "hardware": {k: d["hardware"][k] for k in USER_HARDWARE}, "calibration": d["calibration"]}


def fit_command(log_path: Path, config_path: Path, prefix: Path) -> list[str]:
    """The command line of the calibration (this Python, this ``sea_daemon``)."""
    return [sys.executable, "-m", "sea_daemon", "fit", str(log_path), "--config", str(config_path),
            "--out", str(prefix)]


def run_fit(dl: DegenerateLog, workdir: Path, timeout_s: float = FIT_TIMEOUT_S) -> dict:
    """Write ``dl``'s log (the user's columns only: no truth) and configuration to ``workdir``
    and run ``sea-daemon fit`` on them in a child process.  Returns the outcome (refused,
    calibrated, internal_error, timeout), its one line, the exit status, the effects it added,
    the nan/inf figures it printed or wrote, the paths and the command."""
    workdir.mkdir(parents=True, exist_ok=True)
    log_path, cfg_path, prefix = workdir / "calibration.csv", workdir / "robot.yaml", workdir / "fit"
    write_log(log_path, dataclasses.replace(dl.log, tau_h_act=None, extra={}))
    atomic_write_text(cfg_path, f"# bench generalize --degenerate: {dl.case}: {dl.what}\n"
                      + yaml.safe_dump(user_yaml(dl.config), sort_keys=False))
    for old in (prefix.with_suffix(".yaml"), prefix.with_suffix(".npz"), Path(str(prefix) + ".report.json")):
        old.unlink(missing_ok=True)          # a previous run's files are not this one's
    cmd = fit_command(log_path, cfg_path, prefix)
    env = dict(os.environ, PYTHONPATH=str(import_root()))
    env.pop("SEA_DAEMON_DEBUG", None)
    t0 = time.perf_counter()
    try:
        p = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s, env=env, check=False)
        rc, out, err = p.returncode, p.stdout, p.stderr
    except subprocess.TimeoutExpired as e:
        rc, out, err = None, _text(e.stdout), _text(e.stderr)
    row = {"command": " ".join(cmd), "exit": rc, "fit_s": time.perf_counter() - t0, "prefix": str(prefix)}
    (workdir / "fit.stdout.txt").write_text(out)
    (workdir / "fit.stderr.txt").write_text(err)
    lines = [ln for ln in err.splitlines() if ln.strip()]
    written = "".join(_read(p) for p in (prefix.with_suffix(".yaml"), Path(str(prefix) + ".report.json")))
    row["nonfinite"] = nonfinite_tokens(out + "\n" + err + "\n" + written)
    if rc is None:
        row.update(outcome="timeout", line=f"no answer after {timeout_s:g} s")
    elif rc == 2:
        errs = [ln for ln in lines if ": error:" in ln]
        row.update(outcome="refused", line=(errs or lines or ["(exit 2, nothing on stderr)"])[-1])
    elif rc != 0 or "Traceback" in err or "internal error" in err:
        row.update(outcome="internal_error", line=(lines or [f"exit {rc}"])[-1])
    else:
        row["outcome"] = "calibrated"
        try:
            summ = json.loads(out.strip().splitlines()[-1])
            row["effects"] = list(summ.get("effects", []))
            row["expected_rmse"] = summ.get("expected_rmse")
        except (ValueError, IndexError, AttributeError) as e:
            row.update(outcome="internal_error", line=f"fit's summary on stdout unreadable: {e}")
    return row


def _text(b) -> str:
    return b.decode(errors="replace") if isinstance(b, bytes) else (b or "")


def _read(path: Path) -> str:
    try:
        return path.read_text(errors="replace")
    except OSError:
        return ""


def calibrated_runs(prefix: Path, tests: dict) -> dict:
    """The calibrated model ``prefix`` (``.yaml`` + ``.npz``), loaded as ``replay --model``
    does (Theorem-1 bound on), on every held-out log."""
    def one(log):
        cfg = load_config(prefix.with_suffix(".yaml"))
        est, _ = build_estimator("gp-akf", cfg, log.dt, model_path=prefix.with_suffix(".npz"))
        return score_replay(log, est, bound=True)
    return {name: guarded(lambda log=log: one(log)) for name, log in tests.items()}


# --------------------------------------------------------------- the verdict


def verdict(case: dict) -> dict:
    """The rule for one degenerate calibration (``case``: :func:`run_fit`'s row with
    ``invented`` and, when calibrated, ``sessions`` {name: {"gp-akf": ..., "akf-robot": ...}}):
    ``{"verdict": "refused" | "held" | "FAIL", "ok": bool, "why": [reasons]}``."""
    why = []
    if case.get("nonfinite"):
        why.append(f"{len(case['nonfinite'])} nan/inf printed or written (e.g. '{case['nonfinite'][0].strip()}')")
    if case.get("outcome") in ("internal_error", "timeout"):
        why.append(f"{case['outcome'].replace('_', ' ')}: {case.get('line', '')}")
    if case.get("invented"):
        why.append("effects without the motion that reveals them: " + ", ".join(case["invented"]))
    if case.get("outcome") == "calibrated":
        for name, r in case.get("sessions", {}).items():
            why += _session_faults(name, r.get("gp-akf", {}), r.get("akf-robot", {}))
    if why:
        return {"verdict": "FAIL", "ok": False, "why": why}
    return {"verdict": "refused" if case.get("outcome") == "refused" else "held", "ok": True, "why": []}


def _session_faults(name: str, g: dict, a: dict) -> list[str]:
    """What fails the rule on one held-out session: the calibrated estimator ``g`` against the
    robot-only AKF ``a`` (:func:`score_replay` results)."""
    out = []
    if "internal_error" in a:
        out.append(f"{name}: internal error of the robot-only AKF: {a['internal_error']}")
    if "internal_error" in g:
        return out + [f"{name}: internal error: {g['internal_error']}"]
    if "fault" in g:
        return out + [f"{name}: estimator fault: {g['fault']}"]
    if "refused" in g:
        return out + [f"{name}: the calibrated model refused on this session: {g['refused']}"]
    if "rmse" not in g:
        return out + [f"{name}: no estimate"]
    if not g.get("finite", False):
        out.append(f"{name}: non-finite estimate or bound")
    if "rmse" in a and g["rmse"] > a["rmse"]:
        out.append(f"{name}: RMSE {g['rmse']:.3g} N m > {a['rmse']:.3g} of the AKF on the robot-only model")
    cov = (g.get("bound") or {}).get("coverage_valid")
    if cov is not None and cov < COVERAGE_MIN:
        out.append(f"{name}: coverage {cov:.3f} < {COVERAGE_MIN:g} of the valid samples")
    return out


# --------------------------------------------------------------- one plant at one rate


def run_degenerate_plant(pd, tests: dict, workdir: Path, cases=DEGENERATE, cal_s: float = 60.0,
                         timeout_s: float = FIT_TIMEOUT_S, on_case=None) -> dict:
    """Every degenerate calibration ``cases`` of plant ``pd`` (drawn at its rate) against its
    held-out logs ``tests`` ({name: log}); ``on_case(row)`` after each.  The plant's row."""
    row = {"seed": pd.seed, "rate_hz": pd.nominal.rate_hz, "plant": pd.summary}
    row["akf_robot"] = robot_akf_runs(pd, tests)
    row["cases"] = {}
    for case in cases:
        c: dict = {"case": case}
        try:
            dl = degenerate_calibration(pd, case, cal_s)
            c["what"], c["motion"] = dl.what, motion_of(dl.log)
            c["log_rate_hz"] = 1.0 / dl.log.dt
            c.update(run_fit(dl, workdir / case, timeout_s))
        except Exception as e:    # the benchmark's own failure: shown as such, the other cases go on
            c.update(outcome="internal_error", line=f"bench: {type(e).__name__}: {e}",
                     traceback=traceback.format_exc()[-1500:])
        c["invented"] = invented_effects(c.get("effects", []), c["motion"]) if "motion" in c else []
        if c.get("outcome") == "calibrated":
            runs = calibrated_runs(Path(c["prefix"]), tests)
            c["sessions"] = {n: {"gp-akf": runs[n], "akf-robot": row["akf_robot"][n]} for n in tests}
        c.update(verdict(c))
        row["cases"][case] = c
        if on_case is not None:
            on_case(pd, c)
    return row


def print_case(pd, c: dict) -> None:
    """One degenerate calibration's lines: what it was, what the calibration did, the held-out
    sessions, the verdict and why."""
    head = f"plant {pd.seed} {pd.nominal.rate_hz:g} Hz  {c['case']:13s} ({c.get('what', '?')}): "
    if c.get("outcome") == "calibrated":
        head += (f"calibrated in {c['fit_s']:.0f} s, effects {', '.join(c.get('effects', [])) or 'none'}")
    else:
        head += f"{c.get('outcome')}: {c.get('line', '')}"
    print(head, flush=True)
    for name, r in c.get("sessions", {}).items():
        g, a = r["gp-akf"], r["akf-robot"]
        b = g.get("bound") or {}
        cov = b.get("coverage_valid")
        cell = f"{g['rmse']:.3f}" if "rmse" in g else next(
            (lab for key, lab in (("fault", "FAULT"), ("refused", "REFUSED")) if key in g), "ERROR")
        print(f"    {name:12s} gp-akf {cell:>7s}  akf-robot "
              + (f"{a['rmse']:.3f}" if "rmse" in a else "-").rjust(7)
              + ("  coverage " + ("not measurable (no valid sample)" if cov is None else f"{cov:.3f}")
                 + f" of {100 * b['valid_share']:.0f} % valid, mean bound "
                 + ("-" if b.get("mean_rho_valid") is None else f"{b['mean_rho_valid']:.3g}") if b else ""),
              flush=True)
    print(f"    verdict: {c['verdict']}" + ("" if c["ok"] else ": " + "; ".join(c["why"])), flush=True)


def summarize_degenerate(rows: list[dict]) -> dict:
    """Per rate and case, the verdicts over the plants; the counts the rule names."""
    by: dict = {}
    tot = {"cases": 0, "ok": 0, "refused": 0, "held": 0, "failed": 0, "invented_effects": 0,
           "nonfinite_printed": 0, "internal_errors": 0}
    for row in rows:
        rate = f"{row['rate_hz']:g}"
        for case, c in row.get("cases", {}).items():
            cell = by.setdefault(rate, {}).setdefault(case, {"refused": [], "held": [], "failed": []})
            key = {"refused": "refused", "held": "held"}.get(c["verdict"], "failed")
            cell[key].append(row["seed"])
            tot["cases"] += 1
            tot["ok"] += int(c["ok"])
            tot[key] += 1
            tot["invented_effects"] += len(c.get("invented", []))
            tot["nonfinite_printed"] += len(c.get("nonfinite", []))
            errs = int(c.get("outcome") in ("internal_error", "timeout"))
            errs += sum(int("internal_error" in s.get("gp-akf", {})) for s in c.get("sessions", {}).values())
            tot["internal_errors"] += errs
    return {"by_rate": by, **tot, "all_ok": tot["cases"] > 0 and tot["ok"] == tot["cases"]}
