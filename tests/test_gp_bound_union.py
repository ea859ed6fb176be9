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
