"""report.md and PNG plots of a diagnosis (:class:`sea_daemon.analysis.diagnose.engine.Diagnosis`).

matplotlib is imported inside each plotting function: it is heavy and needed only when plots
are drawn (``--no-plots`` runs without it).
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from sea_daemon.core.config import ModelConfig
from sea_daemon.core.log import MeasuredLog
from sea_daemon.analysis.diagnose.summary import NOT_MEASURABLE


def _fmt(v, nd=4):
    if v is None:
        return "—"
    if isinstance(v, float) and not math.isfinite(v):
        return NOT_MEASURABLE
    if isinstance(v, float):
        if v != 0 and (abs(v) < 1e-3 or abs(v) >= 1e5):
            return f"{v:.3e}"
        return f"{v:.{nd}g}"
    return str(v)


def _pct(v, nd: int = 1) -> str:
    """A share as a percentage, or what the log cannot give."""
    if v is None or not math.isfinite(float(v)):
        return NOT_MEASURABLE
    return f"{100 * float(v):.{nd}f} %"


def _signed(v) -> str:
    return f"{float(v):+.1f}" if v is not None and math.isfinite(float(v)) else NOT_MEASURABLE


def _shade_holdout(ax, dg, t) -> None:
    """Grey band over the held-out validation block, if any."""
    blocks = getattr(dg, "blocks", None) or {}
    m = blocks.get("held_out_block")
    if m is not None and m.any():
        idx = np.flatnonzero(m)
        ax.axvspan(t[idx[0]], t[idx[-1]], color="0.85", zorder=0, label="held-out block")


def plot_residuals(dg, path: Path) -> None:
    import matplotlib          # heavy, only when plotting (module docstring)
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ctx = dg.ctx
    n = ctx.n
    t = ctx.kin.t
    fig, axes = plt.subplots(2 * n, 1, figsize=(10, 3.2 * 2 * n), sharex=True, squeeze=False)
    for ch in range(2 * n):
        ax = axes[ch, 0]
        side = "load" if ch < n else "motor"
        j = ch % n
        ax.plot(t, ctx.r0[:, ch], lw=1.6, color="tab:red", alpha=0.7,
                label=f"before (RMS {np.sqrt(np.mean(ctx.r0[:, ch]**2)):.3g} N m)")
        ax.plot(t, dg.r_after[:, ch], lw=0.8, color="tab:blue",
                label=f"after (RMS {np.sqrt(np.mean(dg.r_after[:, ch]**2)):.3g} N m)")
        ax.axhline(0, color="k", lw=0.5)
        _shade_holdout(ax, dg, t)
        ax.set_ylabel(f"r_{side}{'' if n == 1 else f'[{j + 1}]'} [N m]")
        ax.legend(loc="upper right", fontsize=8)
    axes[-1, 0].set_xlabel("t [s]")
    fig.suptitle("Model residuals before and after adding the effects found")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def plot_estimates(dg, log: MeasuredLog, path: Path) -> bool:
    """The AKF's τ̂_h,act with the model before and after, and the truth."""
    b, a = dg.est.get("before_series"), dg.est.get("after_series")
    if b is None and a is None:
        return False
    import matplotlib          # heavy, only when plotting (module docstring)
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    log = dg.work.log if getattr(dg, "work", None) is not None else log
    n = log.n
    truth = log.tau_h_act if log.tau_h_act is not None else np.zeros_like(log.q)
    fig, axes = plt.subplots(n, 1, figsize=(10, 3.4 * n), sharex=True, squeeze=False)
    for j in range(n):
        ax = axes[j, 0]
        ax.plot(log.t, truth[:, j], "k:", lw=1.2, label="truth" if log.tau_h_act is not None else "truth (passive: 0)")
        if b is not None:
            ax.plot(log.t, b[:, j], color="tab:red", lw=0.9, label=f"AKF, model before (RMSE {dg.est['before']:.3g} N m)")
        if a is not None:
            ax.plot(log.t, a[:, j], color="tab:blue", lw=0.9, label=f"AKF, model after (RMSE {dg.est['after']:.3g} N m)")
        _shade_holdout(ax, dg, log.t)
        ax.set_ylabel(f"τ̂_h,act{'' if n == 1 else f'[{j + 1}]'} [N m]")
        ax.legend(loc="upper right", fontsize=8)
    axes[-1, 0].set_xlabel("t [s]")
    fig.suptitle("Estimated active human torque with the model before and after")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return True


