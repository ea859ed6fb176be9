"""Config loading/validation and the SEA model's Jacobians."""
import numpy as np
import pytest

from sea_daemon.core.config import ModelConfig
from sea_daemon.io.configfile import load_config, default_config_path
from sea_daemon.core.effects import EFFECT_TYPES, make_effect
from sea_daemon.errors import ConfigError
from sea_daemon.core.linalg import discretize
from sea_daemon.core.model import SEAModel


def base_dict():
    return {"joints": 1, "rate_hz": 100,
            "model": {"M": 0.12, "J": 0.08, "D_m": 0.6, "K_s": 110.0, "D_s": 0.25, "gravity": 2.9,
                      "effects": [{"type": "human_viscoelastic", "k_h": 1.2, "q_h0": 0.6, "b_h": 0.25},
                                  {"type": "coulomb", "side": "load", "F_c": 0.35}]}}


def test_contract_example_loads():
    cfg = ModelConfig.from_dict(base_dict())
    assert cfg.joints == 1 and cfg.dt == pytest.approx(0.01)
    assert [e.type for e in cfg.model.effects] == ["human_viscoelastic", "coulomb"]
    assert cfg.estimator.P0.shape == (5, 5)


def test_default_config_loads_and_roundtrips(tmp_path):
    from sea_daemon.io.configfile import save_config
    cfg = load_config(default_config_path())
    p = tmp_path / "c.yaml"
    save_config(cfg.with_effects([make_effect("viscous", "motor", b=0.1)]), p)
    back = load_config(p)
    assert back.model.effects[0].params == {"b": 0.1}
    np.testing.assert_allclose(back.estimator.R, cfg.estimator.R)


@pytest.mark.parametrize("mutate, key", [
    (lambda d: d.update(extra=1), "extra"),
    (lambda d: d["model"].pop("K_s"), "model.K_s"),
    (lambda d: d["model"].update(M=-0.1), "model.M"),
    (lambda d: d["model"].update(K_s=0.0), "model.K_s"),
    (lambda d: d["model"]["effects"].append({"type": "magic"}), "model.effects[2].type"),
    (lambda d: d["model"]["effects"].append({"type": "coulomb", "side": "spring", "F_c": 1}), "model.effects[2].side"),
    (lambda d: d["model"]["effects"].append({"type": "viscous", "side": "load"}), "model.effects[2].b"),
    (lambda d: d.update(joints=0), "joints"),
    (lambda d: d.update(estimator={"delta": 1.5}), "estimator.delta"),
    (lambda d: d.update(estimator={"gp_beta": "conformal"}), "estimator.gp_beta"),
    (lambda d: d.update(estimator={"gp_beta": -2.0}), "estimator.gp_beta"),
    (lambda d: d.update(estimator={"gp_beta": True}), "estimator.gp_beta"),
    (lambda d: d.update(estimator={"Sigma_nom_dt": -0.01}), "estimator.Sigma_nom_dt"),
    (lambda d: d.update(estimator={"tau_m_noise": -1.0}), "estimator.tau_m_noise"),
    (lambda d: d.update(estimator={"tau_h_act_rate": -0.5}), "estimator.tau_h_act_rate"),
    (lambda d: d.update(estimator={"tau_h_act_rate": "fast"}), "estimator.tau_h_act_rate"),
    (lambda d: d.update(estimator={"gp_noise_in_Q": "yes"}), "estimator.gp_noise_in_Q"),
    (lambda d: d.update(estimator={"init_after_kinematics": 1}), "estimator.init_after_kinematics"),
    (lambda d: d.update(learning={"extrapolation_scale": -1.0}), "learning.extrapolation_scale"),
    (lambda d: d.update(learning={"extrapolation_scale": "on"}), "learning.extrapolation_scale"),
    (lambda d: d.update(learning={"clip_leaf_mean": 1}), "learning.clip_leaf_mean"),
])
def test_bad_config_names_key(mutate, key):
    d = base_dict()
    mutate(d)
    with pytest.raises(ConfigError) as ei:
        ModelConfig.from_dict(d, source="x.yaml")
    assert ei.value.key == key
    assert "x.yaml" in str(ei.value)


def _all_effects():
    vals = {"F_c": 0.3, "b": 0.2, "F_s": 0.4, "v_s": 0.3, "dI": 0.02, "a": 0.5, "phi": 0.2, "k_h": 1.2,
            "q_h0": 0.4, "b_h": 0.3, "k3": 300.0, "width": 0.004, "kappa": 0.9, "delta": 0.01,
            "seconds": 0.02, "A": 0.1, "periods": 6.0, "theta_max": 0.02, "k_stop": 500.0, "tau_0": -0.05}
    out = []
    for t, cls in EFFECT_TYPES.items():
        for side in cls.sides:
            out.append(make_effect(t, side, **{p: vals[p] for p in cls.param_names}))
    return out


