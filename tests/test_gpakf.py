"""GP-AKF (Alg. 2): online learning from a passive log, prediction/linearisation/covariance
with the GP (eq:fwdynwtorqueresidual1, eq:linearization, eq:gpakf_covariance, eq:GPvarfwd),
determinism, and ``replay --estimator gp-akf --train``."""
import dataclasses

import numpy as np
import pytest

from sea_daemon.apps import cli
from sea_daemon.apps.bench import apply_settings
from sea_daemon.io.configfile import load_config
from _paths import repo_root
from sea_daemon.core.estimators import AKF
from sea_daemon.core.estimators import make_estimator
from sea_daemon.core.estimators.gpakf import GPAKF, learn_from_log
from sea_daemon.core.log import MeasuredLog
from sea_daemon.io.logcsv import write_log
from sea_daemon.core.model import SEAModel
from sea_daemon.core.replay import replay, summarize

SETTINGS = str(repo_root() / "configs" / "exo_1dof_sim.yaml")


@pytest.fixture(scope="module")
def passive():
    """Shortened passive scenario (Sec. V-B): two moves to learn, the same two moves to estimate."""
    from sea_daemon.runtime.sim_runner import simulate
    from sea_daemon.io.scenario import load_scenario

    sc = load_scenario(repo_root() / "configs" / "scenarios" / "passive.yaml")
    ctrl = sc.controller
    sc = dataclasses.replace(sc, training_samples=700, estimation_samples=700,
                             controller=dataclasses.replace(ctrl, trajectory=dataclasses.replace(ctrl.trajectory, moves=4)))
    sim = simulate(sc)
    settings = load_config(SETTINGS)
    return apply_settings(sc.nominal, settings), sim.training, sim.estimation


@pytest.fixture(scope="module")
def trained(passive):
    cfg, train, _ = passive
    return make_estimator("gp-akf", cfg, dt=train.dt, train=train, bound=False)


def test_gp_akf_is_much_better_than_the_akf_on_a_passive_subject(passive, trained):
    cfg, train, est_log = passive
    rmse_akf = summarize(replay(est_log, AKF(cfg)))["rmse"]
    rmse_gp = summarize(replay(est_log, trained))["rmse"]
    assert trained.n_learned > 600 and not trained.learning
    # the plain AKF misses the arm (gravity, stiffness) and friction: ~1.7 N m; the GP-AKF
    # has learned them (measured 0.138 N m on this short run, 0.163 without gp_noise_in_Q)
    assert rmse_akf > 1.0
    assert rmse_gp < rmse_akf / 8.0
    assert rmse_gp < 0.2


def test_gp_akf_follows_an_active_subject_like_the_oracle():
    """Shortened active scenario (Sec. V-C, 3 s training, 10 s estimation) with the benchmark's
    settings: the GP-AKF meets the accuracy targets of issue 3 (measured: AKF 2.07, oracle 0.040,
    GP-AKF 0.046 N m)."""
    from sea_daemon.runtime.sim_runner import simulate
    from sea_daemon.io.scenario import load_scenario

    sc = load_scenario(repo_root() / "configs" / "scenarios" / "active.yaml")
    sc = dataclasses.replace(sc, training_samples=300, estimation_samples=1000)
    sim = simulate(sc)
    settings = load_config(SETTINGS)
    nominal, true = apply_settings(sc.nominal, settings), apply_settings(sc.true_config(), settings)
    log = sim.estimation
    rmse = {k: summarize(replay(log, est))["rmse"] for k, est in (
        ("akf", AKF(nominal)), ("oracle", AKF(true)), ("gp", make_estimator("gp-akf", nominal, dt=log.dt, train=sim.training, bound=False)))}
    assert rmse["gp"] < 0.1
    assert rmse["gp"] < rmse["akf"] / 20.0
    assert rmse["gp"] < 1.5 * rmse["oracle"]


class _Zero:
    """A residual that is exactly zero: μ = 0, ∂μ/∂z = 0, σ² = 0."""

    def __init__(self, n):
        self.n = n

    def predict(self, z):
        return np.zeros(self.n), np.zeros((self.n, 3 * self.n)), np.zeros(self.n)


