"""The extrapolation term of the GP error bound's local scale (docs/learning.md, "Novelty"):
e(z) = Σ_j |∂μ/∂z_j| |z_j − x*_j|, x* the nearest training input; η = β s + c e."""
import numpy as np
import pytest

from sea_daemon.core.bounds.gp_bound import LocalScale
from sea_daemon.core.config import LearningConfig
from sea_daemon.errors import InputError
from sea_daemon.core.gp.exact import IncrementalGP
from sea_daemon.core.learning import ResidualGP
from sea_daemon.core.gp.loggp import LoGGP


def _manifold_gp(c=2.0):
    """Data on the line x2 = x1 (a trajectory: two inputs that always move together) with a
    truth f = 2 x1 that depends on x1 only: along the data y = 2t; the GP cannot tell x1 from
    x2 and, with equal length scales, attributes half the slope to each.  The prior (σ_f = 0.5,
    l = 3: slopes ~ σ_f/l ≈ 0.17) is far flatter than the fitted mean (slope 1 per input), as in
    a leaf whose hyperparameters were adapted elsewhere: σ grows like σ_f d/l off the line while
    the mean's error grows like its slope times d."""
    rng = np.random.default_rng(5)
    t = np.sort(rng.uniform(-1.0, 1.0, 40))
    gp = LoGGP(2, max_points=100, lengthscales=[3.0, 3.0], sigma_f=0.5, sigma_n=0.01, seed=0,
               extrapolation_scale=c)
    for ti in t:
        gp.update(np.array([ti, ti]), 2.0 * ti + 0.01 * rng.standard_normal())
    return gp


def test_extrapolation_is_zero_on_the_data_and_matches_slope_times_distance():
    rng = np.random.default_rng(1)
    X = rng.uniform(-1, 1, (15, 3))
    g = IncrementalGP(3, 1.3, [0.7, 0.9, 2.0], 0.05)
    for x in X:
        g.add(x, float(np.sin(2 * x[0]) + x[1]))
    assert np.allclose(g.extrapolation_many(X), 0.0)               # x* = x on the data
    Z = rng.uniform(-2, 2, (6, 3))
    e = g.extrapolation_many(Z)
    for z, ez in zip(Z, e):
        _, _, dmu = g.predict_with_grad(z)                          # eq:moejac, compiled
        near = X[np.argmin((((X - z) / g.lengthscales) ** 2).sum(1))]
        assert ez == pytest.approx(np.sum(np.abs(dmu) * np.abs(z - near)), rel=1e-9, abs=1e-12)
    assert np.all(IncrementalGP(3).extrapolation_many(Z) == 0.0)    # no data: nothing extrapolated


def test_sigma_misses_an_off_manifold_error_that_the_extrapolation_term_covers():
    gp = _manifold_gp()
    sc = LocalScale(gp)
    # off the data line, well inside one length scale of it: σ stays small, the mean is wrong
    Z = np.array([[0.5, 0.8], [-0.3, -0.7], [0.2, 0.6]])
    f = 2.0 * Z[:, 0]
    mu, var, s, x = sc.predict_many_ext(Z)
    err = np.abs(f - mu)
    assert np.all(err > 0.2) and np.all(err > 3.0 * np.sqrt(var))   # σ is dishonest here
    e = gp.extrapolation_many(Z)
    assert np.all(err <= 2.0 * e) and np.all(err >= 0.5 * e)        # c = 2: (L_μ + L_f) τ, L_f ≈ L_μ
    np.testing.assert_allclose(x, 2.0 * e)
    assert np.all(s + x >= err) and np.all(s < err)                 # the added term covers it
    # on the data line (between samples) the term is slope × half a sample spacing: small
    on = np.array([[0.1, 0.1], [-0.4, -0.4]])
    _, v_on, s_on = sc.predict_many(on)
    assert np.all(gp.extrapolation_many(on) < 0.25 * e.min())
    assert np.allclose(s_on, [sc(z, v) for z, v in zip(on, v_on)])


def test_the_extrapolation_term_is_added_and_leaves_the_local_scale_alone():
    on, off = _manifold_gp(2.0), _manifold_gp(0.0)
    Z = np.array([[0.5, 0.8], [0.0, 0.0], [1.5, -1.0]])
    m_on, v_on, s_on, x_on = LocalScale(on).predict_many_ext(Z)
    m_off, v_off, s_off, x_off = LocalScale(off).predict_many_ext(Z)
    np.testing.assert_allclose(m_on, m_off)                          # predictions unchanged
    np.testing.assert_allclose(v_on, v_off)
    np.testing.assert_allclose(s_on, s_off)                          # β's scale unchanged
    np.testing.assert_allclose(x_on, 2.0 * on.extrapolation_many(Z), rtol=1e-9)
    assert np.all(x_off == 0.0)
    np.testing.assert_allclose(LocalScale(on).predict_many(Z)[2], s_on)
    for z, v, s in zip(Z, v_on, s_on):
        assert LocalScale(on)(z, v) == pytest.approx(s, rel=1e-9)


