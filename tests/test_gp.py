"""Exact GP (Sec. III-B): closed form, Jacobians, incremental Cholesky, LML and its gradient."""
import json
import math

import numpy as np
import pytest

from sea_daemon.errors import InputError
from sea_daemon.core.gp.exact import IncrementalGP, se_kernel
from sea_daemon.core.gp.hyper import fit_hyperparameters, log_marginal_likelihood

L_TRUE = np.array([0.4, 0.9, 2.5])
SF, SN = 1.3, 0.08


def _data(n=60, seed=0, d=3):
    rng = np.random.default_rng(seed)
    X = rng.uniform(-1.0, 1.0, (n, d))
    y = np.sin(3.0 * X[:, 0]) + 0.5 * X[:, 1] ** 2 + 0.1 * rng.normal(size=n)
    return X, y


def _closed_form(X, y, x, l, sf, sn):
    # eq:GPmean, eq:GPvariance with dense linear algebra
    K = se_kernel(X, X, l, sf) + (sn ** 2 + 1e-10) * np.eye(len(X))   # + the model's jitter
    k = se_kernel(X, x, l, sf)[:, 0]
    mu = y @ np.linalg.solve(K, k)
    var = sf ** 2 - k @ np.linalg.solve(K, k)
    return mu, var


def test_se_kernel_matches_eq_se():
    a, b = np.array([0.1, -0.2, 0.3]), np.array([0.4, 0.1, -0.5])
    want = SF ** 2 * math.exp(-np.sum((a - b) ** 2 / (2 * L_TRUE ** 2)))
    assert se_kernel(a, b, L_TRUE, SF)[0, 0] == pytest.approx(want, rel=1e-14)


def test_incremental_posterior_equals_closed_form():
    X, y = _data()
    gp = IncrementalGP(3, SF, L_TRUE, SN)           # starts at capacity 16: exercises growth
    for xi, yi in zip(X, y):
        gp.add(xi, yi)
    batch = IncrementalGP(3, SF, L_TRUE, SN).fit(X, y)
    rng = np.random.default_rng(1)
    for x in rng.uniform(-1.2, 1.2, (10, 3)):
        mu, var = _closed_form(X, y, x, L_TRUE, SF, SN)
        for model in (gp, batch):
            m, v = model.predict(x)
            assert m == pytest.approx(mu, rel=1e-8, abs=1e-10)
            assert v == pytest.approx(var, rel=1e-6, abs=1e-10)
    # the incrementally grown factor is the Cholesky factor of K + σ²I
    K = se_kernel(X, X, L_TRUE, SF) + (SN ** 2 + 1e-10) * np.eye(len(X))
    assert np.allclose(gp.L_, np.linalg.cholesky(K), atol=1e-9)
    assert np.allclose(gp.alpha_, np.linalg.solve(K, y), rtol=1e-7, atol=1e-8)


def test_empty_gp_returns_prior():
    gp = IncrementalGP(2, 2.0, 1.0, 0.1)
    assert gp.predict([0.3, 0.1]) == (0.0, 4.0)
    mu, var, dmu = gp.predict_with_grad([0.3, 0.1])
    assert mu == 0.0 and var == 4.0 and np.all(dmu == 0)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_jacobians_match_finite_differences(seed):
    X, y = _data(seed=seed)
    gp = IncrementalGP(3, SF, L_TRUE, SN).fit(X, y)
    x = np.random.default_rng(seed + 10).uniform(-1, 1, 3)
    mu, var, dmu, dvar = gp.predict_with_grad(x, var_grad=True)
    assert (mu, var) == pytest.approx(gp.predict(x), rel=1e-12)
    h = 1e-6
    fd_mu = np.array([(gp.predict(x + h * e)[0] - gp.predict(x - h * e)[0]) / (2 * h) for e in np.eye(3)])
    fd_var = np.array([(gp.predict(x + h * e)[1] - gp.predict(x - h * e)[1]) / (2 * h) for e in np.eye(3)])
    assert np.allclose(dmu, fd_mu, rtol=1e-5, atol=1e-6)
    assert np.allclose(dvar, fd_var, rtol=1e-4, atol=1e-6)
    # eq:moejac with eq:kernelderivative written out densely
    K = se_kernel(X, X, L_TRUE, SF) + SN ** 2 * np.eye(len(X))
    k = se_kernel(X, x, L_TRUE, SF)[:, 0]
    dk = ((X - x) / L_TRUE ** 2) * k[:, None]         # ∂k_i/∂x
    assert np.allclose(dmu, dk.T @ np.linalg.solve(K, y), rtol=1e-7, atol=1e-9)


def test_remove_oldest_and_new_hyperparameters_equal_refit():
    X, y = _data(n=40)
    gp = IncrementalGP(3, SF, L_TRUE, SN).fit(X, y)
    gp.remove_oldest(5)
    ref = IncrementalGP(3, SF, L_TRUE, SN).fit(X[5:], y[5:])
    x = np.array([0.2, -0.3, 0.5])
    assert gp.predict(x) == pytest.approx(ref.predict(x), rel=1e-9)
    gp.set_hyperparameters(0.7, [0.3, 0.3, 0.3], 0.2)
    ref2 = IncrementalGP(3, 0.7, 0.3, 0.2).fit(X[5:], y[5:])
    assert gp.predict(x) == pytest.approx(ref2.predict(x), rel=1e-9)
    gp.add(x, 0.5)                                    # appends after a rebuild stay exact
    ref2.fit(np.vstack([X[5:], x]), np.append(y[5:], 0.5))
    assert gp.predict(x + 0.1) == pytest.approx(ref2.predict(x + 0.1), rel=1e-8)