def test_zero_residual_gp_akf_equals_the_akf_step_for_step(passive):
    cfg, _, log = passive
    g = GPAKF(cfg, learning=False)
    g.residual = _Zero(1)
    a = AKF(cfg)
    ra, rg = replay(log, a), replay(log, g)
    assert np.array_equal(ra.x_hat, rg.x_hat)
    assert np.array_equal(ra.tau_h_act_sigma, rg.tau_h_act_sigma)
    assert np.array_equal(a.P, g.P)


@pytest.mark.parametrize("noise_in_Q", [False, True])
def test_untrained_gp_gives_the_akf_prediction_plus_prior_variance(passive, noise_in_Q):
    """An empty GP: μ = 0 and F_GP = 0, so x⁻ and F are the AKF's; Q adds the prior σ_f²
    (eq:GPvarfwd), plus σ_on² with ``estimator.gp_noise_in_Q`` (predictive variance)."""
    cfg, _, log = passive
    cfg = dataclasses.replace(cfg, estimator=dataclasses.replace(cfg.estimator, gp_noise_in_Q=noise_in_Q))
    g = GPAKF(cfg, learning=False)
    a = AKF(cfg)
    for est in (a, g):
        est.reset(log.q[0], log.theta_m[0], log.tau_m[0])
        est.update(log.q[1], log.theta_m[1], log.tau_m[1])
    assert np.allclose(g.x_prior, a.x_prior, rtol=0, atol=1e-15)
    assert np.array_equal(g.F_k, a.F_k)
    var = cfg.learning.sigma_f ** 2 + (cfg.learning.sigma_n ** 2 if noise_in_Q else 0.0)
    assert np.allclose(g.Q_k - g.Sigma_nom, var * g.Gamma_mu @ g.Gamma_mu.T, rtol=1e-12, atol=0)


def _step_at(est, log, k):
    """Run ``est`` to sample k, return (x̂_{k−1}, u_{k−1}, ẑ_{k−1}) used by the k-th prediction."""
    est.reset(log.q[0], log.theta_m[0], log.tau_m[0])
    for i in range(1, k):
        est.update(log.q[i], log.theta_m[i], log.tau_m[i])
    x, P = est.x.copy(), est.P.copy()
    est.update(log.q[k], log.theta_m[k], log.tau_m[k])
    return x, P, est.u_applied.copy() if est.has_delay else log.tau_m[k - 1].copy(), est.z.copy()


def test_linearisation_matches_finite_differences_of_the_gp_akf_prediction(passive, trained):
    """eq:linearization: A_k = ∂/∂x [f_nom(x, u) − I_μ M⁻¹ μ(z(x))] at x̂_{k−1}, μ's Jacobian the
    experts' Σ ω_i ∂μ_i/∂z (the routing weights held at ẑ: the split ramps' ∂ω/∂z left out)."""
    cfg, _, log = passive
    est = trained
    model = SEAModel.from_config(cfg)
    G = model.I_mu @ model.Minv
    gp = est.gp
    g = gp.gps[0]
    in_overlap = 0
    for k in (150, 333, 520):                      # moving, in the learned region
        x0, _, u, z0 = _step_at(est, log, k)
        ddq = z0[2:]
        routed = g.route(est.residual.box.clip(z0))
        in_overlap += len(routed) > 1

        def f(x, experts=True):
            z = np.concatenate([x[:1] + x[1:2], x[2:3] + x[3:4], ddq])
            if experts:         # the leaves' means with the weights of ẑ
                mu = np.array([sum(w * g.leaf(node).predict(z)[0] for node, w, _ in routed)])
            else:
                mu, _, _ = gp.predict(z)
            # eq:fwdynwtorqueresidual1
            return model.f_nom(x, u) - G @ mu

        assert np.allclose(f(x0, False), est.xdot_k, rtol=1e-10, atol=1e-10)
        assert np.allclose(f(x0), est.xdot_k, rtol=1e-10, atol=1e-10)
        h = np.array([1e-6, 1e-6, 1e-5, 1e-5, 1e-4])
        A_fd = np.column_stack([(f(x0 + h[i] * e) - f(x0 - h[i] * e)) / (2 * h[i]) for i, e in enumerate(np.eye(5))])
        scale = np.abs(est.A_k).max()
        assert np.allclose(est.A_k, A_fd, rtol=1e-5, atol=1e-6 * scale), (k, est.A_k - A_fd)
        # the GP part is really there (F_GP ≠ 0 in the θ̈_s row)
        assert np.abs(est.A_k - model.F_nom(x0, u)).max() > 1e-3
    assert in_overlap                              # k = 333 lies in a split's overlap


