"""GP uniform error bound (eq:gpmeanbounds, Lederer et al. 2019) for the SE kernel and merged LoG-GP."""
import math

import numpy as np
import pytest

from sea_daemon.core.bounds.gp_bound import (
    C_STAR, LeafGP, covering_grid, error_bound, log_covering_number, merged_sigma, sample_lipschitz_se,
    se_lipschitz)
from sea_daemon.core.gp.exact import se_kernel
from sea_daemon.core.gp.loggp import LoGGP


def test_se_kernel_lipschitz_constant_is_tight():
    rng = np.random.default_rng(0)
    sf, ls = 1.7, np.array([0.3, 2.0, 5.0])
    Lk = se_lipschitz(sf, ls)
    x2 = np.zeros(3)
    worst = 0.0
    for _ in range(4000):
        x = rng.standard_normal(3) * ls * rng.uniform(0, 2)
        g = -se_kernel(x, x2, ls, sf)[0, 0] * (x - x2) / ls ** 2      # analytic ∇_x k
        worst = max(worst, np.linalg.norm(g))
    assert worst <= Lk + 1e-12
    # attained along the shortest length scale at distance l_min
    x = np.array([ls[0], 0.0, 0.0])
    g = -se_kernel(x, x2, ls, sf)[0, 0] * x / ls ** 2
    assert np.linalg.norm(g) == pytest.approx(Lk)


def test_derivative_kernel_constant_c_star():
    # ‖∇_x k^∂1(x, 0)‖/σ_f² for the unit SE kernel, maximised numerically
    u = np.linspace(-4, 4, 1601)
    U, R = np.meshgrid(u, np.linspace(0, 4, 801))
    g = np.exp(-(U ** 2 + R ** 2) / 2) * np.sqrt(U ** 2 * (3 - U ** 2) ** 2 + (1 - U ** 2) ** 2 * R ** 2)
    assert g.max() <= C_STAR + 1e-12
    assert g.max() == pytest.approx(C_STAR, rel=1e-4)
    # and k^∂1 really is Lipschitz with c*: finite differences in 2-D
    rng = np.random.default_rng(1)
    kd = lambda x: (1 - x[0] ** 2) * np.exp(-x @ x / 2)
    for _ in range(2000):
        a, b = rng.uniform(-3, 3, 2), rng.uniform(-3, 3, 2)
        assert abs(kd(a) - kd(b)) <= C_STAR * np.linalg.norm(a - b) + 1e-12


def test_covering_grid_covers_the_box():
    rng = np.random.default_rng(2)
    lo, hi, tau = np.array([0.0, -1.0]), np.array([1.0, 2.0]), 0.2
    grid = covering_grid(lo, hi, tau)
    assert math.log(len(grid)) == pytest.approx(log_covering_number(hi - lo, tau))
    pts = rng.uniform(lo, hi, size=(5000, 2))
    dmin = np.min(np.linalg.norm(pts[:, None, :] - grid[None], axis=2), axis=1)
    assert dmin.max() <= tau + 1e-12


def test_posterior_mean_lipschitz_constant():
    rng = np.random.default_rng(3)
    ls, sf, sn = np.array([0.5, 1.5]), 1.0, 0.1
    X = rng.uniform(-2, 2, (20, 2))
    y = np.sin(X[:, 0] * 2) + X[:, 1]
    leaf = LeafGP.from_data(X, y, sf, ls, sn)
    c = error_bound([leaf], [-2, -2], [2, 2], 0.05, L_f=[2.0, 1.0])
    mu = lambda x: (se_kernel(x, X, ls, sf) @ leaf.alpha)[0]
    for _ in range(500):
        a = rng.uniform(-2, 2, 2)
        b = a + rng.standard_normal(2) * 1e-3
        # |μ(a) − μ(b)| ≤ L_μ ‖a − b‖ in normalised coordinates
        assert abs(mu(a) - mu(b)) <= c.L_mu * np.linalg.norm((a - b) / ls) * (1 + 1e-9)


