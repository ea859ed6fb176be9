"""LoG-GP (docs/interfaces.md §5): one leaf = exact GP, splits, merged prediction, Jacobians,
continuity across overlaps, memory bound, online hyperparameters, determinism, persistence."""
import json

import numpy as np
import pytest

from sea_daemon.errors import InputError, ModelFileError
from sea_daemon.core.gp.exact import IncrementalGP, se_kernel
from sea_daemon.core.gp.hyper import log_marginal_likelihood
from sea_daemon.core.gp.loggp import LoGGP


def _f(X):
    # smooth SEA-like residual in z = [q, q̇, q̈]: gravity + viscous/Coulomb-like + inertia
    return 1.2 * np.sin(X[:, 0]) + 0.3 * X[:, 1] + 0.35 * np.tanh(X[:, 1] / 0.3) + 0.05 * X[:, 2]


def _stream(n, seed=0, d=3):
    rng = np.random.default_rng(seed)
    X = rng.uniform(-1.0, 1.0, (n, d))
    return X, _f(X) + 0.02 * rng.normal(size=n) if d == 3 else None


def test_contract_face():
    gp = LoGGP(input_dim=3, max_points=100)
    X, y = _stream(250)
    for xi, yi in zip(X, y):
        gp.update(xi, yi)
    mu, var = gp.predict(X[0])
    assert type(mu) is float and type(var) is float and var >= 0
    assert gp.n_points == 250 and gp.n_leaves >= 3
    assert abs(mu - _f(X[:1])[0]) < 0.1


def test_one_leaf_equals_exact_gp():
    X, y = _stream(100, seed=1)
    l, sf, sn = np.array([0.6, 0.8, 1.5]), 1.1, 0.05
    gp = LoGGP(3, max_points=100, lengthscales=l, sigma_f=sf, sigma_n=sn)
    for xi, yi in zip(X, y):
        gp.update(xi, yi)
    assert gp.n_leaves == 1
    K = se_kernel(X, X, l, sf) + (sn ** 2 + 1e-10) * np.eye(100)
    for x in np.random.default_rng(2).uniform(-1, 1, (5, 3)):
        k = se_kernel(X, x, l, sf)[:, 0]
        # eq:GPmean, eq:GPvariance, eq:moejac
        mu, var = y @ np.linalg.solve(K, k), sf ** 2 - k @ np.linalg.solve(K, k)
        dmu = (((X - x) / l ** 2) * k[:, None]).T @ np.linalg.solve(K, y)
        m, v, dm = gp.predict_with_grad(x)
        assert (m, v) == pytest.approx(gp.predict(x), rel=1e-12)
        assert m == pytest.approx(mu, rel=1e-7, abs=1e-9)
        assert v == pytest.approx(var, rel=1e-5, abs=1e-9)
        assert np.allclose(dm, dmu, rtol=1e-6, atol=1e-8)


def test_split_mirrors_log_gp():
    rng = np.random.default_rng(4)
    X = rng.uniform(0, 1, (11, 3)) * np.array([1.0, 3.0, 0.5])   # dim 1 is the widest
    gp = LoGGP(3, max_points=10, overlap=0.2, seed=3)
    for xi in X:
        gp.update(xi, float(xi.sum()))
    assert gp.n_leaves == 2 and gp._dim[0] == 1
    mi, ma = X[:, 1].min(), X[:, 1].max()
    lo, hi = gp._lo[0], gp._hi[0]
    assert 0.5 * (lo + hi) == pytest.approx(0.5 * (mi + ma))
    assert hi - lo == pytest.approx(0.2 * (ma - mi))
    left, right = gp.leaf(gp._left[0]), gp.leaf(gp._right[0])
    assert left.n_ + right.n_ == 11 and left.n_ > 0 and right.n_ > 0
    assert np.all(left.X_[:left.n_, 1] < hi) and np.all(right.X_[:right.n_, 1] > lo)
    # children inherit the parent's hyperparameters
    assert np.allclose(left.log_theta, right.log_theta)