def test_process_noise_includes_the_gp_variance_exactly(passive, trained):
    """eq:gpakf_covariance / eq:GPvarfwd: Q_k = Σ_nom + Γ_μ diag(σ²(ẑ)) Γ_μᵀ, Γ_μ the ZOH map of
    I_μ M⁻¹ over the step (the discrete form of I_μ M⁻¹ diag(σ²) M⁻ᵀ I_μᵀ, ≈ dt I_μ M⁻¹)."""
    cfg, _, log = passive
    est = trained
    model = SEAModel.from_config(cfg)
    _, _, _, z = _step_at(est, log, 400)
    _, _, var = est.gp.predict(z)
    assert var[0] > 0
    if cfg.estimator.gp_noise_in_Q:
        # predictive variance: + Σ ω_i σ_on,i² of the leaves z reaches
        var = var + est.gp.gps[0].noise_variance(z)
    assert np.allclose(est.sigma2, var, rtol=1e-12)
    expect = est.Sigma_nom + var[0] * est.Gamma_mu @ est.Gamma_mu.T
    assert np.allclose(est.Q_k, expect, rtol=1e-12, atol=0)
    # Γ_μ = ∫₀^dt e^{A s} ds I_μ M⁻¹ (ZOH, Van Loan block exponential), A the GP-AKF Jacobian
    from scipy.linalg import expm
    G = model.I_mu @ model.Minv
    blk = np.zeros((6, 6))
    blk[:5, :5], blk[:5, 5:] = est.A_k, G
    assert np.allclose(est.Gamma_mu, expm(blk * est.dt)[:5, 5:], rtol=1e-9, atol=1e-15)


def test_affine_path_equals_the_model(passive):
    """The AKF's cached-block path for an effect-free model equals SEAModel.F_nom / f_nom."""
    cfg, _, _ = passive
    a = AKF(cfg)
    assert a._affine
    rng = np.random.default_rng(3)
    for _ in range(5):
        x = rng.normal(size=5) * [1.0, 0.05, 1.0, 0.5, 2.0]
        u = rng.normal(size=1)
        A, xd = a._nominal_affine(x, u)
        assert np.allclose(A, a.model.F_nom(x, u), rtol=1e-13, atol=1e-12)
        assert np.allclose(xd, a.model.f_nom(x, u), rtol=1e-13, atol=1e-12)


def test_deterministic_under_a_seed(passive):
    cfg, train, log = passive
    short = MeasuredLog(t=train.t[:300], q=train.q[:300], theta_m=train.theta_m[:300],
                        tau_m=train.tau_m[:300], tau_h_act=None, path="<short>")
    r1 = replay(log, make_estimator("gp-akf", cfg, dt=short.dt, train=short, bound=False))
    r2 = replay(log, make_estimator("gp-akf", cfg, dt=short.dt, train=short, bound=False))
    assert np.array_equal(r1.tau_h_act_hat, r2.tau_h_act_hat)
    assert np.array_equal(r1.tau_h_act_sigma, r2.tau_h_act_sigma)


