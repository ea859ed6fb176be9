"""``python -m benchmarks.accuracy``: RMSE of the estimators on the paper's two scenarios.

Note on ``oracle-akf``: it uses the true plant's effects with the configuration's
estimator settings (paper R, Σ_nom, ``sign_eps``).  With Coulomb/Stribeck friction declared
and the joint held still (active scenario) the smoothed friction is a very steep function
of the estimated velocity, and the paper's large velocity process noise lets the filter
explain torque changes by velocity/friction instead of τ_h,act: the oracle is then slower
than the plain AKF (docs/benchmarks.md, "GP-AKF accuracy").

For each scenario (default ``configs/scenarios/passive.yaml`` and ``active.yaml``, Sec. V-B
and V-C of the paper): simulate the training and estimation phases, run every estimator
over the estimation log, print a table (RMSE, mean |error|, mean bound, coverage of the
bound, median step time) and write a plot per scenario like the paper's Fig. 3 / Fig. 4:
estimate vs. truth with the 2σ band of P_k.

Estimators (:data:`CASES`, label -> ``builder(nominal_cfg, true_cfg, train_log, dt, bound)``):
``spring`` (τ_s), ``akf`` (Park et al., nominal model), ``oracle-akf`` (the same AKF given
the true plant's configuration, every hidden effect declared: what the AKF can do with a
perfect model), ``gp-akf`` (learns from ``train_log``, then frozen).  Extension point:
``register(label, builder)`` adds a column.

Estimator settings: ``--settings MODEL.yaml`` (default ``configs/exo_1dof_sim.yaml``: R identified
for the simulated sensors, process noise from the hardware's motor-torque noise plus a τ_h,act
random walk, GP predictive variance in Q) gives its estimator, kinematics and learning sections to
EVERY estimator (one setting for all, both scenarios); ``--settings scenario`` keeps each
scenario's model config (the paper's R, Σ_nom).  See docs/gpakf.md.
"""
from __future__ import annotations

import json
import os
import time
from pathlib import Path
from typing import Callable

import numpy as np

from sea_daemon.apps.bench import add_settings_argument, apply_settings, choose, start_simulated
from sea_daemon.core.estimators import make_estimator
from sea_daemon.core.replay import replay, summarize
from sea_daemon.io.configfile import data_root
from sea_daemon.io.scenario import load_scenario
from sea_daemon.runtime.sim_runner import simulate

NAME = "accuracy"
HELP = "RMSE of spring / AKF / oracle AKF (and GP-AKF when registered) on the paper's scenarios; plots"

CASES: dict[str, Callable] = {
    "spring": lambda nominal, true, train, dt, bound: make_estimator("spring", nominal, dt=dt),
    "akf": lambda nominal, true, train, dt, bound: make_estimator("akf", nominal, dt=dt, bound=bound),
    "oracle-akf": lambda nominal, true, train, dt, bound: make_estimator("akf", true, dt=dt, bound=bound),
    "gp-akf": lambda nominal, true, train, dt, bound: make_estimator("gp-akf", nominal, dt=dt, train=train,
                                                                      bound=bound),
}
COLORS = {"spring": "tab:red", "akf": "navy", "oracle-akf": "tab:gray", "gp-akf": "tab:green"}


def register(label: str, builder: Callable) -> None:
    """Add an estimator column: ``builder(nominal_cfg, true_cfg, train_log, dt, bound) -> Estimator``
    (``bound``: the Theorem-1 bound on or off, as :func:`make_estimator`'s)."""
    CASES[label] = builder


def default_scenarios() -> list[str]:
    d = data_root() / "configs" / "scenarios"
    return [str(d / "passive.yaml"), str(d / "active.yaml")]


def add_arguments(p) -> None:
    p.add_argument("--scenarios", nargs="+", default=None, metavar="SCENARIO.yaml",
                   help="scenario files (default: configs/scenarios/passive.yaml active.yaml)")
    add_settings_argument(p)
    p.add_argument("--out", default="bench_accuracy", help="directory for the plots and results.json")
    p.add_argument("--estimators", default=None, help="comma-separated labels (default: all registered)")
    p.add_argument("--bound", choices=["theorem", "kf"], default="theorem",
                   help="the bound column: 'theorem' = the Theorem-1 rho_k the daemon publishes "
                        "(make_estimator's default; its cost is in the step time), 'kf' = the filter's own "
                        "chi-square bound sqrt(s P_tautau) (default: theorem)")