def test_lml_equals_closed_form_and_gradient_matches_fd():
    X, y = _data(n=50)
    lml, g = log_marginal_likelihood(X, y, SF, L_TRUE, SN)
    K = se_kernel(X, X, L_TRUE, SF) + (SN ** 2 + 1e-10) * np.eye(len(X))
    want = -0.5 * y @ np.linalg.solve(K, y) - 0.5 * np.linalg.slogdet(K)[1] - 0.5 * len(y) * math.log(2 * math.pi)
    assert lml == pytest.approx(want, rel=1e-10)
    t0 = np.log(np.concatenate(([SF], L_TRUE, [SN])))
    h = 1e-5
    for j in range(5):
        e = np.zeros(5)
        e[j] = h
        f = [log_marginal_likelihood(X, y, math.exp(t[0]), np.exp(t[1:4]), math.exp(t[4]), grad=False)
             for t in (t0 + e, t0 - e)]
        assert g[j] == pytest.approx((f[0] - f[1]) / (2 * h), rel=1e-5, abs=1e-6)
    # the incremental model reuses its factor and gives the same figures
    gp = IncrementalGP(3, SF, L_TRUE, SN).fit(X, y)
    lml2, g2 = gp.log_marginal_likelihood()
    assert lml2 == pytest.approx(lml, rel=1e-9) and np.allclose(g2, g, rtol=1e-7, atol=1e-8)


def test_batch_hyperparameters_recover_lengthscale():
    rng = np.random.default_rng(3)
    X = rng.uniform(-2, 2, (120, 2))
    y = np.sin(X[:, 0] / 0.4) + 0.05 * rng.normal(size=120)   # the 2nd input is irrelevant
    t0 = [log_marginal_likelihood(X, y, 1.0, [3.0, 3.0], 0.5, grad=False)]
    sf, l, sn = fit_hyperparameters(X, y, 1.0, [3.0, 3.0], 0.5)
    assert log_marginal_likelihood(X, y, sf, l, sn, grad=False) > t0[0] + 50
    # sin(x/0.4) has period 2.5; an SE fit settles near a third of it; the 2nd input is pruned
    assert 0.4 < l[0] < 1.2 and l[1] > 5 * l[0]
    assert 0.02 < sn < 0.1


def test_to_dict_roundtrip_is_json_and_exact():
    X, y = _data(n=30)
    gp = IncrementalGP(3, SF, L_TRUE, SN).fit(X, y)
    back = IncrementalGP.from_dict(json.loads(json.dumps(gp.to_dict())))
    x = np.array([0.1, 0.2, 0.3])
    assert back.predict(x) == pytest.approx(gp.predict(x), rel=1e-12)


def test_bad_hyperparameters_name_the_value():
    with pytest.raises(InputError, match="lengthscales"):
        IncrementalGP(3, 1.0, [1.0, -1.0, 1.0], 0.1)
    with pytest.raises(InputError, match="sigma_n"):
        IncrementalGP(3, 1.0, 1.0, 0.0)
    with pytest.raises(InputError, match="capacity"):
        g = IncrementalGP(1, capacity=2, max_capacity=2)
        for v in (0.0, 1.0, 2.0):
            g.add([v], v)


def test_lml_of_the_oldest_points_uses_the_leading_factor_block():
    X, y = _data(n=40)
    gp = IncrementalGP(3, SF, L_TRUE, SN)
    for xi, yi in zip(X, y):
        gp.add(xi, yi)
    lml, g = gp.log_marginal_likelihood(points=25)
    lml2, g2 = log_marginal_likelihood(X[:25], y[:25], SF, L_TRUE, SN)
    assert lml == pytest.approx(lml2, rel=1e-9) and np.allclose(g, g2, rtol=1e-7, atol=1e-8)


def test_fit_about_a_given_centre_and_the_read_only_hyperparameter_views():
    """``fit(X, y, center)`` factorises about that centre (as a model rebuilt from a snapshot
    must, to predict to the last bit as the saved one); ``sf2`` and ``il2`` are σ_f² and 1/l²
    and cannot be written through."""
    X, y = _data(n=30)
    a = IncrementalGP(3, SF, L_TRUE, SN).fit(X[5:], y[5:])
    for x in X[:5]:
        a.add(x, 0.0)                                  # centre stays the first point fitted
    b = IncrementalGP(3, SF, L_TRUE, SN).fit(a.X_[:a.n_], a.y_[:a.n_], a.center_)
    assert np.array_equal(b.center_, X[5])
    x = np.array([0.1, 0.2, 0.3])
    assert b.predict(x) == pytest.approx(a.predict(x), rel=1e-12)
    back = IncrementalGP.from_dict(a.to_dict())          # rebuilt about the saved centre
    assert np.array_equal(back.center_, X[5]) and back.predict(x) == b.predict(x)
    assert np.array_equal(back.ap_[:465], b.ap_[:465])
    assert b.sf2 == SF ** 2
    np.testing.assert_allclose(b.il2, 1.0 / np.asarray(L_TRUE, dtype=float) ** 2, rtol=1e-15)
    with pytest.raises(ValueError):
        b.il2[0] = 1.0
