"""``sea-daemon bench capstone``: a measured log with torque truth, fold by fold (docs/diagnose.md).

The log (default ``tests/data/capstone_sea/reference_head.csv``: the real SEA bench's position
loop, nobody touching the load, τ_h,act = 0) and its nominal model (default
``configs/capstone_sea.yaml``) are cut into ``--folds K`` contiguous time blocks of equal length.
Two checks (``--checks``), each per fold:

* ``selection`` — diagnose's effects out of sample (:func:`run_diagnosis`, K cross-validation
  blocks, the whole selection repeated without each block): per held-out block the AKF's
  τ̂_h,act error with the input model, with the effects kept (refitted on the other blocks) and
  with the whole selection repeated on the other blocks alone;
* ``gp-akf`` — the GP-AKF calibrated on one block: first what ``sea-daemon fit`` says of that
  block (accepted, or its one-line refusal naming what the block lacks and what to record
  instead), then the calibration of ``fit`` (:func:`calibrate`) on the block whatever it says —
  a refused block keeps the configured value of what it cannot identify (the physics), so the
  figures show what the refusal protects from — scored on every other block: the GP-AKF's RMSE
  against the AKF's with the input model (target :data:`TARGETS` ``gp_over_akf``), the
  Theorem-1 bound's coverage of the samples marked valid (``coverage``), the share valid, and
  the mean bound over the valid samples over their RMSE (``bound_over_rmse``), and the share of
  the block's samples moving a way the calibration's GP has no data for (``gp_off_direction``:
  there the GP-AKF uses the physical model alone, :meth:`ResidualGP.off_direction`).  Of the
  guaranteed GP error bound (docs/bounds.md §2): its √β and the leaves of its union
  (``gp_sqrt_beta``, ``gp_union_leaves``, joint 1) and the share of the block's steps whose GP
  input set left the box the bound is stated on (``gp_box_left``); with ``--terms``, the mean
  over the valid samples of each term of ρ_k (:class:`~sea_daemon.core.bounds.terms.TermsRecorder`:
  the bound's Python step, slower, the same ρ_k).

Every estimator is run from :data:`WARM_S` before the block it is scored on (a filter needs its
history; the truth is only scored).  Prints a table per check and, with ``--json``, writes the
figures.  The blocks, not the targets, are the only setting: nothing of the log chose them.
"""
from __future__ import annotations

import math
import os
import time
from pathlib import Path

import numpy as np

from sea_daemon.apps.bench import add_choice_argument, add_json_argument, choose, json_output, machine
from sea_daemon.apps.bench.generalize import calibration_row
from sea_daemon.apps.calibration.modelio import directions_lines
from sea_daemon.apps.calibration.pipeline import calibrate, given_keys, options_from_config
from sea_daemon.analysis.diagnose.crossval import WARM_S, BlockScorer
from sea_daemon.analysis.diagnose.engine import run_diagnosis
from sea_daemon.analysis.diagnose.residuals import kinematics_from_log
from sea_daemon.analysis.diagnose.select import SelectOptions
from sea_daemon.analysis.sufficiency import Limits, assess, at_config_rate
from sea_daemon.core.bounds.akf_bound import theorem_bound
from sea_daemon.core.bounds.terms import TERMS, TermsRecorder
from sea_daemon.core.config import ModelConfig
from sea_daemon.core.estimators.validity import REASONS, reason_counts
from sea_daemon.core.log import MeasuredLog
from sea_daemon.core.replay import replay
from sea_daemon.errors import EstimatorFault, InputError
from sea_daemon.io.configfile import data_root, import_root, load_config, load_yaml
from sea_daemon.io.logcsv import read_log

DESCRIPTION = __doc__
CHECKS = ("selection", "gp-akf")
#: the targets of the per-block GP-AKF (a calibration on one block, scored on the others)
TARGETS = {"gp_over_akf": 1.1, "coverage": 0.95, "bound_over_rmse": 5.0, "valid_share": 0.95}
#: the shortest block [s]: the calibration's noise identification needs 2 s of data
MIN_BLOCK_S = 2.0
MAX_FOLDS = 10


def default_log() -> Path:
    return import_root() / "tests" / "data" / "capstone_sea" / "reference_head.csv"


