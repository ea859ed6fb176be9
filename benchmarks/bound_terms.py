"""``python -m benchmarks.bound_terms``: which term of the Theorem-1 bound ρ_k dominates, per session.

Calibrates one plant of ``bench generalize``'s family (its seed, at a rate) on its passive
calibration session, as ``bench generalize`` does, and replays the GP-AKF with the guaranteed-β
bound on held-out sessions with :class:`sea_daemon.core.bounds.terms.TermsRecorder`.  Per session,
means over the samples marked valid: RMSE, coverage, ρ_k, and ρ_k split into the set of means'
τ_h,act half-width per bounded input — the GP error (or a plain AKF's declared model error), the
declared human-torque rate, the declared friction's range, the rest of the linearisation error —
and the Gaussian part ρ_k − h, with √P_g,ττ (docs/bounds.md, "Which term dominates").

``--q-tau`` replaces the calibrated τ_h,act random walk (what the filter's lag costs against its
noise); ``--seeds``: development seeds of ``bench generalize`` unless a figure is to be reported.
"""
from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path

import numpy as np

from sea_daemon.apps.bench import choose
from sea_daemon.apps.bench.generalize import SESSION_NAMES, plant_logs
from sea_daemon.apps.bench._family import sessions
from sea_daemon.apps.calibration.pipeline import CalibrationOptions, HumanSpec, calibrate, sigma_nom_for
from sea_daemon.core.bounds.terms import TERMS, TermsRecorder
from sea_daemon.core.replay import replay
from sea_daemon.errors import InputError

NAME = "bound_terms"
HELP = "the Theorem-1 bound's terms per session on a bench generalize plant"


def add_arguments(p) -> None:
    p.add_argument("--seed", type=int, default=0, help="plant seed (default 0, a development seed)")
    p.add_argument("--rate", type=float, default=None, help="rate [Hz] (default the seed's own)")
    p.add_argument("--cal-s", type=float, default=40.0, help="calibration session length [s] (default 40)")
    p.add_argument("--sessions", default="slow,active_high,still_band",
                   help="comma list of " + ", ".join(SESSION_NAMES))
    p.add_argument("--q-tau", type=float, default=None, help="τ_h,act random walk [N² m²/s] instead of the calibrated one")
    p.add_argument("--cache", default="bench_bound_terms", help="directory of the simulated logs")
    p.add_argument("--json", default=None, help="write the table as JSON here")


def session_terms(res, log) -> dict:
    """One session: RMSE, coverage, valid share over the valid samples and the bound's terms."""
    t0 = time.perf_counter()
    est = res.estimator(dt=log.dt, bound=TermsRecorder)
    r = replay(log, est)
    e = r.tau_h_act_hat[:, 0] - log.tau_h_act[:, 0]
    rho = r.tau_h_act_bound[:, 0]
    v = r.valid.astype(bool) if r.valid is not None else np.ones(len(log), dtype=bool)
    if v.ndim > 1:
        v = v[:, 0]
    out = {"valid": float(v.mean()), "rmse_valid": float(np.sqrt(np.mean(e[v] ** 2))) if v.any() else None,
           "coverage_valid": float(np.mean(np.abs(e[v]) <= rho[v])) if v.any() else None}
    out.update(est.bound.table(v))
    out["seconds"] = time.perf_counter() - t0
    return out


def run(args) -> int:
    names = choose(args.sessions, SESSION_NAMES, "--sessions")
    if args.rate is not None and not 1.0 <= args.rate <= 100000.0:
        raise InputError(f"--rate {args.rate:g}: allowed 1..100000 Hz")
    if not 1.0 <= args.cal_s <= 3600.0:
        raise InputError(f"--cal-s {args.cal_s:g}: allowed 1..3600 s")
    if args.q_tau is not None and not 0.0 < args.q_tau <= 1e6:
        raise InputError(f"--q-tau {args.q_tau:g}: allowed > 0 and <= 1e6 N^2 m^2/s")
    cache = Path(args.cache)
    cache.mkdir(parents=True, exist_ok=True)
    pd, cal, tests = plant_logs(args.seed, args.cal_s, cache, args.rate)
    res = calibrate(cal, pd.nominal, opts=CalibrationOptions(human=HumanSpec(pd.human_band_hz, pd.human_rms),
                                                             working_range=pd.working_range))
    if args.q_tau is not None:
        res.cfg = dataclasses.replace(res.cfg, estimator=dataclasses.replace(
            res.cfg.estimator, **sigma_nom_for(res.cfg, float(args.q_tau))))
    kinds = {sp.name: sp.kind for sp in sessions(pd)}
    est = res.cfg.estimator
    q_tau = args.q_tau if args.q_tau is not None else res.report["tau_h_act_walk"].get("q_tau")
    print(f"plant {args.seed} at {pd.nominal.rate_hz:g} Hz: declared rate {est.tau_h_act_rate:.3g} N m/s, "
          f"q_tau {q_tau:.3g} N^2 m^2/s, GP kept {res.report['gp_kept']}")
    floor = res.report.get("bound_floor")
    if floor:
        print(f"floor of any guaranteed bound (core/bounds/floor.py): {floor['rho'][0]:.3f} N m for the declared rate, "
              f"{floor['band_limited']['rho'][0]:.3f} N m for the declared band's d2tau/dt2")
    cols = ("rmse_valid", "coverage_valid", "rho", "h") + TERMS + ("cut", "gaussian", "sigma_g")
    print(f"{'session':<13}{'kind':<8}" + "".join(f"{c[:10]:>11}" for c in cols))
    table = {}
    for name in names:
        d = session_terms(res, tests[name])
        d["kind"] = kinds[name]
        table[name] = d
        print(f"{name:<13}{d['kind']:<8}" + "".join(
            f"{d[c]:>11.3f}" if d.get(c) is not None else f"{'-':>11}" for c in cols), flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps({"seed": args.seed, "rate_hz": pd.nominal.rate_hz, "q_tau": q_tau,
                                               "bound_floor": floor, "sessions": table}, indent=1))
    return 0


if __name__ == "__main__":
    import sys

    from benchmarks._cli import main
    sys.exit(main(sys.modules[__name__]))