def plot(path: Path, title: str, t: np.ndarray, truth: np.ndarray, results: dict) -> None:
    """Estimate vs truth with the 2σ band of P_k (paper Fig. 3/4)."""
    # local: matplotlib takes ~0.5 s to import and its backend is a process-wide choice, made here
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(9, 4.2))
    t0 = t - t[0]
    for label, res in results.items():
        c = COLORS.get(label)
        h, s = res.tau_h_act_hat[:, 0], res.tau_h_act_sigma[:, 0]
        ax.plot(t0, h, color=c, lw=1.2, label=label)
        ax.fill_between(t0, h - 2 * s, h + 2 * s, color=c, alpha=0.18, lw=0)
    ax.plot(t0, truth[:, 0], "k:", lw=1.6, label="truth")
    ax.set_xlabel("t [s]")
    ax.set_ylabel(r"$\hat\tau_{h,act}$ [N m]")
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(loc="best", fontsize=8, ncol=len(results) + 1)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def run(args) -> int:
    labels = choose(args.estimators, CASES, "--estimators")
    out, settings = start_simulated(args)
    table = {}
    for sc_path in args.scenarios or default_scenarios():
        sc = load_scenario(sc_path)
        sim = simulate(sc)
        log, train = sim.estimation, sim.training
        nominal = sc.declared(apply_settings(sc.nominal, settings))
        true = sc.declared(apply_settings(sc.true_config(), settings))
        name = Path(sc_path).stem
        print(f"\nscenario {name}: {sc.description}; estimation {len(log)} samples, training {len(train)}, "
              f"seed {sc.seed}")
        results = {}
        rows = {}
        for label in labels:
            # bound "theorem": tau_h_act_bound = Theorem-1 rho_k (docs/bounds.md)
            est = CASES[label](nominal, true, train, log.dt, args.bound == "theorem")
            res = replay(log, est, clock=time.perf_counter)
            res.estimator = label
            results[label] = res
            rows[label] = summarize(res)
        print(f"  {'estimator':<11s} {'RMSE':>8s} {'mean|e|':>8s} {'max|e|':>8s} {'bound':>8s} {'cover':>6s} "
              f"{'step med':>9s} {'step p99':>9s}")
        for label, s in rows.items():
            st = s.get("step_time_us", {})
            print(f"  {label:<11s} {s['rmse']:8.3f} {s['mean_abs_error']:8.3f} {s['max_abs_error']:8.3f} "
                  f"{s['mean_bound']:8.3f} {s['coverage']:6.2f} {st.get('median', float('nan')):7.1f}us "
                  f"{st.get('p99', float('nan')):7.1f}us")
        if "gp-akf" in rows:
            g = rows["gp-akf"]["rmse"]
            parts = [f"GP-AKF RMSE {g:.4f} N m"]
            if "akf" in rows:
                parts.append(f"AKF / GP-AKF = {rows['akf']['rmse'] / g:.1f}x")
            if "oracle-akf" in rows:
                parts.append(f"GP-AKF / oracle AKF = {g / rows['oracle-akf']['rmse']:.2f}x")
            print("  " + "; ".join(parts))
        png = out / f"{name}.png"
        plot(png, f"{name}: estimated active human torque (shaded: 2σ of P_k)", log.t, log.tau_h_act, results)
        print(f"  plot: {png}")
        table[name] = rows
    print(f"load average {os.getloadavg()[0]:.2f} at the end")
    (out / "results.json").write_text(json.dumps(table, indent=1))
    what = ("Theorem-1 bound rho_k at delta (step times include it)" if args.bound == "theorem"
            else "KF chi-square bound at delta")
    print(f"\nresults: {out / 'results.json'}  (RMSE in N m; bound = {what}; "
          "cover = fraction of samples with |error| <= bound)")
    return 0


if __name__ == "__main__":
    import sys

    from benchmarks._cli import main
    sys.exit(main(sys.modules[__name__]))
