"""The diagnosis of a log against a model, as a library call (no files).

    from sea_daemon.analysis.diagnose.engine import run_diagnosis
    dg = run_diagnosis(log, cfg)        # dg.result: the docs/interfaces.md §4 dict

1. the log on a uniform time grid, its encoder steps read, a long one cut to segments
   (:mod:`.prepare`); the kinematics and the stick speeds (:class:`Work`);
2. residuals of the configured model on both sides (:mod:`.residuals`), candidates of the
   effect vocabulary (:mod:`.candidates`), their selection (:mod:`.select`);
3. a time-blocked validation on the log's last part, the AKF's estimation error with the model
   before and after (:mod:`.evaluate`), and, when the AKF is worse after, which effect it
   cannot use;
4. the result dict with its statements (:mod:`.summary`).

:mod:`sea_daemon.apps.diagnose` writes diagnosis.json, model_augmented.yaml and report.md from
the :class:`Diagnosis`; the calibration uses ``cfg_after``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, NamedTuple

import numpy as np
from scipy.signal import savgol_coeffs

from sea_daemon.core.config import ModelConfig
from sea_daemon.core.log import MeasuredLog
from sea_daemon.errors import InputError, LogFormatError
from sea_daemon.analysis.diagnose.candidates import Candidate, build_candidates
from sea_daemon.analysis.diagnose.consistency import check_motor_balance
from sea_daemon.analysis.sufficiency import check_columns
from sea_daemon.analysis.diagnose.context import Context
from sea_daemon.analysis.diagnose.crossval import (BlockScorer, CrossValidation, repeated_per_block, time_blocks,
                                                   without)
from sea_daemon.analysis.diagnose.excitation import Excitation, measure
from sea_daemon.analysis.diagnose.evaluate import estimate_rmse, gpakf_rmse
from sea_daemon.analysis.diagnose.prepare import Prepared, encoder_quanta, prepare_log, segment_log
from sea_daemon.analysis.diagnose.residuals import kinematics_from_log, rms, window_samples
from sea_daemon.analysis.diagnose.select import SelectOptions, Selection, Selector
from sea_daemon.analysis.diagnose.summary import (ablation_statements, cv_statements, cv_summary, effects_json,
                                                  missing_statements, num, statements, validation_summary)


def check_log(log: MeasuredLog, cfg: ModelConfig) -> None:
    """The log fits the model's joints, each of its sensor columns reports something while the
    joint moves (:func:`~sea_daemon.analysis.sufficiency.dead_column`), and it is long enough to
    smooth (else InputError / LogFormatError)."""
    if log.n != cfg.joints:
        raise InputError(f"{log.path}: the log has {log.n} joint(s), the model {cfg.source} has {cfg.joints}")
    check_columns(log)
    need = max(4 * window_samples(log.t), 50)
    if len(log) < need:
        raise LogFormatError(log.path, None, f"has {len(log)} data rows; diagnose needs at least {need} "
                                             f"(four smoothing windows of {window_samples(log.t)} samples)")


def stick_speeds(kin, quanta: dict, cfg: ModelConfig) -> tuple[float, float]:
    """Speeds [rad/s] below which the load and the motor side count as sticking.

    3 × the sign smoothing ε, or 3 × the velocity estimate's noise from the encoder's
    quantisation (Δ²/12 through the velocity filter), whichever is larger: a coarse encoder
    cannot tell a slow joint from a stuck one below that."""
    w = kinematics_velocity_window(kin)
    g = float(np.linalg.norm(savgol_coeffs(w, min(kin.degree, w - 1), deriv=1, delta=kin.dt)))
    eps3 = 3.0 * float(cfg.estimator.sign_eps)
    out = []
    for side in ("load", "motor"):
        d = max(e["used"] for e in quanta[side])
        out.append(max(eps3, 3.0 * g * d / math.sqrt(12.0)))
    return out[0], out[1]


def kinematics_velocity_window(kin) -> int:
    return int(getattr(kin, "velocity_window", 0) or window_samples(kin.t, 0.05))


def holdout_blocks(score: np.ndarray, window: int, holdout: float, need: int) -> tuple[np.ndarray | None, dict, str | None]:
    """Fit-block mask and the evaluation blocks of a held-out validation (last ``holdout`` of
    the log kept back; half a smoothing window at the boundary belongs to neither; only the
    samples of ``score``)."""
    N = score.size
    if not holdout or holdout <= 0:
        return None, {}, None
    n_test = int(round(holdout * N))
    guard = window // 2
    n_fit = N - n_test - guard
    if n_fit < need or n_test < need // 2:
        return None, {}, (f"The log is too short to keep {100 * holdout:.0f} % back for validation "
                          f"(the fit needs {need} samples): fitted and scored on the whole log.")
    fit = np.zeros(N, dtype=bool)
    fit[:n_fit] = True
    test = np.zeros(N, dtype=bool)
    test[N - n_test:] = True
    return fit & score, {"fit_block": fit & score, "held_out_block": test & score}, None


class Work:
    """The log as diagnose works on it: uniform grid, segments of a long log, kinematics."""

    def __init__(self, log: MeasuredLog, cfg: ModelConfig, opts: SelectOptions):
        self.prep = prepare_log(log)
        self.quanta = encoder_quanta(log, cfg)
        self.seg = segment_log(self.prep.log, opts.max_rows)
        self.log = self.seg.log if self.seg is not None else self.prep.log
        check_log(self.log, cfg)
        self.kin = kinematics_from_log(self.log)
        #: the motor balance's gain on the spring torque (a swapped log is refused here)
        self.balance = check_motor_balance(cfg, self.kin, log.path)
        self.v_stick = stick_speeds(self.kin, self.quanta, cfg)
        # the samples scored and fitted: all, or those away from the seams of a segmented log
        self.score = (self.seg.away_from_seams(self.kin.window) if self.seg is not None
                      else np.ones(len(self.log), dtype=bool))
        self.spans = self.seg.spans if self.seg is not None else None
        self.notes = list(self.prep.notes)
        #: the log's motion (:mod:`.excitation`) and the candidates it cannot reveal (select_effects)
        self.excitation: Excitation | None = None
        self.not_identifiable: list[dict] = []
        if self.seg is not None:
            a = [round(float(self.prep.log.t[i]), 3) for i, _ in self.seg.source_spans]
            self.notes.append(f"The log has {self.seg.original_rows} rows: diagnose works on {len(self.log)} of them, "
                              f"{len(self.seg.spans)} segments of {self.seg.spans[0][1]} rows spread over it "
                              f"(starting at t = {', '.join(f'{x:g}' for x in a)} s); the fit leaves "
                              f"{self.kin.window} samples either side of a seam out and the AKF runs over each "
                              "segment from its first sample (--max-rows to change).")
        for side, j, conf, obs in self.quanta["mismatch"]:
            self.notes.append(f"The {side} encoder steps by {obs:.3g} rad in the log (joint side), the configuration "
                              f"says {conf:.3g} rad: set hardware.encoder_counts ({side}) to the encoder's counts "
                              "per revolution; diagnose used the log's step.")

    def summary(self) -> dict:
        d = self.prep.summary()
        if self.seg is not None:
            d["segments"] = [[int(a), int(b)] for a, b in self.seg.source_spans]
        return d


def _validation_models(ctx: Context, cands, opts: SelectOptions, sel: Selection, fit_t, v_stick) -> dict:
    """The models of the time-blocked validation, fitted on the fit block alone: (a) ``refit``,
    the effects found with their parameters refitted; (b) ``selection``, the whole selection
    repeated."""
    v_sel = Selector(ctx, cands, opts, fit_t=fit_t, v_min=v_stick)
    out = {"refit": v_sel.refit(list(sel.chosen))}
    if opts.validate_selection:
        out["selection"] = list(v_sel.run().chosen)
    return out


def _ablation(w: Work, cfg: ModelConfig, effects: list, est: dict) -> list[dict]:
    """When the AKF estimates worse with the effects than without: its error with each effect
    left out in turn (which one the filter cannot use on this log)."""
    b, a = est.get("before"), est.get("after")
    if b is None or a is None or a <= b or len(effects) < 1:
        return []
    out = []
    for i, e in enumerate(effects):
        rest = effects[:i] + effects[i + 1:]
        c = cfg.with_effects(list(cfg.model.effects) + rest) if rest else None
        r = estimate_rmse(w.log, cfg, c, spans=w.spans, score=w.score)["after"]
        out.append({"type": e.type, "side": e.side, "estimate_rmse_without": num(r)})
    return out



class Fit(NamedTuple):
    """The selection on the whole log: its context, candidates, selector and result, and the
    model with the effects found."""

    ctx: Context
    cands: list[Candidate]
    selector: Selector
    sel: Selection
    effects: list
    cfg_after: ModelConfig
    r_after: np.ndarray             # (N, 2n) residual of cfg_after


class Evaluation(NamedTuple):
    """The validation and the AKF's error: held-out blocks, validation models, estimates."""

    blocks: dict                    # {"fit_block", "held_out_block"}: (N,) masks, or {}
    block_note: str | None          # why no block was kept back, or None
    val_models: dict                # {"refit", "selection"}: [(candidate, params)]
    est: dict                       # estimate_rmse's dict
    gp: dict | None                 # gpakf_rmse's dict, when the GP-AKF was scored
    ablation: list[dict]            # the AKF's error with each effect left out, when worse after


