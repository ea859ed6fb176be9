"""The diagnosis in words and numbers: the parts of the docs/interfaces.md §4 dict that
:func:`.engine.run_diagnosis` builds from the selection, the validation and the AKF's error."""
from __future__ import annotations

import math

import numpy as np

from sea_daemon.analysis.diagnose.residuals import Kinematics, rms
from sea_daemon.analysis.diagnose.select import Selection


def num(v):
    """``v`` as a JSON number: a float, or None when missing or not finite."""
    if v is None:
        return None
    v = float(v)
    return v if math.isfinite(v) else None


#: what a figure the log cannot give is printed as (never nan or inf)
NOT_MEASURABLE = "not measurable from this log"


def fmt(v, spec: str = ".3g") -> str:
    """A figure for text: ``v`` formatted, or :data:`NOT_MEASURABLE` when missing or not finite."""
    v = num(v)
    return NOT_MEASURABLE if v is None else format(v, spec)


def clean(d):
    """JSON-safe copy: non-finite numbers as None."""
    if isinstance(d, dict):
        return {k: clean(v) for k, v in d.items()}
    if isinstance(d, (list, tuple)):
        return [clean(v) for v in d]
    if isinstance(d, float):
        return num(d)
    return d


def effects_json(sel: Selection, n: int, warn: bool) -> list[dict]:
    """``effects_added`` of docs/interfaces.md §4 with the extensions of docs/diagnose.md."""
    added = []
    for i, ((cand, params), ci, frac, alts) in enumerate(zip(sel.chosen, sel.ci, sel.explained,
                                                              sel.alternatives + [[]] * len(sel.chosen))):
        # relative CI half-widths (angles and rest positions, which may rightly be ≈ 0, aside)
        rel = [abs(hi - lo) / 2 / max(abs(params[p]), 1e-12) for p, (lo, hi) in ci.items()
               if p not in ("phi", "q_h0") and math.isfinite(hi)]
        # static friction the sticking phases bound from below only; any other interval without an
        # end is one the log does not measure
        lower_only = [p for p, (lo, hi) in ci.items() if hi == math.inf and (i, p) in sel.profiled]
        # an interval of zero width (or none at all) is not a precise value: the log did not
        # measure the parameter's uncertainty, so nothing about it is "high" confidence
        measured = bool(ci) and all(p in ci and math.isfinite(ci[p][0]) and math.isfinite(ci[p][1])
                                    and ci[p][1] > ci[p][0] for p in params if p not in lower_only)
        confident = (measured and (not warn) and (not alts) and sel.unexplained < 0.5
                     and all(r < 0.2 for r in rel))
        d = {"type": cand.type, "side": cand.side}
        if n > 1:
            d["joint"] = cand.joint + 1
        d["params"] = {p: num(v) for p, v in params.items()}
        d["explained_fraction"] = num(frac)
        d["ci95"] = {p: [num(lo), num(hi)] for p, (lo, hi) in ci.items()}
        if not measured:
            d["ci95_not_measurable"] = [p for p in params if p not in lower_only
                                        and not (p in ci and math.isfinite(ci[p][0]) and math.isfinite(ci[p][1])
                                                 and ci[p][1] > ci[p][0])]
        d["confidence"] = "high" if confident else "low"
        if alts:
            d["alternatives"] = alts
        if lower_only:
            # static friction: the sticking phases bound it from below only (ci95 [lo, null])
            d["lower_bound_only"] = lower_only
        added.append(d)
    return added


def ablation_statements(ablation: list[dict], est: dict) -> list[str]:
    """The statement on an AKF that estimates worse with the effects found (``ablation``: the
    error with each left out in turn)."""
    if not ablation:
        return []
    worst = min((d for d in ablation if d["estimate_rmse_without"] is not None),
                key=lambda d: d["estimate_rmse_without"], default=None)
    msg = (f"The AKF estimates worse with the effects found than without them ({fmt(est['before'])} → "
           f"{fmt(est['after'])} N m RMS). ")
    if worst is not None:
        msg += (f"Left out in turn, {worst['type']} ({worst['side']}) costs the most: without it "
                f"{fmt(worst['estimate_rmse_without'])} N m. ")
    msg += ("An effect can be real (it lowers the residual) and still not help the filter: friction that "
            "changes within the filter's velocity uncertainty of zero speed is evaluated on the wrong side "
            "of its steep part (docs/diagnose.md, Limits).  model_augmented.yaml holds every effect found; "
            "for estimation, leave out the one named here.")
    return [msg]


