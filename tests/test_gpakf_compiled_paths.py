"""The frozen GP-AKF's compiled sample (gpakf_core) on the rigid body of a URDF (the 2-DoF
shoulder-elbow exoskeleton: Pinocchio's ABA derivatives between two compiled calls) and with the
direction gate of a GP that learned one way only (one joint, no URDF; and the 2-DoF arm): the
same estimates, bounds, validity, state, set of means and gate as the Python step, bit for bit,
and no kernel compiled in its steps."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from sea_daemon.core.bounds.akf_bound import theorem_bound
from sea_daemon.core.config import LearningConfig
from sea_daemon.core.estimators import make_estimator
from sea_daemon.core.estimators.gpakf import GPAKF
from sea_daemon.core.estimators.health import EstimatorNonFinite
from sea_daemon.core.learning import ResidualGP
from sea_daemon.core.model import SEAModel
from sea_daemon.io.configfile import load_config
from tests._paths import repo_root
from tests.test_rigid_filter import HIDDEN, RATE, effects, human, session


@pytest.fixture(scope="module")
def arm():
    """The 2-DoF configuration, a GP-AKF trained 6 s on a passive session of an arm with hidden
    friction (learning then off), and 4 s with a human torque on both joints."""
    cfg = load_config(repo_root() / "configs" / "exo_2dof.yaml")
    true_cfg = dataclasses.replace(cfg, model=cfg.model.with_effects(effects(cfg, HIDDEN)))
    nominal = SEAModel.from_config(cfg)
    train = session(true_cfg, nominal, 6.0, None, 1)
    test = session(true_cfg, nominal, 4.0, human, 2)
    est = make_estimator("gp-akf", cfg, bound=False)
    q, th, u, _ = train
    est.reset(q[0], th[0], u[0])
    for k in range(1, len(q)):
        est.update(q[k], th[k], u[k])
    return cfg, est.gp, test


def one_way_gp(n: int, seed: int = 0) -> ResidualGP:
    """A GP of ``n`` joints whose training pairs move joint 1 up only (q̇₁ in 0.05-0.8 rad/s), the
    others both ways: joint 1's downward direction is gated."""
    rng = np.random.default_rng(seed)
    N = 300
    Z = np.column_stack([rng.uniform(0.2, 1.2, (N, n)), rng.uniform(-0.8, 0.8, (N, n)), rng.uniform(-1, 1, (N, n))])
    Z[:, n] = rng.uniform(0.05, 0.8, N)
    F = -0.02 + 0.001 * rng.normal(size=(N, n))
    gp = ResidualGP(n, LearningConfig(sigma_f=0.05, lengthscales=(0.5,) * n + (0.3,) * n + (50.0,) * n,
                                      sigma_n=0.002, hyperopt=False))
    gp.train(Z, F)
    assert gp.gated and gp.off_direction(np.r_[np.full(n, 0.7), -0.3, np.zeros(2 * n - 1)])
    return gp


def run(cfg, gp, data, fused: bool, dt=None):
    """The frozen GP-AKF with the Theorem-1 bound over ``data`` on the compiled path or the
    Python one: (τ̂, ρ, σ, valid per sample, x, P, the bound's set of means, variances capped,
    gated samples), then a non-finite sample's fault."""
    q, th, u = data[0], data[1], data[2]
    est = GPAKF(cfg, dt=dt, residual=gp, learning=False, bound=theorem_bound)
    est._fz_ok = est._fz_ok and fused
    assert est._fz_ok == fused
    n = est.n
    out = np.zeros((len(q), 3 * n + 1))
    est.reset(q[0], th[0], u[0])
    for k in range(1, len(q)):
        e = est.update(q[k], th[k], u[k])
        out[k] = np.r_[e.tau_h_act_hat, e.tau_h_act_bound, e.tau_h_act_sigma, e.valid]
    assert bool(est._fz_args) == fused                  # the compiled sample ran (or not)
    bad = np.array(q[-1], dtype=float)
    bad[0] = np.nan
    with pytest.raises(EstimatorNonFinite, match="prediction became non-finite"):
        est.update(bad, th[-1], u[-1])
    return out, est.x.copy(), est.P.copy(), est.bound.sm.G_.copy(), est.n_capped, est.residual.n_off_direction


def same(a, b) -> None:
    for x, y in zip(a, b):
        assert np.array_equal(x, y)


def test_the_rigid_body_sample_in_compiled_calls_equals_the_python_step(arm):
    cfg, gp, test = arm
    fused, python = run(cfg, gp, test, True), run(cfg, gp, test, False)
    same(fused, python)
    assert fused[0][-1, -1] == 1.0 and np.all(np.isfinite(fused[0][1:]))


@pytest.mark.parametrize("joints", [1, 2])
def test_the_direction_gate_on_the_compiled_path_equals_the_python_step(arm, passive_1dof, joints):
    """A GP that learned joint 1 moving up only: where joint 1 moves down its mean and Jacobian are
    0 on both paths (the affine model of one joint, the rigid body of two)."""
    cfg, data = (passive_1dof if joints == 1 else arm[::2])
    gp = one_way_gp(joints)
    fused, python = run(cfg, gp, data, True), run(cfg, gp, data, False)
    same(fused, python)
    assert fused[-1] > 50 and fused[-1] < len(data[0]) - 50        # gated while moving down only


@pytest.fixture(scope="module")
def passive_1dof():
    """The simulated one-joint exoskeleton (no declared effects: the affine model) and a shortened
    passive scenario's estimation log (700 samples)."""
    from sea_daemon.apps.bench import apply_settings
    from sea_daemon.io.scenario import load_scenario
    from sea_daemon.runtime.sim_runner import simulate
    sc = load_scenario(repo_root() / "configs" / "scenarios" / "passive.yaml")
    ctrl = sc.controller
    sc = dataclasses.replace(sc, training_samples=700, estimation_samples=700,
                             controller=dataclasses.replace(ctrl, trajectory=dataclasses.replace(ctrl.trajectory, moves=4)))
    log = simulate(sc).estimation
    cfg = apply_settings(sc.nominal, load_config(repo_root() / "configs" / "exo_1dof_sim.yaml"))
    assert GPAKF(cfg, learning=False)._affine
    return cfg, (log.q, log.theta_m, log.tau_m)


def test_the_rigid_body_sample_compiles_nothing_in_its_steps(arm):
    """The daemon's 2-joint estimator runs its samples through the calls compiled at construction."""
    from tests.test_compiled import _dispatchers
    cfg, gp, test = arm
    est = GPAKF(cfg, residual=gp, learning=False, bound=theorem_bound)
    q, th, u = test[0], test[1], test[2]
    est.reset(q[0], th[0], u[0])
    before = {k: len(d.signatures) for k, d in _dispatchers().items()}
    for k in ("rigid_head", "rigid_body", "sample_tail", "frozen_finish"):
        assert before["sea_daemon.core.estimators.gpakf_core." + k] > 0, k
    for k in range(1, 200):
        e = est.update(q[k], th[k], u[k]) if k % 2 else est.update(list(q[k]), list(th[k]), list(u[k]))
    assert est._fz_args and np.isfinite(e.tau_h_act_bound).all()
    assert {k: len(d.signatures) for k, d in _dispatchers().items()} == before
