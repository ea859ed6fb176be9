"""``python -m benchmarks.bounds``: does the Theorem-1 bound ρ_k hold on the paper's scenarios?

For each scenario (default ``configs/scenarios/passive.yaml`` and ``active.yaml``):
simulate, run every estimator over the estimation log with the Theorem-1 bound
(:class:`sea_daemon.core.bounds.akf_bound.AKFTheoremBound`), and report per estimator the
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
and ``gp-akf`` (the GP error bounded by eq:gpmeanbounds).

Scenarios: ``NAME.yaml`` (training and estimation phases of the same scenario) or
``NAME.yaml@TRAIN.yaml`` (estimation phase of NAME, training phase — and R by ALS, and the
conformal calibration log — of TRAIN).  Default: ``passive``, ``active`` (the paper's) and two
with an effect the GP has not seen, trained on ``passive``: ``unseen_range`` (moves up to
110 deg, beyond the 75 deg of the training) and ``unseen_load`` (a 0.5 kg weight in the hand).

Estimator settings (``--settings``, as in ``bench accuracy``): default
``configs/exo_1dof_sim.yaml`` for every estimator (the settings of the accuracy figures and of
``sea-daemon demo``); ``scenario`` keeps each scenario's own config (the paper's R, Σ_nom).
``--als`` then replaces R (and P0's measurement block) by the ALS estimate of the training log.

GP error bound (``--gp-beta``, docs/bounds.md §2): ``lederer`` (LUH19), ``conformal``
(split-conformal β of the GP error from a held-out calibration log: the training phase of the
training scenario simulated again with seed + 1000, which the GP never learned), ``torque``
(the smallest β whose ρ_k covers the GP-AKF's own torque error on that log, §2c), ``exact``
(a diagnostic, not a bound anyone could run: η_k = |f(z_k) − μ(z_k)| at the simulator's true
state, i.e. the GP error known exactly — the least any GP error bound can put into Theorem 1)
or a number; one ``gp-akf`` column per choice.

Human-torque rate (docs/bounds.md §6): a scenario that declares ``tau_h_act_rate`` (active:
1.26 N m/s) sets ``estimator.tau_h_act_rate`` for every estimator's bound.

Step time: ``step`` is the whole update with the bound; ``bound`` its own share (timed around
the bound component's step).
"""
from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path

import numpy as np

from sea_daemon.apps.bench import add_settings_argument, apply_settings, choose, start_simulated, summarize
from sea_daemon.analysis.als import config_with_R, floored_R, identify_noise
from sea_daemon.core.bounds.akf_bound import AKFTheoremBound
from sea_daemon.core.bounds.calibration import conformal_gp_constants, gp_constants, residual_gps
from sea_daemon.core.bounds.ellipsoid import chi2_quantile
from sea_daemon.core.bounds.torque_beta import torque_calibrated_beta
from sea_daemon.core.estimators import make_estimator
from sea_daemon.errors import EstimatorFault, InputError
from sea_daemon.io.configfile import data_root
from sea_daemon.io.scenario import load_scenario
from sea_daemon.runtime.sim_runner import simulate

NAME = "bounds"
HELP = "coverage of the Theorem-1 bound rho_k (and of the KF's own bound) on the paper's scenarios; plots"


def _builders(gp_betas):
    out = {"akf": lambda nominal, true, train, cal, dt: make_estimator("akf", nominal, dt=dt),
           "oracle-akf": lambda nominal, true, train, cal, dt: make_estimator("akf", true, dt=dt)}

    def make(beta):
        def gp(nominal, true, train, cal, dt):
            # the GP constants of a conformal, exact or torque β need the trained GP: the bound
            # component is given after training
            e = make_estimator("gp-akf", nominal, dt=dt, train=train, bound=False)
            if beta == "conformal":
                # δ_GP = δ/2 as in the default bound; calibrated on the held-out log
                consts, box, scores = conformal_gp_constants(e, cal, 0.5 * e.delta)
                e.conformal_info_ = (consts, len(scores))
                e.bound = AKFTheoremBound(e, gp_constants=consts, gp_box=box)
            elif beta == "exact":
                # η_k set per step from the simulator's truth (_ExactGPError.feed in run)
                _, box = gp_constants(residual_gps(e), 0.5 * e.delta, beta=1.0)
                e.bound = AKFTheoremBound(e, gp_constants=[_ExactGPError() for _ in range(e.n)], gp_box=box)
            elif beta == "torque":
                # the smallest β whose ρ covers the torque error of the held-out passive log
                cal_beta = torque_calibrated_beta(e, cal, e.delta)
                e.torque_info_ = cal_beta
                e.bound = AKFTheoremBound(e, gp_constants="auto", gp_beta=cal_beta["beta"])
            else:
                e.bound = AKFTheoremBound(e, gp_constants="auto", gp_beta=beta)
            return e
        return gp
    for beta in gp_betas:
        out["gp-akf" if beta == "lederer" else f"gp-akf/{beta}"] = make(beta)
    return out