def add_arguments(p) -> None:
    p.add_argument("--log", default=str(default_log()),
                   help="measured log with a tau_h_act column (default tests/data/capstone_sea/reference_head.csv)")
    p.add_argument("--config", default=str(data_root() / "configs" / "capstone_sea.yaml"),
                   help="the nominal model (default configs/capstone_sea.yaml)")
    p.add_argument("--folds", type=int, default=2,
                   help=f"contiguous time blocks of equal length, 2-{MAX_FOLDS}, each at least {MIN_BLOCK_S:g} s "
                        "(default 2)")
    p.add_argument("--calibrate-on", default=None, metavar="A-B",
                   help="gp-akf: calibrate once on the samples from A to B seconds of the log and score on every "
                        "block outside it (default: on each block in turn)")
    add_choice_argument(p, "--checks", CHECKS)
    p.add_argument("--terms", action="store_true",
                   help="gp-akf: the mean of each term of the bound over the valid samples (the bound's Python "
                        "step: slower)")
    add_json_argument(p)


def load_inputs(log_path: str, config_path: str, folds: int) -> tuple[MeasuredLog, ModelConfig, dict, list]:
    """(log, configuration, its YAML mapping, the blocks as (start, stop) rows); InputError for a
    log without truth, of another joint count, or too short for ``folds`` blocks."""
    if not Path(log_path).is_file():
        raise InputError(f"--log {log_path}: no such file (a measured log with a tau_h_act column, "
                         "docs/interfaces.md section 1)")
    cfg = load_config(config_path)
    log = read_log(log_path, n=cfg.joints, min_rows=2)
    if log.tau_h_act is None:
        raise InputError(f"{log_path}: no tau_h_act column: the per-fold check scores the estimates against the "
                         "torque truth; give a log with tau_h_act (0 where nobody touches the load)")
    log, _ = at_config_rate(log, cfg)
    duration = len(log) * log.dt
    most = min(MAX_FOLDS, int(duration / MIN_BLOCK_S + 1e-6))
    if not 2 <= folds <= most:
        raise InputError(f"--folds {folds}: allowed 2-{most} for this {duration:.3g} s log (blocks of at least "
                         f"{MIN_BLOCK_S:g} s, at most {MAX_FOLDS} blocks)" if most >= 2 else
                         f"{log_path}: {duration:.3g} s of data; the per-fold check needs two blocks of at least "
                         f"{MIN_BLOCK_S:g} s")
    edges = np.linspace(0, len(log), folds + 1).astype(int)
    return log, cfg, load_yaml(config_path), [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:])]


def calibration_window(text: str | None, log: MeasuredLog) -> list | None:
    """``--calibrate-on A-B`` [s] as [(start, stop)] rows of ``log`` (None without it); InputError
    for a malformed window, one outside the log or shorter than :data:`MIN_BLOCK_S`."""
    if text is None:
        return None
    try:
        lo, hi = (float(v) for v in text.split("-", 1))
    except ValueError:
        lo = hi = float("nan")
    t0, t1 = float(log.t[0]), float(log.t[-1]) + log.dt
    if not (t0 <= lo and hi <= t1 + 1e-9 and hi - lo >= MIN_BLOCK_S):
        raise InputError(f"--calibrate-on {text}: allowed A-B seconds within the log's {t0:.6g}-{t1:.6g} s, "
                         f"at least {MIN_BLOCK_S:g} s long")
    a, b = np.searchsorted(log.t, [lo - 1e-9, hi - 1e-9])
    return [(int(a), int(b))]


def block_span(log: MeasuredLog, a: int, b: int) -> list[float]:
    """[first, last] sample time of rows a..b−1 [s]."""
    return [float(log.t[a]), float(log.t[b - 1])]


# ---------------------------------------------------------------------------- selection per fold