def _trained(overlap, seed=0, n=400):
    X, y = _stream(n, seed=seed)
    gp = LoGGP(3, max_points=40, overlap=overlap, lengthscales=[0.5, 0.5, 1.0], sigma_n=0.05, seed=seed)
    for xi, yi in zip(X, y):
        gp.update(xi, yi)
    return gp


def _inside_overlaps(gp, rng, count):
    """Random inputs that reach at least two leaves."""
    out = []
    while len(out) < count:
        x = rng.uniform(-1, 1, 3)
        if len(gp.route(x)) >= 2:
            out.append(x)
    return out


def test_merged_jacobians_match_finite_differences():
    gp = _trained(overlap=0.3)
    rng = np.random.default_rng(5)
    xs = _inside_overlaps(gp, rng, 6) + [rng.uniform(-1, 1, 3) for _ in range(4)]
    h = 1e-6
    for x in xs:
        mu, var, dmu, dvar = gp.predict_with_grad(x, var_grad=True)
        assert (mu, var) == pytest.approx(gp.predict(x), rel=1e-10, abs=1e-12)
        m3 = gp.predict_with_grad(x)
        assert np.allclose(m3[2], dmu, rtol=1e-12, atol=1e-14)
        fd = [[(gp.predict(x + h * e)[i] - gp.predict(x - h * e)[i]) / (2 * h) for e in np.eye(3)]
              for i in (0, 1)]
        assert np.allclose(dmu, fd[0], rtol=1e-4, atol=1e-5), (x, dmu, fd[0])
        assert np.allclose(dvar, fd[1], rtol=1e-4, atol=1e-5), (x, dvar, fd[1])


def _max_jump(gp, j, a, b, h):
    x0 = np.zeros(3)
    mus = []
    for t in np.arange(a, b, h):
        x0[j] = t
        mus.append(gp.predict(x0))
    mus = np.array(mus)
    return np.abs(np.diff(mus, axis=0)).max(axis=0)


@pytest.mark.parametrize("overlap", [0.1, 0.3])
def test_merged_prediction_is_continuous_across_overlap(overlap):
    gp = _trained(overlap)
    j, lo, hi = gp._dim[0], gp._lo[0], gp._hi[0]
    a, b = lo - 0.02, hi + 0.02
    coarse, fine = _max_jump(gp, j, a, b, 1e-3), _max_jump(gp, j, a, b, 1e-4)
    # Lipschitz: the largest step shrinks with the step (a jump would not)
    assert np.all(fine < 0.2 * coarse + 1e-12), (coarse, fine)
    # a hard split (no overlap) on the same data has a jump at the split
    hard = _trained(0.0)
    j0, s0 = hard._dim[0], hard._lo[0]
    c0, f0 = _max_jump(hard, j0, s0 - 0.01, s0 + 0.01, 1e-3), _max_jump(hard, j0, s0 - 0.01, s0 + 0.01, 1e-4)
    assert f0[0] > 0.5 * c0[0] and f0[0] > 1e-3


def test_seeded_learning_is_deterministic():
    X, y = _stream(600, seed=6)

    def run(seed):
        gp = LoGGP(3, max_points=50, overlap=0.2, hyperopt=True, hyper_every=5, seed=seed)
        for xi, yi in zip(X, y):
            gp.update(xi, yi)
        return gp

    a, b, c = run(11), run(11), run(12)
    assert a.n_hyper_steps > 50
    assert json.dumps(a.to_dict()) == json.dumps(b.to_dict())
    x = np.array([0.1, -0.2, 0.3])
    assert a.predict_with_grad(x)[0] == b.predict_with_grad(x)[0]
    assert json.dumps(a.to_dict()["leaves"]) != json.dumps(c.to_dict()["leaves"])


def test_memory_bound_by_max_leaves():
    X, y = _stream(1500, seed=7)
    gp = LoGGP(3, max_points=20, max_leaves=4, lengthscales=[0.5, 0.5, 1.0])
    for xi, yi in zip(X, y):
        gp.update(xi, yi)
    assert gp.n_leaves == 4
    assert all(gp.leaf(i).n_ <= 20 for i in gp.leaves())
    assert gp.n_points == sum(gp.leaf(i).n_ for i in gp.leaves()) <= 80
    assert gp.n_evicted == 1500 - gp.n_points
    bytes_4 = gp.memory_bytes()
    # the newest point is kept and predicted well (FIFO keeps the recent data)
    assert abs(gp.predict(X[-1])[0] - y[-1]) < 0.1
    for xi, yi in zip(X[:500], y[:500]):
        gp.update(xi, yi)
    assert gp.memory_bytes() == bytes_4


