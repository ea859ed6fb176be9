"""Theorem-1 bound component of the AKF / GP-AKF (sea_daemon.core.bounds.akf_bound)."""
import numpy as np
import pytest

from sea_daemon.core import learning
from sea_daemon.core.bounds.akf_bound import AKFTheoremBound
from sea_daemon.core.bounds.friction_range import FrictionRange
from sea_daemon.core.bounds.gp_bound import BoundConstants
from sea_daemon.core.bounds.ellipsoid import chi2_quantile
from sea_daemon.core.config import ModelConfig
from sea_daemon.io.configfile import default_config_path, load_config


def _from_first_sample(cfg):
    """``cfg`` with the filter started at the first sample (Alg. 1 as written): the bound is
    propagated from there, not after the differentiator's window."""
    import dataclasses
    return dataclasses.replace(cfg, estimator=dataclasses.replace(cfg.estimator, init_after_kinematics=False))
from sea_daemon.core.estimators import AKF
from sea_daemon.core.model import SEAModel

from synth import simulate


def with_bound(akf, **kwargs) -> AKFTheoremBound:
    """Give ``akf`` the bound component AKFTheoremBound(akf, **kwargs); returns it."""
    akf.bound = AKFTheoremBound(akf, **kwargs)
    return akf.bound


def run(est, log):
    est.reset(log.q[0], log.theta_m[0], log.tau_m[0])
    out = np.zeros((len(log), 3))
    for k in range(1, len(log)):
        e = est.update(log.q[k], log.theta_m[k], log.tau_m[k], log.t[k] - log.t[k - 1])
        out[k] = e.tau_h_act_hat[0], e.tau_h_act_bound[0], e.P[4, 4]
    return out


@pytest.mark.parametrize("sets", ["zonotope", "ellipsoid"])
def test_linear_plant_bound_equals_kf_chi2_projection(sets):
    cfg = ModelConfig.from_dict({"joints": 1, "rate_hz": 100, "model": {
        "M": 0.12, "J": 0.08, "D_m": 0.6, "K_s": 110.0, "D_s": 0.25, "gravity": 0.0}})
    log = simulate(SEAModel.from_config(cfg), T=0.6, tau_h=lambda t: np.array([np.sin(3 * t)]), seed=1)
    akf = AKF(cfg)
    tb = with_bound(akf, projection="state", sets=sets)
    out = run(akf, log)
    plain = run(AKF(cfg), log)
    assert np.max(np.abs(tb.sm.X_)) == 0.0                     # set of means stays a point
    np.testing.assert_allclose(out[1:, 1], np.sqrt(chi2_quantile(1 - cfg.estimator.delta, 5) * out[1:, 2]),
                               rtol=1e-10)
    np.testing.assert_allclose(out[:, :2], plain[:, :2], rtol=1e-10)   # estimate and bound unchanged
    # default: the τ marginal's χ²_1 quantile (scalar claim eq:bounds)
    akf = AKF(cfg)
    with_bound(akf, sets=sets)
    out = run(akf, log)
    np.testing.assert_allclose(out[1:, 1], np.sqrt(chi2_quantile(1 - cfg.estimator.delta, 1) * out[1:, 2]),
                               rtol=1e-10)


def test_gravity_nonlinearity_widens_bound_and_it_covers():
    cfg = _from_first_sample(load_config(default_config_path()))
    log = simulate(SEAModel.from_config(cfg), T=1.5, tau_h=lambda t: np.array([2.0 * np.sin(2 * np.pi * 0.3 * t)]),
                   seed=3)
    akf = AKF(cfg)
    tb = with_bound(akf)
    out = run(akf, log)
    plain = run(AKF(cfg), log)
    np.testing.assert_allclose(out[:, 0], plain[:, 0])           # the estimate is untouched
    # the set of means only adds to the KF part √(χ²_1 P_ττ) (plain AKF publishes √(χ²_5 P_ττ))
    d = cfg.estimator.delta
    kf1 = plain[1:, 1] * np.sqrt(chi2_quantile(1 - d, 1) / chi2_quantile(1 - d, 5))
    assert np.all(out[1:, 1] >= kf1 - 1e-12) and np.any(out[1:, 1] > kf1 + 1e-6)
    assert tb.lin_err_[3] > 0 and tb.sm.X_[4, 4] > 0             # gravity: θ̈_s row is non-linear
    err = np.abs(out[20:, 0] - log.tau_h_act[20:, 0])
    assert np.mean(err <= out[20:, 1]) >= 1 - cfg.estimator.delta


class BiasedResidual:
    """μ(z) = f(z) + e with a bounded error |e| ≤ 0.3 the bound must absorb; σ = 0.1."""

    def __init__(self, f, bias):
        self.f, self.bias = f, bias

    def predict(self, z):
        mu = np.array([self.f(z) + self.bias])
        h = 1e-6
        jac = np.array([[(self.f(z + h * e) - self.f(z - h * e)) / (2 * h) for e in np.eye(3)]])
        return mu, jac, np.array([0.01])