def selection_check(log: MeasuredLog, cfg: ModelConfig, folds: int) -> dict:
    """Diagnose's cross-validation over ``folds`` blocks, the whole selection repeated per fold:
    per held-out block the AKF's error with the input model, the effects kept and the selection
    repeated, and whether every block improves."""
    opts = SelectOptions(cv_blocks=folds, cv_repeat_selection=True, validate_selection=False)
    res = run_diagnosis(log, cfg, opts).result
    cv = res["cross_validation"]
    rows = []
    spans = [(log.t >= b["t_s"][0]) & (log.t <= b["t_s"][1]) for b in cv.get("blocks", [])]
    for k, (b, r) in enumerate(zip(cv.get("blocks", []), cv.get("selection_repeated", []))):
        o = r["out_of_sample"]
        others = np.any([m for j, m in enumerate(spans) if j != k], axis=0)
        rows.append({"t_s": b["t_s"], "q_unvisited": unvisited_share(log, cfg, others, spans[k]),
                     "akf_input": b["estimate_rmse_before"], "kept": b["estimate_rmse_after"],
                     "repeated": o["estimate_rmse_after"],
                     "repeated_effects": [f"{e['type']}/{e['side']}" for e in r["effects"]]})

    def better(key):
        return all(r[key] is not None and r["akf_input"] is not None and r[key] <= r["akf_input"] for r in rows)
    return {"effects_kept": [f"{d['type']}/{d['side']}" for d in res["effects_added"]],
            "dropped": [f"{d['type']}/{d['side']}" for d in cv.get("dropped", [])], "blocks": rows,
            "kept_never_worse": bool(rows) and better("kept"), "repeated_never_worse": bool(rows) and better("repeated"),
            "kept_improves_every_block": bool(rows) and all(
                r["kept"] is not None and r["kept"] < r["akf_input"] for r in rows),
            "repeated_improves_every_block": bool(rows) and all(
                r["repeated"] is not None and r["repeated"] < r["akf_input"] for r in rows)}


# ---------------------------------------------------------------------------- GP-AKF per block

def unvisited_share(log: MeasuredLog, cfg: ModelConfig, seen: np.ndarray, scored_rows: np.ndarray) -> float:
    """The share of the ``scored_rows`` whose load angle lies outside the range of the ``seen``
    rows, widened by the span of a still arm (:class:`Limits` ``still_span_deg``) or one load
    encoder step, whichever is larger: where what was fitted on those is extrapolated in q."""
    q = np.asarray(log.q, float)[:, 0]
    step = max(float(cfg.hardware.encoder_resolution(cfg.joints)[0][0]), math.radians(Limits.still_span_deg))
    lo, hi = np.min(q[seen]) - step, np.max(q[seen]) + step
    qs = q[scored_rows]
    return float(np.mean((qs < lo) | (qs > hi))) if qs.size else 0.0


def fit_verdict(block: MeasuredLog, cfg: ModelConfig) -> str | None:
    """What ``sea-daemon fit`` says of ``block``: None (accepted) or its one-line refusal."""
    return assess(block, cfg).refusal


class BoxShareBound:
    """A GP-AKF's Theorem-1 bound component (``res.estimator(bound=BoxShareBound.of(terms))``) that
    notes, per step, whether the GP input set left the box its GP constants are stated on
    (:attr:`left_`); ``terms``: the bound's :class:`TermsRecorder` (its Python step) instead of the
    compiled one.  Everything else is the bound's."""

    def __init__(self, akf, terms: bool = False):
        self.inner = TermsRecorder(akf) if terms else theorem_bound(akf)
        self.left_: list = []
        self._seen = 0

    @classmethod
    def of(cls, terms: bool):
        return lambda akf: cls(akf, terms)

    def __getattr__(self, name):
        if name == "inner":
            raise AttributeError(name)
        return getattr(self.inner, name)

    def reset(self, est, record) -> None:
        self.inner.reset(est, record)
        self.left_ = []
        self._seen = self.inner.gp_box_violations_

    def step(self, est, record) -> None:
        self.inner.step(est, record)
        seen = self.inner.gp_box_violations_
        self.left_.append(seen > self._seen)
        self._seen = seen


def bound_figures(rec: BoxShareBound, valid: np.ndarray, rows: int) -> dict:
    """Of the GP error bound behind ``rec`` over the last ``rows`` steps (``valid``: the replay's
    mask, aligned with its last rows): √β and the union's leaves (joint 1), the share of the steps
    whose GP input set left the bound's box, and with terms the means of :meth:`TermsRecorder.table`."""
    c = (rec.gp_constants or [None])[0]
    left = np.asarray(rec.left_[-rows:], bool)
    out = {"gp_sqrt_beta": None if c is None else float(c.sqrt_beta),
           "gp_union_leaves": None if c is None else int(c.n_leaves),
           "gp_box_left": float(np.mean(left)) if left.size and c is not None else None}
    if isinstance(rec.inner, TermsRecorder):
        out["terms"] = rec.inner.table(valid) or None
    return out