def test_online_hyperparameters_raise_lml_and_find_lengthscale():
    rng = np.random.default_rng(8)
    X = rng.uniform(-2, 2, (150, 2))
    y = np.sin(X[:, 0] / 0.4) + 0.05 * rng.normal(size=150)    # the 2nd input is irrelevant
    gp = LoGGP(2, max_points=200, lengthscales=[3.0, 3.0], sigma_f=1.0, sigma_n=0.5,
               hyperopt=True, hyper_every=1, hyper_lr=0.05)
    for xi, yi in zip(X, y):
        gp.update(xi, yi)
    for _ in range(250):
        gp.hyper_slice()
    leaf = gp.leaf(gp.leaves()[0])
    before = log_marginal_likelihood(X, y, 1.0, [3.0, 3.0], 0.5, grad=False)
    after = leaf.log_marginal_likelihood(grad=False)
    assert after > before + 50
    l = leaf.lengthscales
    assert 0.4 < l[0] < 1.2 and l[1] > 3 * l[0], l
    assert leaf.sigma_n < 0.2
    # the rebuilt factor is exact for the new hyperparameters
    ref = IncrementalGP(2, leaf.sigma_f, l, leaf.sigma_n).fit(X, y)
    assert leaf.predict([0.3, 0.1]) == pytest.approx(ref.predict([0.3, 0.1]), rel=1e-8)


def test_to_dict_roundtrip_continues_identically():
    X, y = _stream(500, seed=9)
    a = LoGGP(3, max_points=30, overlap=0.2, hyperopt=True, hyper_every=7, seed=4)
    for xi, yi in zip(X[:300], y[:300]):
        a.update(xi, yi)
    b = LoGGP.from_dict(json.loads(json.dumps(a.to_dict())))
    x = np.array([0.2, 0.1, -0.4])
    assert b.predict(x) == pytest.approx(a.predict(x), rel=1e-9)
    for xi, yi in zip(X[300:], y[300:]):
        a.update(xi, yi)
        b.update(xi, yi)
    assert a.n_leaves == b.n_leaves and a._dim == b._dim
    assert b.predict(x) == pytest.approx(a.predict(x), rel=1e-8)
    with pytest.raises(ModelFileError):
        LoGGP.from_dict({"format": "x"})


def test_bad_inputs_raise_input_error():
    gp = LoGGP(3)
    with pytest.raises(InputError, match="shape"):
        gp.update(np.zeros(2), 1.0)
    with pytest.raises(InputError, match="finite"):
        gp.update(np.zeros(3), float("nan"))
    with pytest.raises(InputError, match="overlap"):
        LoGGP(3, overlap=1.5)
    with pytest.raises(InputError, match="max_points"):
        LoGGP(3, max_points=1)


def test_hyper_slice_runs_in_two_phases_on_consecutive_updates():
    X, y = _stream(40, seed=10)
    gp = LoGGP(3, max_points=100, hyperopt=True, hyper_every=20, hyper_min_points=10)
    for xi, yi in zip(X[:19], y[:19]):
        gp.update(xi, yi)
    theta0 = gp.leaf(0).log_theta
    gp.update(X[19], y[19])                          # 20th update: phase 1 (propose)
    assert gp.hyper_proposal is not None and np.array_equal(gp.leaf(0).log_theta, theta0)
    gp.update(X[20], y[20])                          # 21st: phase 2 (swap in, rebuilt)
    assert gp.hyper_proposal is None and not np.array_equal(gp.leaf(0).log_theta, theta0)
    ref = IncrementalGP(3, *(lambda t: (np.exp(t[0]), np.exp(t[1:4]), np.exp(t[4])))(gp.leaf(0).log_theta))
    ref.fit(X[:21], y[:21])
    assert gp.predict(X[30]) == pytest.approx(ref.predict(X[30]), rel=1e-8)