def add_arguments(p) -> None:
    p.add_argument("--scenarios", nargs="+", default=None, metavar="SCENARIO.yaml[@TRAIN.yaml]",
                   help="scenario files; NAME.yaml@TRAIN.yaml estimates on NAME's estimation log with the "
                        "training (ALS, calibration) of TRAIN (default: configs/scenarios/passive.yaml "
                        "active.yaml unseen_range.yaml@passive.yaml unseen_load.yaml@passive.yaml)")
    p.add_argument("--out", default="bench_bounds", help="directory for the plots and results.json")
    p.add_argument("--estimators", default=None, help="comma-separated labels (default: all available)")
    add_settings_argument(p)
    p.add_argument("--als", action="store_true",
                   help="identify R from each scenario's training log by ALS (identify-noise) and use it "
                        "(and P0 = R) for every estimator instead of the configured R")
    p.add_argument("--gp-beta", default="lederer,conformal,torque",
                   help="comma-separated GP error bounds, one gp-akf column each: lederer, conformal, torque, "
                        "exact (diagnostic: the true GP error from the simulator), or a number beta "
                        "(default: lederer,conformal,torque)")


def _gp_betas(text: str) -> list:
    out = []
    for s in (t.strip() for t in text.split(",") if t.strip()):
        if s in ("lederer", "conformal", "torque", "exact"):
            out.append(s)
            continue
        try:
            v = float(s)
        except ValueError:
            v = float("nan")
        if not (np.isfinite(v) and v > 0):
            raise InputError(f"--gp-beta {s}: must be lederer, conformal, torque, exact or a number > 0")
        out.append(v)
    if not out:
        raise InputError("--gp-beta: give at least one of lederer, conformal, torque, exact, a number > 0")
    return out


class _ExactGPError:
    """Stands in for the GP error constants of one joint: η = |f(z) − μ(z)| at the simulator's
    true (q, q̇, q̈) of the step being predicted (``--gp-beta exact``).  f is the sum of the true
    plant's load-side effects (the GP's target under ass:passive_human, eq:loadsidewmotor) with
    the plant's own friction smoothing."""

    sqrt_beta, gamma, method, scale = float("nan"), 0.0, "exact", "sigma"

    def __init__(self):
        self.value = 0.0

    def eta(self, s):
        return np.full(np.shape(s), self.value)

    @staticmethod
    def feeder(est, log, sc):
        """``feed(k)``: set η for the step k−1 → k from the log's true-state columns."""
        gps = residual_gps(est)
        effects = [dataclasses.replace(e, eps=sc.plant.sign_eps) if hasattr(e, "eps") else e
                   for e in sc.plant.effects if e.side == "load" and e.additive]
        x = log.extra
        q, dq = x["q_true"], x["dq_true"]
        ddq = np.gradient(dq, log.dt)
        consts = est.bound.gp_constants
        n = len(gps)

        def feed(k):
            z = np.empty(3 * n)
            z[:n], z[n:2 * n] = q[k - 1], dq[k - 1]
            z[2 * n:] = est.z[2 * n:]                  # q̈ as the filter measures it
            f = sum(e.torque(q[k - 1], dq[k - 1], ddq[k - 1]) for e in effects)
            for j, g in enumerate(gps):
                mu, _ = g.predict(z)
                consts[j].value = abs(f - mu)
        return feed


def _run_one(est, log, feed=None):
    """Replay with the per-step KF-only bound recorded next to ρ_k, and the step time split
    into the filter step and the bound's own share; ``feed(k)`` (if given) runs before step k,
    outside the timing."""
    N, n = len(log), log.n
    hat, rho, kf = np.zeros((N, n)), np.zeros((N, n)), np.zeros((N, n))
    times, inner = np.zeros(N - 1), np.zeros(N - 1)
    tb = getattr(est, "bound", None)
    s = tb.sm.s_tau if tb is not None else chi2_quantile(1 - est.delta, 5 * n)
    spent = [0.0]
    if tb is not None:
        est.bound = _TimedBound(tb, spent)
    e = est.reset(log.q[0], log.theta_m[0], log.tau_m[0])
    hat[0], rho[0] = e.tau_h_act_hat, e.tau_h_act_bound
    kf[0] = np.sqrt(s * np.diagonal(e.P)[4 * n:])
    fault = None
    for k in range(1, N):
        spent[0] = 0.0
        if feed is not None:
            feed(k)
        t0 = time.perf_counter()
        try:
            e = est.update(log.q[k], log.theta_m[k], log.tau_m[k], log.t[k] - log.t[k - 1])
        except EstimatorFault as exc:
            # the daemon's reaction (docs/safety.md): the fault latches, the estimate is invalid
            # from here on -- the rows after it are not estimates and are cut off
            fault = (k, f"{type(exc).__name__}: {exc}")
            N = k
            hat, rho, kf, times, inner = hat[:k], rho[:k], kf[:k], times[:k - 1], inner[:k - 1]
            break
        times[k - 1] = time.perf_counter() - t0
        inner[k - 1] = spent[0]
        hat[k], rho[k] = e.tau_h_act_hat, e.tau_h_act_bound
        kf[k] = np.sqrt(s * np.diagonal(e.P)[4 * n:])
    if tb is not None:
        est.bound = tb
    return hat, rho, kf, times, (inner if tb is not None else None), fault


