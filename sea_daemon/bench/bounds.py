"""``sea-daemon bench bounds``: does the Theorem-1 bound ρ_k hold on the paper's scenarios?

For each scenario (default ``configs/scenarios/passive.yaml`` and ``active.yaml``):
simulate, run every estimator over the estimation log with the Theorem-1 bound attached
(:func:`sea_daemon.bounds.akf_bound.attach_default_bound`), and report per estimator the
coverage of ρ_k (fraction of samples with |τ̂ − τ| ≤ ρ_k; eq:bounds promises ≥ 1 − δ where
the theorem's assumptions hold), the coverage of the KF's own χ² bound √(s P_ττ) in the same
run, mean ρ, mean |error|, median step time; plus a plot of the estimate with the ρ band
against the truth.

Known result (docs/bounds.md §4): with the true plant's smoothed Coulomb/Stribeck friction
declared (oracle), the EKF's Jacobian at θ̇ ≈ 0 has slope F_c/sign_eps, and the first-order
linearisation error over the confidence set is huge — ρ_k is valid but far too wide.

Estimators: ``akf`` (nominal model: the unmodelled human/friction dynamics are an
*unbounded* model error for Theorem 1, so no coverage is promised), ``oracle-akf`` (the true
plant's configuration: no model error — Theorem 1's assumptions hold up to the noise model),
and ``gp-akf`` when ``sea_daemon.estimators.gpakf`` exists (the GP error bounded by
eq:gpmeanbounds).
"""
from __future__ import annotations

import json
import os
import time
from pathlib import Path

import numpy as np

from ..config import repo_root
from ..errors import InputError

NAME = "bounds"
HELP = "coverage of the Theorem-1 bound rho_k (and of the KF's own bound) on the paper's scenarios; plots"


def _builders():
    from ..bounds.akf_bound import attach_default_bound
    from ..estimators import AKF

    def akf(cfg, dt):
        e = AKF(cfg, dt=dt)
        attach_default_bound(e)
        return e

    out = {"akf": lambda nominal, true, train, dt: akf(nominal, dt),
           "oracle-akf": lambda nominal, true, train, dt: akf(true, dt)}
    import importlib.util
    if importlib.util.find_spec("sea_daemon.estimators.gpakf") is not None:
        import importlib
        mod = importlib.import_module("sea_daemon.estimators.gpakf")

        def gp(nominal, true, train, dt):
            e = mod.build(nominal, train, dt)
            if getattr(e, "theorem_bound", None) is None and hasattr(e, "residual"):
                attach_default_bound(e)
            return e
        out["gp-akf"] = gp
    return out


def add_arguments(p) -> None:
    p.add_argument("--scenarios", nargs="+", default=None, metavar="SCENARIO.yaml",
                   help="scenario files (default: configs/scenarios/passive.yaml active.yaml)")
    p.add_argument("--out", default="bench_bounds", help="directory for the plots and results.json")
    p.add_argument("--estimators", default=None, help="comma-separated labels (default: all available)")
    p.add_argument("--als", action="store_true",
                   help="identify R from each scenario's training log by ALS (identify-noise) and use it "
                        "(and P0 = R) for every estimator instead of the configured R")


def _run_one(est, log):
    """Replay with the per-step KF-only bound recorded next to ρ_k."""
    from ..bounds.setmember import chi2_quantile
    N, n = len(log), log.n
    hat, rho, kf, times = np.zeros((N, n)), np.zeros((N, n)), np.zeros((N, n)), np.zeros(N - 1)
    tb = getattr(est, "theorem_bound", None)
    s = tb.sm.s_tau if tb is not None else chi2_quantile(1 - est.delta, 5 * n)
    e = est.reset(log.q[0], log.theta_m[0], log.tau_m[0])
    hat[0], rho[0] = e.tau_h_act_hat, e.tau_h_act_bound
    kf[0] = np.sqrt(s * np.diagonal(e.P)[4 * n:])
    for k in range(1, N):
        t0 = time.perf_counter()
        e = est.update(log.q[k], log.theta_m[k], log.tau_m[k], log.t[k] - log.t[k - 1])
        times[k - 1] = time.perf_counter() - t0
        hat[k], rho[k] = e.tau_h_act_hat, e.tau_h_act_bound
        kf[k] = np.sqrt(s * np.diagonal(e.P)[4 * n:])
    return hat, rho, kf, times


