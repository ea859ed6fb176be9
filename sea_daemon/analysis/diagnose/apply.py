"""The diagnosed model on other logs: what the estimator says a person did (``--apply``).

A diagnosis is made on a log whose truth is known (usually a passive one: nobody touches the
load, τ_h,act = 0).  The point of the model is the logs where the truth is *not* known: a
person pushes the load and there is no torque sensor.  :func:`apply_model` runs the AKF
(Alg. 1) over such a log with the model before and after the diagnosis and returns τ̂_h,act
with its bound, next to the spring torque τ_s = K_s θ_s that a plain SEA torque readout
would show; :func:`claims` says what can and cannot be concluded from them without a torque
sensor (the report draws them: :func:`sea_daemon.apps.diagnose.report.plot_applied`).

The bound drawn is the filter's own confidence interval, √(χ²_{5n}(1−δ) P_ττ) (the
Theorem-1 set of the KF with a point set of means, docs/estimators.md): it holds under the
filter's noise model and says nothing about model errors the diagnosis did not find.
"""
from __future__ import annotations

import numpy as np

from sea_daemon.core.config import ModelConfig
from sea_daemon.core.log import MeasuredLog
from sea_daemon.core.model import SEAModel
from sea_daemon.errors import EstimatorFault
from sea_daemon.analysis.diagnose.evaluate import akf_run
from sea_daemon.analysis.diagnose.prepare import prepare_log


def apply_model(log: MeasuredLog, cfg_before: ModelConfig, cfg_after: ModelConfig) -> dict:
    """AKF over ``log`` with both models: series and summary figures."""
    prep = prepare_log(log)
    lg = prep.log
    runs = {"before": akf_run(lg, cfg_before), "after": akf_run(lg, cfg_after)}
    m = SEAModel.from_config(cfg_before)
    q, th = m.correct_measurement(lg.q, lg.theta_m)
    # eq:spring_torque with the nominal spring: what an SEA's deflection reading gives
    tau_s = (q - th) @ m.K_s.T
    out = {"log": str(log.path), "samples": int(len(lg)), "resampled": prep.resampled, "t": lg.t,
           "tau_s": tau_s, "q": lg.q, "truth": lg.tau_h_act}
    summ = {"spring_torque_peak": float(np.max(np.abs(tau_s)))}
    for k, r in runs.items():
        hat, bnd = r["hat"], r["bound"]
        out[k] = {"hat": hat, "bound": bnd}
        s = {"peak_abs": float(np.max(np.abs(hat))), "mean_bound": float(np.mean(bnd)),
             "nis_mean": float(np.mean(r["nis"])) if r["nis"].size else None,
             # share of the log where the interval excludes zero: the filter claims a torque
             "share_nonzero": float(np.mean(np.abs(hat) > bnd))}
        if lg.tau_h_act is not None:
            e = hat - lg.tau_h_act
            s["rmse"] = float(np.sqrt(np.mean(e**2)))
            s["coverage"] = float(np.mean(np.abs(e) <= bnd))
        s["theorem1"] = theorem1_summary(lg, cfg_before if k == "before" else cfg_after, summ["spring_torque_peak"])
        summ[k] = s
    out["summary"] = summ
    return out


def theorem1_summary(log: MeasuredLog, cfg: ModelConfig, scale: float) -> dict:
    """The Theorem-1 bound ρ_k (docs/bounds.md) the AKF publishes by default over ``log``:
    median, largest and the share of samples where it exceeds ``scale`` (the peak spring torque:
    a bound wider than everything the spring carried says nothing); ``diverged`` when the set of
    means overflowed (the estimator then raises)."""
    try:
        rho = akf_run(log, cfg, bound=True)["bound"]
    except EstimatorFault:
        return {"diverged": True}
    rho = np.where(np.isfinite(rho), rho, np.inf)
    return {"diverged": False, "median": float(np.median(rho)), "max": float(np.max(rho)),
            "share_vacuous": float(np.mean(rho > scale))}