def _gp_posterior(Xg, idx, y, sf, ls, sn):
    K = se_kernel(Xg[idx], Xg[idx], ls, sf) + sn ** 2 * np.eye(len(idx))
    Ks = se_kernel(Xg, Xg[idx], ls, sf)
    alpha = np.linalg.solve(K, y)
    mu = Ks @ alpha
    var = sf ** 2 - np.sum(Ks * np.linalg.solve(K, Ks.T).T, axis=1)
    return mu, np.sqrt(np.clip(var, 0, None))


def test_bound_holds_on_gp_samples_and_naive_beta_does_not():
    """f ~ GP(0, k), noisy data; |f − μ| ≤ √β σ + γ on the whole grid, at the promised rate."""
    rng = np.random.default_rng(4)
    sf, ls, sn, delta = 1.0, np.array([0.3]), 0.05, 0.1
    Xg = np.linspace(0.0, 3.0, 240)[:, None]
    Kg = se_kernel(Xg, Xg, ls, sf) + 1e-10 * np.eye(len(Xg))
    Lc = np.linalg.cholesky(Kg)
    runs, viol, viol_naive, widths = 200, 0, 0, []
    for _ in range(runs):
        f = Lc @ rng.standard_normal(len(Xg))
        idx = np.sort(rng.choice(len(Xg), 12, replace=False))
        y = f[idx] + sn * rng.standard_normal(len(idx))
        mu, sd = _gp_posterior(Xg, idx, y, sf, ls, sn)
        leaf = LeafGP.from_data(Xg[idx], y, sf, ls, sn)
        c = error_bound([leaf], [0.0], [3.0], delta, delta_lipschitz=0.01)
        err = np.abs(f - mu)
        viol += np.any(err > c.eta(sd))
        viol_naive += np.any(err > 1.0 * sd)        # β = 1 is not a uniform bound
        widths.append(c.sqrt_beta)
    assert viol / runs <= delta
    assert viol_naive / runs > delta               # the test can detect a too-small β
    assert 2.0 < np.median(widths) < 15.0          # not absurd: √β grows only like √log(1/τ)


def test_merged_loggp_bound_and_sigma():
    """Mixture of two leaf GPs: |f − Σ w μ_i| ≤ √β σ̃ + max γ_i with σ̃ from merged_sigma."""
    rng = np.random.default_rng(5)
    sf, ls, sn, delta = 1.0, np.array([0.4]), 0.05, 0.1
    Xg = np.linspace(0.0, 4.0, 200)[:, None]
    Lc = np.linalg.cholesky(se_kernel(Xg, Xg, ls, sf) + 1e-10 * np.eye(len(Xg)))
    viol = 0
    for _ in range(100):
        f = Lc @ rng.standard_normal(len(Xg))
        left, right = np.arange(0, 120), np.arange(80, 200)   # overlapping leaf regions
        ia = np.sort(rng.choice(left, 8, replace=False))
        ib = np.sort(rng.choice(right, 8, replace=False))
        ya, yb = f[ia] + sn * rng.standard_normal(8), f[ib] + sn * rng.standard_normal(8)
        ma, sa = _gp_posterior(Xg, ia, ya, sf, ls, sn)
        mb, sb = _gp_posterior(Xg, ib, yb, sf, ls, sn)
        w = np.clip((Xg[:, 0] - 1.6) / 0.8, 0, 1)              # weight of leaf b
        mu = (1 - w) * ma + w * mb
        sig = np.array([merged_sigma([1 - wi, wi], [a, b], [p, q]) for wi, a, b, p, q in zip(w, sa, sb, ma, mb)])
        c = error_bound([LeafGP.from_data(Xg[ia], ya, sf, ls, sn), LeafGP.from_data(Xg[ib], yb, sf, ls, sn)],
                        [0.0], [4.0], delta, delta_lipschitz=0.01)
        assert c.n_leaves == 2
        viol += np.any(np.abs(f - mu) > c.eta(sig))
        # σ̃ dominates Σ w σ_i (what the proof needs), both variants
        assert np.all(sig >= (1 - w) * sa + w * sb - 1e-12)
        s2 = np.array([merged_sigma([1 - wi, wi], [a, b]) for wi, a, b in zip(w, sa, sb)])
        assert np.all(s2 >= (1 - w) * sa + w * sb - 1e-12)
    assert viol / 100 <= delta