def test_off_loop_adaptation_equals_in_loop_slice():
    from sea_daemon.core.gp.hyper import adam_steps
    X, y = _stream(300, seed=12)
    a = LoGGP(3, max_points=60, seed=2)
    b = LoGGP(3, max_points=60, seed=2)
    for xi, yi in zip(X, y):
        a.update(xi, yi)
        b.update(xi, yi)
    node = a.last_leaf
    a.hyper_slice(node)
    req = b.hyper_request(node)
    res = adam_steps(json.loads(json.dumps(req)), steps=1, lr=b.hyper.lr)
    assert b.hyper_apply(json.loads(json.dumps(res)))
    assert np.allclose(a.leaf(node).log_theta, b.leaf(node).log_theta, rtol=1e-10)
    assert b.predict(X[5]) == pytest.approx(a.predict(X[5]), rel=1e-9)
    # several steps off the loop raise the leaf's LML
    res5 = adam_steps(b.hyper_request(node), steps=5)
    assert res5["lml"][-1] > res5["lml"][0]
    b.update(X[0] + 5.0, 0.0)                         # a result for a node that split is dropped
    stale = dict(res5, node=0)
    assert not b.hyper_apply(stale)


def test_repeated_identical_inputs_stay_finite():
    gp = LoGGP(3, max_points=10, sigma_n=1e-3)
    x = np.array([0.3, -0.1, 0.2])
    ys = np.random.default_rng(13).normal(1.0, 0.01, 60)
    for yi in ys:
        gp.update(x, yi)                              # a leaf of identical points cannot split
    assert gp.n_leaves == 1 and gp.leaf(0).n_ <= 10 and gp.n_evicted > 0
    mu, var, dmu = gp.predict_with_grad(x)
    assert np.isfinite(mu) and np.isfinite(var) and np.all(np.isfinite(dmu))
    assert abs(mu - ys[-gp.leaf(0).n_:].mean()) < 0.01


def test_offline_optimisation_raises_every_leaf_lml():
    X, y = _stream(240, seed=14)
    gp = LoGGP(3, max_points=60, lengthscales=3.0, sigma_n=0.3)
    for xi, yi in zip(X, y):
        gp.update(xi, yi)
    before = {i: gp.leaf(i).log_marginal_likelihood(grad=False) for i in gp.leaves()}
    gp.optimize_hyperparameters(steps=15)
    assert gp.n_hyper_steps == 15 * len(before)
    for i, b in before.items():
        assert gp.leaf(i).log_marginal_likelihood(grad=False) > b


def test_noise_variance_is_the_weighted_leaf_noise():
    """σ² + noise_variance(x) is the predictive variance of a new target: Σ ω_i σ_on,i²."""
    gp = _trained(overlap=0.3)
    rng = np.random.default_rng(2)
    leaves = gp.leaves()
    for k, node in enumerate(leaves):          # distinct noise per leaf
        lg = gp.leaf(node)
        lg.set_hyperparameters(lg.sigma_f, lg.lengthscales, 0.01 * (k + 1))
    for x in _inside_overlaps(gp, rng, 4) + [rng.uniform(-1, 1, 3) for _ in range(4)]:
        route = gp.route(x)
        expect = sum(w * gp.leaf(node).sigma_n ** 2 for node, w, _ in route)
        assert gp.noise_variance(x) == pytest.approx(expect, rel=1e-12)
        assert min(gp.leaf(n).sigma_n for n in leaves) ** 2 <= gp.noise_variance(x) + 1e-15
        assert gp.noise_variance(x) <= max(gp.leaf(n).sigma_n for n in leaves) ** 2 + 1e-15
    assert any(len(gp.route(x)) > 1 for x in _inside_overlaps(gp, rng, 4))


