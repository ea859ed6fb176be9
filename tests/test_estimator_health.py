"""Estimator hygiene: NIS divergence, positive-definite P, bounded GP inputs (health.py)."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from sea_daemon.io.configfile import default_config_path, load_config
from sea_daemon.errors import fault_of
from sea_daemon.errors import Fault
from sea_daemon.errors import EstimatorFault
from sea_daemon.core.estimators.akf import AKF
from sea_daemon.core.estimators.gpakf import GPAKF
from sea_daemon.core.estimators.health import InputBox, NISMonitor, check_pd
from sea_daemon.core.model import SEAModel
from synth import simulate


@pytest.fixture(scope="module")
def cfg():
    return load_config(default_config_path())


@pytest.fixture(scope="module")
def healthy_log(cfg):
    # the filter's own model, 19-bit encoders, 20 s at 100 Hz, an active torque on top
    return simulate(SEAModel.from_config(cfg), T=20.0, seed=1,
                    tau_h=lambda t: np.array([1.0 * np.sin(2 * np.pi * 0.3 * t)]))


def run(est, log, corrupt=None):
    """Run over the log; returns (estimates (N,), the fault raised or None, its step)."""
    est.reset(log.q[0], log.theta_m[0], log.tau_m[0])
    out = []
    for k in range(1, len(log)):
        q, th = log.q[k].copy(), log.theta_m[k].copy()
        if corrupt is not None:
            q, th = corrupt(k, q, th)
        try:
            e = est.update(q, th, log.tau_m[k])
        except EstimatorFault as exc:
            return np.array(out), exc, k
        out.append(e.tau_h_act_hat[0])
        assert np.isfinite(e.x_hat).all() and np.isfinite(e.P).all()
    return np.array(out), None, None


def test_chi2_band_of_the_windowed_mean():
    mon = NISMonitor(dof=4, window=100, alpha=1e-3)
    # E[χ²_4] = 4; the band of the mean of 100 is about 4 ± 3.3·sqrt(8/100)
    assert mon.lower < 4 < mon.upper and mon.upper == pytest.approx(4 + 3.29 * np.sqrt(8 / 100), rel=0.05)
    rng = np.random.default_rng(0)
    inside = []
    for x in rng.chisquare(4, size=20000):
        mon.update(float(x))
        inside.append(mon.inside)
    assert np.mean(inside[100:]) > 0.99          # a consistent filter: inside the band


def test_healthy_filter_never_trips(cfg, healthy_log):
    est = AKF(cfg, dt=healthy_log.dt)
    out, exc, _ = run(est, healthy_log)
    assert exc is None and len(out) == len(healthy_log) - 1
    assert est.health.nis.mean < est.health.nis.threshold / 10


def test_healthy_gp_akf_learning_never_trips(cfg, healthy_log):
    est = GPAKF(cfg, dt=healthy_log.dt)
    _, exc, _ = run(est, healthy_log)
    assert exc is None and est.n_learned > 1000


def test_wrong_model_fed_an_unmodelled_jump_raises_nis_divergence_never_nan(cfg, healthy_log):
    # the spring 'breaks' in the data: θ_s reads 0.4 rad more from step 1000 on (a jump the
    # filter's model cannot explain: 44 N m of spring torque that no input produced)
    def jump(k, q, th):
        return (q + 0.4, th) if k >= 1000 else (q, th)
    est = AKF(cfg, dt=healthy_log.dt)
    out, exc, k = run(est, healthy_log, jump)
    assert exc is not None and "NIS divergence" in str(exc)
    assert fault_of(exc) is Fault.NIS_DIVERGENCE
    assert 1000 < k <= 1000 + est.health.nis.window + est.health.nis.sustain
    assert np.isfinite(out).all()


def test_covariance_not_pd_is_caught(cfg, healthy_log):
    est = AKF(cfg, dt=healthy_log.dt)

    def poison(k, q, th):
        if k == 50:
            est.P[4, 4] = -10.0                 # τ_h,act variance negative: P indefinite
        return q, th
    out, exc, k = run(est, healthy_log, poison)
    assert exc is not None and k == 50 and fault_of(exc) is Fault.COVARIANCE_NOT_PD, exc
    assert np.isfinite(out).all()
    with pytest.raises(EstimatorFault, match="not symmetric"):
        check_pd(np.array([[1.0, 0.5], [0.0, 1.0]]))


def test_nan_measurement_raises_nonfinite(cfg, healthy_log):
    est = AKF(cfg, dt=healthy_log.dt)
    _, exc, k = run(est, healthy_log, lambda k, q, th: (q * np.nan, th) if k == 30 else (q, th))
    assert k == 30 and fault_of(exc) is Fault.ESTIMATOR_NONFINITE


def test_health_settings_come_from_the_config(cfg):
    c = dataclasses.replace(cfg, estimator=dataclasses.replace(cfg.estimator, nis_window=20, nis_scale=2.0))
    est = AKF(c)
    assert est.health.nis.window == 20 and est.health.nis.threshold == pytest.approx(2 * est.health.nis.upper)


def test_gp_inputs_are_clipped_to_the_training_box(cfg, healthy_log):
    box = InputBox(3, margin=0.1)
    assert np.array_equal(box.clip(np.array([1.0, 2.0, 3.0])), [1.0, 2.0, 3.0])   # no data: nothing clipped
    box.add(np.array([0.0, -1.0, -10.0]))
    box.add(np.array([1.0, 1.0, 10.0]))
    z = box.clip(np.array([0.5, 1e3, np.nan]))
    assert z[0] == 0.5 and z[1] == pytest.approx(1.2) and z[2] == 0.0
    assert box.clipped.tolist() == [False, True, True]
    z = box.clip(np.array([np.inf, -np.inf, 3.0]))
    assert z.tolist() == [1.1, -1.2, 3.0] and box.clipped.tolist() == [True, True, False]
    box.add(np.array([np.nan, 5.0, 0.0]))                      # non-finite training input: ignored
    assert box.lo_.tolist() == [0.0, -1.0, -10.0] and box.hi_.tolist() == [1.0, 1.0, 10.0]
    empty = InputBox(2)
    assert empty.clip(np.array([np.nan, np.inf])).tolist() == [0.0, 1e6] and empty.clipped.all()
    # in the GP-AKF: a velocity spike far outside what was learned gives finite, bounded μ, σ²
    est = GPAKF(cfg, dt=healthy_log.dt)
    run(est, healthy_log)
    hook = est.residual
    mu_in, _, var_in = (a.copy() for a in hook.predict(np.array([0.3, 0.0, 0.0])))
    mu, jac, var = hook.predict(np.array([0.3, 1e4, -1e5]))
    assert np.isfinite(mu).all() and np.isfinite(var).all() and jac[0, 1] == 0 and jac[0, 2] == 0
    assert hook.box.clipped[1] and hook.box.clipped[2]
    assert abs(mu[0]) < 10 * (abs(mu_in[0]) + np.sqrt(var_in[0]) + 1)
