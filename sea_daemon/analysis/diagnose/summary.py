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
        d["params"] = {p: num(v) for p, v in params.items()}
        d["explained_fraction"] = num(frac)
        d["ci95"] = {p: [num(lo), num(hi)] for p, (lo, hi) in ci.items()}
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
    for name, params, ci in sel.dropped:
        ps = ", ".join(f"{k}={v:.4g} [{ci[k][0]:.3g}, {ci[k][1]:.3g}]" for k, v in params.items() if k in ci)
        out.append(f"{name} would explain part of the residual, but this log does not determine its parameters "
                   f"(95 % intervals wider than the values: {ps}); not added.")
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