@pytest.mark.parametrize("overlap", [0.0, 0.3, 0.9])
def test_batched_prediction_equals_per_point(overlap):
    # predict_many (compiled routing of every row, one compiled call per leaf) = predict per row,
    # also for rows in overlap regions (several leaves) and rows outside the data; the local
    # scale's batch (gp_bound.LocalScale.predict_many) = the mixture of route + leaf.predict
    from sea_daemon.core.bounds.gp_bound import LocalScale
    rng = np.random.default_rng(3)
    gp = LoGGP(3, max_points=12, overlap=overlap, lengthscales=[0.5, 0.5, 1.0], sigma_n=0.05, seed=2)
    for x in rng.uniform(-1, 1, (150, 3)):
        gp.update(x, float(np.sin(3 * x[0]) + x[1] * x[2]))
    assert gp.n_leaves > 5
    Z = rng.uniform(-1.3, 1.3, (60, 3))
    mu, var = gp.predict_many(Z)
    ref = np.array([gp.predict(z) for z in Z])
    np.testing.assert_allclose(mu, ref[:, 0], rtol=1e-13, atol=1e-15)
    np.testing.assert_allclose(var, ref[:, 1], rtol=1e-12, atol=1e-15)
    idx, nodes, w, _, _ = gp.leaf_predictions(Z)
    multi = np.bincount(idx, minlength=len(Z)) > 1
    assert multi.any() == (overlap > 0)
    if overlap == 0.9:                            # many leaves per row: the compiled routing's buffers grow
        assert len(idx) > 2 * len(Z) + 8 and np.bincount(idx).max() > 10
    for i, z in enumerate(Z):                     # the same leaves, weights and order as route
        r = gp.route(z)
        assert nodes[idx == i].tolist() == [node for node, _, _ in r]
        np.testing.assert_array_equal(w[idx == i], [om for _, om, _ in r])
    sc = LocalScale(gp)
    m2, v2, s2 = sc.predict_many(Z)
    for i, z in enumerate(Z):
        a = b = sl = 0.0
        for node, om, _ in gp.route(z):
            m, v = gp.leaf(node).predict(z)
            a, b, sl = a + om * m, b + om * (v + m * m), sl + om * sc.r_.get(node, 0.0)
        vr = max(b - a * a, 0.0)
        np.testing.assert_allclose([m2[i], v2[i], s2[i]], [a, vr, np.sqrt(vr + sl * sl)], rtol=1e-12, atol=1e-15)
    # the tree grows: the routing follows the new splits
    for x in rng.uniform(-1, 1, (100, 3)):
        gp.update(x, float(x[0]))
    np.testing.assert_allclose(gp.predict_many(Z)[0], [gp.predict(z)[0] for z in Z], rtol=1e-13, atol=1e-15)
    with pytest.raises(InputError):
        gp.predict_many(np.full((2, 3), np.nan))


def test_tree_arrays_follow_every_split():
    """The compiled routing's arrays are written by each split (not rebuilt per step): after
    hundreds of splits with predictions in between they equal the tree's lists, and routing
    through them gives the predictions of arrays built afresh."""
    from sea_daemon.core.gp.routing import Tree
    gp = LoGGP(input_dim=2, max_points=10, overlap=0.1, seed=1)
    rng = np.random.default_rng(0)
    Z = rng.uniform(-1.0, 1.0, (50, 2))
    for k in range(1500):
        x = rng.uniform(-1.0, 1.0, 2)
        gp.update(x, float(np.sin(3.0 * x[0]) + x[1]))
        if k % 7 == 0:
            gp.predict_with_grad(Z[k % 50])         # the arrays exist between the splits
    assert gp.n_leaves > 100
    # a split with room left writes into the same arrays (no copy of the tree)
    t0, leaves = gp._tree_arrays(), gp.n_leaves
    while gp.n_leaves == leaves:
        x = rng.uniform(-1.0, 1.0, 2)
        gp.update(x, float(np.sin(3.0 * x[0]) + x[1]))
    assert len(gp._dim) <= t0.links.shape[1] and gp._tree_arrays().links is t0.links
    t = gp._tree_arrays()
    fresh = Tree.of(gp._dim, gp._lo, gp._hi, gp._left, gp._right)
    n = len(gp._dim)
    assert np.array_equal(t.links[:, :n], fresh.links) and np.array_equal(t.span[:, :n], fresh.span)
    mu, var = gp.predict_many(Z)
    g = [gp.predict_with_grad(z)[2] for z in Z]
    gp._tree_cache = None
    mu2, var2 = gp.predict_many(Z)
    assert np.array_equal(mu, mu2) and np.array_equal(var, var2)
    assert all(np.array_equal(a, gp.predict_with_grad(z)[2]) for a, z in zip(g, Z))