class _TimedBound:
    """The bound component ``bound`` with the time of its last step in ``spent[0]``."""

    def __init__(self, bound, spent):
        self.bound, self.spent = bound, spent

    def reset(self, *args):
        self.bound.reset(*args)

    def step(self, *args):
        t0 = time.perf_counter()
        try:
            self.bound.step(*args)
        finally:
            self.spent[0] = time.perf_counter() - t0


def _cases(paths):
    d = data_root() / "configs" / "scenarios"
    if not paths:
        return [(d / "passive.yaml", d / "passive.yaml"), (d / "active.yaml", d / "active.yaml"),
                (d / "unseen_range.yaml", d / "passive.yaml"), (d / "unseen_load.yaml", d / "passive.yaml")]
    out = []
    for p in paths:
        est, _, train = p.partition("@")
        out.append((Path(est), Path(train or est)))
    return out


def run(args) -> int:
    gp_betas = _gp_betas(args.gp_beta)
    builders = _builders(gp_betas)
    labels = choose(args.estimators, builders, "--estimators")
    out, settings = start_simulated(args)
    table = {}
    sims = {}

    def sim_of(path, seed=None):
        key = (str(path), seed)
        if key not in sims:
            sims[key] = simulate(load_scenario(path), seed=seed)
        return sims[key]

    for est_path, train_path in _cases(args.scenarios):
        table[Path(est_path).stem] = _scenario(args, est_path, train_path, sim_of, gp_betas,
                                               {label: builders[label] for label in labels}, settings, out)
    (out / "results.json").write_text(json.dumps(table, indent=1))
    print(f"\nresults: {out / 'results.json'}  (cover = fraction of samples with |error| <= bound; "
          f"eq:bounds promises >= 1 - delta where Theorem 1's assumptions hold; KF = the filter's own "
          f"sqrt(s P_tautau) with the same s)")
    return 0


def _scenario(args, est_path, train_path, sim_of, gp_betas, builders: dict, settings, out: Path) -> dict:
    """One scenario (estimated on ``est_path``'s estimation log, trained on ``train_path``'s
    training log): every estimator of ``builders`` replayed, its row printed, the plot.
    Returns label -> row."""
    sc, sc_train = load_scenario(est_path), load_scenario(train_path)
    log = sim_of(est_path).estimation
    train = sim_of(train_path).training
    cal = None
    if "conformal" in gp_betas or "torque" in gp_betas:
        # held-out calibration: the training session again, independent noise (seed + 1000)
        cal = sim_of(train_path, sc_train.seed + 1000).training
    name = Path(est_path).stem
    delta = sc.nominal.estimator.delta
    nominal = sc.declared(apply_settings(sc.nominal, settings))
    true = sc.declared(apply_settings(sc.true_config(), settings))
    trained = "" if train_path == est_path else f", trained on {Path(train_path).stem}"
    print(f"\nscenario {name}{trained}: {len(log)} samples, delta = {delta}, seed {sc.seed}")
    if args.als:
        R, enc, _ = floored_R(nominal, identify_noise(nominal, train))
        nominal, true = config_with_R(nominal, R), config_with_R(true, R)
        print(f"  R identified by ALS on the training log ({len(train)} samples): encoder variances "
              f"{enc}; diag R = {np.array2string(np.diag(R), precision=3)}")
    print(f"  {'estimator':<14s} {'cover rho':>9s} {'cover KF':>9s} {'mean rho':>9s} {'mean KF':>8s} "
          f"{'mean|e|':>8s} {'max|e|':>8s} {'rho/|e|':>8s}  step time / bound's share [us]")
    rows, curves = {}, {}
    for label, build in builders.items():
        try:
            est = build(nominal, true, train, cal, log.dt)
        except EstimatorFault as exc:
            rows[label] = {"fault": f"training: {exc}"}
            print(f"  {label:<14s} fault while learning the training log: {exc}")
            continue
        rows[label], curves[label] = _estimator_row(label, est, log, sc)
    png = out / f"{name}.png"
    _plot(png, f"{name}{trained}: estimate ± Theorem-1 bound ρ_k (δ = {delta})", log.t, log.tau_h_act, curves)
    print(f"  plot: {png}")
    return rows


