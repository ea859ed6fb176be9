"""The union over a LoG-GP's leaves in the guaranteed GP bound (docs/bounds.md §2): the leaves
that can predict while the constants are used — a frozen GP's own, a learning GP's plus one per
pair it may learn before they are made again (sea_daemon.core.bounds.calibration.union_leaves)."""
import dataclasses

import numpy as np
import pytest

from sea_daemon.core.bounds.calibration import gp_constants, residual_gps, union_leaves
from sea_daemon.core.estimators import make_estimator
from sea_daemon.core.gp.loggp import LoGGP
from sea_daemon.core.model import SEAModel
from sea_daemon.io.configfile import default_config_path, load_config

from synth import simulate


def _grown(max_leaves=40, pairs=300, seed=0):
    """A 2-input LoG-GP after ``pairs`` pairs, with its leaf count after each."""
    gp = LoGGP(2, max_points=10, max_leaves=max_leaves, lengthscales=[0.3, 0.3], sigma_f=1.0, sigma_n=0.05,
               hyperopt=False, seed=seed)
    rng = np.random.default_rng(seed)
    counts = []
    for _ in range(pairs):
        z = rng.uniform(-1.0, 1.0, 2)
        gp.update(z, float(np.sin(3 * z[0]) + z[1]))
        counts.append(gp.n_leaves)
    return gp, np.array(counts)


def test_each_training_pair_splits_at_most_one_leaf():
    # what the growth allowance rests on: L + g covers every leaf after g more pairs
    _, counts = _grown(max_leaves=10_000, pairs=400)
    steps = np.diff(np.concatenate([[1], counts]))
    assert counts[-1] > 20 and steps.min() >= 0 and steps.max() <= 1


def test_union_leaves_frozen_growing_and_capped():
    gp, _ = _grown(max_leaves=40, pairs=150)
    have = gp.n_leaves
    assert 1 < have < 40
    assert union_leaves(gp) == 40                       # no allowance: the cap
    assert union_leaves(gp, 0) == have                  # frozen: its own leaves
    assert union_leaves(gp, 3) == have + 3
    assert union_leaves(gp, 10_000) == 40               # never beyond the cap
    with pytest.raises(ValueError, match="growth must be an integer >= 0"):
        union_leaves(gp, -1)
    # fewer leaves in the union: a smaller √β, the same γ's form
    c_cap = gp_constants([gp], 0.025)[0][0]
    c_own = gp_constants([gp], 0.025, growth=0)[0][0]
    assert c_own.n_leaves == have and c_cap.n_leaves == 40 and c_own.sqrt_beta < c_cap.sqrt_beta


def _frozen_gp_akf():
    cfg = load_config(default_config_path())
    cfg = dataclasses.replace(cfg, estimator=dataclasses.replace(cfg.estimator, init_after_kinematics=False))
    train = simulate(SEAModel.from_config(cfg), T=1.5, seed=6)
    return cfg, make_estimator("gp-akf", cfg, train=train), simulate(SEAModel.from_config(cfg), T=0.2, seed=7)


def test_a_frozen_gp_akf_bound_unions_over_its_own_leaves():
    cfg, est, log = _frozen_gp_akf()
    est.reset(log.q[0], log.theta_m[0], log.tau_m[0])
    gp = residual_gps(est)[0]
    c = est.bound.gp_constants[0]
    assert not est.learning and c.n_leaves == gp.n_leaves < cfg.learning.max_leaves


def test_a_gp_that_learns_again_gets_the_allowance_at_its_first_new_pair():
    cfg, est, log = _frozen_gp_akf()
    tb = est.bound
    est.reset(log.q[0], log.theta_m[0], log.tau_m[0])
    frozen = tb.gp_constants
    est.learning = True
    learned0 = est.n_learned
    k = 1
    while est.n_learned == learned0:           # until the first new pair (after the differentiator's window)
        est.update(log.q[k], log.theta_m[k], log.tau_m[k], log.t[k] - log.t[k - 1])
        k += 1
    est.update(log.q[k], log.theta_m[k], log.tau_m[k], log.t[k] - log.t[k - 1])
    gp = residual_gps(est)[0]
    c = tb.gp_constants[0]
    assert tb.gp_constants is not frozen
    assert c.n_leaves == min(cfg.learning.max_leaves, gp.n_leaves + tb.refresh_every)


