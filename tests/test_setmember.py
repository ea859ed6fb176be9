"""Theorem-1 set-membership propagation: linear reduction to the KF, coverage on a nonlinear plant."""
import numpy as np
import pytest
from scipy.stats import chi2

from sea_daemon.core.bounds.setmember import SetMembershipBound, discrete_residual
from sea_daemon.core.linalg import discretize
from sea_daemon.io.configfile import load_config, default_config_path
from sea_daemon.core.model import SEAModel


def kf_step(x, P, F, dx, Q, H, R, y):
    xm = x + dx
    Pm = F @ P @ F.T + Q
    S = H @ Pm @ H.T + R
    K = np.linalg.solve(S, H @ Pm).T
    xp = xm + K @ (y - H @ xm)
    Pp = (np.eye(len(x)) - K @ H) @ Pm
    return xp, 0.5 * (Pp + Pp.T), K


@pytest.mark.parametrize("sets", ["zonotope", "ellipsoid"])
def test_linear_plant_zero_gp_error_reduces_to_kf_chi2_ellipsoid(sets):
    cfg = load_config(default_config_path())
    import dataclasses
    params = dataclasses.replace(cfg.model, gravity=np.zeros_like(np.asarray(cfg.model.gravity)))
    model = SEAModel(params)                       # no gravity, no effects: a linear SEA
    dt, d, n = cfg.dt, 5, 1
    H = np.hstack([np.eye(4), np.zeros((4, 1))])
    R, Q = cfg.estimator.R, np.diag([1e-8, 1e-8, 1e-4, 1e-4, 1e-3])
    rng = np.random.default_rng(0)
    x_true = np.array([0.1, 0.01, 0.0, 0.0, 0.5])
    x, P = x_true + rng.multivariate_normal(np.zeros(d), cfg.estimator.P0), cfg.estimator.P0.copy()
    sm = SetMembershipBound(d, [4], delta=0.05, projection="state", sets=sets)
    sm_marg = SetMembershipBound(d, [4], delta=0.05, projection="marginal", sets=sets)
    A = model.F_nom(x, np.zeros(n))                # constant: the plant is linear
    Gamma = discretize(A, model.I_mu @ model.Minv, dt)[1]
    G_u = discretize(A, model.B_nom(), dt)[1]
    s_d, s_1 = chi2.ppf(0.95, d), chi2.ppf(0.95, 1)
    for k in range(100):
        u = np.array([np.sin(0.05 * k)])
        F, dx = discretize(A, model.f_nom(x, u), dt)
        # exact ZOH transition of the linear plant (what discretize computes, without an expm per point)
        fd = lambda z: F @ z + G_u @ u
        assert np.allclose(x + dx, fd(x), atol=1e-12)
        C = sm.confidence_set(x, P)
        # C_k is the KF's χ² ellipsoid while the set of means is a point
        assert np.allclose(C.c, x) and np.allclose(C.X, s_d * P, rtol=1e-12, atol=0)
        Ft, dxt = discretize(model.F_nom(x_true, u), model.f_nom(x_true, u), dt)
        x_true = x_true + dxt + np.sqrt(np.diag(Q)) * rng.standard_normal(d)
        y = H @ x_true + np.sqrt(np.diag(R)) * rng.standard_normal(4)
        x_new, P_new, K = kf_step(x, P, F, dx, Q, H, R, y)
        rho = sm.step(x_hat=x, P=P, F=F, K=K, H=H, P_post=P_new, resid=discrete_residual(fd, x, F),
                      Gamma=Gamma, eta=np.zeros(n))
        rho_m = sm_marg.step(x_hat=x, P=P, F=F, K=K, H=H, P_post=P_new, resid=discrete_residual(fd, x, F),
                             Gamma=Gamma, eta=np.zeros(n))
        x, P = x_new, P_new
        assert np.max(np.abs(sm.X_)) == 0.0                  # the set of means stays a point
        # ρ = half-width of the KF's χ² ellipsoid E(x̂, sP) along τ_h,act
        assert rho[0] == pytest.approx(np.sqrt(s_d * P[4, 4]), rel=1e-12)
        assert rho_m[0] == pytest.approx(np.sqrt(s_1 * P[4, 4]), rel=1e-12)


class Pendulum:
    """x = [θ, ω, τ]: m ω̇ = τ + u − a sin θ − b ω + d(t), τ̇ = 0 (a 1-joint 'torque observer' toy)."""

    m, a, b, dt = 0.1, 4.0, 0.2, 0.01

    def f(self, x, u):
        return np.array([x[1], (x[2] + u - self.a * np.sin(x[0]) - self.b * x[1]) / self.m, 0.0])

    def A(self, x):
        return np.array([[0, 1, 0], [-self.a * np.cos(x[0]) / self.m, -self.b / self.m, 1 / self.m], [0, 0, 0]])

    def fd(self, x, u):
        # the discrete model of Theorem 1 (explicit Euler; its Jacobian is I + dt A)
        return x + self.dt * self.f(x, u)