def _estimator_row(label: str, est, log, sc) -> tuple[dict, tuple]:
    """One estimator replayed over ``log``: its row of results.json (printed) and its curve
    (estimate, ρ_k)."""
    feed = _ExactGPError.feeder(est, log, sc) if label == "gp-akf/exact" else None
    hat, rho, kf, times, btimes, fault = _run_one(est, log, feed)
    err = np.abs(hat - log.tau_h_act[:len(hat)])
    row = {"coverage_rho": float(np.mean(err <= rho)), "coverage_kf": float(np.mean(err <= kf)),
           "mean_rho": float(np.mean(rho)), "mean_kf_bound": float(np.mean(kf)),
           "mean_abs_error": float(np.mean(err)), "max_abs_error": float(np.max(err)),
           "step_time": summarize(times)}
    row["rho_over_error"] = row["mean_rho"] / max(row["mean_abs_error"], 1e-300)
    if fault is not None:
        row["fault_step"], row["fault"] = fault
        row["valid_fraction"] = len(hat) / len(log)
    tail = f"step median {1e6 * np.median(times):.0f}, p99 {1e6 * np.percentile(times, 99):.0f}"
    if btimes is not None:
        row["bound_time"] = summarize(btimes)
        row["bound_time_median_us"] = float(1e6 * np.median(btimes))
        row["bound_time_p99_us"] = float(1e6 * np.percentile(btimes, 99))
        tail += f"; bound median {row['bound_time_median_us']:.0f}, p99 {row['bound_time_p99_us']:.0f}"
    tb = getattr(est, "bound", None)
    if tb is not None:
        row["gp_box_violations"] = int(tb.gp_box_violations_)
        if tb.gp_constants:
            c = tb.gp_constants[0]
            row["gp_beta"] = float(c.sqrt_beta)
            row["gp_gamma"] = float(c.gamma)
            row["gp_beta_method"] = c.method
            tail += f"; beta {c.sqrt_beta:.3g} ({c.method}), box violations {tb.gp_box_violations_}"
    info = getattr(est, "conformal_info_", None)
    if info is not None:
        row["conformal_calibration_pairs"] = int(info[1])
    tinfo = getattr(est, "torque_info_", None)
    if tinfo is not None:
        row["torque_calibration"] = {k: tinfo[k] for k in ("beta", "coverage", "steps", "target")}
        tail += f"; calibration log covered {tinfo['coverage']:.3f} ({tinfo['steps']} steps)"
    if fault is not None:
        tail += (f"; FAULT latched at step {fault[0]} (t = {log.t[fault[0]] - log.t[0]:.2f} s, "
                 f"{fault[1].split(':')[0]}): figures over the {len(hat)} valid samples")
    print(f"  {label:<14s} {row['coverage_rho']:9.3f} {row['coverage_kf']:9.3f} {row['mean_rho']:9.3f} "
          f"{row['mean_kf_bound']:8.3f} {row['mean_abs_error']:8.3f} {row['max_abs_error']:8.3f} "
          f"{row['rho_over_error']:8.1f}  {tail}")
    return row, (hat, rho)


def _plot(path: Path, title: str, t, truth, curves) -> None:
    # local: matplotlib takes ~0.5 s to import and its backend is a process-wide choice, made here
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    colors = {"akf": "navy", "oracle-akf": "tab:gray", "gp-akf": "tab:green", "gp-akf/conformal": "tab:orange",
              "gp-akf/torque": "tab:purple", "gp-akf/exact": "tab:red"}
    fig, ax = plt.subplots(figsize=(9, 4.2))
    t0 = t - t[0]
    for label, (h, r) in curves.items():
        c = colors.get(label)
        # variants of one estimator (gp-akf/...) share its estimate: dashed, so both stay visible
        tt = t0[:len(h)]            # a latched fault ends an estimator's curve
        ax.plot(tt, h[:, 0], color=c, lw=1.2, ls="--" if "/" in label else "-", label=f"{label} ± ρ")
        ax.fill_between(tt, h[:, 0] - r[:, 0], h[:, 0] + r[:, 0], color=c, alpha=0.15, lw=0)
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


if __name__ == "__main__":
    import sys

    from benchmarks._cli import main
    sys.exit(main(sys.modules[__name__]))