def test_more_leaves_and_smaller_delta_widen_the_bound():
    rng = np.random.default_rng(6)
    X = rng.uniform(0, 1, (10, 2))
    leaf = LeafGP.from_data(X, np.sin(X[:, 0]), 1.0, [0.5, 0.5], 0.1)
    a = error_bound([leaf], [0, 0], [1, 1], 0.05, L_f=1.0)
    b = error_bound([leaf], [0, 0], [1, 1], 0.05, L_f=1.0, n_leaves=1000)
    c = error_bound([leaf], [0, 0], [1, 1], 0.001, L_f=1.0)
    assert b.sqrt_beta > a.sqrt_beta and c.sqrt_beta > a.sqrt_beta
    assert sample_lipschitz_se(1.0, [2.0, 2.0], 0.01) > sample_lipschitz_se(1.0, [2.0, 2.0], 0.1)
    with pytest.raises(ValueError):
        error_bound([leaf], [0, 0], [1, 1], 0.05)          # no L_f and no δ_L


def test_leaves_with_different_hyperparameters_use_the_maxima():
    rng = np.random.default_rng(7)
    X = rng.uniform(0, 1, (10, 2))
    a = LeafGP.from_data(X, np.sin(X[:, 0]), 1.0, [0.5, 0.5], 0.1)
    b = LeafGP.from_data(X, np.cos(X[:, 1]), 2.0, [0.2, 0.9], 0.05)
    both = error_bound([a, b], [0, 0], [1, 1], 0.05, L_f=1.0)
    for one in (a, b):
        c = error_bound([one], [0, 0], [1, 1], 0.05, L_f=1.0, n_leaves=2, tau_grid=[both.tau])
        assert c.sqrt_beta <= both.sqrt_beta + 1e-12 and c.gamma <= both.gamma + 1e-12


def test_loggp_leaves_and_merged_bound_on_a_real_loggp():
    rng = np.random.default_rng(8)
    gp = LoGGP(input_dim=1, max_points=15, lengthscales=[0.3], sigma_f=1.0, sigma_n=0.05, seed=0)
    Xg = np.linspace(0.0, 3.0, 150)[:, None]
    Lc = np.linalg.cholesky(se_kernel(Xg, Xg, np.array([0.3]), 1.0) + 1e-10 * np.eye(len(Xg)))
    f = Lc @ rng.standard_normal(len(Xg))
    for i in rng.choice(len(Xg), 60, replace=True):
        gp.update(Xg[i], float(f[i] + 0.05 * rng.standard_normal()))
    from sea_daemon.core.bounds.gp_bound import loggp_leaves
    leaves = loggp_leaves(gp)
    assert len(leaves) == len(gp.leaves()) > 1 and sum(lf.N for lf in leaves) == 60
    c = error_bound(leaves, [0.0], [3.0], 0.05, delta_lipschitz=0.005, n_leaves=50)
    pred = np.array([gp.predict(x) for x in Xg])
    # the merged prediction with its (mixture) σ̃ satisfies the bound on this sample
    assert np.all(np.abs(f - pred[:, 0]) <= c.eta(np.sqrt(pred[:, 1])))


def test_conformal_quantile_finite_sample_coverage():
    from sea_daemon.core.bounds.gp_bound import conformal_quantile
    rng = np.random.default_rng(11)
    m, alpha, trials = 19, 0.1, 4000
    cover = np.mean([rng.exponential() <= conformal_quantile(rng.exponential(size=m), alpha) for _ in range(trials)])
    # split conformal: 1 − α ≤ coverage ≤ 1 − α + 1/(m + 1) (exchangeable scores); 3 MC std margin
    mc = 3 * math.sqrt(0.9 * 0.1 / trials)
    assert 1 - alpha - mc <= cover <= 1 - alpha + 1 / (m + 1) + mc
    # the plain empirical quantile (no (m + 1) correction) under-covers here
    naive = np.mean([rng.exponential() <= np.quantile(rng.exponential(size=m), 1 - alpha) for _ in range(trials)])
    assert naive < 1 - alpha - mc
    with pytest.raises(ValueError, match="at least 19"):
        conformal_quantile(np.ones(10), 0.05)