def run_pendulum(seed, steps=200, eta=0.3, delta=0.05, sets="zonotope", projection="marginal"):
    """EKF + Theorem-1 bound on a pendulum with a persistent bounded disturbance |d| ≤ η."""
    pl = Pendulum()
    rng = np.random.default_rng(seed)
    d = 3
    H = np.array([[1.0, 0, 0]])
    R = np.array([[1e-4]])
    Q = np.diag([1e-8, 1e-5, 1e-4])
    Gamma = np.array([[0.0], [pl.dt / pl.m], [0.0]])   # how d enters x_{k+1} (Euler)
    x_true = np.array([rng.uniform(-1, 1), 0.0, rng.uniform(-1, 1)])
    P = np.diag([0.05, 0.05, 1.0])
    x = x_true + rng.multivariate_normal(np.zeros(d), P)
    sm = SetMembershipBound(d, [2], delta=delta, delta_gp=0.0, projection=projection, n_dirs=4,
                            sets=sets)
    sign = rng.choice([-1.0, 1.0])
    hit_set, hit_kf = [], []
    s_1 = chi2.ppf(1 - delta, 1)
    for k in range(steps):
        u = 2.0 * np.sin(0.02 * k)
        if rng.uniform() < 0.01:
            sign = -sign
        dist = sign * eta                                  # bounded, persistent, unknown
        F = np.eye(d) + pl.dt * pl.A(x)
        dx = pl.fd(x, u) - x
        x_true = pl.fd(x_true, u) + Gamma[:, 0] * dist + np.sqrt(np.diag(Q)) * rng.standard_normal(d)
        y = H @ x_true + np.sqrt(R[0, 0]) * rng.standard_normal(1)
        x_new, P_new, K = kf_step(x, P, F, dx, Q, H, R, y)
        rho = sm.step(x_hat=x, P=P, F=F, K=K, H=H, P_post=P_new,
                      resid=discrete_residual(lambda z: pl.fd(z, u), x, F), Gamma=Gamma, eta=np.array([eta]))
        x, P = x_new, P_new
        err = abs(x[2] - x_true[2])
        hit_set.append(err <= rho[0])
        hit_kf.append(err <= np.sqrt(s_1 * P[2, 2]))
    return np.array(hit_set), np.array(hit_kf), sm


@pytest.mark.parametrize("sets,projection", [("zonotope", "scalar"), ("zonotope", "marginal"),
                                            ("ellipsoid", "marginal")])
def test_nonlinear_coverage_at_promised_rate(sets, projection):
    delta = 0.05
    hs, hk = [], []
    for seed in range(8):
        s, k, sm = run_pendulum(seed, delta=delta, sets=sets, projection=projection)
        hs.append(s)
        hk.append(k)
    cov_set, cov_kf = np.mean(hs), np.mean(hk)
    assert cov_set >= 1 - delta                 # Theorem 1: ρ holds at the promised rate
    assert cov_kf < 1 - delta                   # the KF's own χ² bound alone does not
    assert np.all(np.isfinite(sm.X_)) and np.trace(sm.X_) > 0


def test_linearization_error_box_exact_for_quadratic_along_axis():
    sm = SetMembershipBound(2, [1], delta=0.1, margin=0.0)
    from sea_daemon.core.bounds.ellipsoid import Ellipsoid
    C = Ellipsoid(np.array([1.0, -2.0]), np.diag([0.25, 4.0]))
    resid = lambda x: np.array([(x[0] - 1.0) ** 2, 0.5 * (x[1] + 2.0) ** 2])
    b = sm.linearization_error_box(resid, C)
    assert b == pytest.approx([0.25, 2.0])
    # every point of C has |ε_i| ≤ b_i for this quadratic
    pts = C.sample(2000, 0)
    assert np.all(np.abs(np.array([resid(p) for p in pts])) <= b + 1e-12)


def test_discretize_input_matrix_matches_integral():
    rng = np.random.default_rng(3)
    A = rng.standard_normal((4, 4))
    B = rng.standard_normal((4, 2))
    G = discretize(A, B, 0.05)[1]
    s = np.linspace(0, 0.05, 201)
    from scipy.linalg import expm
    E = expm(A * (s[1] - s[0]))
    vals, M = [], np.eye(4)
    for _ in s:
        vals.append(M @ B)
        M = M @ E
    assert np.allclose(G, np.trapezoid(np.array(vals), s, axis=0), atol=1e-6)