def plot_effect(dg, k: int, path: Path) -> None:
    """Partial residual (after + this effect's share) against the effect's regressor."""
    import matplotlib          # heavy, only when plotting (module docstring)
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ctx = dg.ctx
    n = ctx.n
    cand, params = dg.sel.chosen[k]
    eff = cand.effect(params)
    d = ctx.delta_r([eff]).reshape(ctx.r0.shape)           # this effect's share of the residual
    ch = cand.joint if cand.side in ("load", "spring") else n + cand.joint
    x, label = cand.regressor(ctx, params.get(cand.nonlinear) if cand.nonlinear else None)
    keep = dg.selector.keep_t
    partial = dg.r_after[:, ch] + d[:, ch]
    fig, ax = plt.subplots(figsize=(7, 4.5))
    ax.plot(x[keep], partial[keep], ".", ms=2, color="tab:gray", label="residual without the other effects")
    o = np.argsort(x[keep])
    ax.plot(x[keep][o], d[keep, ch][o], ".", ms=2, color="tab:blue", label=f"{cand.type} fitted")
    if (~keep).any():
        ax.plot(x[~keep], partial[~keep], "x", ms=2, color="tab:orange", alpha=0.5, label="left out (low velocity / edges)")
    ax.set_xlabel(label)
    ax.set_ylabel(f"r_{'load' if ch < n else 'motor'} [N m]")
    ps = ", ".join(f"{p}={_fmt(v)}" for p, v in params.items())
    ax.set_title(f"{cand.type} ({cand.side}): {ps}")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def plot_structure(dg, path: Path) -> None:
    """Leftover residual against q and q̇ (what no candidate took)."""
    import matplotlib          # heavy, only when plotting (module docstring)
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ctx = dg.ctx
    n = ctx.n
    keep = dg.selector.keep_t
    fig, axes = plt.subplots(2, 2, figsize=(10, 7), squeeze=False)
    for row, ch in enumerate((0, n)):
        for col, (x, lab) in enumerate(((ctx.kin.q[:, 0], "q [rad]"), (ctx.kin.dq[:, 0], "q̇ [rad/s]"))):
            ax = axes[row, col]
            up = keep & (ctx.kin.dq[:, 0] > 0)
            dn = keep & (ctx.kin.dq[:, 0] <= 0)
            ax.plot(x[up], dg.r_after[up, ch], ".", ms=2, color="tab:blue", label="q̇ > 0")
            ax.plot(x[dn], dg.r_after[dn, ch], ".", ms=2, color="tab:orange", label="q̇ ≤ 0")
            ax.legend(fontsize=7)
            ax.set_xlabel(lab)
            ax.set_ylabel(f"r_{'load' if ch < n else 'motor'} after [N m]")
    fig.suptitle("Residual left after the effects found, against the joint's state")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def plot_applied(res: dict, path: Path, title: str) -> None:
    import matplotlib          # heavy, only when plotting (module docstring)
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = res["t"]
    n = res["tau_s"].shape[1]
    fig, axes = plt.subplots(n + 1, 1, figsize=(10, 3.6 * n + 2.4), sharex=True, squeeze=False,
                             gridspec_kw={"height_ratios": [3] * n + [1.4]})
    for j in range(n):
        ax = axes[j, 0]
        ax.plot(t, res["tau_s"][:, j], color="k", lw=1.0, label="spring torque K_s θ_s")
        for key, col, lab in (("before", "tab:red", "AKF, model before"), ("after", "tab:blue", "AKF, model after")):
            h, b = res[key]["hat"][:, j], res[key]["bound"][:, j]
            ax.fill_between(t, h - b, h + b, color=col, alpha=0.15, lw=0)
            ax.plot(t, h, color=col, lw=0.8, label=f"{lab} (± bound)")
        if res["truth"] is not None:
            ax.plot(t, res["truth"][:, j], "k:", lw=1.2, label="truth")
        ax.axhline(0, color="k", lw=0.4)
        ax.set_ylabel(f"τ̂_h,act{'' if n == 1 else f'[{j + 1}]'} [N m]")
        ax.legend(loc="upper right", fontsize=8)
    ax = axes[n, 0]
    ax.plot(t, res["q"], lw=0.9)
    ax.set_ylabel("q [rad]")
    ax.set_xlabel("t [s]")
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def write_report(dg, out: Path, log: MeasuredLog, cfg: ModelConfig, plots: bool = True) -> None:
    """report.md (and, with ``plots``, its PNGs) of the diagnosis ``dg`` into ``out``."""
    res = dg.result
    lines = _result_lines(res, log, cfg) + _effects_lines(res)
    v = res.get("validation")
    if v:
        lines += _validation_lines(v)
    lines += _cv_lines(res.get("cross_validation") or {})
    lines += _candidate_lines(dg) + _method_lines(res["fit"])
    lines += _applied_lines(dg, out, plots)
    if plots:
        lines += _plot_lines(dg, out, log)
    (out / "report.md").write_text("\n".join(lines))