# ---------------------------------------------------------------- the nested boxes (docs/bounds.md §2, "The box")

def test_the_nested_boxes_share_delta_and_grow_by_doubling():
    from sea_daemon.core.bounds.calibration import BOX_LEVELS, box_level, gp_constant_levels
    gp, _ = _grown(max_leaves=40, pairs=150)
    c0, (lo, hi), lev = gp_constant_levels([gp], 0.025, growth=0)
    K = BOX_LEVELS
    assert lev.sqrt_beta.shape == (K, 1) and lev.lo.shape == (K, 2)
    np.testing.assert_allclose(lev.lo[0], lo)
    np.testing.assert_allclose(lev.hi[0], hi)
    np.testing.assert_allclose(lev.hi - lev.lo, (hi - lo)[None] * 2.0 ** np.arange(K)[:, None])
    # a wider box and a smaller share of δ: a larger √β at every level
    assert np.all(np.diff(lev.sqrt_beta[:, 0]) > 0) and c0[0].sqrt_beta == lev.sqrt_beta[0, 0]
    # the shares 2^-(k+1)/(1 - 2^-K) of δ_GP add up to δ_GP (each level's constants carry their δ)
    assert c0[0].delta == pytest.approx(0.025 * 0.5 / (1 - 0.5 ** K))
    assert sum(0.025 * 0.5 ** (k + 1) / (1 - 0.5 ** K) for k in range(K)) == pytest.approx(0.025)
    assert box_level(lev, lo, hi) == (0, False)
    mid, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
    assert box_level(lev, mid - 1.5 * half, mid + half) == (1, False)
    assert box_level(lev, mid - 3 * half, mid) == (2, False)
    assert box_level(lev, mid - 2.0 ** K * half, mid) == (K - 1, True)


def test_a_set_beyond_the_training_box_takes_a_wider_boxs_constants_in_both_steps():
    """Trained on small motions, run on larger ones: the GP input set leaves the training box, and
    each such step takes the constants of the smallest nested box that holds it — no step outside
    every box, the Python and the compiled step alike."""
    cfg = load_config(default_config_path())
    cfg = dataclasses.replace(cfg, estimator=dataclasses.replace(cfg.estimator, init_after_kinematics=False))
    small = lambda t: np.full(1, 0.4 * np.sin(2 * np.pi * 0.5 * t))
    train = simulate(SEAModel.from_config(cfg), T=1.5, seed=6, tau_m=small)
    log = simulate(SEAModel.from_config(cfg), T=0.6, seed=8)
    rho, levels, bounds = [], [], []
    for compiled in (False, True):
        est = make_estimator("gp-akf", cfg, train=train)
        est.bound.compiled = compiled
        est.reset(log.q[0], log.theta_m[0], log.tau_m[0])
        r, lv = [], []
        for k in range(1, len(log)):
            e = est.update(log.q[k], log.theta_m[k], log.tau_m[k], log.t[k] - log.t[k - 1])
            r.append(e.tau_h_act_bound[0])
            lv.append(est.bound.box_level_)
        rho.append(np.array(r))
        levels.append(np.array(lv))
        bounds.append(est.bound)
    assert bounds[1]._compiled_pack() is not None and bounds[0]._compiled_pack() is None
    assert levels[0].max() >= 1 and np.mean(levels[0] > 0) > 0.2
    assert bounds[0].gp_box_violations_ == bounds[1].gp_box_violations_ == 0
    np.testing.assert_allclose(rho[1], rho[0], rtol=1e-12, atol=1e-14)