def test_replay_cli_gp_akf_with_train(tmp_path, passive, capsys):
    import json

    from sea_daemon.core.sim.session import run_session
    cfg, _, log = passive
    tp, lp, out = tmp_path / "train.csv", tmp_path / "log.csv", tmp_path / "est.csv"
    # 3 s with the arm held still: too short to identify the physics in motion, so the calibration
    # keeps the configured model and says so (docs/calibration.md); a few seconds of work
    train = run_session(cfg, 3.0, hold_q=0.3, seed=1)
    write_log(tp, MeasuredLog(t=train.t, q=train.q, theta_m=train.theta_m, tau_m=train.tau_m, tau_h_act=None))
    write_log(lp, MeasuredLog(t=log.t[:200], q=log.q[:200], theta_m=log.theta_m[:200], tau_m=log.tau_m[:200],
                              tau_h_act=log.tau_h_act[:200]))
    code = cli.main(["replay", str(lp), "--config", SETTINGS, "--train", str(tp), "--estimator", "gp-akf",
                     "--out", str(out)])
    assert code == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["estimator"] == "gp-akf" and summary["samples"] == 200 and summary["rmse"] is not None
    # --train runs the whole calibration on TRAIN.csv (docs/calibration.md): its summary says what
    # was identified (the values the configuration gives are kept)
    cal = summary["calibration"]
    assert summary["train"]["log"] == str(tp) and {"effects", "gp_kept", "coverage", "text"} <= set(cal)
    assert out.exists() and "tau_h_act_bound" in out.read_text().splitlines()[0]
    # bad --train: missing, malformed, absent
    bad = tmp_path / "bad.csv"
    bad.write_text("t,q,theta_m\n0,1,2\n0.01,1,2\n")
    for extra in (["--train", str(tmp_path / "nope.csv")], ["--train", str(bad)], []):
        code = cli.main(["replay", str(lp), "--config", SETTINGS, *extra, "--estimator", "gp-akf",
                         "--out", str(out)])
        assert code == 2
        err = capsys.readouterr().err
        assert err.strip() and "Traceback" not in err


def test_learning_pairs_use_the_filter_kinematics(passive):
    """Training targets come from the same causal kinematics as the filter (eq:loadsidewmotor)."""
    from sea_daemon.core.learning import training_pairs_from_log

    cfg, train, _ = passive
    est = GPAKF(cfg)
    seen = []
    orig = est._learn

    def spy(tau_m):
        orig(tau_m)
        seen.append((est.z_train.copy(), est.f_train.copy()))

    est._learn = spy
    learn_from_log(est, train)
    Z, F = training_pairs_from_log(SEAModel.from_config(cfg), train, kinematics=cfg.kinematics, causal=True)
    # the learner skips the samples while the differentiator fills, like training_pairs_from_log
    Zs = np.array([s[0] for s in seen])
    Fs = np.array([s[1] for s in seen])
    m = min(len(Zs), len(Z))
    assert np.allclose(Zs[-m:], Z[-m:], rtol=1e-9, atol=1e-9)
    assert np.allclose(Fs[-m:], F[-m:], rtol=1e-8, atol=1e-8)


def test_bench_latency_gp_akf_case_runs(capsys):
    code = cli.main(["bench", "latency", "--seconds", "1", "--repeat", "1", "--estimators", "gp-akf",
                     "--max-points", "1000"])
    out, _ = capsys.readouterr()
    assert code == 0
    assert "gp-akf-1e3: pre-filled 1000 points" in out and "gp-akf-1e3: per step median" in out
    assert "load average" in out and "gp-akf-1e4" not in out
    # the calibrated model's step (learning off) is timed too
    assert "gp-akf-calibrated: residual GP of" in out and "gp-akf-calibrated: per step median" in out
    # the CPU time split by what the LoG-GP did: 950 steps, mostly plain, slices every 10 updates
    line = next(l for l in out.splitlines() if "CPU time by what the LoG-GP did" in l)  # gp-akf-1e3's
    assert "plain" in line and "hyper phase 1" in line and "hyper phase 2" in line


def test_step_kind_reads_the_loggp_counters():
    from sea_daemon.apps.bench.latency import step_kind
    # (n_leaves, n_evicted, n_hyper_steps, pending)
    assert step_kind((5, 0, 3, False), (6, 0, 3, False)) == "split"
    assert step_kind((5, 0, 3, False), (5, 10, 3, False)) == "eviction"
    assert step_kind((5, 0, 3, False), (5, 0, 4, True)) == "hyper phase 1"
    assert step_kind((5, 0, 4, True), (5, 0, 4, False)) == "hyper phase 2"
    assert step_kind((5, 0, 4, False), (5, 0, 4, False)) == "plain"




def _two_joint_log(cfg, seconds, tau_h_amp, seed):
    """Encoder-quantised log of ``cfg``'s model (declared effects = the true plant)."""
    from sea_daemon.apps.bench.latency import model_log
    n, dt = cfg.joints, cfg.dt
    t = np.arange(int(seconds / dt) + 1) * dt
    ph = np.random.default_rng(seed).uniform(0, 2 * np.pi, size=(2, n))
    tau_m = 1.5 * np.sin(2 * np.pi * 0.4 * t[:, None] + ph[0]) + 0.6 * np.sin(2 * np.pi * 1.1 * t[:, None] + ph[1])
    tau_h = tau_h_amp * np.sin(2 * np.pi * 0.25 * t[:, None]) * np.array([1.0, -0.5])
    return model_log(cfg, t, tau_m, tau_h, path="<two>")