def test_bad_arguments():
    with pytest.raises(ValueError):
        SetMembershipBound(3, [2], delta=1.5)
    with pytest.raises(ValueError):
        SetMembershipBound(3, [2], delta=0.05, delta_gp=0.05)


def test_zonotope_outer_ellipsoid_and_order_reduction_contain_the_zonotope():
    from sea_daemon.core.bounds.ellipsoid import Ellipsoid, minkowski_shape, segments_shapes
    from sea_daemon.core.bounds.zonotope import reduce_generators, zonotope_shape
    rng = np.random.default_rng(21)
    d, m = 4, 30
    G = rng.standard_normal((d, m)) * rng.uniform(0.01, 1.0, m)
    # the outer ellipsoid equals the n-ary trace-minimal sum of the segments, and contains vertices
    X = zonotope_shape(G)
    assert np.allclose(X, minkowski_shape(segments_shapes(G, np.ones(m))), rtol=1e-10)
    V = np.sign(rng.standard_normal((500, m))) @ G.T
    assert np.all(Ellipsoid(np.zeros(d), X).contains(V))
    # reduction keeps m generators and contains the original (support functions dominate)
    Gr = reduce_generators(G, 12)
    assert Gr.shape == (d, 12)
    E = rng.standard_normal((2000, d))
    h, hr = np.abs(E @ G).sum(1), np.abs(E @ Gr).sum(1)
    assert np.all(hr >= h - 1e-12) and np.any(hr > h + 1e-6)
    assert reduce_generators(G, 40) is G


def test_reduction_every_few_steps_holds_a_map_whose_one_step_box_grows():
    """A contracting map (spectral radius 0.93) whose one step still grows an axis-aligned box
    (two badly scaled, correlated coordinates, like the AKF's τ_h,act error and velocity):
    boxed at every step the set of means grows ~1000× beyond the exact one; reduced every 5 steps
    (the AKF bound's 50 ms at 100 Hz, REDUCE_PERIOD_S) it stays within 2× of it."""
    from sea_daemon.core.bounds.setmember import REDUCE_PERIOD_S
    assert round(REDUCE_PERIOD_S / 0.01) >= 5
    S = np.diag([1.0, 100.0])
    M = S @ np.array([[0.95, 0.3], [-0.05, 0.9]]) @ np.linalg.inv(S)
    g = np.array([[0.01], [1.0]])
    ratio = {}
    for every in (1, 5):
        sm = SetMembershipBound(2, [1], 0.05, max_generators=6)
        sm.reduce_every = every
        exact = np.zeros((2, 0))
        for _ in range(300):
            sm.predict(M, Gamma=g, eta=np.array([1.0]))
            sm.update(np.zeros((2, 1)), np.zeros((1, 2)))
            exact = np.hstack([M @ exact, g])
        ratio[every] = sm.means_half_widths() / np.abs(exact).sum(1)
        assert np.all(ratio[every] >= 1 - 1e-12)                    # an outer approximation
    assert np.all(ratio[1] > 100) and np.all(ratio[5] < 2)