@dataclass
class Diagnosis:
    """Everything a diagnosis found (the JSON dict plus the objects the report draws)."""

    result: dict
    ctx: Context
    sel: Selection
    selector: Selector
    cfg_after: ModelConfig
    r_after: np.ndarray
    est: dict
    prep: Prepared | None = None
    blocks: dict = field(default_factory=dict)
    work: Work | None = None
    #: the model on other logs (:func:`.apply.apply_model`), filled by the caller
    applied: list = field(default_factory=list)


def excitation(w: Work, ctx: Context, mask: np.ndarray | None = None) -> Excitation:
    """The motion of the log over ``mask`` (default the samples scored) (:mod:`.excitation`)."""
    q, th = ctx.angles()
    steps = {side: [e["used"] for e in w.quanta[side]] for side in ("load", "motor")}
    return measure(w.kin, q, th, w.v_stick, steps, w.score if mask is None else mask)


def identifiable(cands: list[Candidate], exc: Excitation) -> tuple[list[Candidate], list[dict]]:
    """The candidates whose motion the log holds, and for the others what motion is missing."""
    keep, missing = [], []
    for c in cands:
        why = exc.missing(c.type, c.side, c.joint)
        if why is None:
            keep.append(c)
        else:
            missing.append({"type": c.type, "side": c.side, "joint": c.joint + 1, "missing": why})
    return keep, missing