def test_gp_akf_bound_absorbs_a_bounded_gp_error():
    cfg = _from_first_sample(load_config(default_config_path()))
    f = lambda z: 0.8 * np.tanh(3.0 * z[1]) + 0.5 * z[0]

    class Plant(SEAModel):
        def f_nom(self, x, u, f_res=None):
            return super().f_nom(x, u, f_res=np.array([f(np.array([x[0] + x[1], x[2] + x[3], 0.0]))]))

    log = simulate(Plant(cfg.model), T=1.5, tau_h=lambda t: np.array([np.sin(2 * np.pi * 0.5 * t)]), seed=2)
    consts = [BoundConstants(sqrt_beta=3.0, gamma=0.0, tau=0.0, L_f=0.0, L_mu=0.0, omega_sigma=0.0,
                             delta=0.025, n_leaves=1)]               # η = 3·0.1 = 0.3 ≥ |e|
    outs = {}
    for bias in (0.3, -0.3):
        akf = AKF(cfg, residual=BiasedResidual(f, bias))
        tb = with_bound(akf, gp_constants=consts)
        out = run(akf, log)
        assert tb.eta_[0] == pytest.approx(0.3)
        err = np.abs(out[20:, 0] - log.tau_h_act[20:, 0])
        assert np.mean(err <= out[20:, 1]) >= 1 - cfg.estimator.delta
        outs[bias] = out
    # the GP error term widens the bound beyond the AKF's Gaussian part
    assert np.mean(outs[0.3][20:, 1]) > np.mean(np.sqrt(chi2_quantile(1 - cfg.estimator.delta / 2, 5)
                                                        * outs[0.3][20:, 2]))
    with pytest.raises(ValueError, match="gp_constants"):
        with_bound(AKF(cfg, residual=BiasedResidual(f, 0.0)))


def test_phi_shortcut_matches_expm():
    from sea_daemon.core.linalg import discretize
    cfg = _from_first_sample(load_config(default_config_path()))
    akf = AKF(cfg)
    tb = with_bound(akf)
    akf.reset(np.array([0.3]), np.array([0.29]), np.array([0.1]))
    akf.update(np.array([0.31]), np.array([0.295]), np.array([0.1]))
    b = np.array([0, 0, 0, 1.0, 0])
    full = discretize(akf.A_k, np.eye(5), akf.dt)[1]
    np.testing.assert_allclose(tb._phi(akf.A_k, b, akf.dt, akf.Gamma_mu)[:, 3], full[:, 3], rtol=1e-9, atol=1e-14)
    np.testing.assert_allclose(tb._phi(akf.A_k, np.ones(5), akf.dt, akf.Gamma_mu), full)


def _residual(learning, cfg, noise: float = 0.0):
    """A 1-joint ResidualGP trained on 120 random z with f = 0.3 tanh(2 q̇) + 0.1 q (+ noise)."""
    res = learning.ResidualGP(1, cfg.learning, hyperopt=False)
    rng = np.random.default_rng(0)
    for _ in range(120):
        z = rng.uniform([-0.2, -1.0, -5.0], [0.8, 1.0, 5.0])
        f = 0.3 * np.tanh(2 * z[1]) + 0.1 * z[0]
        res.update(z, np.array([f + noise * rng.standard_normal() if noise else f]))
    return res


def test_make_estimator_gp_akf_with_residual_gp_gets_auto_constants():
    from sea_daemon.core.estimators import make_estimator
    cfg = _from_first_sample(load_config(default_config_path()))
    res = _residual(learning, cfg)
    est = make_estimator("akf", cfg, residual=res)
    tb = est.bound
    log = simulate(SEAModel.from_config(cfg), T=0.3, seed=4)
    out = run(est, log)
    assert tb.gp_constants is not None and len(tb.gp_constants) == 1
    # the union over the leaves of the frozen residual (calibration.union_leaves)
    assert tb.gp_constants[0].n_leaves == res.gps[0].n_leaves < cfg.learning.max_leaves
    assert np.all(tb.eta_ > 0) and np.all(np.isfinite(out[1:, 1]))
    # ρ ≥ the Gaussian part alone, at the GP-AKF's δ_N = δ/2
    s = chi2_quantile(1 - cfg.estimator.delta / 2, 5)
    assert np.all(out[1:, 1] >= np.sqrt(s * out[1:, 2]) - 1e-12)


def test_gp_akf_estimator_gets_the_theorem_bound():
    from sea_daemon.core.bounds.calibration import residual_gps
    from sea_daemon.core.estimators import make_estimator
    cfg = _from_first_sample(load_config(default_config_path()))
    train = simulate(SEAModel.from_config(cfg), T=1.5, seed=6)
    est = make_estimator("gp-akf", cfg, train=train)
    tb = est.bound
    assert isinstance(tb, AKFTheoremBound) and residual_gps(est) is not None
    log = simulate(SEAModel.from_config(cfg), T=0.3, seed=7)
    out = run(est, log)
    assert np.all(tb.eta_ > 0) and np.all(np.isfinite(out[1:, 1]))
    assert est.bound is tb and not est.learning