def _result_lines(res: dict, log: MeasuredLog, cfg: ModelConfig) -> list[str]:
    """The title, the statements and the before/after table."""
    lines = [f"# Model diagnosis of `{Path(log.path).name}`", "",
             f"Model: `{cfg.source}`; log: `{log.path}`, {res['samples']} samples at "
             f"{1.0 / log.dt:.4g} Hz; truth for the estimate: {res['fit']['truth']}.", ""]
    lines += ["## Result", ""]
    for s in res["statements"]:
        lines.append(f"- {s}")
    lines += ["", "| | before | after |", "|---|---|---|",
              f"| residual RMS, both sides [N m] | {_fmt(res['residual_rms_before'])} | {_fmt(res['residual_rms_after'])} |",
              f"| residual RMS, load side [N m] | {_fmt(res['residual_rms_channels']['before']['load'])} | {_fmt(res['residual_rms_channels']['after']['load'])} |",
              f"| residual RMS, motor side [N m] | {_fmt(res['residual_rms_channels']['before']['motor'])} | {_fmt(res['residual_rms_channels']['after']['motor'])} |",
              f"| AKF estimation RMSE of τ_h,act [N m] | {_fmt(res['estimate_rmse_before'])} | {_fmt(res['estimate_rmse_after'])} |",
              "", f"Unexplained share of the residual's mean square: {_fmt(res['unexplained_fraction'])}; of it, "
              f"structured but matching no candidate: {_fmt(res['unexplained_structure']['fraction'])}"
              + (f" (follows {', '.join(res['unexplained_structure']['follows'])}, {res['unexplained_structure']['channel']} side)"
                 if res['unexplained_structure']['follows'] else "") + ".", ""]
    return lines


def _effects_lines(res: dict) -> list[str]:
    """The table of the effects added, if any."""
    if not res["effects_added"]:
        return []
    lines = ["## Effects added to `model_augmented.yaml`", "",
             "| # | type | side | parameters (95 % CI) | share of mean square | confidence |",
             "|---|---|---|---|---|---|"]
    for i, d in enumerate(res["effects_added"], 1):
        ps = "; ".join((f"{p} ≥ {_fmt(v)} (the sticking phases bound it from below only)"
                        if p in d.get("lower_bound_only", ()) else
                        f"{p} = {_fmt(v)} [{_fmt(d['ci95'].get(p, [None, None])[0])}, "
                        f"{_fmt(d['ci95'].get(p, [None, None])[1])}]")
                       for p, v in d["params"].items())
        side = d["side"] + (f"[{d['joint']}]" if "joint" in d else "")
        lines.append(f"| {i} | {d['type']} | {side} | {ps} | {_pct(d['explained_fraction'], 1)} | {d['confidence']} |")
    lines.append("")
    return lines