def test_compiled_zonotope_prediction_equals_the_direct_formulas():
    # SetMembershipBound.predict (one compiled call) = F·G ⊕ Γ·|η| ⊕ Φ·|b| without the zero
    # generators and Girard's reduction written out with numpy; zonotope_shape = its formula
    from sea_daemon.core.bounds.zonotope import zonotope_shape
    rng = np.random.default_rng(5)
    d, n = 5, 1
    sm = SetMembershipBound(d, [4], 0.05, delta_gp=0.025, max_generators=12)
    sm.G_ = rng.standard_normal((d, 9))
    F, Gam, Phi = rng.standard_normal((d, d)), rng.standard_normal((d, n)), rng.standard_normal((d, d))
    eta, b = np.array([-0.3]), np.array([0.0, 0.2, 0.0, -1.0, 0.5])   # zeros: no generator
    G = np.hstack([F @ sm.G_, Gam * np.abs(eta), Phi * np.abs(b)])
    G = G[:, np.any(G != 0.0, axis=0)]
    score = np.abs(G).sum(0) - np.abs(G).max(0)
    order = np.argsort(score, kind="stable")
    small, big = order[:G.shape[1] - (12 - d)], order[G.shape[1] - (12 - d):]
    box = np.abs(G[:, small]).sum(1)
    ref = np.hstack([G[:, big], np.diag(box)[:, box > 0]])
    np.testing.assert_allclose(sm.predict(F, Gamma=Gam, eta=eta, lin_err_box=b, Phi=Phi), ref, rtol=1e-12, atol=1e-14)
    # without boxes (and Φ = I by default): F·G only, no reduction needed
    sm.G_ = sm.G_[:, :4]
    np.testing.assert_allclose(sm.predict(F), F @ sm.G_, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(sm.predict(F, lin_err_box=b), np.hstack([F @ sm.G_, np.diag(np.abs(b))[:, b != 0]]),
                               rtol=1e-12, atol=1e-14)
    t = np.linalg.norm(ref, axis=0)
    P = np.diag(rng.uniform(0.1, 1.0, d))
    T = t.sum() + np.sqrt(np.trace(P))
    X = T * (ref / t) @ ref.T + T / np.sqrt(np.trace(P)) * P
    np.testing.assert_allclose(zonotope_shape(ref, extra=P), X, rtol=1e-12)


def test_zonotope_propagation_is_exact_and_bounds_the_ellipsoid_one():
    # fixed error boxes: the set of means is exactly the zonotope of all mapped generators
    from scipy.linalg import expm, solve_discrete_are
    rng = np.random.default_rng(22)
    d, steps, dt = 4, 150, 0.01
    # a torque observer like the AKF: mass-spring [x, v], a second mass [x2, v2]... with an
    # unknown input state w (random walk) — x = [x, v, x2, w], positions measured
    A = np.array([[0, 1, 0, 0], [-100, -2, 50, 10], [0, 0, -5, 0], [0, 0, 0, 0.0]])
    F = expm(A * dt)
    H = np.array([[1.0, 0, 0, 0], [0, 0, 1.0, 0]])
    P = solve_discrete_are(F.T, H.T, np.diag([1e-6, 1e-3, 1e-6, 1e-2]), 1e-6 * np.eye(2))
    K = P @ H.T @ np.linalg.inv(H @ P @ H.T + 1e-6 * np.eye(2))
    Gamma = np.array([[0, 0], [dt, 0], [0, dt], [0, 0.0]])
    sms = {"exact": SetMembershipBound(d, [3], 0.05, sets="zonotope", max_generators=10 ** 6),
           "reduced": SetMembershipBound(d, [3], 0.05, sets="zonotope", max_generators=40),
           "ellipsoid": SetMembershipBound(d, [3], 0.05, sets="ellipsoid")}
    gens = np.zeros((d, 0))
    for k in range(steps):
        eta = rng.uniform(0.0, 1.0, 2)
        gens = (np.eye(d) - K @ H) @ np.hstack([F @ gens, Gamma * eta])
        for sm in sms.values():
            sm.predict(F, Gamma=Gamma, eta=eta)
            sm.update(K, H)
        exact = np.abs(gens).sum(1)
        np.testing.assert_allclose(sms["exact"].means_half_widths(), exact, rtol=1e-9)
        assert np.all(sms["reduced"].means_half_widths() >= exact * (1 - 1e-12))
        assert np.all(sms["ellipsoid"].means_half_widths() >= exact * (1 - 1e-9))
    # the outer ellipsoid is strictly looser than the exact set; the reduction stays near exact
    assert sms["ellipsoid"].means_half_widths()[3] > 1.05 * exact[3]
    assert sms["reduced"].means_half_widths()[3] < 1.1 * exact[3]


def test_shifted_gaussian_halfwidth_is_the_exact_worst_case_quantile():
    from scipy.stats import norm
    from sea_daemon.core.bounds.setmember import shifted_gaussian_halfwidth
    h = np.array([0.0, 0.3, 1.0, 4.0, 0.2])
    s = np.array([1.0, 0.5, 1.0, 1.0, 0.0])
    rho = shifted_gaussian_halfwidth(h, s, 0.05)
    # the defining equation, and the limits: two-sided at h = 0, one-sided + h for h ≫ σ, h at σ = 0
    ok = s > 0
    assert np.allclose(norm.sf((rho[ok] - h[ok]) / s[ok]) + norm.sf((rho[ok] + h[ok]) / s[ok]), 0.05, atol=1e-12)
    assert rho[0] == pytest.approx(norm.ppf(0.975)) and rho[3] == pytest.approx(4.0 + norm.ppf(0.95), rel=1e-9)
    assert rho[4] == 0.2
    # never above the union-style h + two-sided quantile, never below h + one-sided
    assert np.all(rho[ok] <= h[ok] + s[ok] * norm.ppf(0.975) + 1e-12)
    assert np.all(rho[ok] >= h[ok] + s[ok] * norm.ppf(0.95) - 1e-12)
    # Monte Carlo at the worst shift a = h (and a smaller shift covers more)
    rng = np.random.default_rng(5)
    g = 0.5 * rng.standard_normal(400_000)
    assert abs(np.mean(np.abs(0.3 + g) > rho[1]) - 0.05) < 0.002
    assert np.mean(np.abs(0.1 + g) > rho[1]) < 0.05