def select_effects(w: Work, cfg: ModelConfig, opts: SelectOptions, passive: bool) -> Fit:
    """The selection on every sample of the log (away from the seams of a segmented one), over
    the candidates whose motion the log holds (:mod:`.excitation`)."""
    ctx = Context(cfg, w.kin, None, passive=passive, v_stick=w.v_stick)
    ctx.r0 = ctx.residual()
    w.excitation = excitation(w, ctx)
    cands, w.not_identifiable = identifiable(build_candidates(ctx), w.excitation)
    selector = Selector(ctx, cands, opts, fit_t=w.score, v_min=w.v_stick)
    sel = selector.run()
    return _fit(cfg, ctx, cands, selector, sel)


def _fit(cfg: ModelConfig, ctx: Context, cands, selector: Selector, sel: Selection) -> Fit:
    effects = [c.effect(p) for c, p in sel.chosen]
    cfg_after = cfg.with_effects(list(cfg.model.effects) + effects)
    r_after = ctx.residual(effects)
    return Fit(ctx, cands, selector, sel, effects, cfg_after, r_after)


class CV(NamedTuple):
    """The cross-validation over time blocks (:mod:`.crossval`)."""

    blocks: list                    # (N,) masks of the held-out blocks
    dropped: list[dict]             # effects the selection found that do not help out of sample
    kept: dict | None               # per block held-out figures of the effects kept, refitted per fold
    repeated: list[dict]            # per block: the whole selection repeated without it
    note: str | None                # why there is no cross-validation


def _inner(w: Work) -> np.ndarray:
    """The samples scored, away from the smoother's ends."""
    N, e = len(w.log), w.kin.window
    m = np.zeros(N, dtype=bool)
    m[e:N - e] = True
    return m & w.score