def test_configured_gp_beta_uses_the_local_scale_and_scales_the_gp_term():
    import dataclasses
    from sea_daemon.core.bounds.gp_bound import LocalScale
    from sea_daemon.core.estimators import make_estimator
    base = _from_first_sample(load_config(default_config_path()))
    res = _residual(learning, base, noise=0.02)
    log = simulate(SEAModel.from_config(base), T=0.3, seed=4)
    means = {}
    for beta in (2.0, 4.0):
        cfg = dataclasses.replace(base, estimator=dataclasses.replace(base.estimator, gp_beta=beta))
        est = make_estimator("akf", cfg, residual=res)
        tb = est.bound
        h = []
        est.reset(log.q[0], log.theta_m[0], log.tau_m[0])
        for k in range(1, len(log) - 1):
            e = est.update(log.q[k], log.theta_m[k], log.tau_m[k], log.dt)
            h.append(tb.sm.means_half_widths()[4])
            # ρ ≥ the set of means' half-width plus the one-sided Gaussian quantile
            assert e.tau_h_act_bound[0] >= h[-1] + 1.64 * np.sqrt(e.P[4, 4])
        c = tb.gp_constants[0]
        assert c.method == "fixed" and c.scale == "local" and c.sqrt_beta == beta and c.gamma == 0.0
        # η = β · max s over the projected set ≥ β · s(ẑ) ≥ β · σ(ẑ), ẑ where the step evaluated the GP
        zhat = est.z.copy()
        est.update(log.q[-1], log.theta_m[-1], log.tau_m[-1], log.dt)
        mu, var, s0 = LocalScale(res.gps[0]).predict(zhat)
        assert tb.eta_[0] >= beta * s0 * (1 - 1e-9) and s0 >= np.sqrt(var)
        means[beta] = np.array(h)
    # the GP term dominates the set of means and is linear in β for a given confidence set; the
    # set grows with β and the points then reach further (feedback), so slightly above 2 is possible
    ratio = np.mean(means[4.0]) / np.mean(means[2.0])
    assert 1.7 < ratio < 2.3
    with pytest.raises(ValueError, match="gp_beta"):
        with_bound(AKF(base, residual=res), gp_constants="auto", gp_beta=-1.0)


class SplitResidual:
    """μ(z) = c·min(q̇, 0)² (curved only for q̇ < 0), σ(z) = σ0 + k·max(q̇, 0) (uncertain only for
    q̇ > 0): over a confidence set around q̇ ≈ 0 the GP mean's linearisation error peaks at the
    negative velocity end, the GP error at the positive one."""

    c, s0, k = 30.0, 0.01, 25.0

    def predict(self, z):
        v = z[1]
        mu = np.array([self.c * min(v, 0.0) ** 2])
        jac = np.array([[0.0, 2.0 * self.c * min(v, 0.0), 0.0]])
        return mu, jac, np.array([(self.s0 + self.k * max(v, 0.0)) ** 2])


def test_gp_error_and_gp_linearisation_error_are_bounded_as_one_torque_error():
    """f − μ̄ = (f − μ)(z) + (μ − μ̄)(z) at the same z, both entering through Γ_μ: η is the max over
    the points of the sum, not the sum of the two maxima (which sit at opposite ends here)."""
    from sea_daemon.core.bounds.setmember import ellipsoid_points
    cfg = _from_first_sample(ModelConfig.from_dict({"joints": 1, "rate_hz": 100, "model": {
        "M": 0.12, "J": 0.08, "D_m": 0.6, "K_s": 110.0, "D_s": 0.25, "gravity": 0.0}}))
    log = simulate(SEAModel.from_config(cfg), T=0.1, seed=5)
    res = SplitResidual()
    akf = AKF(cfg, residual=res)
    beta = 2.0
    consts = [BoundConstants(sqrt_beta=beta, gamma=0.0, tau=0.0, L_f=0.0, L_mu=0.0, omega_sigma=0.0,
                             delta=0.025, n_leaves=1)]
    tb = with_bound(akf, gp_constants=consts)
    akf.reset(log.q[0], log.theta_m[0], log.tau_m[0])
    x0, P0, zhat = akf.x.copy(), akf.P.copy(), akf.z.copy()
    # the points of the projected confidence set C_0 (X̂_0 = 0) on which the bound samples
    pts = ellipsoid_points(tb.sm.confidence_set(x0, P0, T=tb._T, s=tb._s_z), tb._Uz)
    mu0, J0, _ = res.predict(zhat)
    E, S = [], []
    for p in pts:
        z = zhat.copy()
        z[:2] = p
        m, _, v = res.predict(z)
        E.append(abs(m[0] - mu0[0] - J0[0, :2] @ (p - zhat[:2])))
        S.append(np.sqrt(v[0]))
    E, S = np.array(E), np.array(S)
    eta = np.max(beta * S + (1 + tb.sm.margin) * E)
    separate = beta * S.max() + (1 + tb.sm.margin) * E.max()
    assert eta < 0.8 * separate                    # the test has teeth: the maxima are apart
    akf.update(log.q[1], log.theta_m[1], log.tau_m[1], log.dt)
    # X̂_1 = (I − K H) Γ_μ box(η) (no gravity: the nominal model is linear): its τ half-width
    IKH = np.eye(5) - akf.K_k @ akf.H
    expected = abs((IKH @ akf.Gamma_mu)[4, 0]) * eta
    assert tb.sm.means_half_widths()[4] == pytest.approx(expected, rel=1e-9)
    assert np.all(tb.lin_err_ == 0.0)
    assert tb.eta_[0] == pytest.approx(beta * S.max(), rel=1e-12)
    assert tb.gp_lin_err_[0] == pytest.approx((1 + tb.sm.margin) * E.max(), rel=1e-12)