def test_two_joints_learn_a_hidden_load_torque_per_joint():
    """n = 2: one GP per joint on z = [q₁, q₂, q̇₁, q̇₂, q̈₁, q̈₂]; a hidden viscoelastic load per
    joint is learned from a passive log and no longer biases the estimate."""
    from sea_daemon.core.config import ModelConfig
    from sea_daemon.core.effects import make_effect

    d = {"joints": 2, "rate_hz": 100, "model": {
        "M": [[0.2, 0.03], [0.03, 0.1]], "J": [0.08, 0.05], "D_m": [0.6, 0.4], "K_s": [110.0, 80.0],
        "D_s": [0.25, 0.2], "gravity": [2.0, 0.5]},
        "estimator": {"R": [1e-12, 1e-12, 1e-12, 1e-12, 1e-5, 1e-5, 1e-5, 1e-5],
                      "Sigma_nom": [1e-9, 1e-9, 1e-9, 1e-9, 1e-5, 1e-5, 1e-5, 1e-5, 1e-2, 1e-2]},
        "kinematics": {"method": "savgol", "window": 5, "degree": 3}}
    cfg = ModelConfig.from_dict(d)
    hidden = [make_effect("human_viscoelastic", "load", joint=j, k_h=k, q_h0=0.2, b_h=0.1)
              for j, k in ((0, 1.5), (1, 0.8))]
    true = cfg.with_effects(hidden)
    train = _two_joint_log(true, 10.0, 0.0, seed=1)          # passive subject
    log = _two_joint_log(true, 8.0, 0.5, seed=1)             # same motion, active torque
    est = make_estimator("gp-akf", cfg, dt=cfg.dt, train=train, bound=False)
    assert est.gp.n == 2 and len(est.gp.gps) == 2 and est.gp.gps[0].input_dim == 6
    r_gp = replay(log, est)
    r_akf = replay(log, AKF(cfg))
    e_gp = np.sqrt(np.mean((r_gp.tau_h_act_hat - log.tau_h_act)[100:] ** 2, axis=0))
    e_akf = np.sqrt(np.mean((r_akf.tau_h_act_hat - log.tau_h_act)[100:] ** 2, axis=0))
    assert np.all(e_akf > 0.2), e_akf
    assert np.all(e_gp < e_akf / 3), (e_gp, e_akf)


def test_residual_hook_with_noise_in_q_adds_the_merged_leaf_noise():
    """gp_noise_in_Q: the hook's σ² is the latent variance plus Σ ω_i σ_on,i² of the leaves z
    reaches (LoGGP.noise_variance), inside and outside split overlaps."""
    from sea_daemon.core.estimators.gpakf import _ResidualHook
    from sea_daemon.core.learning import ResidualGP
    rng = np.random.default_rng(5)
    res = ResidualGP(1, overlap=0.3, max_points=20)
    Z = rng.uniform(-1, 1, (200, 3))
    for z in Z:
        res.update(z, [np.sin(3 * z[0]) + 0.1 * z[1]])
    g = res.gps[0]
    plain, noisy = _ResidualHook(res), _ResidualHook(res, noise_in_Q=True)
    seen = set()
    for z in rng.uniform(-0.9, 0.9, (40, 3)):
        mu0, jac0, var0 = (a.copy() for a in plain.predict(z))
        mu1, jac1, var1 = noisy.predict(z)
        assert mu1[0] == mu0[0] and np.array_equal(jac1, jac0)
        assert var1[0] == pytest.approx(var0[0] + g.noise_variance(z), rel=1e-12, abs=1e-15)
        seen.add(len(g.route(z)) > 1)
    assert seen == {False, True}