def cross_validate(w: Work, cfg: ModelConfig, opts: SelectOptions, fit: Fit, estimate: bool) -> tuple[Fit, CV]:
    """Keep only the effects that help blocks of the log their fit did not see
    (:class:`.crossval.CrossValidation`); with ``opts.cv_repeat_selection`` and ``estimate``, the
    whole selection repeated without each block and scored on it."""
    need = max(4 * w.kin.window, 50)
    inner = _inner(w)
    blocks = time_blocks(inner, opts.cv_blocks, need) if opts.cv_blocks >= 2 else []
    if not blocks:
        if not fit.sel.chosen:
            return fit, CV([], [], None, [], None)
        why = (f"The log is too short to check an effect on time its fit did not see (two blocks of at least "
               f"{need} samples): nothing added." if opts.cv_blocks >= 2 else None)
        if why is None:
            return fit, CV([], [], None, [], "Cross-validation switched off: the effects are not checked out of sample.")
        sel = fit.selector.restrict(fit.sel, [])
        return _fit(cfg, fit.ctx, fit.cands, fit.selector, sel), CV([], [], None, [], why)
    guard = w.kin.window // 2
    scorer = BlockScorer(w.log, w.spans) if estimate else None
    sels = [Selector(fit.ctx, fit.cands, opts, fit_t=without(w.score, b, guard), v_min=w.v_stick) for b in blocks]
    cv = CrossValidation(fit.ctx, cfg, blocks, sels, inner, scorer)
    pairs = list(fit.sel.chosen)
    keep, dropped = cv.prune(pairs) if pairs else ([], [])
    if len(keep) < len(pairs):
        fit = _fit(cfg, fit.ctx, fit.cands, fit.selector, fit.selector.restrict(fit.sel, keep))
    kept = cv.score(pairs, tuple(keep))
    repeated = []
    if opts.cv_repeat_selection and estimate:
        def cands_for(mask):
            return identifiable(build_candidates(fit.ctx), excitation(w, fit.ctx, mask))[0]
        repeated = repeated_per_block(fit.ctx, cfg, cands_for, opts, w.score, blocks, guard, inner, scorer, w.v_stick)
    return fit, CV(blocks, dropped, {"figures": kept, "sizes": cv.sizes}, repeated, None)


def evaluate(w: Work, cfg: ModelConfig, opts: SelectOptions, fit: Fit, estimate: bool) -> Evaluation:
    """Time-blocked validation (the first part of the log fitted, the last part scored), the
    AKF before and after and, when the AKF is worse after, which effect it cannot use."""
    kin = w.kin
    fit_t, blocks, block_note = holdout_blocks(w.score, kin.window, opts.holdout, max(4 * kin.window, 50))
    val_models = _validation_models(fit.ctx, fit.cands, opts, fit.sel, fit_t, w.v_stick) if blocks else {}
    cfgs = {"after": fit.cfg_after if fit.effects else None}
    for k, pairs in val_models.items():
        cfgs[k] = cfg.with_effects(list(cfg.model.effects) + [c.effect(p) for c, p in pairs]) if pairs else None
    est = (estimate_rmse(w.log, cfg, cfgs, blocks, spans=w.spans, score=w.score) if estimate
           else {"before": None, "after": None})
    gp = None
    if estimate and blocks and opts.validate_gp_akf:
        gp = gpakf_rmse(w.log, {"before": cfg, **{k: v for k, v in cfgs.items() if k != "after"}},
                        blocks["fit_block"], blocks, spans=w.spans)
    ablation = _ablation(w, cfg, fit.effects, est) if estimate else []
    return Evaluation(blocks, block_note, val_models, est, gp, ablation)


#: the steps of :func:`run_diagnosis`, as its progress callback names them
STEPS = ("the log on a uniform grid", "selecting the effects", "validation and the AKF before and after",
         "summary")


def run_diagnosis(log: MeasuredLog, cfg: ModelConfig, options: SelectOptions | None = None,
                  passive: bool | None = None, estimate: bool = True,
                  progress: Callable | None = None) -> Diagnosis:
    """Run the whole diagnosis (no files).  ``passive``: ignore a tau_h_act column.
    ``progress(done, total, what)``, when given, is called before each of its :data:`STEPS`.

    The log is put on a uniform grid (:func:`.prepare.prepare_log`), a long one cut to segments
    (:func:`.prepare.segment_log`); the selection runs on it (:class:`.select.Selector`), then the
    time-blocked validation, the AKF before and after and, when the AKF is worse after, which
    effect it cannot use."""
    def step(k: int) -> None:
        if progress is not None:
            progress(k, len(STEPS), STEPS[k])
    check_log(log, cfg)
    opts = options or SelectOptions()
    step(0)
    w = Work(log, cfg, opts)
    passive = bool(passive)
    step(1)
    fit = select_effects(w, cfg, opts, passive)
    step(2)
    fit, cv = cross_validate(w, cfg, opts, fit, estimate)
    ev = evaluate(w, cfg, opts, fit, estimate)
    w.notes += [ev.block_note] if ev.block_note else []
    step(3)
    result = _result(w, opts, fit, ev, passive)
    result["cross_validation"] = cv_summary(cv, w.log.t)
    result["statements"] += cv_statements(result["cross_validation"], cv.note)
    if not result["effects_added"] and cv.dropped:
        result["statements"][0] = ("No effect added: what the selection found does not help the blocks of the log "
                                   "its fit did not see (cross-validation, below).")
    return Diagnosis(result, fit.ctx, fit.sel, fit.selector, fit.cfg_after, fit.r_after, ev.est,
                     prep=w.prep, blocks=ev.blocks, work=w)