def test_conformal_constants_bound_the_noise_free_error_from_noisy_targets():
    from sea_daemon.core.bounds.gp_bound import conformal_constants
    rng = np.random.default_rng(12)
    delta, misses, trials = 0.1, 0, 300
    for _ in range(trials):
        # GP error e = f − μ heavy-tailed, scale s(z) known; targets y = f + symmetric noise
        s = rng.uniform(0.5, 2.0, 201)
        e = s * rng.standard_t(3, 201)
        y_minus_mu = e + rng.normal(0, 0.5, 201)
        c = conformal_constants(np.abs(y_minus_mu[:200]) / s[:200], delta)
        misses += abs(e[200]) > c.eta(s[200])
    assert misses / trials <= delta                  # Pr(|f − μ| > q s) ≤ 2 · δ/2
    assert c.method == "conformal" and c.scale == "local" and c.gamma == 0.0


def test_local_scale_is_the_leaf_residual_rms():
    from sea_daemon.core.bounds.gp_bound import LocalScale
    rng = np.random.default_rng(13)
    gp = LoGGP(input_dim=1, max_points=20, lengthscales=[0.3], sigma_f=1.0, sigma_n=0.1, seed=0)
    X = rng.uniform(0, 3, 80)
    for x in X:
        # noise grows with x: leaves on the right fit worse
        gp.update(np.array([x]), float(np.sin(3 * x) + 0.02 * (1 + 5 * x) * rng.standard_normal()))
    sc = LocalScale(gp)
    assert len(sc.r_) == len(gp.leaves()) > 2
    for node in gp.leaves():
        lf = gp.leaf(node)
        n = lf.n_
        Xl, yl = np.asarray(lf.X_[:n]), np.asarray(lf.y_[:n])
        res = yl - np.array([lf.predict(x)[0] for x in Xl])           # y − μ_leaf(X) by prediction
        assert sc.r_[node] == pytest.approx(np.sqrt(np.mean(res ** 2)), rel=1e-6)
    # s(z) ≥ σ(z), and the right end (noisier data) has the larger local scale
    z0, z1 = np.array([0.2]), np.array([2.8])
    assert sc(z0, 0.01) >= 0.1 and sc.local(z1) > sc.local(z0)


def test_posterior_sigma_modulus_is_sigma_f_tau_and_chooses_a_larger_tau():
    """ω_σ(τ) = σ_f τ (normalised coordinates) holds for the posterior σ of a GP with little noise,
    where LUH19's √(2τL_k(1 + N‖(K + σ_n²I)⁻¹‖σ_f²)) is orders larger: the bound takes it, picks a
    larger τ and a smaller √β than with LUH19's modulus (19 → 14 on a 6-D LoG-GP of a 2-DoF arm)."""
    rng = np.random.default_rng(11)
    sf, ls, sn = 1.3, np.array([0.4, 0.7, 1.1]), 0.01
    X = rng.uniform(-1, 1, (60, 3))
    y = np.sin(3 * X[:, 0]) * X[:, 1] + 0.2 * X[:, 2]
    Xg = rng.uniform(-1, 1, (400, 3))
    Xp = Xg + rng.standard_normal((400, 3)) * 0.02
    allX = np.vstack([X, Xg, Xp])
    _, sd = _gp_posterior(allX, np.arange(60), y, sf, ls, sn)
    d = np.linalg.norm((Xg - Xp) / ls, axis=1)
    assert np.all(np.abs(sd[60:460] - sd[460:]) <= sf * d * (1 + 1e-9) + 1e-12)
    leaf = LeafGP.from_data(X, y, sf, ls, sn)
    c = error_bound([leaf], [-1, -1, -1], [1, 1, 1], 0.05, delta_lipschitz=0.005)
    assert c.omega_sigma <= sf * c.tau * (1 + 1e-12)
    Kn = leaf.Kinv_norm
    luh = math.sqrt(2.0 * se_lipschitz(sf) * (1.0 + leaf.N * Kn * sf ** 2) * c.tau)
    assert c.omega_sigma < 1e-2 * luh
    assert c.tau >= 1e-8 and c.sqrt_beta < 10.0