def test_tree_views_and_route_one():
    """The public, read-only views of the tree: ``n_nodes``, ``tree`` (the lists as arrays,
    leaves −1 / 0) and ``route_one`` (the leaves ``route`` reports, with the same weights)."""
    gp = LoGGP(input_dim=2, max_points=10, overlap=0.2, seed=1)
    rng = np.random.default_rng(2)
    for _ in range(300):
        x = rng.uniform(-1.0, 1.0, 2)
        gp.update(x, float(np.sin(3.0 * x[0]) + x[1]))
    n = gp.n_nodes
    assert n == len(gp._dim) and n == 2 * gp.n_leaves - 1
    t = gp.tree
    assert t.links.shape == (3, n) and t.span.shape == (2, n)
    assert t.links.tolist() == [gp._dim, gp._left, gp._right]
    assert t.span.tolist() == [gp._lo, gp._hi]
    with pytest.raises(ValueError):
        t.links[0, 0] = 5
    for z in rng.uniform(-1.0, 1.0, (20, 2)):
        nodes, ws, dws = gp.route_one(np.ascontiguousarray(z), True)
        want = gp.route(z, grad=True)
        assert nodes == [r[0] for r in want] and ws.tolist() == [r[1] for r in want]
        assert all(np.array_equal(a, r[2]) for a, r in zip(dws, want))


def test_split_in_lengthscales_splits_the_dimension_the_kernel_resolves():
    """In raw units the wide-but-smooth dimension (span 30, length scale 60) takes every split;
    measured in length scales the tree splits the dimension the kernel resolves (span 1,
    length scale 0.2), and the option survives a save/load."""
    rng = np.random.default_rng(3)
    X = np.column_stack([rng.uniform(0, 1, 600), rng.uniform(-15, 15, 600)])
    y = np.sin(6 * X[:, 0])
    dims = {}
    for scaled in (False, True):
        gp = LoGGP(2, max_points=50, lengthscales=[0.2, 60.0], sigma_f=1.0, sigma_n=0.05,
                   split_in_lengthscales=scaled)
        for x, t in zip(X, y):
            gp.update(x, t)
        dims[scaled] = {d for d in gp._dim if d >= 0}
        back = LoGGP.from_dict(gp.to_dict())
        assert back.split_in_lengthscales is scaled
    assert dims[False] == {1} and dims[True] == {0}


def test_a_saturated_leaf_forgets_instead_of_splitting():
    """With split_in_lengthscales, points that all lie within a small fraction of the length
    scales (a still arm: encoder and velocity noise) are one location to the kernel: the full
    leaf forgets its oldest points instead of splitting on the noise; in raw units it splits.
    Points spread over the length scale still split."""
    from sea_daemon.core.gp.loggp import MIN_SPLIT_SPREAD
    rng = np.random.default_rng(5)
    ls = np.array([0.2, 0.2, 20.0])
    still = rng.normal(0.0, 1e-3, (300, 3)) * ls        # spread ~0.006 length scales
    y = 2.0 + 0.01 * rng.standard_normal(300)
    for scaled, leaves in ((True, 1), (False, None)):
        gp = LoGGP(3, max_points=50, lengthscales=ls, sigma_f=2.0, sigma_n=0.01, split_in_lengthscales=scaled)
        for x, t in zip(still, y):
            gp.update(x, t)
        if leaves is None:
            assert gp.n_leaves > 1 and gp.n_evicted == 0
        else:
            assert gp.n_leaves == 1 and gp.n_points == 50 and gp.n_evicted == 250
            assert abs(gp.predict(still[0])[0] - 2.0) < 0.01
    moving = rng.uniform(-1, 1, (300, 3)) * ls * 5 * MIN_SPLIT_SPREAD
    gp = LoGGP(3, max_points=50, lengthscales=ls, sigma_f=2.0, sigma_n=0.01, split_in_lengthscales=True)
    for x in moving:
        gp.update(x, float(np.sin(x[0] / ls[0])))
    assert gp.n_leaves > 1 and gp.n_evicted == 0