def scored(log: MeasuredLog, est, a: int, b: int) -> dict:
    """``est`` run over rows [a − WARM_S, b) of ``log`` and scored on rows [a, b): RMSE; with a
    bound, its coverage of the samples marked valid, the share valid, the mean bound over them
    and its ratio to their RMSE (and :func:`bound_figures` for a :class:`BoxShareBound` bound).
    ``{"fault": ...}`` when the estimator stops."""
    lo = max(a - max(int(round(WARM_S / log.dt)), 1), 0)
    try:
        r = replay(log.slice(lo, b), est)
    except EstimatorFault as e:
        return {"fault": str(e)[:300]}
    e = (r.tau_h_act_hat - log.tau_h_act[lo:b])[a - lo:, 0]
    if not np.all(np.isfinite(e)):
        return {"fault": "non-finite estimate"}
    out = {"rmse": float(np.sqrt(np.mean(e ** 2)))}
    rho = r.tau_h_act_bound[a - lo:, 0]
    if np.any(rho > 0):
        v = np.ones(len(e), bool) if r.valid is None else np.asarray(r.valid[a - lo:], bool)
        out["valid_share"] = float(np.mean(v))
        if r.reason is not None and not v.all():
            why = np.bincount(np.asarray(r.reason[a - lo:], int), minlength=len(REASONS))
            out["invalid_reasons"] = reason_counts(why)["invalid"]
        if v.any():
            rmse_v = float(np.sqrt(np.mean(e[v] ** 2)))
            out.update(coverage=float(np.mean(np.abs(e[v]) <= rho[v])), mean_bound=float(np.mean(rho[v])),
                       rmse_valid=rmse_v, bound_over_rmse=float(np.mean(rho[v]) / max(rmse_v, 1e-12)))
        if isinstance(est.bound, BoxShareBound):
            full = np.zeros(b - lo, bool)
            full[a - lo:] = v
            out.update(bound_figures(est.bound, full, b - a))
    return out


def calibration_summary(report: dict) -> dict:
    """What the calibration identified (:func:`.generalize.calibration_row`) and whether it
    identified the physics or kept the configured model (and why)."""
    skipped = (report.get("diagnose") or {}).get("skipped")
    return {**calibration_row(report), "physics": "identified" if skipped is None else f"configured ({skipped})",
            "gp_directions": report.get("gp_directions")}


def off_direction_share(log: MeasuredLog, gp, a: int, b: int) -> float | None:
    """The share of rows a..b−1 whose (smoothed) q̇ moves a way ``gp`` has no data for (None
    without a GP)."""
    if gp is None:
        return None
    kin = kinematics_from_log(log)
    z = np.hstack([np.asarray(kin.q, float), np.asarray(kin.dq, float), np.asarray(kin.ddq, float)])
    return float(np.mean([gp.off_direction(z[k]) for k in range(a, b)])) if b > a else 0.0