def _candidate_lines(dg) -> list[str]:
    """How the candidates are judged, and each selection step's table."""
    opts = dg.selector.opts
    lines = ["## Candidates tried", "",
             "Every type of the effect vocabulary on every side it may sit on.  At each step all "
             "remaining candidates are fitted jointly with the effects already chosen (nonlinear "
             "parameter on a grid, linear ones by least squares); the best by BIC that passes every test is "
             "accepted: BIC falls (effective sample size from the residual's autocorrelation, plus a look-elsewhere "
             "penalty for grid-searched parameters), the blocked cross-validated mean square on held-out "
             "time segments falls by at least "
             f"{100 * opts.min_cv_gain:.0f} %, it explains at least {100 * opts.min_fraction:.0f} % "
             f"of the initial mean square or {100 * opts.min_fraction_current:.0f} % of what is left, and its "
             f"share is at least {opts.min_effect_rms:.3g} N m RMS over the log.  Of two that fit about equally "
             "well, BIC prefers the one with fewer parameters; near-ties are reported as alternatives.  Shares of "
             "the mean square are counted over the whole log, as Shapley values (each effect's decrease of the "
             "sum of squares averaged over every order of adding them), at the final parameters (refined "
             "jointly by nonlinear least squares on the exact residual); the 95 % intervals "
             "come from the Gauss–Newton covariance widened by the residual's autocorrelation time.", ""]
    for st in dg.sel.steps:
        lines += [f"### Step {st.step}: {st.reason}", "",
                  "| candidate | parameters at best fit | explains (of the initial MS of the fitted samples) | ΔBIC |", "|---|---|---|---|"]
        for r in sorted(st.rows, key=lambda r: r["delta_bic"]):
            ps = ", ".join(f"{k}={_fmt(v)}" for k, v in r["params"].items())
            mark = " **(chosen)**" if r["candidate"] == st.chosen else ""
            lines.append(f"| {r['candidate']}{mark} | {ps} | {_pct(r['explains'], 2)} | {_signed(r['delta_bic'])} |")
        lines.append("")
    return lines


def _method_lines(f: dict) -> list[str]:
    """The residuals' definition and the fit's settings (the result's ``fit`` section)."""
    return ["## Method and settings", "",
            "Residuals: load side r_load = τ_h,act − (M q̈ + C(q) + declared load effects + τ_s) "
            "(eq:unknwn_load), motor side r_motor = κ τ_m − (J θ̈_m + D_m θ̇_m + declared motor effects − τ_s) "
            "(eq:motorside); a spring effect appears in both with opposite sign, a load effect only in the "
            "first, a motor effect only in the second.  Each balance is formed per sample (second "
            "differences for accelerations, short-window velocities) and then smoothed with one zero-phase "
            "Savitzky–Golay filter so that every term sees the same filter.", "",
            f"- smoothing window: {f['smoothing_window_samples']} samples; samples used in the fit: {f['samples_used']} "
            f"(left out: {100 * f['low_velocity_share_left_out']:.1f} %, the filter's edges and near-zero velocities where "
            "the smoothed sign of friction models cannot follow sticking)",
            f"- residual autocorrelation time: {_fmt(f['autocorrelation_time_samples'])} samples (widens the CIs and "
            "shrinks the effective sample size of BIC)",
            f"- candidates: {f['candidates']}", ""]