@pytest.mark.parametrize("effect", _all_effects(), ids=lambda e: f"{e.type}-{e.side}")
def test_jacobian_matches_finite_differences(effect):
    cfg = ModelConfig.from_dict(base_dict()).with_effects([effect])
    m = SEAModel.from_config(cfg)
    rng = np.random.default_rng(1)
    for _ in range(5):
        x = rng.normal(size=5) * [0.5, 0.01, 1.0, 0.3, 1.0]
        x[1] = 0.03 if effect.type == "spring_backlash" else x[1]   # away from the kink
        u = rng.normal(size=1)
        A = m.F_nom(x, u)
        h = 1e-6
        An = np.column_stack([(m.f_nom(x + h * e, u) - m.f_nom(x - h * e, u)) / (2 * h) for e in np.eye(5)])
        np.testing.assert_allclose(A, An, rtol=1e-5, atol=1e-4 * max(1.0, np.abs(An).max()))
        Bn = np.column_stack([(m.f_nom(x, u + h) - m.f_nom(x, u - h)) / (2 * h)])
        np.testing.assert_allclose(m.B_nom(), Bn, rtol=1e-6, atol=1e-6)


def test_two_joint_jacobian():
    d = base_dict()
    d["joints"] = 2
    d["model"] = {"M": [[0.2, 0.03], [0.03, 0.1]], "J": [0.08, 0.05], "D_m": 0.6, "K_s": [110, 90],
                  "D_s": 0.25, "gravity": [2.9, 1.0],
                  "effects": [{"type": "coulomb", "side": "load", "joint": 2, "F_c": 0.2}]}
    m = SEAModel.from_config(ModelConfig.from_dict(d))
    x = np.array([0.1, -0.2, 0.01, 0.02, 0.5, -0.3, 0.1, 0.05, 0.4, -0.2])
    u = np.array([0.5, -1.0])
    h = 1e-6
    An = np.column_stack([(m.f_nom(x + h * e, u) - m.f_nom(x - h * e, u)) / (2 * h) for e in np.eye(10)])
    np.testing.assert_allclose(m.F_nom(x, u), An, rtol=1e-5, atol=1e-5)


def test_discretize_is_exact_for_linear_system():
    from scipy.linalg import expm
    rng = np.random.default_rng(0)
    A = rng.normal(size=(4, 4))
    B = rng.normal(size=(4, 1))
    x, u, dt = rng.normal(size=4), rng.normal(size=1), 0.05
    Fd, dx = discretize(A, A @ x + B @ u, dt)
    big = expm(np.block([[A, B], [np.zeros((1, 5))]]) * dt)
    np.testing.assert_allclose(Fd, big[:4, :4], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(x + dx, big[:4, :4] @ x + big[:4, 4:] @ u, rtol=1e-10, atol=1e-12)


def test_two_joint_config_roundtrips_with_default_learning(tmp_path):
    from sea_daemon.io.configfile import save_config
    d = {"joints": 2, "rate_hz": 100, "model": {"M": 0.1, "J": 0.1, "D_m": 0.1, "K_s": 100, "D_s": 0.1}}
    cfg = ModelConfig.from_dict(d)
    assert len(cfg.learning.lengthscales) == 6
    save_config(cfg, tmp_path / "c.yaml")
    assert load_config(tmp_path / "c.yaml").learning.lengthscales == cfg.learning.lengthscales
    d["learning"] = {"lengthscales": [1, 2, 3]}
    assert ModelConfig.from_dict(d).learning.lengthscales == (1, 1, 2, 2, 3, 3)


def test_gp_beta_default_number_and_round_trip():
    d = base_dict()
    assert ModelConfig.from_dict(d).estimator.gp_beta == "lederer"
    d["estimator"] = {"gp_beta": 2}
    cfg = ModelConfig.from_dict(d)
    assert cfg.estimator.gp_beta == 2.0
    assert ModelConfig.from_dict(cfg.to_dict()).estimator.gp_beta == 2.0


def test_process_noise_options_roundtrip(tmp_path):
    from sea_daemon.io.configfile import save_config
    cfg = load_config(default_config_path())
    e = cfg.estimator
    # the defaults (docs/configuration.md): Σ_nom per 10 ms, the GP's predictive variance in Q,
    # the filter started once the kinematics are measured
    assert (e.Sigma_nom_dt, e.tau_m_noise, e.gp_noise_in_Q, e.init_after_kinematics) == (0.01, 0.0, True, True)
    assert e.tau_h_act_rate == 0.0
    d = cfg.to_dict()
    d["estimator"].update(Sigma_nom_dt=0.0, tau_m_noise=0.02, gp_noise_in_Q=False, init_after_kinematics=False,
                          tau_h_act_rate=1.5)
    p = tmp_path / "c.yaml"
    save_config(ModelConfig.from_dict(d, source="x.yaml"), p)
    e = load_config(p).estimator
    assert (e.Sigma_nom_dt, e.tau_m_noise, e.gp_noise_in_Q, e.init_after_kinematics) == (0.0, 0.02, False, False)
    assert e.tau_h_act_rate == 1.5