def test_gravity_linearisation_error_is_bounded_over_the_chi2_n_set_of_q():
    """Without declared effects the linearisation error depends on x only through q (plain AKF) or
    (q, q̇) (GP-AKF), so the set it is bounded over is the χ²_n (χ²_2n) confidence set of those
    coordinates — not the χ²_5n set of the whole state (Theorem 1 only needs x ∈ that set)."""
    cfg = _from_first_sample(load_config(default_config_path()))
    log = simulate(SEAModel.from_config(cfg), T=0.1, seed=3)
    akf = AKF(cfg)
    tb = with_bound(akf)
    d = cfg.estimator.delta
    akf.reset(log.q[0], log.theta_m[0], log.tau_m[0])
    x0, P0 = akf.x.copy(), akf.P.copy()
    akf.update(log.q[1], log.theta_m[1], log.tau_m[1], log.dt)
    # X̂_0 = 0: |q − q̂| ≤ r = √(χ²_1(1 − δ) eᵀ P_0 e), e = e_θm + e_θs; the exact max of the gravity
    # term's linearisation error over it, on a fine grid
    e = np.array([1.0, 1.0, 0, 0, 0])
    r = np.sqrt(chi2_quantile(1 - d, 1) * e @ P0 @ e)
    qh = x0[0] + x0[1]
    D = np.linspace(-r, r, 20001)
    h = np.max(np.abs(np.sin(qh + D) - np.sin(qh) - np.cos(qh) * D))
    scale = abs(SEAModel.from_config(cfg).Minv[0, 0]) * abs(cfg.model.gravity[0])
    assert h > 0
    # the bound's grid (65 points) adds at most its documented gap term min(2, r)·r/64
    assert scale * h <= tb.lin_err_[3] <= scale * (h + min(2.0, r) * r / 64)
    assert tb._s_z == pytest.approx(chi2_quantile(1 - d, 1))
    # with a GP the set is that of (q, q̇): χ²_2
    consts = [BoundConstants(sqrt_beta=2.0, gamma=0.0, tau=0.0, L_f=0.0, L_mu=0.0, omega_sigma=0.0,
                             delta=0.025, n_leaves=1)]
    tb2 = with_bound(AKF(cfg, residual=SplitResidual()), gp_constants=consts)
    assert tb2._s_z == pytest.approx(chi2_quantile(1 - (d - tb2.sm.delta_gp), 2))


def test_held_input_matches_scipy_expm():
    # Γ_τ = ∫₀^dt e^{As} ds E_τ by the compiled zoh against scipy's expm of Van Loan's block matrix
    from scipy.linalg import expm
    from sea_daemon.core.linalg import zoh
    cfg = _from_first_sample(load_config(default_config_path()))
    akf = AKF(cfg)
    akf.reset(np.array([0.3]), np.array([0.29]), np.array([0.1]))
    akf.update(np.array([0.31]), np.array([0.295]), np.array([0.1]))
    E = np.zeros((5, 1))
    E[4, 0] = 1.0
    aug, Ez = np.empty((6, 6)), np.empty((6, 6))
    zoh(akf.A_k, E, akf.dt, aug, Ez)
    G = Ez[:5, 5:]
    ref = expm(np.block([[akf.A_k, E], [np.zeros((1, 6))]]) * akf.dt)[:5, 5:]
    np.testing.assert_allclose(G, ref, rtol=1e-12, atol=1e-15)
    assert G[4, 0] == pytest.approx(akf.dt, rel=1e-15)          # τ rows: exactly dt


def test_declared_human_torque_rate_bounds_the_filters_lag_on_a_ramp():
    # a linear plant and a human torque ramping at 2 N m/s: the KF's random walk lags behind and
    # its own χ² bound misses most steps; with the declared rate r = 2 N m/s the set of means
    # holds the lag (the ramp is one of the inputs |τ̇| ≤ r) and ρ covers every step
    import dataclasses
    cfg = ModelConfig.from_dict({"joints": 1, "rate_hz": 100, "model": {
        "M": 0.12, "J": 0.08, "D_m": 0.6, "K_s": 110.0, "D_s": 0.25, "gravity": 0.0},
        "estimator": {"R": [1e-7, 1e-7, 1e-3, 1e-3], "Sigma_nom": [1e-10, 1e-10, 1e-6, 1e-6, 1e-5], "P0_tau": 1e-4,
                      "init_after_kinematics": False}})
    log = simulate(SEAModel.from_config(cfg), T=2.0, tau_h=lambda t: np.array([2.0 * t]), seed=2)
    out0 = run(AKF(cfg), log)
    err = np.abs(out0[:, 0] - log.tau_h_act[:, 0])
    akf = AKF(cfg)
    with_bound(akf, tau_h_act_rate=0.0)
    plain = run(akf, log)
    assert np.mean(err[1:] <= plain[1:, 1]) < 0.1                 # the random walk alone misses
    rated = dataclasses.replace(cfg, estimator=dataclasses.replace(cfg.estimator, tau_h_act_rate=2.0))
    akf = AKF(rated)
    tb = with_bound(akf)                                # from estimator.tau_h_act_rate
    assert tb.tau_h_act_rate == 2.0
    out = run(akf, log)
    np.testing.assert_allclose(out[:, 0], out0[:, 0])             # the estimate is untouched
    assert np.all(err[1:] <= out[1:, 1])
    # the τ half-width of the set of means is the worst lag of a ramp at r: r·Σ|c_j|, which
    # the steady lag of this ramp reaches from below
    h = tb.sm.means_half_widths()[4]
    assert err[-1] <= h <= 3 * err[-1]
    with pytest.raises(ValueError, match="tau_h_act_rate"):
        with_bound(AKF(cfg), tau_h_act_rate=-1.0)


def _passive_gp_akf(seed):
    from sea_daemon.core.estimators import make_estimator
    from _paths import repo_root
    cfg = load_config(repo_root() / "configs" / "exo_1dof_sim.yaml")
    train = simulate(SEAModel.from_config(cfg), T=1.5, seed=6)
    return (make_estimator("gp-akf", cfg, train=train, bound=False),
            simulate(SEAModel.from_config(cfg), T=0.6, seed=seed))