def gpakf_check(log: MeasuredLog, cfg: ModelConfig, raw: dict, blocks: list, windows: list | None = None,
                terms: bool = False) -> list[dict]:
    """Per calibration window (default: each block): what fit says, the calibration on it (its
    refusal set aside), the GP-AKF with its Theorem-1 bound (``terms``: and its terms) and the AKF
    with the input model scored on every block outside the window."""
    akf = BlockScorer(log)
    folds = []
    for k, (a, b) in enumerate(windows or blocks):
        block = log.slice(a, b)
        refusal = fit_verdict(block, cfg)
        opts = options_from_config(cfg)
        opts.refuse = False
        t0 = time.perf_counter()
        res = calibrate(block, cfg, given=given_keys(raw), opts=opts)
        fold = {"block": k + 1, "t_s": block_span(log, a, b), "fit": "accepted" if refusal is None else refusal,
                "calibration": calibration_summary(res.report), "calibration_s": time.perf_counter() - t0, "scored": []}
        for j, (c, d) in enumerate(blocks):
            if c < b and a < d:          # overlaps the calibration
                continue
            mask = np.zeros(len(log), bool)
            mask[c:d] = True
            g = scored(log, res.estimator(dt=log.dt, bound=BoxShareBound.of(terms)), c, d)
            seen = np.zeros(len(log), bool)
            seen[a:b] = True
            row = {"block": j + 1, "t_s": block_span(log, c, d), "q_unvisited": unvisited_share(log, cfg, seen, mask),
                   "gp_akf": g, "akf_input": akf.rmse(cfg, mask),
                   "akf_calibrated": scored(log, res.estimator(dt=log.dt, kind="akf"), c, d).get("rmse"),
                   "gp_off_direction": off_direction_share(log, res.gp, c, d)}
            row["gp_over_akf"] = (g["rmse"] / row["akf_input"] if "rmse" in g and row["akf_input"] else None)
            row["met"] = targets_met(row)
            fold["scored"].append(row)
        folds.append(fold)
        print(f"  calibrated on {_span(fold['t_s'])} s in {fold['calibration_s']:.0f} s", flush=True)
    return folds


def targets_met(row: dict) -> dict:
    """Each target of :data:`TARGETS` met (True/False; False where not measurable)."""
    g = row["gp_akf"]
    return {"gp_over_akf": row["gp_over_akf"] is not None and row["gp_over_akf"] <= TARGETS["gp_over_akf"],
            "coverage": g.get("coverage") is not None and g["coverage"] >= TARGETS["coverage"],
            "bound_over_rmse": g.get("bound_over_rmse") is not None and g["bound_over_rmse"] <= TARGETS["bound_over_rmse"],
            "valid_share": g.get("valid_share") is not None and g["valid_share"] >= TARGETS["valid_share"]}


# ---------------------------------------------------------------------------- printing

def _f(v, fmt: str = ".4f") -> str:
    return "-" if v is None else format(v, fmt)


def print_selection(sel: dict) -> None:
    print(f"\nselection repeated per fold (AKF tau_h_act_hat RMSE on the held-out block [N m]); effects kept on the "
          f"whole log: {', '.join(sel['effects_kept']) or 'none'}")
    print("| held-out block [s] | its q beyond the other blocks' (±1 deg) | AKF, input model | effects kept, refitted without "
          "the block | whole selection repeated without the block (effects) |")
    print("|---|---|---|---|---|")
    for r in sel["blocks"]:
        print(f"| {_span(r['t_s'])} | {100 * r['q_unvisited']:.0f} % | {_f(r['akf_input'])} | {_f(r['kept'])} | {_f(r['repeated'])} "
              f"({', '.join(r['repeated_effects']) or 'none found'}) |")
    print(f"effects kept: every held-out block improves: {_yes(sel['kept_improves_every_block'])} (none worse: "
          f"{_yes(sel['kept_never_worse'])}); selection repeated: every block improves: "
          f"{_yes(sel['repeated_improves_every_block'])} (none worse: {_yes(sel['repeated_never_worse'])})")


def _span(t_s) -> str:
    return f"{t_s[0]:.2f}-{t_s[1]:.2f}"


def _yes(v: bool) -> str:
    return "yes" if v else "NO"