def _result(w: Work, opts: SelectOptions, fit: Fit, ev: Evaluation, passive: bool) -> dict:
    """The docs/interfaces.md §4 dict with the extensions of docs/diagnose.md."""
    ctx, sel, selector, r_after, est, blocks = fit.ctx, fit.sel, fit.selector, fit.r_after, ev.est, ev.blocks
    log, kin, score, n = w.log, w.kin, w.score, ctx.cfg.joints
    warn = bool(sel.structure.get("warn"))
    added = effects_json(sel, n, warn)
    says = (statements(sel, added, warn, kin) + missing_statements(w.not_identifiable) + w.notes
            + ablation_statements(ev.ablation, est))
    validation = None
    if blocks:
        val_r = {k: ctx.residual([c.effect(p) for c, p in pairs]) for k, pairs in ev.val_models.items()}
        validation = validation_summary(ctx.r0, val_r, ev.val_models, est, blocks, selector.edge, log.t, ev.gp)
        says.append(validation["statement"])
    r0s, ras = ctx.r0[score], r_after[score]
    result = {
        "samples": int(w.prep.original_samples),
        "residual_rms_before": num(rms(r0s)),
        "residual_rms_after": num(rms(ras)),
        "effects_added": added,
        "unexplained_fraction": num(sel.unexplained),
        "estimate_rmse_before": num(est["before"]),
        "estimate_rmse_after": num(est["after"]),
        # --- extensions (docs/interfaces.md §4 allows additions)
        # RMS over the samples the fit used (moving, away from the filter's edges): without
        # the turning points, where sticking friction leaves a residual no smooth model explains
        "residual_rms_fit_before": num(rms(ctx.r0[selector.keep_t])),
        "residual_rms_fit_after": num(rms(r_after[selector.keep_t])),
        "residual_rms_channels": {
            "before": {"load": num(rms(r0s[:, :n])), "motor": num(rms(r0s[:, n:]))},
            "after": {"load": num(rms(ras[:, :n])), "motor": num(rms(ras[:, n:]))},
        },
        "unexplained_structure": {
            "fraction": num(sel.structure.get("fraction", 0.0)),
            "rms": num(sel.structure.get("rms", 0.0)),
            "follows": sel.structure.get("signals", []),
            "channel": sel.structure.get("channel"),
            "matches_no_candidate": warn,
        },
        "statements": says,
        "fit": _fit_summary(w, opts, fit, bool(blocks), passive),
        "estimate_nis_before": num(est.get("nis_before")),
        "estimate_nis_after": num(est.get("nis_after")),
        "correlated_pairs": [{k: (num(v) if isinstance(v, float) else v) for k, v in c.items()}
                             for c in sel.correlated],
    }
    result["not_identifiable"] = w.not_identifiable
    result["excitation"] = w.excitation.to_json() if w.excitation is not None else []
    if ev.ablation:
        result["estimate_ablation"] = ev.ablation
    if validation:
        result["validation"] = {k: v for k, v in validation.items() if k != "statement"}
    return result


def _fit_summary(w: Work, opts: SelectOptions, fit: Fit, held_out: bool, passive: bool) -> dict:
    """The result's ``fit`` section: the samples, windows and thresholds the selection used."""
    ctx, selector, kin, log, v_stick = fit.ctx, fit.selector, w.kin, w.log, w.v_stick
    return {
        "samples_used": int(np.sum(selector.keep_t)),
        "fit_stride": int(selector.stride),
        "low_velocity_share_left_out": num(selector.masked_share),
        "smoothing_window_samples": int(kin.window),
        "autocorrelation_time_samples": num(fit.sel.tau_int),
        "candidates": len(fit.cands),
        "truth": "tau_h_act column" if (log.tau_h_act is not None and not passive) else "zero (passive subject)",
        "stick_speed_rad_s": {"load": num(v_stick[0]), "motor": num(v_stick[1])},
        "encoder_step_rad": {side: [{k: num(v) for k, v in e.items()} for e in w.quanta[side]]
                             for side in ("load", "motor")},
        "fast_command_gain": [{"kappa": num(k), "ci95_half_width": num(h)}
                              for k, h in zip(ctx.fast_gain.kappa, ctx.fast_gain.half_width)],
        "time_grid": w.summary(),
        "holdout": num(opts.holdout if held_out else 0.0),
        "min_effect_rms": num(selector.opts.min_effect_rms),
    }
