"""The residual GP's directions of motion: recorded by training, saved with the model, and the
GP-AKF's hooks use its mean only where the joint moves a way the GP learned."""
from __future__ import annotations

import numpy as np
import pytest

from sea_daemon.core.config import LearningConfig
from sea_daemon.core.learning import DIRECTION_MIN_PAIRS, ResidualGP


def _up_only_gp(seed: int = 0) -> tuple[ResidualGP, np.ndarray]:
    """A one-joint GP trained on friction moving up only (q̇ in 0.05-0.8 rad/s): f = −0.02 N m."""
    rng = np.random.default_rng(seed)
    Z = np.column_stack([rng.uniform(0.2, 1.2, 300), rng.uniform(0.05, 0.8, 300), rng.uniform(-1, 1, 300)])
    F = np.full((300, 1), -0.02) + 0.001 * rng.normal(size=(300, 1))
    gp = ResidualGP(1, LearningConfig(sigma_f=0.05, lengthscales=(0.5, 0.3, 50.0), sigma_n=0.002, hyperopt=False))
    gp.train(Z, F)
    return gp, Z


def test_training_records_the_directions_and_the_model_file_keeps_them():
    gp, Z = _up_only_gp()
    assert gp.directions.tolist() == [[0, 300]]
    assert gp.off_direction(np.array([0.7, -0.3, 0.0]))          # moving down: no data
    assert not gp.off_direction(np.array([0.7, 0.3, 0.0]))       # moving up: covered
    assert not gp.off_direction(np.array([0.7, -0.01, 0.0]))     # slower than the direction speed
    arrays, meta = gp.to_arrays()
    back = ResidualGP.from_arrays(arrays, meta)
    assert back.directions.tolist() == [[0, 300]] and back.off_direction(np.array([0.7, -0.3, 0.0]))
    assert ResidualGP.from_dict(gp.to_dict()).directions_record() == gp.directions_record()
    # a model saved without the record (older files): no record, no gate
    del meta["residual_gp"]["directions"]
    old = ResidualGP.from_arrays(arrays, meta)
    assert old.directions is None and old.directions_record() is None
    assert not old.off_direction(np.array([0.7, -0.3, 0.0]))


def test_a_malformed_directions_record_is_a_model_file_error():
    from sea_daemon.errors import ModelFileError
    gp, _ = _up_only_gp()
    arrays, meta = gp.to_arrays()
    meta["residual_gp"]["directions"]["pairs_down_up"] = [[-1, 3]]
    with pytest.raises(ModelFileError):
        ResidualGP.from_arrays(arrays, meta)


def test_weighted_hook_uses_the_physics_alone_moving_a_way_the_gp_never_learned():
    """With a q̇ length scale of 0.3 rad/s the GP carries the friction learned moving up across
    q̇ = 0; moving down, the hook's mean and Jacobian are 0 (its variance still in Q)."""
    from sea_daemon.core.estimators.weighted import WeightedResidual
    gp, _ = _up_only_gp()
    hook = WeightedResidual(gp, margin=0.1, noise_in_Q=False)
    mu_up = float(hook.predict(np.array([0.7, 0.3, 0.0]))[0][0])
    assert mu_up == pytest.approx(-0.02, abs=0.005) and not hook.off
    ungated = float(gp.gps[0].predict(np.array([0.7, -0.04, 0.0]))[0])
    assert ungated < -0.01                                        # the learned friction, wrong sign there
    mu, J, var = (np.array(a) for a in hook.predict(np.array([0.7, -0.04, 0.0])))
    assert mu[0] == 0.0 and np.all(J == 0.0) and var[0] > 0.0 and hook.off and hook.n_off_direction == 1


def test_plain_hook_gates_on_both_paths_and_online_learning_covers_the_direction():
    from sea_daemon.core.estimators.gpakf import _ResidualHook
    gp, _ = _up_only_gp()
    hook = _ResidualHook(gp)
    z_down = np.array([0.7, -0.04, 0.0])
    for key in (None, 1):                                         # Python path, then the compiled one
        hook.freeze(key)
        mu, J, _ = hook.predict(z_down)
        assert mu[0] == 0.0 and np.all(J == 0.0)
        mu, _, _ = hook.predict(np.array([0.7, 0.3, 0.0]))
        assert mu[0] == pytest.approx(-0.02, abs=0.005)
    # learning online while moving down: the direction becomes covered, the GP's mean is used
    rng = np.random.default_rng(3)
    for _ in range(DIRECTION_MIN_PAIRS):
        gp.update(np.array([rng.uniform(0.2, 1.2), -rng.uniform(0.05, 0.8), 0.0]), np.array([0.02]))
    assert not gp.gated and not gp.off_direction(z_down)
    hook.freeze(None)
    assert hook.predict(z_down)[0][0] != 0.0


def test_gpakf_learning_online_counts_the_directions_it_learns():
    """The GP-AKF's own training pairs (learning on) are counted as ResidualGP.update's are."""
    from sea_daemon.core.estimators.gpakf import GPAKF
    from sea_daemon.io.configfile import data_root, load_config
    cfg = load_config(data_root() / "configs" / "exo_1dof.yaml")
    est = GPAKF(cfg, dt=0.01, learning=True)
    assert est.gp.directions.tolist() == [[0, 0]]
    t = np.arange(400) * 0.01
    q = 0.5 * np.sin(2 * np.pi * 0.5 * t)                        # both ways, up to 1.6 rad/s
    est.reset(np.array([q[0]]), np.array([q[0]]), np.zeros(1))
    for k in range(1, len(t)):
        est.update(np.array([q[k]]), np.array([q[k]]), np.zeros(1))
    down, up = est.gp.directions[0]
    assert down > 0 and up > 0 and down + up <= est.n_learned


def test_calibration_output_says_which_direction_the_gp_lacks():
    from sea_daemon.apps.calibration.modelio import directions_lines
    gp, _ = _up_only_gp()
    lines = directions_lines(gp.directions_record())
    assert len(lines) == 1 and "up only" in lines[0] and "Moving down" in lines[0] and "physical model alone" in lines[0]
    both = {"speed": 0.03, "min_pairs": 50, "pairs_down_up": [[60, 70]], "covered_down_up": [[True, True]]}
    still = {"speed": 0.03, "min_pairs": 50, "pairs_down_up": [[0, 0]], "covered_down_up": [[False, False]]}
    assert directions_lines(both) == directions_lines(still) == directions_lines(None) == []


def test_a_gp_learned_at_rest_only_is_not_gated():
    """Pairs at rest only (a still-arm calibration) carry no sign of friction: no direction gate,
    the GP stays as its variance weights it."""
    rng = np.random.default_rng(2)
    Z = np.column_stack([rng.uniform(0.5, 0.52, 100), rng.uniform(-0.01, 0.01, 100), np.zeros(100)])
    gp = ResidualGP(1, LearningConfig(sigma_f=0.05, lengthscales=(0.5, 0.3, 50.0), sigma_n=0.002, hyperopt=False))
    gp.train(Z, np.full((100, 1), 0.01))
    assert gp.directions.tolist() == [[0, 0]] and not gp.gated
    assert not gp.off_direction(np.array([0.5, 0.3, 0.0])) and not gp.off_direction(np.array([0.5, -0.3, 0.0]))
