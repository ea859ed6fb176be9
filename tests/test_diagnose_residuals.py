"""diagnose internals: the two residual channels agree with the model, candidates' regressors
agree with recomputing the residual, array torques agree with the effects' own."""
from __future__ import annotations

import numpy as np
import pytest

from sea_daemon.io.configfile import default_config_path, load_config
from sea_daemon.analysis.diagnose.candidates import build_candidates
from sea_daemon.analysis.diagnose.context import Context
from sea_daemon.analysis.diagnose.residuals import applied_torque, kinematics_from_log, residual_channels
from sea_daemon.core.effects import EFFECT_TYPES, make_effect
from sea_daemon.core.log import MeasuredLog
from sea_daemon.core.model import SEAModel

ADDITIVE = [
    make_effect("coulomb", "load", F_c=0.3), make_effect("coulomb", "motor", F_c=0.2),
    make_effect("viscous", "load", b=0.4), make_effect("viscous", "motor", b=0.3),
    make_effect("stribeck", "load", F_s=0.3, v_s=0.08), make_effect("stribeck", "motor", F_s=0.2, v_s=0.2),
    make_effect("inertia", "load", dI=0.05), make_effect("inertia", "motor", dI=0.02),
    make_effect("gravity", "load", a=0.7, phi=0.4),
    make_effect("human_viscoelastic", "load", k_h=1.2, q_h0=0.6, b_h=0.25),
    make_effect("spring_cubic", "spring", k3=5000.0),
    make_effect("cogging", "motor", A=0.2, periods=30.0, phi=0.3),
    make_effect("spring_saturation", "spring", theta_max=0.01, k_stop=400.0),
    make_effect("torque_offset", "motor", tau_0=-0.07),
]
STRUCTURAL = [
    make_effect("spring_backlash", "spring", width=0.004), make_effect("torque_scale", "motor", kappa=0.9),
    make_effect("encoder_offset", "load", delta=0.01), make_effect("encoder_offset", "motor", delta=-0.01),
    make_effect("delay", "motor", seconds=0.013),
]


def _log(N=600, seed=0) -> MeasuredLog:
    """A smooth synthetic motion (the residual maths needs no physics to be checked)."""
    rng = np.random.default_rng(seed)
    t = np.arange(N) * 0.01
    q = 0.7 + 0.5 * np.sin(0.9 * t) + 0.05 * np.sin(3.1 * t + 1.0)
    th_s = 0.02 * np.sin(0.9 * t + 0.3) + 0.003 * np.cos(2.3 * t)
    tau = 2.0 + 1.5 * np.sin(0.9 * t + 0.2) + rng.normal(0, 0.02, N)
    return MeasuredLog(t=t, q=q[:, None], theta_m=(q - th_s)[:, None], tau_m=tau[:, None],
                       tau_h_act=0.1 * np.sin(0.5 * t)[:, None])


@pytest.fixture(scope="module")
def ctx():
    cfg = load_config(default_config_path()).with_effects(
        [make_effect("coulomb", "load", F_c=0.2), make_effect("human_viscoelastic", "load", k_h=1.0, q_h0=0.5, b_h=0.1)])
    c = Context(cfg, kinematics_from_log(_log()), None)
    c.r0 = c.residual()
    return c


#: the torque column of the vocabulary table (docs/interfaces.md §2), written out with numpy
TABLE = {
    "coulomb": lambda e, a, v, c: e.F_c * np.tanh(v / e.eps),
    "viscous": lambda e, a, v, c: e.b * v,
    "stribeck": lambda e, a, v, c: e.F_s * np.exp(-(v / e.v_s) ** 2) * np.tanh(v / e.eps),
    "inertia": lambda e, a, v, c: e.dI * c,
    "gravity": lambda e, a, v, c: e.a * np.sin(a + e.phi),
    "human_viscoelastic": lambda e, a, v, c: e.k_h * (a - e.q_h0) + e.b_h * v,
    "cogging": lambda e, a, v, c: e.A * np.sin(e.periods * a + e.phi),
    "spring_cubic": lambda e, a, v, c: e.k3 * a ** 3,
    "spring_saturation": lambda e, a, v, c: e.k_stop * (e.smooth * np.logaddexp(0, (a - e.theta_max) / e.smooth)
                                                       - e.smooth * np.logaddexp(0, (-a - e.theta_max) / e.smooth)),
    # the drive delivers tau_0 more: a torque of −tau_0 the motor side need not overcome
    "torque_offset": lambda e, a, v, c: np.full_like(a, -e.tau_0),
}


