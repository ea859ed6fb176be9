"""``diagnose``: find the effects a measured log holds that the model lacks (issue 6).

    from sea_daemon.apps.diagnose import diagnose
    result = diagnose(log, cfg, out_dir="diag_out")      # docs/interfaces.md §4 JSON as a dict

1. residuals of the configured model on both sides (:mod:`.residuals`),
2. candidates of the effect vocabulary on every side (:mod:`.candidates`),
3. forward selection with BIC, blocked cross-validation and a size floor, joint
   refinement and confidence intervals, a check for structure no candidate explains
   (:mod:`.select`),
4. the augmented model and the AKF's estimation error with the model before and after
   (:mod:`.evaluate`), and ``report.md`` with plots (:mod:`.report`).
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
from sea_daemon.apps.diagnose.candidates import Context, build_candidates
from sea_daemon.apps.diagnose.evaluate import estimate_rmse
from sea_daemon.apps.diagnose.residuals import kinematics_from_log, rms, window_samples
from sea_daemon.apps.diagnose.select import SelectOptions, Selection, Selector

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
    dt = np.diff(log.t)
    if np.max(dt) > 1.5 * np.median(dt) or np.min(dt) < 0.5 * np.median(dt):
        i = int(np.argmax(np.abs(dt - np.median(dt))))
        raise LogFormatError(log.path, i + 3, f"sample period {dt[i]:.6g} s differs from the median "
                                              f"{np.median(dt):.6g} s by more than 50 %; diagnose needs a uniform rate")


def run_diagnosis(log: MeasuredLog, cfg: ModelConfig, options: SelectOptions | None = None,
                  passive: bool | None = None, estimate: bool = True) -> Diagnosis:
    """Run the whole diagnosis (no files).  ``passive``: ignore a tau_h_act column."""
    _check(log, cfg)
    opts = options or SelectOptions()
    kin = kinematics_from_log(log)
    passive = bool(passive)
    ctx = Context(cfg, kin, None, passive=passive)
    ctx.r0 = ctx.residual()
    cands = build_candidates(ctx)
    selector = Selector(ctx, cands, opts)
    sel = selector.run()
    n = cfg.joints
    effects = [c.effect(p) for c, p in sel.chosen]
    cfg_after = cfg.with_effects(list(cfg.model.effects) + effects)
    r_after = ctx.residual(effects)
    est = (estimate_rmse(log, cfg, cfg_after if effects else None) if estimate
           else {"before": None, "after": None})

    warn = bool(sel.structure.get("warn"))
    added = []
    for k, ((cand, params), ci, frac, alts) in enumerate(zip(sel.chosen, sel.ci, sel.explained,
                                                             sel.alternatives + [[]] * len(sel.chosen))):
        # relative CI half-widths (angles and rest positions, which may rightly be ≈ 0, aside)
        rel = [abs(hi - lo) / 2 / max(abs(params[p]), 1e-12) for p, (lo, hi) in ci.items()
               if p not in ("phi", "q_h0")]
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
        added.append(d)
    statements = _statements(sel, added, warn, selector)
    nch = n
    result = {
        "samples": int(len(log)),
        "residual_rms_before": _num(rms(ctx.r0)),
        "residual_rms_after": _num(rms(r_after)),
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
            "before": {"load": _num(rms(ctx.r0[:, :nch])), "motor": _num(rms(ctx.r0[:, nch:]))},
            "after": {"load": _num(rms(r_after[:, :nch])), "motor": _num(rms(r_after[:, nch:]))},
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
            "low_velocity_share_left_out": _num(selector.masked_share),
            "smoothing_window_samples": int(kin.window),
            "autocorrelation_time_samples": _num(sel.tau_int),
            "candidates": len(cands),
            "truth": "tau_h_act column" if (log.tau_h_act is not None and not passive) else "zero (passive subject)",
        },
    }
    return Diagnosis(result, ctx, sel, selector, cfg_after, r_after, est)


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
             plots: bool = True) -> dict:
    """Diagnose ``log`` against ``cfg``; return the docs/interfaces.md §4 dict.

    With ``out_dir``: write diagnosis.json, model_augmented.yaml, report.md and PNGs there.
    """
    dg = run_diagnosis(log, cfg, options, passive)
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