def print_gpakf(folds: list[dict]) -> None:
    t = TARGETS
    print(f"\nGP-AKF calibrated on one block, scored on the others (targets: GP-AKF/AKF <= {t['gp_over_akf']:g}, "
          f"coverage >= {t['coverage']:g} of the valid samples, valid >= {t['valid_share']:g}, mean bound / RMSE "
          f"<= {t['bound_over_rmse']:g})")
    for f in folds:
        print(f"calibrated on {_span(f['t_s'])} s: fit "
              + ("accepts it" if f["fit"] == "accepted" else f"refuses it: {f['fit']}"))
        c = f["calibration"]
        print(f"  calibration (refusal set aside): physics {c['physics']}; effects {', '.join(c['effects']) or 'none'};"
              f" GP {'kept' if c['gp_kept'] else 'not kept'}; q_tau {_f(c['q_tau'], '.3g')}")
        for line in directions_lines(c.get("gp_directions")):
            print("  " + line)
    print("| calibrated on [s] | scored on [s] | q beyond the calibration's (±1 deg) | moving a way the GP has no data for | GP-AKF RMSE | AKF input model | GP-AKF / AKF | AKF calibrated | coverage "
          "(valid) | valid | mean bound | bound / RMSE | met |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for f in folds:
        for r in f["scored"]:
            g = r["gp_akf"]
            met = "all" if all(r["met"].values()) else "NO: " + ", ".join(k for k, v in r["met"].items() if not v)
            off = r.get("gp_off_direction")
            print(f"| {_span(f['t_s'])} | {_span(r['t_s'])} | {100 * r['q_unvisited']:.0f} % | "
                  f"{'-' if off is None else f'{100 * off:.0f} %'} | "
                  + (f"fault: {g['fault'][:60]}" if "fault" in g else _f(g.get("rmse")))
                  + f" | {_f(r['akf_input'])} | {_f(r['gp_over_akf'], '.2f')} | {_f(r['akf_calibrated'])} | "
                  f"{_f(g.get('coverage'), '.3f')} | {_f(g.get('valid_share'), '.3f')} | {_f(g.get('mean_bound'), '.3g')} | "
                  f"{_f(g.get('bound_over_rmse'), '.1f')} | {met} |")
    print_bound_terms(folds)


def print_bound_terms(folds: list[dict]) -> None:
    """The guaranteed GP error bound per scored block with a GP: √β (of the smallest nested box),
    the union's leaves, the steps whose GP input set left every box, and with --terms the mean of
    each term of ρ_k over the valid samples."""
    rows = [(f, r, r["gp_akf"]) for f in folds for r in f["scored"] if r["gp_akf"].get("gp_sqrt_beta") is not None]
    if not rows:
        return
    terms = any(g.get("terms") for _, _, g in rows)
    cols = ["rho", *TERMS, "gaussian"] if terms else []
    print("\nthe GP error bound (docs/bounds.md §2), joint 1" + ("; terms: mean over the valid samples [N m]" if terms else ""))
    print("| calibrated on [s] | scored on [s] | sqrt(beta) on the training box | leaves in the union | GP input set outside "
          "the bound's boxes |"
          + "".join(f" {c} |" for c in cols))
    print("|---" * (5 + len(cols)) + "|")
    for f, r, g in rows:
        t = g.get("terms") or {}
        left = g.get("gp_box_left")
        print(f"| {_span(f['t_s'])} | {_span(r['t_s'])} | {_f(g['gp_sqrt_beta'], '.2f')} | {g['gp_union_leaves']} | "
              f"{'-' if left is None else f'{100 * left:.0f} %'} |" + "".join(f" {_f(t.get(c))} |" for c in cols))


def run(args) -> int:
    checks = choose(args.checks, CHECKS, "--checks")
    write = json_output(args)
    log, cfg, raw, blocks = load_inputs(args.log, args.config, args.folds)
    print(f"bench capstone: {args.log} ({len(log)} samples, {len(log) * log.dt:.3g} s at {1 / log.dt:.6g} Hz), "
          f"model {args.config}, {args.folds} blocks of {(blocks[0][1] - blocks[0][0]) * log.dt:.3g} s; {machine()}; "
          f"load average {os.getloadavg()[0]:.2f}", flush=True)
    out: dict = {"log": args.log, "config": args.config, "folds": args.folds, "machine": machine(),
                 "blocks_s": [block_span(log, a, b) for a, b in blocks], "targets": TARGETS}
    t0 = time.perf_counter()
    if "selection" in checks:
        out["selection"] = selection_check(log, cfg, args.folds)
        print_selection(out["selection"])
    if "gp-akf" in checks:
        out["gp_akf_per_block"] = gpakf_check(log, cfg, raw, blocks, calibration_window(args.calibrate_on, log),
                                              args.terms)
        print_gpakf(out["gp_akf_per_block"])
        rows = [r for f in out["gp_akf_per_block"] for r in f["scored"]]
        out["gp_akf_met"] = {k: all(r["met"][k] for r in rows) for k in TARGETS}
    out["wall_s"] = time.perf_counter() - t0
    write(out)
    print(f"\n{out['wall_s']:.0f} s; load average {os.getloadavg()[0]:.2f} at the end")
    return 0
