"""The integrated random walk of τ_h,act (``estimator.tau_h_act_model: integrated``): the state
layout in one place, the configuration's keys, a filter that tracks τ̇_h,act (no lag behind a
ramp, where the random walk lags), its Theorem-1 bound with the declared |τ̈_h,act| ≤ a (the
compiled step equal to the Python one, covering the truth), the frozen GP-AKF's compiled sample
equal to its Python step, and the calibration's scan of the τ̇_h,act walk."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from sea_daemon.core.bounds.akf_bound import AKFTheoremBound
from sea_daemon.core.config import EstimatorConfig
from sea_daemon.core.estimators.akf import AKF
from sea_daemon.core.model import StateLayout
from sea_daemon.core.replay import replay
from sea_daemon.core.sim.session import run_session
from sea_daemon.errors import ConfigError
from sea_daemon.io.configfile import load_config
from tests._paths import repo_root
from tests.test_gpakf_compiled_paths import arm  # noqa: F401  (the 2-DoF arm fixture)


def integrated(cfg, q_dtau: float, accel: float = 0.0, q_tau: float | None = None):
    """``cfg`` with the integrated walk: τ̇_h,act's walk q_dtau [N² m²/s³] (per Sigma_nom_dt), none on
    τ_h,act; P0 of τ̇_h,act 100; the declared |τ̈_h,act| ≤ accel.  ``q_tau``: the walk of the plain
    random walk instead (the same configuration with the walk, for comparison)."""
    e = cfg.estimator
    n = cfg.joints
    dt = e.Sigma_nom_dt
    if q_tau is not None:
        S = np.array(e.Sigma_nom, dtype=float)
        S[4 * n:, 4 * n:] = np.eye(n) * q_tau * dt
        return dataclasses.replace(cfg, estimator=dataclasses.replace(e, Sigma_nom=S))
    S = np.zeros((6 * n, 6 * n))
    S[:4 * n, :4 * n] = e.Sigma_nom[:4 * n, :4 * n]
    S[5 * n:, 5 * n:] = np.eye(n) * q_dtau * dt
    P0 = np.zeros((6 * n, 6 * n))
    P0[:5 * n, :5 * n] = e.P0
    P0[5 * n:, 5 * n:] = np.eye(n) * 100.0
    return dataclasses.replace(cfg, estimator=dataclasses.replace(e, tau_h_act_model="integrated", Sigma_nom=S, P0=P0,
                                                                  tau_h_act_accel=accel))


@pytest.fixture(scope="module")
def sim_cfg():
    return load_config(repo_root() / "configs" / "exo_1dof_sim.yaml")


def test_the_layout_names_where_each_part_of_the_state_lies():
    w, i = StateLayout.of(2, "walk"), StateLayout.of(2, "integrated")
    assert (w.d, w.m, i.d, i.m) == (10, 8, 12, 8)
    assert list(w.tau_idx) == list(i.tau_idx) == [8, 9] and w.dtau is None and i.dtau == slice(10, 12)
    assert list(w.rate_idx) == [8, 9] and list(i.rate_idx) == [10, 11]
    A = i.embed(np.eye(10))
    assert A.shape == (12, 12) and A[8, 10] == A[9, 11] == 1.0 and A[10:].sum() == 0.0
    assert w.embed(np.eye(10)).shape == (10, 10) and i.pad(np.ones((10, 2))).shape == (12, 2)
    with pytest.raises(ValueError, match="tau_h_act_model must be one of walk, integrated"):
        StateLayout.of(1, "irw")


def test_the_configuration_declares_the_model_and_refuses_a_wrong_one_in_one_line():
    walk = EstimatorConfig.from_dict({}, 1, "m.yaml")
    assert walk.d == 5 and walk.tau_h_act_model == "walk" and walk.tau_h_act_accel == 0.0
    e = EstimatorConfig.from_dict({"tau_h_act_model": "integrated", "tau_h_act_accel": 750.0}, 2, "m.yaml")
    assert e.d == 12 and e.P0.shape == (12, 12) and e.tau_h_act_accel == 750.0
    assert np.all(np.diag(e.Sigma_nom)[8:10] == 0.0) and np.all(np.diag(e.Sigma_nom)[10:] > 0)
    assert np.all(np.diag(e.P0)[10:] == 100.0)
    assert EstimatorConfig.from_dict(e.to_dict(), 2, "m.yaml").tau_h_act_model == "integrated"
    for bad, key in (({"tau_h_act_model": "irw"}, "tau_h_act_model"), ({"tau_h_act_accel": -1.0}, "tau_h_act_accel"),
                     ({"tau_h_act_model": "integrated", "Sigma_nom": [1, 1, 1, 1, 1]}, "Sigma_nom")):
        with pytest.raises(ConfigError) as ei:
            EstimatorConfig.from_dict(bad, 1, "m.yaml")
        assert f"estimator.{key}" in str(ei.value) and "\n" not in str(ei.value)


def _still_session(cfg, human, seconds: float, seed: int):
    return run_session(cfg, seconds, hold_q=0.4, human=human, seed=seed)


def test_the_integrated_walk_follows_a_ramp_where_the_walk_lags(sim_cfg):
    """A wearer whose torque rises at 10 N m/s for 2 s on a still arm: the random walk's estimate
    lags behind the ramp; the integrated walk estimates τ̇_h,act and lags about half as much (what
    is left, ≈ slope·dt/2, is the motor torque held over each step)."""
    slope = 10.0
    log = _still_session(sim_cfg, lambda t: slope * min(max(t - 1.0, 0.0), 2.0), 3.5, 3)
    late = (log.t >= log.t[0] + 2.2) & (log.t <= log.t[0] + 3.0)      # on the ramp, after the transient
    err = {}
    for name, cfg in (("walk", integrated(sim_cfg, 0.0, q_tau=3.0)), ("integrated", integrated(sim_cfg, 300.0))):
        est = AKF(cfg, dt=log.dt)
        assert est.d == (6 if name == "integrated" else 5)
        r = replay(log, est)
        err[name] = float(np.mean(np.abs(r.tau_h_act_hat[late, 0] - log.tau_h_act[late, 0])))
        if name == "integrated":
            assert abs(np.mean(r.x_hat[late, 5]) - slope) < 1.0      # τ̇_h,act estimated
    assert err["walk"] > slope * sim_cfg.dt                          # the walk's lag behind the ramp
    assert err["integrated"] < 0.6 * err["walk"]


def test_the_integrated_bound_covers_and_its_compiled_step_equals_the_python_one(sim_cfg):
    """A 1 Hz wearer of 1.5 N m amplitude (|τ̈_h,act| ≤ (2π)² 1.5 = 59 N m/s²) with a = 60 declared."""
    log = _still_session(sim_cfg, lambda t: 1.5 * math.sin(2 * math.pi * t), 6.0, 4)
    cfg = integrated(sim_cfg, 3000.0, accel=60.0)
    # the plant is the model: a small declared model error makes the plain AKF's estimate a valid one
    cfg = dataclasses.replace(cfg, estimator=dataclasses.replace(cfg.estimator, model_error=0.01))
    out = []
    for compiled in (True, False):
        est = AKF(cfg, dt=log.dt, bound=lambda a, c=compiled: AKFTheoremBound(a, compiled=c))
        assert est.bound.tau_h_act_rate == 60.0 and list(np.flatnonzero(est.bound._E_tau[:, 0])) == [5]
        out.append(replay(log, est))
    fast, py = out
    np.testing.assert_allclose(fast.tau_h_act_bound, py.tau_h_act_bound, rtol=1e-9, atol=1e-12)
    v = np.asarray(py.valid, bool).reshape(-1)
    assert v.mean() > 0.9
    e = np.abs(py.tau_h_act_hat[v, 0] - log.tau_h_act[v, 0])
    assert np.mean(e <= py.tau_h_act_bound[v, 0]) >= 0.95
    assert np.all(np.isfinite(py.tau_h_act_bound))


def test_the_frozen_integrated_gpakf_sample_in_compiled_calls_equals_the_python_step():
    """The one-joint affine model with a GP that learned one direction only (the direction gate):
    the compiled frozen sample and the Python step, bit for bit, in 6 states."""
    # local import: the fixtures' helpers of the compiled-path tests, used here on the integrated walk
    from tests.test_gpakf_compiled_paths import one_way_gp, run, same
    cfg = integrated(load_config(repo_root() / "configs" / "exo_1dof_sim.yaml"), 3000.0, accel=750.0)
    cfg = dataclasses.replace(cfg, estimator=dataclasses.replace(cfg.estimator, nis_scale=1e12))  # made-up motion
    t = np.arange(0.0, 5.0, cfg.dt)
    q = (0.7 + 0.4 * np.sin(0.8 * t))[:, None]
    th = q - 0.002 * np.sin(2.0 * t)[:, None]
    u = (0.5 * np.sin(1.3 * t))[:, None]
    gp = one_way_gp(1)
    fused, python = run(cfg, gp, (q, th, u), True), run(cfg, gp, (q, th, u), False)
    same(fused, python)
    assert fused[1].shape == (6,) and fused[-1] > 0          # 6 states; the gate acted


def test_the_calibration_scans_the_rate_walk_and_declares_the_acceleration(sim_cfg):
    # local import: the calibration is an application of the core filter tested here
    from sea_daemon.apps.calibration.pipeline import HumanSpec, sigma_nom_for
    from sea_daemon.apps.calibration.tau_model import declared_inputs, walk_scale
    human = HumanSpec((0.1, 3.0), 1.5)
    irw = integrated(sim_cfg, 1.0)
    assert walk_scale(sim_cfg, human) == 1.0
    assert walk_scale(irw, human) == pytest.approx((2 * math.pi * 3.0) ** 2)
    S = np.diag(sigma_nom_for(irw, 2.0)["Sigma_nom"])
    assert S.shape == (6,) and S[4] == 0.0 and S[5] == pytest.approx(2.0 * irw.dt)
    assert np.diag(sigma_nom_for(sim_cfg, 2.0)["Sigma_nom"]).shape == (5,)
    c = declared_inputs(irw, human).estimator
    assert c.tau_h_act_accel == pytest.approx((2 * math.pi * 3.0) ** 2 * math.sqrt(2) * 1.5)
    assert c.tau_h_act_rate == pytest.approx(2 * math.pi * 3.0 * math.sqrt(2) * 1.5)
    assert declared_inputs(sim_cfg, human).estimator.tau_h_act_accel == 0.0


def test_the_floor_of_the_integrated_bound_rests_on_the_declared_acceleration(sim_cfg):
    """The calibration's floor record: with the integrated walk and a declared a, the floor of the
    filter's own bound (lower than the rate's), and the line says the bound rests on it."""
    from sea_daemon.core.bounds.floor import bound_floor, floor_line, floor_record
    cfg = integrated(sim_cfg, 300.0, accel=750.0)
    cfg = dataclasses.replace(cfg, estimator=dataclasses.replace(cfg.estimator, tau_h_act_rate=40.0))
    rec = floor_record(cfg, (0.1, 3.0), 1.5)
    assert rec["integrated"] and rec["band_limited"]["tau_h_act_accel"] == 750.0
    assert rec["band_limited"]["rho"] == pytest.approx(list(bound_floor(cfg, accel=750.0).rho), rel=1e-3)  # 4 digits
    assert rec["band_limited"]["rho"][0] < rec["rho"][0]
    assert "its bound rests on |d2tau_h,act/dt2| <= 750" in floor_line(rec)
    walk = dataclasses.replace(sim_cfg, estimator=dataclasses.replace(sim_cfg.estimator, tau_h_act_rate=40.0))
    walk_line = floor_line(floor_record(walk, (0.1, 3.0), 1.5))
    assert "random walk" in walk_line and "tau_h_act_model: integrated" in walk_line   # where to turn


def test_the_frozen_integrated_gpakf_on_a_rigid_body_equals_the_python_step(arm):
    """The 2-DoF shoulder-elbow arm (a URDF's rigid body, Pinocchio between the compiled calls) with
    the integrated walk: 12 states, the compiled sample and the Python step bit for bit."""
    # local import: the helpers of the compiled-path tests, used here on the integrated walk
    from tests.test_gpakf_compiled_paths import run, same
    cfg, gp, test = arm
    cfg = integrated(cfg, 3000.0, accel=750.0)
    fused, python = run(cfg, gp, test, True), run(cfg, gp, test, False)
    same(fused, python)
    assert fused[1].shape == (12,) and np.all(np.isfinite(fused[0][1:]))


def test_settings_take_the_other_model_with_their_own_defaults_and_the_rest_kept(sim_cfg):
    """What `bench generalize --tau-model` gives the calibration: the model's Sigma_nom and P0, R kept."""
    e = sim_cfg.estimator
    assert e.with_tau_model("walk", 1) is e
    i = e.with_tau_model("integrated", 1)
    assert i.d == 6 and i.tau_h_act_model == "integrated" and np.array_equal(i.R, e.R)
    assert np.array_equal(i.P0[:4, :4], e.R) and i.Sigma_nom_dt == e.Sigma_nom_dt
    assert i.with_tau_model("walk", 1).d == 5
