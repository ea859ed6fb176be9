"""The measurement's strips on the prior set of means (core/bounds/measurement_strip.py) and the
1 kHz still arm with declared friction they keep from running away (docs/bounds.md §4)."""
import numpy as np
import pytest
from scipy.optimize import linprog

from sea_daemon.core.bounds.akf_bound import AKFTheoremBound
from sea_daemon.core.bounds.measurement_strip import cut_generators, strip_halfwidths
from sea_daemon.core.config import ModelConfig
from sea_daemon.core.estimators import AKF
from sea_daemon.core.model import SEAModel

from synth import simulate
from test_akf_bound import _from_first_sample


def test_the_cut_zonotope_holds_every_point_of_the_zonotope_inside_the_strips():
    """Random zonotopes and strips that cut them: every sampled point of Z ∩ strips lies in the cut
    zonotope (an LP finds its generator weights within [−1, 1]), and a strip that does not cut
    leaves the generators as they are."""
    rng = np.random.default_rng(0)
    H = np.eye(4, 5)
    checked = 0
    for _ in range(60):
        k = int(rng.integers(3, 25))
        G = rng.normal(size=(5, k)) * rng.uniform(0.01, 3.0, size=(5, 1))
        c = np.sum(np.abs(H @ G), axis=1) * rng.uniform(0.05, 1.2, size=4)
        G2 = cut_generators(G, H, c)
        for _ in range(15):
            a = G @ np.clip(2.0 * rng.uniform(-1.0, 1.0, size=k), -1.0, 1.0)
            if np.any(np.abs(H @ a) > c):
                continue
            res = linprog(np.zeros(G2.shape[1]), A_eq=G2, b_eq=a, bounds=[(-1.0, 1.0)] * G2.shape[1])
            assert res.status == 0
            checked += 1
    assert checked > 100
    # a cut that would widen the rows of ``keep`` is left out: their half-width never grows
    for _ in range(60):
        G = rng.normal(size=(5, 12)) * rng.uniform(0.01, 3.0, size=(5, 1))
        keep = rng.normal(size=(1, 5))
        c = np.sum(np.abs(H @ G), axis=1) * rng.uniform(0.05, 1.0, size=4)
        assert np.abs(keep @ cut_generators(G, H, c, keep)).sum() <= np.abs(keep @ G).sum() * (1 + 1e-12)
    G = rng.normal(size=(5, 6))
    assert cut_generators(G, H, np.full(4, 1e9)) is G


def test_strip_halfwidths_are_the_innovation_plus_z_standard_deviations():
    e = np.array([0.1, -0.2, 0.0, 0.3])
    S = np.diag([4.0, 1.0, 0.25, 0.0])
    np.testing.assert_allclose(strip_halfwidths(e, S, 2.0), [4.1, 2.2, 1.0, 0.3])


def _still_arm_1khz():
    """A 1 kHz model with declared load Coulomb friction (ε = 3 mrad/s), measured velocities, a
    τ_h,act walk and declared rate as a calibration writes them; the arm held by the friction while
    the subject pushes below it (0.3 N m against F_c = 0.5 N m)."""
    cfg = _from_first_sample(ModelConfig.from_dict({"joints": 1, "rate_hz": 1000, "model": {
        "M": 0.12, "J": 0.08, "D_m": 0.6, "K_s": 110.0, "D_s": 0.25, "gravity": 0.0, "effects": [
            {"type": "coulomb", "side": "load", "F_c": 0.5}]},
        "estimator": {"sign_eps": 0.003, "R": [3e-12, 3e-12, 3.6e-6, 4.8e-6],
                      "Sigma_nom": [1e-16, 1e-16, 0.0, 0.0, 1e-3], "tau_h_act_rate": 40.0}}))
    log = simulate(SEAModel.from_config(cfg), T=1.0, rate=1000.0, tau_m=lambda t: np.array([0.0]),
                   tau_h=lambda t: np.array([0.3 * np.sin(2 * np.pi * 0.5 * t)]))
    return cfg, log


@pytest.mark.parametrize("strips", [True, False])
def test_the_strips_keep_a_1khz_still_arm_with_declared_friction_off_the_caps(strips):
    """Without the strips the set of means reaches the caps within 0.1 s (its velocity extent
    grows, the friction's interval with it); with them it stays finite and off the caps, and ρ
    covers the subject's torque at every step."""
    cfg, log = _still_arm_1khz()
    akf = AKF(cfg)
    tb = AKFTheoremBound(akf)
    akf.bound = tb
    if not strips:
        tb.friction.cut = lambda *a: None
    akf.reset(log.q[0], log.theta_m[0], log.tau_m[0])
    rho, err = [], []
    for k in range(1, len(log)):
        e = akf.update(log.q[k], log.theta_m[k], log.tau_m[k], log.t[k] - log.t[k - 1])
        rho.append(e.tau_h_act_bound[0])
        err.append(abs(e.tau_h_act_hat[0] - log.tau_h_act[k, 0]))
    rho, err = np.array(rho), np.array(err)
    if strips:
        assert tb.saturated_ == 0
        assert np.all(np.isfinite(rho)) and np.all(err <= rho)
        assert rho.mean() < 3.0
    else:
        assert tb.saturated_ > 500