@pytest.mark.parametrize("e", ADDITIVE, ids=lambda e: f"{e.type}-{e.side}")
def test_effect_torque_is_the_vocabulary_formula_at_one_sample_and_over_arrays(e):
    rng = np.random.default_rng(1)
    a, v, c = rng.normal(0, 0.2, (3, 300))
    ref = TABLE[e.type](e, a, v, c)
    np.testing.assert_allclose(e.torque_array(a, v, c), ref, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose([e.torque(x, y, z) for x, y, z in zip(a, v, c)], ref, rtol=1e-12, atol=1e-12)


def test_every_vocabulary_type_has_a_candidate_on_every_side(ctx):
    got = {(c.type, c.side) for c in build_candidates(ctx)}
    want = {(t, s) for t, cls in EFFECT_TYPES.items() for s in cls.sides}
    assert got == want


@pytest.mark.parametrize("e", [e for e in ADDITIVE if e.type not in ("coulomb", "stribeck")],
                         ids=lambda e: f"{e.type}-{e.side}")
def test_additive_shortcut_equals_recomputed_residual(ctx, e):
    fast = ctx._additive_delta(e)
    exact = ctx.r0 - ctx.residual([e])
    np.testing.assert_allclose(fast, exact, atol=1e-10)


@pytest.mark.parametrize("e", ADDITIVE + STRUCTURAL, ids=lambda e: f"{e.type}-{e.side}")
def test_effect_shows_on_the_channels_its_side_predicts(ctx, e):
    """load: r_load only; motor: r_motor only; spring: both with opposite sign."""
    d = ctx.r0 - ctx.residual([e])
    load, motor = d[:, 0], d[:, 1]
    big = max(np.abs(d).max(), 1e-12)
    if e.type == "encoder_offset":      # an angle error reaches τ_s, hence both channels
        assert np.abs(load).max() > 0.01 * big and np.abs(motor).max() > 0.01 * big
    elif e.side == "load":
        assert np.abs(motor).max() < 1e-9 * big + 1e-12
    elif e.side == "motor":
        assert np.abs(load).max() < 1e-9 * big + 1e-12
    else:
        np.testing.assert_allclose(load, -motor, atol=1e-9 * big + 1e-12)


def test_channels_sum_to_the_models_inverse_dynamics(ctx):
    """r_load + r_motor = S(f(z)) of eq:loadsidewmotor, SEAModel.residual_from_kinematics per sample."""
    kin = ctx.kin
    m = SEAModel.from_config(ctx.cfg)
    u = applied_torque(m, kin) / m.kappa
    f = np.array([m.residual_from_kinematics(kin.q[k], kin.dq[k], kin.d2q[k], kin.theta_m[k], kin.dtheta_m[k],
                                             kin.d2theta_m[k], u[k], kin.tau_h_act[k]) for k in range(kin.N)])
    r = residual_channels(m, kin)          # v_stick = 0: the smoothed-sign model as is
    np.testing.assert_allclose(r[:, 0] + r[:, 1], kin.smooth(f)[:, 0], atol=1e-9)


def test_sticking_friction_takes_up_what_it_can(ctx):
    """While stuck, declared friction is set-valued up to its static limit (here F_c = 0.2 N m)."""
    m = SEAModel.from_config(ctx.cfg)
    r0 = residual_channels(m, ctx.kin)
    rs = residual_channels(m, ctx.kin, v_stick=0.05)
    moving = np.abs(ctx.kin.dq[:, 0]) > 0.05 + 1e-9
    w = ctx.kin.window
    far = np.convolve(~moving, np.ones(w), mode="same") == 0      # beyond the smoother's reach
    np.testing.assert_allclose(rs[far], r0[far], atol=1e-12)
    assert np.sqrt(np.mean(rs[~moving, 0] ** 2)) <= np.sqrt(np.mean(r0[~moving, 0] ** 2))


def test_passive_flag_ignores_tau_h_act(ctx):
    m = SEAModel.from_config(ctx.cfg)
    with_col = residual_channels(m, ctx.kin)
    passive = residual_channels(m, ctx.kin, passive=True)
    np.testing.assert_allclose(with_col[:, 0] - passive[:, 0], ctx.kin.smooth(ctx.kin.tau_h_act)[:, 0], atol=1e-12)
    np.testing.assert_allclose(with_col[:, 1], passive[:, 1])


def test_two_joints_run_end_to_end(tmp_path):
    """n = 2: candidates per joint, the JSON names the joint, the augmented model loads."""
    from sea_daemon.core.config import ModelConfig
    from sea_daemon.io.configfile import load_config
    from sea_daemon.apps.diagnose import diagnose

    base = load_config(default_config_path()).to_dict()
    base["joints"] = 2
    for k in ("M", "J", "D_m", "K_s", "D_s"):
        base["model"][k] = [base["model"][k]] * 2
    base["model"]["gravity"] = [base["model"]["gravity"]] * 2
    base["estimator"] = {}
    base.pop("hardware", None)      # per-joint bus settings: the defaults for two joints
    base["learning"] = {"lengthscales": [0.5, 0.5, 1.0, 1.0, 10.0, 10.0]}   # 3n (the default is for n = 1)
    cfg = ModelConfig.from_dict(base, "<two joints>")
    one = _log(N=500)
    # the motor winds the spring the way it pushes (θ_m − q in phase with τ_m): a consistent log
    one.theta_m = 2.0 * one.q - one.theta_m
    two = MeasuredLog(t=one.t, q=np.hstack([one.q, 0.8 * one.q]), theta_m=np.hstack([one.theta_m, 0.8 * one.theta_m]),
                      tau_m=np.hstack([one.tau_m, 0.8 * one.tau_m]))
    res = diagnose(two, cfg, tmp_path, plots=False)
    assert res["samples"] == 500
    assert set(res["residual_rms_channels"]["before"]) == {"load", "motor"}
    for d in res["effects_added"]:
        assert d["joint"] in (1, 2)
    aug = load_config(tmp_path / "model_augmented.yaml")
    assert aug.joints == 2 and len(aug.model.effects) == len(res["effects_added"])


def test_fast_command_gain_finds_the_drives_gain():
    """fast_command_gain on simulated logs: a drive delivering κ = 0.85 of the command, and one
    delivering all of it, are told apart from the fast part of the command alone."""
    from diagnose_sim import passive_log
    from sea_daemon.analysis.diagnose.residuals import fast_command_gain

    for kappa in (0.85, 1.0):
        extra = [make_effect("torque_scale", "motor", kappa=kappa)] if kappa != 1.0 else []
        log, cfg = passive_log(extra)
        g = fast_command_gain(SEAModel.from_config(cfg), kinematics_from_log(log), 3 * cfg.estimator.sign_eps)
        k, hw = g.kappa[0], g.half_width[0]
        assert np.isfinite(k) and hw < 0.2 * k, (kappa, k, hw)
        assert abs(k - kappa) <= max(hw, 0.1 * kappa), (kappa, k, hw)