def test_torque_calibrated_beta_is_the_smallest_covering_beta_and_detaches():
    from sea_daemon.core.bounds.torque_beta import torque_calibrated_beta, torque_coverage
    est, cal = _passive_gp_akf(seed=8)
    # a truth the estimate misses by a ramp: only a GP term of some size covers it
    truth = np.linspace(0.0, 0.3, len(cal))[:, None]
    seen = []
    r = torque_calibrated_beta(est, cal, 0.05, truth=truth, progress=lambda b, c: seen.append((b, c)))
    assert seen == r["runs"] and len(r["runs"]) <= 10
    m = len(cal) - 1
    assert r["steps"] == m and r["target"] == pytest.approx(np.ceil((m + 1) * 0.95) / m)
    assert r["coverage"] >= r["target"]
    # a third of an octave less no longer covers (the search's resolution is 3 %)
    below = [c for b, c in r["runs"] if b < r["beta"]]
    assert below and max(below) < r["target"]
    c_less, _ = torque_coverage(est, cal, r["beta"] / 1.26, truth)
    assert c_less < r["target"]
    # the estimator is left as it was: no bound component, learning flag restored
    assert est.bound is None
    assert est.learning is False
    # with the true τ_h,act = 0 less β is needed
    assert torque_calibrated_beta(est, cal, 0.05)["beta"] < r["beta"]
    with pytest.raises(ValueError, match="delta"):
        torque_calibrated_beta(est, cal, 1.5)


def test_the_extrapolation_term_is_added_to_eta_unscaled_by_beta():
    # η = max over the GP-input set of β s + c e (+ the GP mean's linearisation error) ≥ its
    # value at ẑ; with β tiny what is left is c e, which does not shrink with β
    import dataclasses
    from sea_daemon.core.bounds.gp_bound import LocalScale
    from sea_daemon.core.estimators import make_estimator
    base = _from_first_sample(load_config(default_config_path()))
    base = dataclasses.replace(base, learning=dataclasses.replace(base.learning, extrapolation_scale=1.0))
    res = _residual(learning, base, noise=0.02)
    assert res.gps[0].extrapolation_scale == 1.0
    log = simulate(SEAModel.from_config(base), T=0.3, seed=4)
    etas = {}
    for beta in (1e-4, 1.0):
        cfg = dataclasses.replace(base, estimator=dataclasses.replace(base.estimator, gp_beta=beta))
        est = make_estimator("akf", cfg, residual=res)
        tb = est.bound
        est.reset(log.q[0], log.theta_m[0], log.tau_m[0])
        for k in range(1, len(log) - 1):
            est.update(log.q[k], log.theta_m[k], log.tau_m[k], log.dt)
        zhat = est.z.copy()
        est.update(log.q[-1], log.theta_m[-1], log.tau_m[-1], log.dt)
        _, _, s0, x0 = LocalScale(res.gps[0]).predict_many_ext(zhat[None])
        assert x0[0] > 0
        assert tb.eta_[0] >= beta * s0[0] + x0[0] - 1e-12
        etas[beta] = tb.eta_[0]
    assert etas[1e-4] >= x0[0] - 1e-12 and etas[1.0] > etas[1e-4]


@pytest.mark.parametrize("case", ["akf", "akf+model_error", "akf+model_error+rate", "lederer", "local", "local+rate",
                                  "gp-friction"])