def claims(summary: dict, reference: dict) -> list[str]:
    """What a τ̂_h,act without a torque sensor supports, and what it does not.

    ``reference``: the diagnosis log's AKF error with the model after ({'all', 'held_out'};
    N m), the floor below which an estimated torque cannot be told from model error."""
    b, a = summary["before"], summary["after"]
    floor = reference.get("held_out") or reference.get("all")
    out = []
    if "rmse" in a:
        out.append(f"This log has a torque column: the AKF's error is {b['rmse']:.3g} N m RMS with the model before "
                   f"and {a['rmse']:.3g} N m after (bound covers {100 * a['coverage']:.0f} % of the samples).")
        return out
    out += [
        "Without a torque sensor the human torque is not measured; τ̂_h,act is what the load-side model cannot "
        "explain.  What this supports:",
        "",
        f"- when and in which direction a person acted, and how large that was against the spring torque "
        f"(peak |τ̂_h,act| {a['peak_abs']:.3g} N m after, {b['peak_abs']:.3g} before; peak spring torque "
        f"{summary['spring_torque_peak']:.3g} N m);",
        _nis_line(b, a),
        (f"- torques above the model's own error: on the passive log this model was diagnosed on, τ̂_h,act is "
         f"off by {floor:.3g} N m RMS (held out where available); a feature smaller than that cannot be told "
         "from model error." if floor else "- (no reference error: the diagnosis log had no truth)"),
        "",
        "What it does not support:",
        "- an absolute accuracy: every load-side effect the model still lacks appears as human torque, and an "
        "error of K_s scales the whole estimate (the spring's stiffness is the design value, not measured);",
        "- active versus passive: a hand that holds the load still and one that is not there give the same "
        "τ̂_h,act when the load does not move (static friction takes up any torque within its band);",
        f"- the bound: it is the filter's interval under its noise model (it excludes zero on "
        f"{100 * a['share_nonzero']:.0f} % of this log after, {100 * b['share_nonzero']:.0f} % before); it does "
        "not cover model errors the diagnosis did not find.",
        _theorem1_line(b, a, summary["spring_torque_peak"]),
    ]
    return out


def _theorem1_line(b: dict, a: dict, scale: float) -> str:
    """What the Theorem-1 bound (the one ``replay`` and ``run`` publish) does on this log."""
    def say(t):
        if not t or t.get("diverged"):
            return "diverges (the set of means overflows)"
        return (f"median {t['median']:.3g} N m, largest {t['max']:.3g} N m, wider than the peak spring torque on "
                f"{100 * t['share_vacuous']:.0f} % of the samples")
    tb, ta = b.get("theorem1"), a.get("theorem1")
    line = f"- the Theorem-1 bound ρ that `replay` and `run` publish: before {say(tb)}; after {say(ta)}."
    if ta and (ta.get("diverged") or ta["share_vacuous"] > 0.05):
        line += ("  Declared friction F·tanh(v/ε) is steep around zero speed: while a side creeps or sticks, the "
                 "friction's unknown sign enters ρ at every step (through the filter's Jacobian or, when narrower, "
                 "as the friction's range over the set's velocity interval; docs/diagnose.md, Limits). "
                 "The band drawn here is therefore the filter's own interval, not ρ.")
    return line


def _nis_line(b: dict, a: dict) -> str:
    nb, na = b.get("nis_mean"), a.get("nis_mean")
    if nb is None or na is None:
        return "- (no NIS: the filter did not run)"
    verdict = ("fit this log's measurements more consistently" if na < 0.9 * nb else
               "fit this log's measurements no more consistently" if na <= 1.1 * nb else
               "fit this log's measurements less consistently")
    return (f"- whether the model after is also the better model of this log: its innovations "
            f"{verdict} (mean NIS {nb:.3g} → {na:.3g}; the noise model expects about the measurement dimension; the diagnosis log decides "
            "the model, this log only checks it);")