def validation_summary(r0, val_r: dict, val_models: dict, est: dict, blocks: dict, edge: int, t,
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
        out[name] = {"t_s": [num(t[idx[0]]), num(t[idx[-1]])], "samples": int(m.sum())}

    def ratio(b, a):
        return num(b / a) if (b is not None and a) else None

    def x(v):
        return "—" if v is None else f"{v:.2f}×"

    def pc(v):
        return "—" if v is None else f"{100 * v:.0f} %"
    for key, pairs in val_models.items():
        r = val_r[key]
        d: dict = {"effects": [{"type": c.type, "side": c.side, "params": {k: num(v) for k, v in p.items()}}
                               for c, p in pairs]}
        for name, m in blocks.items():
            mm = m & inner
            d[name] = {"residual_rms_before": num(rms(r0[mm])), "residual_rms_after": num(rms(r[mm])),
                       "estimate_rmse_before": num(est.get(f"{name}_before")),
                       "estimate_rmse_after": num(est.get(f"{name}_{key}"))}
        for kind in ("residual_rms", "estimate_rmse"):
            f, h = d["fit_block"], d["held_out_block"]
            rf = ratio(f[f"{kind}_before"], f[f"{kind}_after"])
            rh = ratio(h[f"{kind}_before"], h[f"{kind}_after"])
            share = num((1 - 1 / rh) / (1 - 1 / rf)) if (rf and rh and rf != 1.0) else None
            d["residual" if kind == "residual_rms" else "estimate"] = {
                "improvement_fit_block": rf, "improvement_held_out": rh, "held_out_share": share}
        if gp is not None and gp.get("before") and gp.get(key):
            d["gp_akf"] = {name: {"estimate_rmse_before": num(gp["before"][name]),
                                  "estimate_rmse_after": num(gp[key][name])} for name in blocks}
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


def statements(sel: Selection, added: list[dict], warn: bool, kin: Kinematics) -> list[str]:
    """The statements of the diagnosis: what was found, what is left, what the log cannot tell."""
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
    for name, params, ci, why in sel.dropped:
        ps = ", ".join(f"{k}={fmt(v, '.4g')} [{fmt(ci[k][0])}, {fmt(ci[k][1])}]" for k, v in params.items() if k in ci)
        out.append(f"{name} would explain part of the residual, but this log does not determine its parameters "
                   + (f"({why}; 95 % intervals: {ps})" if why else f"(95 % intervals reaching 0 or without an end: {ps})")
                   + "; not added.")
    for c in sel.correlated:
        out.append(f"{c['kept']} and {c['dropped']} trade against each other on this log (parameter correlation "
                   f"{c['correlation']:+.2f}; {c['reason']}): kept {c['kept']}, the physically sensible one, "
                   f"dropped {c['dropped']}.")
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


def missing_statements(missing: list[dict]) -> list[str]:
    """"Not identifiable from this log" for the candidates whose motion the log lacks, one line
    per missing motion (:mod:`.excitation`)."""
    by: dict[str, list[str]] = {}
    for d in missing:
        j = f"[{d['joint']}]" if any(m["joint"] > 1 for m in missing) else ""
        by.setdefault(d["missing"], []).append(f"{d['type']} ({d['side']}{j})")
    return [f"Not identifiable from this log: {', '.join(names)} — {why}." for why, names in by.items()]


def _block_rows(blocks: list, t, figures, sizes) -> list[dict]:
    out = []
    for k, b in enumerate(blocks):
        idx = np.flatnonzero(b)
        row = {"t_s": [num(t[idx[0]]), num(t[idx[-1]])], "samples": int(sizes[k]),
               "residual_rms_before": num(figures.residual_before[k]),
               "residual_rms_after": num(figures.residual_after[k])}
        if figures.estimate_after is not None:
            row["estimate_rmse_before"] = num(figures.estimate_before[k])
            row["estimate_rmse_after"] = num(figures.estimate_after[k])
        out.append(row)
    return out


def _improves(before, after) -> bool | None:
    if before is None or after is None:
        return None
    return bool(after <= before)


def cv_summary(cv, t) -> dict:
    """The result's ``cross_validation`` section (docs/diagnose.md): the blocks, the effects
    kept with their held-out figures refitted per fold, the effects dropped and why, and the
    whole selection repeated without each block (in and out of sample)."""
    if not cv.blocks:
        return {"blocks": [], "note": cv.note}
    f = cv.kept["figures"]
    rows = _block_rows(cv.blocks, t, f, cv.kept["sizes"])
    key = "estimate_rmse" if f.estimate_after is not None else "residual_rms"
    out = {"criterion": key, "blocks": rows, "dropped": cv.dropped,
           "kept_improves_every_block": all(_improves(r.get(f"{key}_before"), r.get(f"{key}_after")) is not False
                                            for r in rows)}
    if cv.repeated:
        rep = []
        for r, row in zip(cv.repeated, rows):
            rep.append({"t_s": row["t_s"], "effects": r["effects"], "dropped": r["dropped"],
                        "in_sample": {k: num(v) for k, v in r["in_sample"].items()},
                        "out_of_sample": {k: num(v) for k, v in r["out_of_sample"].items()}})
        out["selection_repeated"] = rep
        out["selection_repeated_improves_every_block"] = all(
            _improves(r["out_of_sample"].get(f"{key}_before"), r["out_of_sample"].get(f"{key}_after")) is not False
            for r in rep)
    return out


def cv_statements(cvs: dict, note: str | None) -> list[str]:
    """The cross-validation in words."""
    if not cvs.get("blocks"):
        return [note] if note else []
    key = cvs["criterion"]
    what = "the AKF's τ̂_h,act error" if key == "estimate_rmse" else "the residual RMS"
    out = []
    for d in cvs["dropped"]:
        out.append(f"{d['type']} ({d['side']}) found but not kept: {d['reason']}.")
    per = ", ".join(f"{fmt(r.get(key + '_before'))} → {fmt(r.get(key + '_after'))}" for r in cvs["blocks"])
    msg = (f"Cross-validation over {len(cvs['blocks'])} time blocks (each fitted on the others alone): "
           f"{what} per held-out block {per} N m")
    if "selection_repeated" in cvs:
        rep = ", ".join(f"{fmt(r['out_of_sample'].get(key + '_before'))} → {fmt(r['out_of_sample'].get(key + '_after'))}"
                        for r in cvs["selection_repeated"])
        msg += f"; with the whole selection repeated without each block: {rep} N m"
    return [msg + "."]