def run(args) -> int:
    try:
        from ..sim.runner import simulate
        from ..sim.scenario import load_scenario
    except ImportError:
        raise InputError("bench bounds needs the simulator (sea_daemon.sim)") from None
    from . import choose, machine, summarize
    builders = _builders()
    labels = choose(args.estimators, builders, "--estimators")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    d = repo_root() / "configs" / "scenarios"
    scenarios = args.scenarios or [str(d / "passive.yaml"), str(d / "active.yaml")]
    print(f"machine: {machine()}; load average {os.getloadavg()[0]:.2f} at start")
    table = {}
    for sc_path in scenarios:
        sc = load_scenario(sc_path)
        sim = simulate(sc)
        log, train = sim.estimation, sim.training
        name = Path(sc_path).stem
        delta = sc.nominal.estimator.delta
        nominal, true = sc.nominal, sc.true_config()
        print(f"\nscenario {name}: {len(log)} samples, delta = {delta}, seed {sc.seed}")
        if args.als:
            from ..als import config_with_R, floored_R, identify_noise
            R, enc, _ = floored_R(nominal, identify_noise(nominal, train))
            nominal, true = config_with_R(nominal, R), config_with_R(true, R)
            print(f"  R identified by ALS on the training log ({len(train)} samples): encoder variances "
                  f"{enc}; diag R = {np.array2string(np.diag(R), precision=3)}")
        print(f"  {'estimator':<11s} {'cover rho':>9s} {'cover KF':>9s} {'mean rho':>9s} {'mean KF':>8s} "
              f"{'mean|e|':>8s} {'max|e|':>8s}  step time")
        rows, curves = {}, {}
        for label in labels:
            est = builders[label](nominal, true, train, log.dt)
            hat, rho, kf, times = _run_one(est, log)
            err = np.abs(hat - log.tau_h_act)
            row = {"coverage_rho": float(np.mean(err <= rho)), "coverage_kf": float(np.mean(err <= kf)),
                   "mean_rho": float(np.mean(rho)), "mean_kf_bound": float(np.mean(kf)),
                   "mean_abs_error": float(np.mean(err)), "max_abs_error": float(np.max(err)),
                   "step_time": summarize(times)}
            tb = getattr(est, "theorem_bound", None)
            if tb is not None:
                row["gp_box_violations"] = int(tb.gp_box_violations_)
            rows[label] = row
            curves[label] = (hat, rho)
            print(f"  {label:<11s} {row['coverage_rho']:9.3f} {row['coverage_kf']:9.3f} {row['mean_rho']:9.3f} "
                  f"{row['mean_kf_bound']:8.3f} {row['mean_abs_error']:8.3f} {row['max_abs_error']:8.3f}  "
                  f"{row['step_time']}")
        png = out / f"{name}.png"
        _plot(png, f"{name}: estimate with the Theorem-1 bound ρ_k (δ = {delta})", log.t, log.tau_h_act, curves)
        print(f"  plot: {png}")
        table[name] = rows
    (out / "results.json").write_text(json.dumps(table, indent=1))
    print(f"\nresults: {out / 'results.json'}  (cover = fraction of samples with |error| <= bound; "
          f"eq:bounds promises >= 1 - delta where Theorem 1's assumptions hold)")
    return 0


def _plot(path: Path, title: str, t, truth, curves) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    colors = {"akf": "navy", "oracle-akf": "tab:gray", "gp-akf": "tab:green"}
    fig, ax = plt.subplots(figsize=(9, 4.2))
    t0 = t - t[0]
    for label, (h, r) in curves.items():
        c = colors.get(label)
        ax.plot(t0, h[:, 0], color=c, lw=1.2, label=f"{label} ± ρ")
        ax.fill_between(t0, h[:, 0] - r[:, 0], h[:, 0] + r[:, 0], color=c, alpha=0.15, lw=0)
    ax.plot(t0, truth[:, 0], "k:", lw=1.6, label="truth")
    # keep the estimates readable when a ρ band is huge (it is then clipped by the axes)
    lo = min(truth[:, 0].min(), *(h[:, 0].min() for h, _ in curves.values()))
    hi = max(truth[:, 0].max(), *(h[:, 0].max() for h, _ in curves.values()))
    pad = max(2.0, 0.5 * (hi - lo))
    ax.set_ylim(lo - pad, hi + pad)
    ax.set_xlabel("t [s]")
    ax.set_ylabel(r"$\hat\tau_{h,act}$ [N m]")
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