def test_merged_extrapolation_weights_the_leaves_and_the_option_persists():
    rng = np.random.default_rng(3)
    gp = LoGGP(2, max_points=15, overlap=0.3, lengthscales=[0.5, 0.5], seed=2, extrapolation_scale=1.5)
    for x in rng.uniform(-1, 1, (120, 2)):
        gp.update(x, float(np.sin(3 * x[0]) * x[1]))
    Z = rng.uniform(-1.2, 1.2, (40, 2))
    idx, nodes, w, _, _ = gp.leaf_predictions(Z)
    assert len(idx) > len(Z)                                         # some rows in overlaps
    want = np.zeros(len(Z))
    for i, nd, wi in zip(idx, nodes, w):
        want[i] += wi * gp.leaf(int(nd)).extrapolation_many(Z[i:i + 1])[0]
    np.testing.assert_allclose(gp.extrapolation_many(Z), want, rtol=1e-12)
    back = LoGGP.from_dict(gp.to_dict())
    arrays, meta = gp.to_arrays()
    assert back.extrapolation_scale == LoGGP.from_arrays(arrays, meta).extrapolation_scale == 1.5
    np.testing.assert_allclose(back.extrapolation_many(Z), want, rtol=1e-9)
    for bad in (-0.1, 11.0, True, "2"):
        with pytest.raises(InputError, match="extrapolation_scale"):
            LoGGP(2, extrapolation_scale=bad)


def test_learning_config_passes_the_scale_to_every_joint():
    lc = LearningConfig.from_dict({"extrapolation_scale": 2.0}, 2, "x.yaml")
    assert lc.extrapolation_scale == 2.0 and LearningConfig().extrapolation_scale == 0.7
    assert lc.to_dict()["extrapolation_scale"] == 2.0
    res = ResidualGP(2, lc)
    assert [g.extrapolation_scale for g in res.gps] == [2.0, 2.0]


def test_clipped_leaf_mean_stops_at_its_data_box_and_sigma_keeps_growing():
    rng = np.random.default_rng(7)
    X = rng.uniform([0.0, -0.01], [1.0, 0.01], (30, 2))              # thin along x2 (a standstill)
    y = X[:, 0] + 100.0 * X[:, 1]                                      # steep along the thin side
    free = IncrementalGP(2, 1.0, [0.5, 0.5], 0.01)
    clip = IncrementalGP(2, 1.0, [0.5, 0.5], 0.01, clip_mean=True)
    for x, v in zip(X, y):
        free.add(x, v)
        clip.add(x, v)
    np.testing.assert_allclose(clip.lo_, X.min(0)) and np.testing.assert_allclose(clip.hi_, X.max(0))
    inside = np.array([0.5, 0.0])
    assert clip.predict(inside) == pytest.approx(free.predict(inside))
    far = np.array([0.5, 0.2])                                         # 20 widths off along x2
    face = np.array([0.5, X[:, 1].max()])
    m_free, v_free = free.predict(far)
    m_clip, v_clip = clip.predict(far)
    assert abs(m_free - m_clip) > 3.0                                  # the free mean runs off with the slope
    assert m_clip == pytest.approx(free.predict(face)[0], rel=1e-9)    # the clipped one stays on the face
    assert v_clip == pytest.approx(v_free, rel=1e-12) and v_clip > clip.predict(face)[1]
    # batch, gradient (zero along the clipped coordinate) and ∂σ²/∂x at x agree with predict
    Z = np.array([inside, far, [1.5, -0.3]])
    mu, var = clip.predict_many(Z)
    for z, m, v in zip(Z, mu, var):
        assert (m, v) == pytest.approx(clip.predict(z), rel=1e-9)
        m2, v2, dm, dv = clip.predict_with_grad(z, var_grad=True)
        m3, v3, dm3 = clip.predict_with_grad(z)
        assert (m2, v2) == pytest.approx((m, v), rel=1e-9) and (m3, v3) == pytest.approx((m, v), rel=1e-9)
        np.testing.assert_allclose(dm, dm3)
        np.testing.assert_allclose(dv, free.predict_with_grad(z, var_grad=True)[3], rtol=1e-9)
        h = 1e-6
        for j in range(2):
            e = np.zeros(2)
            e[j] = h
            fd = (clip.predict(z + e)[0] - clip.predict(z - e)[0]) / (2 * h)
            assert dm[j] == pytest.approx(fd, rel=1e-4, abs=1e-6)
    assert dm3[0] == 0.0 and dm3[1] == 0.0                             # both coordinates clipped at [1.5, -0.3]
    # the extrapolation term keeps the data's slope (how fast f may move away from the data)
    assert clip.extrapolation_many(far[None])[0] == pytest.approx(free.extrapolation_many(far[None])[0])
    assert clip.extrapolation_many(far[None])[0] > 3.0


def test_clipped_leaf_mean_survives_splits_eviction_and_persistence():
    rng = np.random.default_rng(9)
    gp = LoGGP(2, max_points=12, max_leaves=4, lengthscales=[0.4, 0.4], seed=1, clip_leaf_mean=True)
    for x in rng.uniform(-1, 1, (150, 2)):
        gp.update(x, float(np.sin(2 * x[0]) + x[1]))
    assert gp.n_evicted > 0 and all(gp.leaf(nd).clip_mean for nd in gp.leaves())
    for nd in gp.leaves():
        lf = gp.leaf(nd)
        np.testing.assert_allclose(lf.lo_, lf.X_[:lf.n_].min(0))       # the box follows eviction
        np.testing.assert_allclose(lf.hi_, lf.X_[:lf.n_].max(0))
    Z = rng.uniform(-2, 2, (25, 2))
    back = LoGGP.from_dict(gp.to_dict())
    arrays, meta = gp.to_arrays()
    again = LoGGP.from_arrays(arrays, meta)
    for g in (back, again):
        assert g.clip_leaf_mean
        np.testing.assert_allclose(g.predict_many(Z)[0], gp.predict_many(Z)[0], rtol=1e-9)
    lc = LearningConfig.from_dict({"clip_leaf_mean": False}, 1, "x.yaml")
    assert not ResidualGP(1, lc).gps[0].clip_leaf_mean and ResidualGP(1, LearningConfig()).gps[0].clip_leaf_mean
