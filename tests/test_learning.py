"""Residual data generation (eq:loadsidewmotor, ass:passive_human) and the per-joint LoG-GP."""
import json

import numpy as np
import pytest

from sea_daemon.io.configfile import load_config, default_config_path
from sea_daemon.core.effects import make_effect
from sea_daemon.errors import InputError
from sea_daemon.core.learning import ResidualGP, training_pairs, training_pairs_from_log
from sea_daemon.core.model import SEAModel

EXTRA = [make_effect("human_viscoelastic", "load", k_h=1.2, q_h0=0.6, b_h=0.25),
         make_effect("viscous", "load", b=0.3)]


def _passive_run(N=2100, seed=0):
    """Consistent passive kinematics of a plant whose load side has EXTRA effects."""
    cfg = load_config(default_config_path())
    nominal = SEAModel.from_config(cfg)
    true = SEAModel.from_config(cfg.with_effects(list(cfg.model.effects) + EXTRA))
    t = np.arange(N) * 0.01
    q = 0.75 + 0.55 * np.sin(0.9 * t) + 0.1 * np.sin(2.7 * t)
    dq = 0.55 * 0.9 * np.cos(0.9 * t) + 0.27 * np.cos(2.7 * t)
    ddq = -0.55 * 0.81 * np.sin(0.9 * t) - 0.729 * np.sin(2.7 * t)
    th = q - 0.02 * np.sin(0.9 * t)                  # some spring deflection
    dth = dq - 0.018 * np.cos(0.9 * t)
    ddth = ddq + 0.0162 * np.sin(0.9 * t)
    tau = np.empty(N)
    for k in range(N):
        # load side with τ_h,act = 0: τ_s = −τ_l,true(z); motor side: κτ_m = Jθ̈_m + D_mθ̇_m − τ_s
        tau_s = -true.load_torque(q[k:k + 1], dq[k:k + 1], ddq[k:k + 1])
        mo, _, _ = true.motor_effects_torque(th[k:k + 1], dth[k:k + 1])
        tau[k] = ((true.J @ ddth[k:k + 1] + true.D_m @ dth[k:k + 1] + mo - tau_s) / true.kappa)[0]
    extra = 1.2 * (q - 0.6) + 0.25 * dq + 0.3 * dq
    return cfg, nominal, (q, dq, ddq, th, dth, ddth, tau), extra


def test_training_targets_are_the_unmodelled_load_torque():
    cfg, nominal, kin, extra = _passive_run(N=300)
    Z, F = training_pairs(nominal, *kin)
    assert Z.shape == (300, 3) and F.shape == (300, 1)
    assert np.allclose(Z, np.column_stack(kin[:3]))
    # eq:loadsidewmotor: f = τ_m − (τ_l + Jθ̈_m + D_mθ̇_m) = the load torque the model misses
    assert np.allclose(F[:, 0], extra, atol=1e-9)


def test_residual_gp_learns_the_passive_residual():
    cfg, nominal, kin, extra = _passive_run()
    Z, F = training_pairs(nominal, *kin)
    res = ResidualGP.from_config(cfg)
    res.train(Z[::2], F[::2])                        # train on every other sample
    assert res.n_points == 1050
    err = []
    for z, f in zip(Z[1::2][::10], extra[1::2][::10]):      # predict the held-out samples
        mu, jac, var = res.predict(z)
        assert mu.shape == (1,) and jac.shape == (1, 3) and var.shape == (1,) and var[0] >= 0
        err.append(mu[0] - f)
    assert np.sqrt(np.mean(np.square(err))) < 0.05
    # the Jacobian is that of the predicted mean (eq:moejac), against central differences
    z = Z[501]
    mu, jac, _ = res.predict(z)
    h = 1e-6
    fd = [(res.predict(z + h * e)[0][0] - res.predict(z - h * e)[0][0]) / (2 * h) for e in np.eye(3)]
    assert np.allclose(jac[0], fd, rtol=1e-4, atol=1e-4)


def test_two_joints_shapes_and_roundtrip():
    rng = np.random.default_rng(1)
    res = ResidualGP(2, hyperopt=False)
    Z = rng.uniform(-1, 1, (150, 6))
    F = np.column_stack([np.sin(Z[:, 0]), Z[:, 4] ** 2])
    res.train(Z, F)
    mu, jac, var = res.predict(Z[3])
    assert mu.shape == (2,) and jac.shape == (2, 6) and var.shape == (2,)
    back = ResidualGP.from_dict(json.loads(json.dumps(res.to_dict())))
    mu2, jac2, var2 = back.predict(Z[3])
    assert np.allclose(mu, mu2, rtol=1e-9) and np.allclose(jac, jac2, rtol=1e-7, atol=1e-10)
    with pytest.raises(InputError, match="shape"):
        res.update(Z[0], [1.0])
    with pytest.raises(InputError, match="shape"):
        res.predict(Z[0][:3])


def test_training_pairs_from_a_log():
    from sea_daemon.core.log import MeasuredLog
    cfg, nominal, kin, extra = _passive_run(N=600)
    q, dq, ddq, th, dth, ddth, tau = kin
    t = np.arange(600) * 0.01
    log = MeasuredLog(t, q[:, None], th[:, None], tau[:, None])
    Z, F = training_pairs_from_log(nominal, log, cfg.kinematics, causal=False)
    inner = slice(20, -20)                            # away from the smoothing edges
    assert np.allclose(Z[inner, 0], q[inner], atol=1e-9)
    assert np.allclose(F[inner, 0], extra[inner], atol=1e-3)
    Zc, Fc = training_pairs_from_log(nominal, log, cfg.kinematics, causal=True)
    assert Zc.shape[0] < 600 and Zc.shape[1] == 3
    # causal kinematics lag (group delay) but stay close on this slow motion
    assert np.sqrt(np.mean((Fc[:, 0] - extra[600 - Fc.shape[0]:]) ** 2)) < 0.03


def test_residual_gp_saves_through_the_model_file(tmp_path):
    from sea_daemon.io.modelfile import load_model, save_model
    rng = np.random.default_rng(2)
    res = ResidualGP(1, hyperopt=True, hyper_every=3, max_points=30)
    Z = rng.uniform(-1, 1, (200, 3))
    F = np.sin(2 * Z[:, :1]) + 0.1 * Z[:, 1:2]
    res.train(Z, F)
    arrays, meta = res.to_arrays()
    save_model(tmp_path / "m.npz", arrays, meta)
    back = ResidualGP.from_arrays(*load_model(tmp_path / "m.npz"))
    for z in Z[:5]:
        a, b = res.predict(z), back.predict(z)
        assert all(np.allclose(u, v, rtol=1e-9, atol=1e-12) for u, v in zip(a, b))
    # learning continues the same way after the round trip (tree, random state, Adam state);
    # the reloaded factors are rebuilt in one go, so figures agree to rounding, not bitwise
    for z, f in zip(Z[:40] + 0.01, F[:40]):
        res.update(z, f)
        back.update(z, f)
    a, b = res.gps[0], back.gps[0]
    assert a._dim == b._dim and a.n_points == b.n_points and a.n_hyper_steps == b.n_hyper_steps
    for z in Z[50:55]:
        assert all(np.allclose(u, v, rtol=1e-8, atol=1e-10) for u, v in zip(res.predict(z), back.predict(z)))