def _applied_lines(dg, out: Path, plots: bool) -> list[str]:
    """One section per other log the model was run on (``--apply``), with its plot."""
    lines = []
    for k, ap in enumerate(getattr(dg, "applied", []) or [], 1):
        name = f"apply_{k}_{Path(ap['log']).stem}.png"
        sm = ap["summary"]
        lines += [f"## The model on `{Path(ap['log']).name}`", "",
                  "The AKF run over this log with the model before and after the diagnosis; the band is each "
                  "estimate's bound (the filter's own interval, √(χ²(1−δ) P_ττ)), the black line the spring torque "
                  "K_s θ_s.", "",
                  "| | before | after |", "|---|---|---|",
                  f"| peak \\|τ̂_h,act\\| [N m] | {_fmt(sm['before']['peak_abs'])} | {_fmt(sm['after']['peak_abs'])} |",
                  f"| mean bound [N m] | {_fmt(sm['before']['mean_bound'])} | {_fmt(sm['after']['mean_bound'])} |",
                  f"| mean NIS | {_fmt(sm['before']['nis_mean'])} | {_fmt(sm['after']['nis_mean'])} |",
                  f"| share of the log where the interval excludes 0 | {_fmt(sm['before']['share_nonzero'])} | "
                  f"{_fmt(sm['after']['share_nonzero'])} |"]
        lines.append(f"| Theorem-1 ρ, median [N m] (share wider than the peak spring torque) | "
                     f"{_theorem1_cell(sm['before'])} | {_theorem1_cell(sm['after'])} |")
        if "rmse" in sm["after"]:
            lines.append(f"| τ̂_h,act RMSE [N m] | {_fmt(sm['before']['rmse'])} | {_fmt(sm['after']['rmse'])} |")
        lines += [""] + ap["claims"] + [""]
        if plots:
            plot_applied(ap, out / name, f"{Path(ap['log']).name}: estimated human torque before and after the diagnosis")
            lines += ["", f"![{name}]({name})", ""]
    return lines


def _plot_lines(dg, out: Path, log: MeasuredLog) -> list[str]:
    """The residual, estimate, per-effect and leftover plots, drawn into ``out``."""
    sel, res = dg.sel, dg.result
    plot_residuals(dg, out / "residuals.png")
    lines = ["## Plots", "", "![residuals before and after](residuals.png)", ""]
    if plot_estimates(dg, log, out / "estimate.png"):
        lines += ["![AKF estimate before and after](estimate.png)", ""]
    for k, (cand, _) in enumerate(sel.chosen):
        name = f"effect_{k + 1}_{cand.type}_{cand.side}.png"
        plot_effect(dg, k, out / name)
        lines += [f"![{cand.type} {cand.side}]({name})", ""]
    if not sel.chosen or res["unexplained_structure"]["matches_no_candidate"]:
        plot_structure(dg, out / "leftover.png")
        lines += ["![leftover residual against the state](leftover.png)", ""]
    return lines


def _theorem1_cell(s: dict) -> str:
    t = s.get("theorem1") or {}
    if not t or t.get("diverged"):
        return "diverges"
    return f"{_fmt(t['median'], 3)} ({100 * t['share_vacuous']:.0f} %)"