def test_compiled_step_gives_the_python_steps_rho(case):
    """bound_core.bound_step (the daemon's compiled step) against the Python step it replaces:
    the same ρ_k, GP error, linearisation error, box violations and choices of the range form,
    to rounding.  ``gp-friction``: the plant has a Coulomb friction the model lacks and moves and
    stops, so the GP learns a steep residual and the range form is taken at some steps."""
    import dataclasses
    from sea_daemon.core.effects import make_effect
    from sea_daemon.core.estimators import make_estimator
    from _paths import repo_root
    cfg = load_config(repo_root() / "configs" / "exo_1dof_sim.yaml")
    if case.startswith("local"):
        cfg = dataclasses.replace(cfg, estimator=dataclasses.replace(
            cfg.estimator, gp_beta=1.5, tau_h_act_rate=4.0 if case == "local+rate" else 0.0))
    if case.startswith("akf+"):         # a plain AKF's declared model error (and rate): [Γ_μ e | Γ_τ r]
        cfg = dataclasses.replace(cfg, estimator=dataclasses.replace(
            cfg.estimator, model_error=0.3, tau_h_act_rate=4.0 if case.endswith("rate") else 0.0))
    if case == "gp-friction":
        true = dataclasses.replace(cfg, model=dataclasses.replace(cfg.model, effects=tuple(cfg.model.effects) + (
            make_effect("coulomb", "load", F_c=0.5, eps=0.003),)))
        tm = lambda t: np.array([np.sin(2 * np.pi * 0.5 * t) if (t % 2.0) < 1.0 else 0.4])
        train = simulate(SEAModel.from_config(true), T=2.0, seed=6, tau_m=tm)
        log = simulate(SEAModel.from_config(true), T=1.0, seed=8, tau_m=tm,
                       tau_h=lambda t: np.array([0.3 * np.sin(4 * t)]))
    else:
        train = simulate(SEAModel.from_config(cfg), T=1.5, seed=6)
        log = simulate(SEAModel.from_config(cfg), T=0.6, seed=8, tau_h=lambda t: np.array([0.5 * np.sin(4 * t)]))
    outs, bounds = [], []
    for compiled in (False, True):
        if case.startswith("akf"):
            est = make_estimator("akf", cfg)
        else:
            est = make_estimator("gp-akf", cfg, train=train)
        est.bound.compiled = compiled
        outs.append(run(est, log))
        bounds.append(est.bound)
    assert bounds[1]._compiled_pack() is not None and bounds[0]._compiled_pack() is None
    np.testing.assert_allclose(outs[1], outs[0], rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(bounds[1].eta_, bounds[0].eta_, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(bounds[1].lin_err_, bounds[0].lin_err_, rtol=1e-12, atol=1e-14)
    assert bounds[1].gp_box_violations_ == bounds[0].gp_box_violations_
    assert bounds[1].range_steps_ == bounds[0].range_steps_
    if case == "gp-friction":
        assert bounds[0].range_steps_ > 0
        assert np.mean(np.abs(outs[0][1:, 0] - log.tau_h_act[1:, 0]) <= outs[0][1:, 1]) >= 0.95
    np.testing.assert_allclose(bounds[1].sm.G_, bounds[0].sm.G_, rtol=1e-10, atol=1e-14)
    if case.startswith("akf+"):
        assert bounds[0].model_error_term and outs[0][-1, 1] > 0.2   # the term is in ρ_k (e = 0.3 N m)


def test_compiled_step_is_skipped_while_the_gp_learns():
    from sea_daemon.core.estimators import make_estimator
    cfg = _from_first_sample(load_config(default_config_path()))
    est = make_estimator("gp-akf", cfg)
    assert est.learning and est.bound._compiled_pack() is None


def _friction_cfg(side: str = "load"):
    """A 100 Hz model with declared Coulomb + Stribeck friction on ``side`` (and gravity), the
    estimator's sign smoothing 0.005 rad/s."""
    return _from_first_sample(ModelConfig.from_dict({"joints": 1, "rate_hz": 100, "model": {
        "M": 0.12, "J": 0.08, "D_m": 0.6, "K_s": 110.0, "D_s": 0.25, "gravity": 1.5, "effects": [
            {"type": "coulomb", "side": side, "F_c": 0.4},
            {"type": "stribeck", "side": side, "F_s": 0.3, "v_s": 0.05}]},
        "estimator": {"sign_eps": 0.005}}))


def test_friction_range_contains_the_friction_torque_over_the_interval():
    """FrictionRange.range is interval arithmetic: every value of τ_g on [lo, hi] (dense samples) lies
    in [L, U] — for a Stribeck term of either sign, and for one with its own ε — and the interval
    is not vacuous: on average within 0.1 N m of the sampled range (F_c + |F_s| = 0.7 N m)."""
    from sea_daemon.core.effects import COULOMB, STRIBECK, evaluate
    rng = np.random.default_rng(3)
    for F_s, eps_s in ((-0.3, 0.005), (0.3, 0.005), (0.3, 0.02)):
        effs = [(COULOMB, np.array([0.4, 0.005, 0.0])), (STRIBECK, np.array([F_s, 0.05, eps_s]))]
        excess = []
        for _ in range(200):
            c, r = rng.normal(0.0, 0.05), abs(rng.normal(0.0, 0.03))
            lo, hi = c - r, c + r
            L, U = FrictionRange.range(effs, lo, hi)
            v = np.linspace(lo, hi, 4001)
            tau = np.array([sum(evaluate(code, p, 0.0, vv, 0.0)[0] for code, p in effs) for vv in v])
            assert L <= tau.min() + 1e-12 and tau.max() <= U + 1e-12
            excess.append((U - L) - (tau.max() - tau.min()))
        assert np.mean(excess) < 0.1


@pytest.mark.parametrize("side", ["load", "motor"])
def test_friction_range_step_is_the_filter_step_rewritten(side):
    """The identity behind the range candidate: for x = x̂ + a + g,
    F a + Φ ε(x) = F_B a + Φ ε_smooth(x) + Σ Φc [τ_g(v) − τ_g(v̂) − κ_g ℓᵀa − s_g ℓᵀg] (ε the filter's
    linearisation error, ε_smooth the model's without friction), and the bracket lies in ±w_g
    for a in the set of means and g on the χ² set of P."""
    from sea_daemon.core.linalg import discretize
    cfg = _friction_cfg(side)
    model = SEAModel.from_config(cfg)
    log = simulate(model, T=1.0, seed=2)
    akf = AKF(cfg)
    tb = with_bound(akf)
    assert len(tb.friction.groups) == 1
    akf.reset(log.q[0], log.theta_m[0], log.tau_m[0])
    for k in range(1, 40):
        akf.update(log.q[k], log.theta_m[k], log.tau_m[k], log.t[k] - log.t[k - 1])
    x0, P0, u, dt = akf.record.x_prev.copy(), akf.record.P_prev.copy(), np.asarray(log.tau_m[39], float), 0.01
    side_, ell, c, effs = tb.friction.groups[0]
    x0[2:4] = 0.0                        # the friction's velocity at 0, where its slope is steepest
    # the filter's step from there: A_k, F_k = e^{A dt}, Γ_μ = Φ I_μ M⁻¹
    akf.A_k[:] = model.F_nom(x0, u)
    F, Phi = discretize(akf.A_k, np.eye(5), dt)
    akf.F_k[:] = F
    akf.Gamma_mu[:] = Phi @ model.I_mu @ model.Minv
    C = tb.sm.confidence_set(x0, P0)
    pts = tb.sm.sample_points(C)
    dF, GamF, w, b_s, _, b = tb.friction.candidate(x0, u, P0, pts, akf.A_k.copy(), dt, akf.A_k, akf.Gamma_mu,
                                                  tb.sm, tb._phi)
    # the one-pass boxes are the filter-slope box and the box of the model without friction
    np.testing.assert_allclose(b, (1 + tb.sm.margin) * akf.tables.lin_error_box(pts, u, x0, akf.A_k), rtol=1e-12)
    FB = akf.F_k + dF
    from sea_daemon.core.effects import evaluate
    tau_g = lambda v: sum(evaluate(code, p, 0.0, v, 0.0)[0] for code, p in effs)
    s_g = sum(evaluate(code, p, 0.0, float(ell @ x0), 0.0)[2] for code, p in effs)
    smooth = lambda x: model.f_nom(x, u) - c * tau_g(float(ell @ x))
    A_s = akf.A_k - s_g * np.outer(c, ell)
    rng = np.random.default_rng(0)
    L = np.linalg.cholesky(P0 + 1e-30 * np.eye(5))
    s = tb.sm.s_state
    G = tb.sm.G_
    g_ext = P0 @ ell * np.sqrt(s / float(ell @ P0 @ ell))     # the point of E(0, sP) with the largest ℓᵀg
    worst = 0.0
    for i in range(100):
        a = G @ rng.uniform(-1, 1, G.shape[1]) if G.shape[1] else np.zeros(5)
        if i % 2:
            z = rng.normal(size=5)
            g = L @ (z / np.linalg.norm(z) * np.sqrt(s) * rng.uniform(0, 1))
        else:
            g = g_ext * rng.uniform(-1, 1)
        x = x0 + a + g
        eps = model.f_nom(x, u) - model.f_nom(x0, u) - akf.A_k @ (x - x0)
        lhs = akf.F_k @ a + Phi @ eps
        kap = tb.friction.kappa_[0]         # the slope the range form kept in F_B
        bracket = tau_g(float(ell @ x)) - tau_g(float(ell @ x0)) - kap * float(ell @ a) - s_g * float(ell @ g)
        eps_s = smooth(x) - smooth(x0) - A_s @ (x - x0)
        rhs = FB @ a + Phi @ eps_s + GamF[:, 0] * bracket
        assert np.allclose(lhs, rhs, rtol=1e-9, atol=1e-12 * (1 + np.abs(lhs).max()))
        assert abs(bracket) <= w[0] * (1 + 1e-12)
        worst = max(worst, abs(bracket))
    eps_pts = np.array([smooth(x) - smooth(x0) - A_s @ (x - x0) for x in pts])
    np.testing.assert_allclose(b_s, (1 + tb.sm.margin) * np.abs(eps_pts).max(axis=0), rtol=1e-9, atol=1e-12)
    assert worst > 0.5 * w[0]            # w is reached, not a loose cap


def test_friction_range_keeps_the_bound_valid_and_finite_at_standstill():
    """A plant with the declared friction (model = truth) that moves, stops and holds still while
    the subject pushes: the range candidate is taken at the stops, ρ covers the true torque, and
    its peak is far below the filter-slope bound's (which grows with the set's q̇ extent at
    q̇ = 0, where the slope is (F_c + F_s)/ε)."""
    cfg = _friction_cfg()
    model = SEAModel.from_config(cfg)
    tau_m = lambda t: np.array([1.2 * np.sin(2 * np.pi * 0.5 * t) if t < 2.0 else 0.3])
    tau_h = lambda t: np.array([0.5 * np.sin(2 * np.pi * 0.3 * t) if t >= 2.0 else 0.0])
    log = simulate(model, T=4.0, tau_m=tau_m, tau_h=tau_h, seed=4)
    res = {}
    for use_range in (True, False):
        akf = AKF(cfg)
        tb = with_bound(akf)
        if not use_range:
            tb.friction.groups = []
        out = run(akf, log)
        e = np.abs(out[1:, 0] - log.tau_h_act[1:, 0])
        res[use_range] = (out[1:, 1], e, tb.range_steps_)
    rho, e, steps = res[True]
    assert steps > 0
    assert np.all(np.isfinite(rho))
    assert np.mean(e <= rho) >= 0.95
    assert rho.max() < 0.5 * res[False][0].max()


def test_declared_rate_replaces_the_random_walk_in_the_gaussian_part():
    # a filter tuned with a wide τ_h,act random walk (q_τ = 1e-2 per step: it tracks fast subjects)
    # and a subject within the declared rate: the set of means holds the subject's change
    # (Γ_τ box(r)), so the bound's Gaussian part is propagated without the walk — the filter's
    # gain, its measurement noise and the rest of Σ_nom, Joseph form — and ρ is far below the
    # filter's own √(χ²₁ P_ττ) while it still covers every step
    import dataclasses
    cfg = ModelConfig.from_dict({"joints": 1, "rate_hz": 100, "model": {
        "M": 0.12, "J": 0.08, "D_m": 0.6, "K_s": 110.0, "D_s": 0.25, "gravity": 0.0},
        "estimator": {"R": [1e-7, 1e-7, 1e-3, 1e-3], "Sigma_nom": [1e-10, 1e-10, 1e-6, 1e-6, 1e-2], "P0_tau": 1e-2,
                      "init_after_kinematics": False, "tau_h_act_rate": 3.2}})
    log = simulate(SEAModel.from_config(cfg), T=3.0, tau_h=lambda t: np.array([0.5 * np.sin(2 * np.pi * t)]), seed=3)
    s1 = chi2_quantile(1 - cfg.estimator.delta, 1)
    akf = AKF(cfg)
    tb = with_bound(akf)
    akf.reset(log.q[0], log.theta_m[0], log.tau_m[0])
    rho, kf, err, recs = [], [], [], []
    for k in range(1, len(log)):
        e = akf.update(log.q[k], log.theta_m[k], log.tau_m[k], log.t[k] - log.t[k - 1])
        rho.append(e.tau_h_act_bound[0])
        kf.append(np.sqrt(s1 * e.P[4, 4]))
        err.append(abs(e.tau_h_act_hat[0] - log.tau_h_act[k, 0]))
        r = akf.record
        recs.append((r.F_k.copy(), r.K_k.copy(), np.array(getattr(r, "Sigma_nom", akf.Sigma_nom)),
                     np.array(tb.gauss.P) if hasattr(tb, "gauss") else np.zeros((5, 5))))
    rho, kf, err = np.array(rho), np.array(kf), np.array(err)
    assert np.all(err <= rho)
    assert np.mean(rho[50:]) < 0.75 * np.mean(kf[50:])
    # P_g: the Joseph form with the filter's F, K, R and Σ_nom without its τ_h,act row and column
    akf.reset(log.q[0], log.theta_m[0], log.tau_m[0])
    Pg = akf.P.copy()
    for F, K, S, Pg_bound in recs:
        Q = S.copy()
        Q[4, :] = Q[:, 4] = 0.0
        IKH = np.eye(5) - K @ akf.H
        Pg = IKH @ (F @ Pg @ F.T + Q) @ IKH.T + K @ akf.R @ K.T
        np.testing.assert_allclose(Pg_bound, Pg, rtol=1e-9, atol=1e-18)
    # without a declared rate the walk is the only term for the subject's change: P_g = P
    assert tb.gauss.own
    plain = dataclasses.replace(cfg, estimator=dataclasses.replace(cfg.estimator, tau_h_act_rate=0.0))
    assert not with_bound(AKF(plain)).gauss.own


def test_friction_range_keeps_a_slope_that_damps_the_set_of_means():
    """The range form keeps a slope κ of the friction in its transition F − Φc (s − κ) ℓᵀ, chosen
    every 50 ms by the steady τ_h,act half-width it builds (FrictionRange._choose): at
    standstill the slope kept gives a contracting closed loop (I − KH) F_B when κ = 0 does not
    contract faster, and the candidate's F_B − F is the rule's (s − κ) term."""
    from sea_daemon.core.bounds.friction_range import SLOPE_RULES
    cfg = _friction_cfg()
    model = SEAModel.from_config(cfg)
    log = simulate(model, T=1.0, seed=2)
    akf = AKF(cfg)
    tb = with_bound(akf)
    akf.reset(log.q[0], log.theta_m[0], log.tau_m[0])
    for k in range(1, 40):
        akf.update(log.q[k], log.theta_m[k], log.tau_m[k], log.t[k] - log.t[k - 1])
    assert tb.friction.choose_every == 5                     # 50 ms at 100 Hz
    x0, P0, u = akf.record.x_prev.copy(), akf.record.P_prev.copy(), np.asarray(log.tau_m[39], float)
    x0[2:4] = 0.0
    C = tb.sm.confidence_set(x0, P0)
    IKH = np.eye(5) - akf.K_k @ akf.H
    fr = tb.friction
    fr.reset()
    dF, GamF, w, *_ = fr.candidate(x0, u, P0, tb.sm.sample_points(C), akf.A_k.copy(), 0.01, akf.A_k,
                                   akf.Gamma_mu, tb.sm, tb._phi, (akf.F_k, IKH))
    _, ell, _, effs = fr.groups[0]
    from sea_daemon.core.effects import evaluate
    s_g = sum(evaluate(code, p, 0.0, 0.0, 0.0)[2] for code, p in effs)
    kap = fr.kappa_[0]
    assert 0.0 <= kap <= s_g
    np.testing.assert_allclose(dF, -(s_g - kap) * np.outer(GamF[:, 0], ell), rtol=1e-12, atol=1e-15)
    radius = lambda k: max(abs(np.linalg.eigvals(IKH @ (akf.F_k - (s_g - k) * np.outer(GamF[:, 0], ell)))))
    assert radius(kap) < 1.0
    assert radius(kap) <= max(radius(0.0), radius(s_g)) + 1e-12
    assert SLOPE_RULES[fr.rule_] != 0.0 or radius(0.0) <= radius(s_g)


def test_a_configured_beta_keeps_the_filters_covariance_as_the_gaussian_part(monkeypatch):
    """The guaranteed β's bound propagates its own Gaussian part (no GP variance; with a declared
    rate no τ_h,act walk); a configured β (what calibrate-bound calibrates, replaying with the
    filter's P) keeps the filter's P, in the replays that calibrate it and in estimation alike."""
    import dataclasses
    from sea_daemon.core.bounds import torque_beta
    seen = []

    class Spy(AKFTheoremBound):
        def __init__(self, *a, **kw):
            super().__init__(*a, **kw)
            seen.append((self.gauss.own, self.gauss.drop_tau))

    monkeypatch.setattr(torque_beta, "AKFTheoremBound", Spy)
    est, cal = _passive_gp_akf(seed=8)
    est.cfg = dataclasses.replace(est.cfg, estimator=dataclasses.replace(est.cfg.estimator, tau_h_act_rate=2.0))
    torque_beta.torque_coverage(est, cal, 1.0)
    assert seen == [(False, False)]
    g = AKFTheoremBound(est, gp_constants="auto", gp_beta="lederer").gauss
    assert g.own and g.drop_tau
    assert not AKFTheoremBound(est, gp_constants="auto", gp_beta=1.5).gauss.own