def test_frozen_sample_in_one_compiled_call_equals_the_python_step(passive, trained):
    """The frozen GP-AKF's compiled sample (gpakf_core) with the Theorem-1 bound gives the Python
    path's estimate, bound, σ, validity, state and set of means bit for bit, and the same typed
    fault for a non-finite sample."""
    from sea_daemon.core.bounds.akf_bound import theorem_bound
    from sea_daemon.core.estimators.health import EstimatorNonFinite
    cfg, _, log = passive
    runs = []
    for fused in (True, False):
        est = GPAKF(cfg, dt=log.dt, residual=trained.gp, learning=False, bound=theorem_bound)
        est._fz_ok = est._fz_ok and fused
        assert est._fz_ok == fused
        out = np.zeros((len(log), 4))
        est.reset(log.q[0], log.theta_m[0], log.tau_m[0])
        for k in range(1, len(log)):
            e = est.update(log.q[k], log.theta_m[k], log.tau_m[k])
            out[k] = e.tau_h_act_hat[0], e.tau_h_act_bound[0], e.tau_h_act_sigma[0], e.valid
        assert bool(est._fz_args) == fused                  # the compiled sample ran (or not)
        runs.append((out, est.x.copy(), est.P.copy(), est.bound.sm.G_.copy(), est.n_capped))
        bad = log.q[-1].copy()
        bad[0] = np.nan
        with pytest.raises(EstimatorNonFinite, match="prediction became non-finite"):
            est.update(bad, log.theta_m[-1], log.tau_m[-1])
    (a, xa, Pa, Ga, ca), (b, xb, Pb, Gb, cb) = runs
    assert np.array_equal(a, b) and np.array_equal(xa, xb) and np.array_equal(Pa, Pb) and np.array_equal(Ga, Gb)
    assert ca == cb and a[-1, 3] == 1.0 and np.all(np.isfinite(a[1:, 1]))


def _disagreeing_experts(overlap: float):
    """A one-joint residual GP of two leaves split at q̇ = 0 that disagree there: +1 N m below,
    −1 N m above (seeded points, q̇ spanning ±0.2 rad/s: the split's ramp is 0.4·overlap wide)."""
    from sea_daemon.core.config import LearningConfig
    from sea_daemon.core.learning import ResidualGP
    rng = np.random.default_rng(3)
    res = ResidualGP(1, LearningConfig(max_points=20, overlap=overlap, sigma_f=1.0, lengthscales=(1.0, 1.0, 10.0),
                                       sigma_n=0.05, hyperopt=False))
    for i in range(21):
        v = (-1.0 if i % 2 else 1.0) * (0.2 if i < 2 else rng.uniform(0.01, 0.2))
        res.update(np.array([rng.uniform(0.45, 0.55), v, rng.uniform(-0.1, 0.1)]), [-np.sign(v)])
    return res


@pytest.mark.parametrize("overlap", [0.01, 0.1])
def test_the_routing_ramp_between_disagreeing_leaves_stays_out_of_the_linearisation(overlap):
    """eq:linearization takes the experts' Jacobian Σ ω_i ∂μ_i/∂z (eq:moejac per leaf), not the
    ramp μ_i ∂ω_i/∂z of the split between them: on a still arm in the overlap of two leaves
    2 N m apart (the merged mean falls 2 N m over 0.4·overlap rad/s: ∂μ/∂q̇ ≈ −5/overlap
    N m s/rad, anti-damping) the filter runs, its covariance within its caps."""
    res = _disagreeing_experts(overlap)
    g = res.gps[0]
    z = np.array([0.5, 0.0, 0.0])
    nodes = g.route(z, True)
    assert len(nodes) == 2 and g.predict_with_grad(z)[2][1] < -4.0 / overlap      # the merged mean's ramp
    cfg = load_config(SETTINGS)
    est = GPAKF(cfg, residual=res, learning=False)
    q = np.array([0.5])
    est.reset(q, q, np.zeros(1))
    for _ in range(100):
        e = est.update(q, q, np.zeros(1))
    experts = np.zeros(3)
    g.predict_grad_into(est.residual.box.clip(est.z), experts, False, False)
    assert np.allclose(est.residual.jac[0], experts, rtol=0, atol=1e-12)
    assert abs(experts[1]) < 1.0
    assert np.all(np.isfinite(est.P)) and np.all(np.diag(est.P) <= est.P_max) and np.isfinite(e.tau_h_act_hat).all()