def _validation_lines(v: dict) -> list[str]:
    fb, hb = v["fit_block"], v["held_out_block"]
    lines = ["## Validation on a held-out time block", "",
             f"The log's last part ({_fmt(hb['t_s'][0])}–{_fmt(hb['t_s'][1])} s, {hb['samples']} samples) is kept "
             f"back; the first part ({_fmt(fb['t_s'][0])}–{_fmt(fb['t_s'][1])} s) is fitted.  Two checks: *refit* — the "
             "effects found on the whole log, their parameters fitted again on the first part alone; *selection* — "
             "the whole diagnosis repeated on the first part alone (it may find other effects).  Errors over each "
             "block (the smoother's ends aside); the AKF runs over the whole log and is scored per block.", "",
             "| check | block | residual RMS before → after [N m] | × | AKF τ̂_h,act RMSE before → after [N m] | × |",
             "|---|---|---|---|---|---|"]
    for key in ("refit", "selection"):
        d = v.get(key)
        if not d:
            continue
        for blk, label in (("fit_block", "fitted"), ("held_out_block", "held out")):
            b = d[blk]
            rr = d["residual"]["improvement_fit_block" if blk == "fit_block" else "improvement_held_out"]
            ee = d["estimate"]["improvement_fit_block" if blk == "fit_block" else "improvement_held_out"]
            lines.append(f"| {key} | {label} | {_fmt(b['residual_rms_before'])} → {_fmt(b['residual_rms_after'])} | "
                         f"{_fmt(rr, 3)} | {_fmt(b['estimate_rmse_before'])} → {_fmt(b['estimate_rmse_after'])} | {_fmt(ee, 3)} |")
    lines.append("")
    for key in ("refit", "selection"):
        d = v.get(key)
        if not d:
            continue
        eff = ", ".join(f"{e['type']} ({e['side']}): " + ", ".join(f"{k}={_fmt(x)}" for k, x in e["params"].items())
                        for e in d["effects"]) or "nothing"
        lines.append(f"- {key}: {eff}.  Share of the fitted block's reduction that holds out of sample: residual "
                     f"{_fmt(d['residual']['held_out_share'], 3)}, AKF {_fmt(d['estimate']['held_out_share'], 3)}.")
        if "gp_akf" in d:
            g = d["gp_akf"]
            lines.append(f"  GP-AKF learned on the fitted block: held-out RMSE {_fmt(g['held_out_block']['estimate_rmse_before'])} "
                         f"→ {_fmt(g['held_out_block']['estimate_rmse_after'])} N m ({_fmt(g['improvement_held_out'], 3)}×).")
    lines.append("")
    return lines


def _cv_lines(cv: dict) -> list[str]:
    """The cross-validation over time blocks: per block, the effects kept refitted on the other
    blocks and the whole selection repeated without it, in and out of sample."""
    if not cv.get("blocks"):
        return []
    key = cv["criterion"]
    what = "AKF τ̂_h,act RMSE" if key == "estimate_rmse" else "residual RMS"
    lines = ["## Cross-validation over time blocks", "",
             f"The log is cut into {len(cv['blocks'])} contiguous time blocks; each is held out in turn, the effects "
             "fitted on the other blocks alone (half a smoothing window either side of it belongs to neither) and "
             f"scored on it.  An effect is kept only if it lowers the {what} over the held-out blocks, and only a set "
             "that errs no more than the input model on every held-out block.", "",
             "| block | t [s] | residual RMS before → after [N m] | AKF τ̂_h,act RMSE before → after [N m] |",
             "|---|---|---|---|"]
    for k, r in enumerate(cv["blocks"], 1):
        lines.append(f"| {k} | {_fmt(r['t_s'][0])}–{_fmt(r['t_s'][1])} | {_fmt(r['residual_rms_before'])} → "
                     f"{_fmt(r['residual_rms_after'])} | {_fmt(r.get('estimate_rmse_before'))} → "
                     f"{_fmt(r.get('estimate_rmse_after'))} |")
    lines.append("")
    for d in cv.get("dropped", []):
        lines.append(f"- {d['type']} ({d['side']}) not kept: {d['reason']}.")
    rep = cv.get("selection_repeated")
    if rep:
        lines += ["", "The whole selection (candidates, selection, refinement and this pruning over the remaining "
                  "blocks) repeated without each block:", "",
                  "| block | effects kept | in sample: residual, AKF before → after [N m] | "
                  "out of sample: residual, AKF before → after [N m] |", "|---|---|---|---|"]
        for k, r in enumerate(rep, 1):
            names = ", ".join(f"{e['type']} ({e['side']})" for e in r["effects"]) or "none"
            i, o = r["in_sample"], r["out_of_sample"]
            lines.append(f"| {k} | {names} | {_fmt(i['residual_rms_before'])} → {_fmt(i['residual_rms_after'])}, "
                         f"{_fmt(i.get('estimate_rmse_before'))} → {_fmt(i.get('estimate_rmse_after'))} | "
                         f"{_fmt(o['residual_rms_before'])} → {_fmt(o['residual_rms_after'])}, "
                         f"{_fmt(o.get('estimate_rmse_before'))} → {_fmt(o.get('estimate_rmse_after'))} |")
    lines.append("")
    return lines
