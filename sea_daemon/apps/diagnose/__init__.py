"""``diagnose``: find the effects a measured log holds that the model lacks (issue 6).

    from sea_daemon.apps.diagnose import diagnose
    result = diagnose(log, cfg, out_dir="diag_out")      # docs/interfaces.md §4 JSON as a dict

1. residuals of the configured model on both sides (:mod:`.residuals`),
2. candidates of the effect vocabulary on every side (:mod:`.candidates`),
3. forward selection with BIC, blocked cross-validation and a size floor, joint
   refinement and confidence intervals, a check for structure no candidate explains
   (:mod:`.select`),
4. the augmented model and the AKF's estimation error with the model before and after
   (:mod:`.evaluate`), a time-blocked validation on the log's last part, the model on other
   logs without truth (:mod:`.apply`), and ``report.md`` with plots (:mod:`.report`).

The log is first put on a uniform time grid, its encoder steps read and, when it is longer than
``SelectOptions.max_rows``, cut to segments (:mod:`.prepare`).  As a library call (the
calibration uses it on its logs): ``run_diagnosis(log, cfg, options, passive, estimate)`` returns a
:class:`Diagnosis` (``result`` the JSON dict, ``cfg_after`` the augmented configuration) and
writes nothing.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from sea_daemon.core.config import ModelConfig
from sea_daemon.io.configfile import config_text, save_config
from sea_daemon.io.files import atomic_write_text
from sea_daemon.errors import ConfigError, InputError, LogFormatError, shown
from sea_daemon.core.log import MeasuredLog
from sea_daemon.analysis.diagnose.candidates import Context, build_candidates
from sea_daemon.analysis.diagnose.evaluate import estimate_rmse, gpakf_rmse
from sea_daemon.analysis.diagnose.prepare import encoder_quanta, prepare_log, segment_log
from sea_daemon.analysis.diagnose.residuals import kinematics_from_log, rms, window_samples
from sea_daemon.analysis.diagnose.select import SelectOptions, Selection, Selector

__all__ = ["diagnose", "SelectOptions", "run_diagnosis", "Diagnosis"]


class Diagnosis:
    """Everything a diagnosis found (the JSON dict plus the objects the report draws)."""

    def __init__(self, result: dict, ctx: Context, sel: Selection, selector: Selector,
                 cfg_after: ModelConfig, r_after: np.ndarray, est: dict):
        self.result = result
        self.ctx = ctx
        self.sel = sel
        self.selector = selector
        self.cfg_after = cfg_after
        self.r_after = r_after
        self.est = est


def _check(log: MeasuredLog, cfg: ModelConfig) -> None:
    if log.n != cfg.joints:
        raise InputError(f"{log.path}: the log has {log.n} joint(s), the model {cfg.source} has {cfg.joints}")
    need = max(4 * window_samples(log.t), 50)
    if len(log) < need:
        raise LogFormatError(log.path, None, f"has {len(log)} data rows; diagnose needs at least {need} "
                                             f"(four smoothing windows of {window_samples(log.t)} samples)")


def stick_speeds(kin, quanta: dict, cfg: ModelConfig) -> tuple[float, float]:
    """Speeds [rad/s] below which the load and the motor side count as sticking.

    3 × the sign smoothing ε, or 3 × the velocity estimate's noise from the encoder's
    quantisation (Δ²/12 through the velocity filter), whichever is larger: a coarse encoder
    cannot tell a slow joint from a stuck one below that."""
    from scipy.signal import savgol_coeffs
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


def _blocks(score: np.ndarray, window: int, holdout: float, need: int) -> tuple[np.ndarray | None, dict, str | None]:
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


class _Work:
    """The log as diagnose works on it: uniform grid, segments of a long log, kinematics."""

    def __init__(self, log: MeasuredLog, cfg: ModelConfig, opts: SelectOptions):
        self.prep = prepare_log(log)
        self.quanta = encoder_quanta(log, cfg)
        self.seg = segment_log(self.prep.log, opts.max_rows)
        self.log = self.seg.log if self.seg is not None else self.prep.log
        _check(self.log, cfg)
        self.kin = kinematics_from_log(self.log)
        self.v_stick = stick_speeds(self.kin, self.quanta, cfg)
        # the samples scored and fitted: all, or those away from the seams of a segmented log
        self.score = (self.seg.away_from_seams(self.kin.window) if self.seg is not None
                      else np.ones(len(self.log), dtype=bool))
        self.spans = self.seg.spans if self.seg is not None else None
        self.notes = list(self.prep.notes)
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


def _effects_json(sel: Selection, n: int, warn: bool) -> list[dict]:
    """``effects_added`` of docs/interfaces.md §4 with the extensions of docs/diagnose.md."""
    added = []
    for (cand, params), ci, frac, alts in zip(sel.chosen, sel.ci, sel.explained,
                                              sel.alternatives + [[]] * len(sel.chosen)):
        # relative CI half-widths (angles and rest positions, which may rightly be ≈ 0, aside)
        rel = [abs(hi - lo) / 2 / max(abs(params[p]), 1e-12) for p, (lo, hi) in ci.items()
               if p not in ("phi", "q_h0") and math.isfinite(hi)]
        lower_only = [p for p, (lo, hi) in ci.items() if hi == math.inf]
        confident = (not warn) and (not alts) and sel.unexplained < 0.5 and all(r < 0.2 for r in rel)
        d = {"type": cand.type, "side": cand.side}
        if n > 1:
            d["joint"] = cand.joint + 1
        d["params"] = {p: _num(v) for p, v in params.items()}
        d["explained_fraction"] = _num(frac)
        d["ci95"] = {p: [_num(lo), _num(hi)] for p, (lo, hi) in ci.items()}
        d["confidence"] = "high" if confident else "low"
        if alts:
            d["alternatives"] = alts
        if lower_only:
            # static friction: the sticking phases bound it from below only (ci95 [lo, null])
            d["lower_bound_only"] = lower_only
        added.append(d)
    return added


def _ablation(w: "_Work", cfg: ModelConfig, effects: list, est: dict) -> list[dict]:
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
        out.append({"type": e.type, "side": e.side, "estimate_rmse_without": _num(r)})
    return out


def run_diagnosis(log: MeasuredLog, cfg: ModelConfig, options: SelectOptions | None = None,
                  passive: bool | None = None, estimate: bool = True) -> Diagnosis:
    """Run the whole diagnosis (no files).  ``passive``: ignore a tau_h_act column.

    The log is put on a uniform grid (:func:`.prepare.prepare_log`), a long one cut to segments
    (:func:`.prepare.segment_log`); the selection runs on it (:class:`.select.Selector`), then the
    time-blocked validation, the AKF before and after and, when the AKF is worse after, which
    effect it cannot use."""
    _check(log, cfg)
    opts = options or SelectOptions()
    w = _Work(log, cfg, opts)
    log, kin, v_stick, score = w.log, w.kin, w.v_stick, w.score
    passive = bool(passive)
    ctx = Context(cfg, kin, None, passive=passive, v_stick=v_stick)
    ctx.r0 = ctx.residual()
    cands = build_candidates(ctx)
    # the diagnosis: every sample of the log (away from the seams of a segmented one)
    selector = Selector(ctx, cands, opts, fit_t=score, v_min=v_stick)
    sel = selector.run()
    n = cfg.joints
    effects = [c.effect(p) for c, p in sel.chosen]
    cfg_after = cfg.with_effects(list(cfg.model.effects) + effects)
    r_after = ctx.residual(effects)
    # time-blocked validation: the first part of the log is fitted, the last part scored
    fit_t, blocks, block_note = _blocks(score, kin.window, opts.holdout, max(4 * kin.window, 50))
    val_models = _validation_models(ctx, cands, opts, sel, fit_t, v_stick) if blocks else {}
    cfgs = {"after": cfg_after if effects else None}
    for k, pairs in val_models.items():
        cfgs[k] = cfg.with_effects(list(cfg.model.effects) + [c.effect(p) for c, p in pairs]) if pairs else None
    est = (estimate_rmse(log, cfg, cfgs, blocks, spans=w.spans, score=score) if estimate
           else {"before": None, "after": None})
    gp = None
    if estimate and blocks and opts.validate_gp_akf:
        gp = gpakf_rmse(log, {"before": cfg, **{k: v for k, v in cfgs.items() if k != "after"}},
                        blocks["fit_block"], blocks, spans=w.spans)
    ablation = _ablation(w, cfg, effects, est) if estimate else []
    w.notes += [block_note] if block_note else []

    warn = bool(sel.structure.get("warn"))
    added = _effects_json(sel, n, warn)
    statements = _statements(sel, added, warn, selector) + w.notes + _ablation_statements(ablation, est)
    nch = n
    validation = None
    if blocks:
        val_r = {k: ctx.residual([c.effect(p) for c, p in pairs]) for k, pairs in val_models.items()}
        validation = _validation(ctx.r0, val_r, val_models, est, blocks, selector.edge, log.t, gp)
        statements.append(validation["statement"])
    r0s, ras = ctx.r0[score], r_after[score]
    result = {
        "samples": int(w.prep.original_samples),
        "residual_rms_before": _num(rms(r0s)),
        "residual_rms_after": _num(rms(ras)),
        "effects_added": added,
        "unexplained_fraction": _num(sel.unexplained),
        "estimate_rmse_before": _num(est["before"]),
        "estimate_rmse_after": _num(est["after"]),
        # --- extensions (docs/interfaces.md §4 allows additions)
        # RMS over the samples the fit used (moving, away from the filter's edges): without
        # the turning points, where sticking friction leaves a residual no smooth model explains
        "residual_rms_fit_before": _num(rms(ctx.r0[selector.keep_t])),
        "residual_rms_fit_after": _num(rms(r_after[selector.keep_t])),
        "residual_rms_channels": {
            "before": {"load": _num(rms(r0s[:, :nch])), "motor": _num(rms(r0s[:, nch:]))},
            "after": {"load": _num(rms(ras[:, :nch])), "motor": _num(rms(ras[:, nch:]))},
        },
        "unexplained_structure": {
            "fraction": _num(sel.structure.get("fraction", 0.0)),
            "rms": _num(sel.structure.get("rms", 0.0)),
            "follows": sel.structure.get("signals", []),
            "channel": sel.structure.get("channel"),
            "matches_no_candidate": warn,
        },
        "statements": statements,
        "fit": {
            "samples_used": int(np.sum(selector.keep_t)),
            "fit_stride": int(selector.stride),
            "low_velocity_share_left_out": _num(selector.masked_share),
            "smoothing_window_samples": int(kin.window),
            "autocorrelation_time_samples": _num(sel.tau_int),
            "candidates": len(cands),
            "truth": "tau_h_act column" if (log.tau_h_act is not None and not passive) else "zero (passive subject)",
            "stick_speed_rad_s": {"load": _num(v_stick[0]), "motor": _num(v_stick[1])},
            "encoder_step_rad": {side: [{k: _num(v) for k, v in e.items()} for e in w.quanta[side]]
                                 for side in ("load", "motor")},
            "fast_command_gain": [{"kappa": _num(k), "ci95_half_width": _num(h)}
                                  for k, h in zip(ctx.fast_gain.kappa, ctx.fast_gain.half_width)],
            "time_grid": w.summary(),
            "holdout": _num(opts.holdout if blocks else 0.0),
            "min_effect_rms": _num(selector.opts.min_effect_rms),
        },
        "estimate_nis_before": _num(est.get("nis_before")),
        "estimate_nis_after": _num(est.get("nis_after")),
        "correlated_pairs": [{k: (_num(v) if isinstance(v, float) else v) for k, v in c.items()}
                             for c in sel.correlated],
    }
    if ablation:
        result["estimate_ablation"] = ablation
    if validation:
        result["validation"] = {k: v for k, v in validation.items() if k != "statement"}
    dg = Diagnosis(result, ctx, sel, selector, cfg_after, r_after, est)
    dg.prep, dg.blocks, dg.work = w.prep, blocks, w
    return dg


def _ablation_statements(ablation: list[dict], est: dict) -> list[str]:
    if not ablation:
        return []
    worst = min((d for d in ablation if d["estimate_rmse_without"] is not None),
                key=lambda d: d["estimate_rmse_without"], default=None)
    msg = (f"The AKF estimates worse with the effects found than without them ({est['before']:.3g} → "
           f"{est['after']:.3g} N m RMS). ")
    if worst is not None:
        msg += (f"Left out in turn, {worst['type']} ({worst['side']}) costs the most: without it "
                f"{worst['estimate_rmse_without']:.3g} N m. ")
    msg += ("An effect can be real (it lowers the residual) and still not help the filter: friction that "
            "changes within the filter's velocity uncertainty of zero speed is evaluated on the wrong side "
            "of its steep part (docs/diagnose.md, Limits).  model_augmented.yaml holds every effect found; "
            "for estimation, leave out the one named here.")
    return [msg]


def _validation(r0, val_r: dict, val_models: dict, est: dict, blocks: dict, edge: int, t,
                gp: dict | None = None) -> dict:
    """Errors before/after on the fit block and on the held-out block (time-blocked) of each
    validation model, and how much of the fit block's improvement holds on the block the fit
    never saw.  ``refit``: the effects found, parameters refitted on the fit block;
    ``selection``: the whole diagnosis repeated on the fit block."""
    N = r0.shape[0]
    inner = np.zeros(N, dtype=bool)
    inner[edge:N - edge] = True
    out: dict = {}
    for name, m in blocks.items():
        idx = np.flatnonzero(m)
        out[name] = {"t_s": [_num(t[idx[0]]), _num(t[idx[-1]])], "samples": int(m.sum())}

    def ratio(b, a):
        return _num(b / a) if (b is not None and a) else None

    def x(v):
        return "—" if v is None else f"{v:.2f}×"

    def pc(v):
        return "—" if v is None else f"{100 * v:.0f} %"
    for key, pairs in val_models.items():
        r = val_r[key]
        d: dict = {"effects": [{"type": c.type, "side": c.side, "params": {k: _num(v) for k, v in p.items()}}
                               for c, p in pairs]}
        for name, m in blocks.items():
            mm = m & inner
            d[name] = {"residual_rms_before": _num(rms(r0[mm])), "residual_rms_after": _num(rms(r[mm])),
                       "estimate_rmse_before": _num(est.get(f"{name}_before")),
                       "estimate_rmse_after": _num(est.get(f"{name}_{key}"))}
        for kind in ("residual_rms", "estimate_rmse"):
            f, h = d["fit_block"], d["held_out_block"]
            rf = ratio(f[f"{kind}_before"], f[f"{kind}_after"])
            rh = ratio(h[f"{kind}_before"], h[f"{kind}_after"])
            share = _num((1 - 1 / rh) / (1 - 1 / rf)) if (rf and rh and rf != 1.0) else None
            d["residual" if kind == "residual_rms" else "estimate"] = {
                "improvement_fit_block": rf, "improvement_held_out": rh, "held_out_share": share}
        if gp is not None and gp.get("before") and gp.get(key):
            d["gp_akf"] = {name: {"estimate_rmse_before": _num(gp["before"][name]),
                                  "estimate_rmse_after": _num(gp[key][name])} for name in blocks}
            g = d["gp_akf"]["held_out_block"]
            d["gp_akf"]["improvement_held_out"] = ratio(g["estimate_rmse_before"], g["estimate_rmse_after"])
        out[key] = d
    h = out["held_out_block"]
    msg = f"Validation on a held-out time block ({h['t_s'][0]:.3g}–{h['t_s'][1]:.3g} s)"
    if "refit" in out:
        r, e = out["refit"]["residual"], out["refit"]["estimate"]
        msg += (f": the effects found, refitted on the rest of the log alone, lower the residual RMS there "
                f"{x(r['improvement_held_out'])} ({x(r['improvement_fit_block'])} where they were fitted; "
                f"{pc(r['held_out_share'])} of the reduction holds out of sample) and the AKF's τ̂_h,act error "
                f"{x(e['improvement_held_out'])} ({x(e['improvement_fit_block'])}; {pc(e['held_out_share'])} holds)")
    if "refit" in out and "gp_akf" in out["refit"]:
        msg += (f"; the GP-AKF, trained on the rest of the log, "
                f"{x(out['refit']['gp_akf']['improvement_held_out'])} there")
    if "selection" in out:
        sv = out["selection"]
        names = ", ".join(f"{d['type']} ({d['side']})" for d in sv["effects"]) or "nothing"
        msg += (f". The whole diagnosis repeated without that block finds {names}: residual "
                f"{x(sv['residual']['improvement_held_out'])}, τ̂_h,act error {x(sv['estimate']['improvement_held_out'])} "
                "on the held-out block")
    out["statement"] = msg + "."
    return out


def _num(v):
    if v is None:
        return None
    v = float(v)
    return v if math.isfinite(v) else None


def _statements(sel: Selection, added: list[dict], warn: bool, selector: Selector) -> list[str]:
    out = []
    st = sel.structure
    if not added and sel.dropped:
        out.append("No effect added: what the candidates explain, this log cannot pin down (see below).")
    elif not added:
        out.append("No undeclared effect found: no candidate of the vocabulary explains a worthwhile part "
                   "of the residual (see the candidate table for the best one and why it was rejected).")
    else:
        names = ", ".join(f"{d['type']} ({d['side']})" for d in added)
        out.append(f"Found: {names}; together they explain {100 * (1 - sel.unexplained):.1f} % of the "
                   f"residual's mean square.")
    if warn:
        out.append(f"A part of the residual ({100 * st['fraction']:.0f} % of its mean square, "
                   f"{st['channel']} side) follows {', '.join(st['signals'])} but matches no candidate "
                   "of the vocabulary: the model lacks an effect diagnose cannot name"
                   + ("; the effects above are at best a partial explanation." if added else "."))
    for name, params, ci in sel.dropped:
        ps = ", ".join(f"{k}={v:.4g} [{ci[k][0]:.3g}, {ci[k][1]:.3g}]" for k, v in params.items() if k in ci)
        out.append(f"{name} would explain part of the residual, but this log does not determine its parameters "
                   f"(95 % intervals wider than the values: {ps}); not added.")
    for c in sel.correlated:
        out.append(f"{c['kept']} and {c['dropped']} trade against each other on this log (parameter correlation "
                   f"{c['correlation']:+.2f}; {c['reason']}): kept {c['kept']}, the physically sensible one, "
                   f"dropped {c['dropped']}.")
    kin = selector.ctx.kin
    span = float(np.max(np.ptp(kin.q, axis=0)))
    if span < 0.05:
        out.append(f"The log hardly moves the joint (q spans {span:.3g} rad): effects that depend on the "
                   "angle or the velocity look alike (a constant torque); parameters of such effects are "
                   "weakly determined.  A log with motion over the working range tells them apart.")
    for d, alts in zip(added, sel.alternatives):
        if alts:
            msg = (f"{d['type']} ({d['side']}) and {', '.join(alts)} explain the residual almost equally "
                   "well on this log; the choice between them is weak")
            if any("spring_backlash" in a for a in alts) or d["type"] == "spring_backlash":
                msg += " (a dead band is only visible when the spring deflection changes sign)"
            out.append(msg + ".")
    return out


def diagnose(log: MeasuredLog, cfg: ModelConfig, out_dir: str | Path | None = None,
             options: SelectOptions | None = None, passive: bool | None = None,
             plots: bool = True, apply: list[MeasuredLog] | tuple = ()) -> dict:
    """Diagnose ``log`` against ``cfg``; return the docs/interfaces.md §4 dict.

    With ``out_dir``: write diagnosis.json, model_augmented.yaml, report.md and PNGs there.
    ``apply``: other logs (a person acting, no torque truth) to run the AKF on with the model
    before and after (:mod:`.apply`); their summaries go to the dict's ``applied``.
    """
    dg = run_diagnosis(log, cfg, options, passive)
    dg.applied = []
    if apply:
        from sea_daemon.apps.diagnose.apply import apply_model, claims
        v = dg.result.get("validation", {}).get("refit", {}).get("held_out_block", {})
        ref = {"all": dg.result["estimate_rmse_after"], "held_out": v.get("estimate_rmse_after")}
        for other in apply:
            if other.n != cfg.joints:
                raise InputError(f"{other.path}: the log has {other.n} joint(s), the model {cfg.source} has {cfg.joints}")
            res = apply_model(other, cfg, dg.cfg_after)
            res["claims"] = claims(res["summary"], ref)
            dg.applied.append(res)
        dg.result["applied"] = [{"log": r["log"], "samples": r["samples"], "resampled": r["resampled"],
                                 "summary": _clean(r["summary"]), "claims": r["claims"]} for r in dg.applied]
    if out_dir is not None:
        out = Path(out_dir)
        # never a model its own loader refuses (an effect fitted out of its range: the log does
        # not fit the nominal model, e.g. K_s off by a factor): refused before anything is written
        try:
            config_text(dg.cfg_after, out / "model_augmented.yaml")
        except ConfigError as e:
            raise InputError(f"{shown(log.path)}: the effects found make a configuration the loader refuses "
                             f"({e.key}: {e.problem}); the log does not fit the nominal model of "
                             f"{shown(cfg.source)} (check its model section); nothing written") from None
        out.mkdir(parents=True, exist_ok=True)
        atomic_write_text(out / "diagnosis.json", json.dumps(dg.result, indent=2, ensure_ascii=False) + "\n")
        save_config(dg.cfg_after, out / "model_augmented.yaml",
                    header=f"sea-daemon diagnose: {cfg.source} with the effects found in {log.path}")
        from sea_daemon.apps.diagnose.report import write_report
        write_report(dg, out, log, cfg, plots=plots)
    return dg.result


def _clean(d):
    """JSON-safe copy: non-finite numbers as None."""
    if isinstance(d, dict):
        return {k: _clean(v) for k, v in d.items()}
    if isinstance(d, (list, tuple)):
        return [_clean(v) for v in d]
    if isinstance(d, float):
        return _num(d)
    return d
