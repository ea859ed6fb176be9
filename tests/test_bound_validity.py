"""valid = 1 only when the published bound is a real estimate (docs/estimators.md, "Validity"):
never for an estimator whose bound has no model-error term (a plain AKF without
estimator.model_error), never while a covariance sits at its cap, never above
estimator.bound_limit; the reason is counted in the summary."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from _paths import repo_root
from sea_daemon.core.estimators import make_estimator
from sea_daemon.core.estimators.validity import (ABOVE_LIMIT, COVARIANCE_CAP, NO_MODEL_ERROR_TERM, REASONS,
                                                 STARTUP)
from sea_daemon.core.replay import replay, summarize
from sea_daemon.errors import ConfigError
from sea_daemon.io.configfile import load_config
from sea_daemon.io.scenario import load_scenario
from sea_daemon.runtime.sim_runner import simulate

ROOT = repo_root()


@pytest.fixture(scope="module")
def passive():
    return simulate(load_scenario(ROOT / "configs" / "scenarios" / "passive.yaml"))


def _cfg(**est):
    cfg = load_config(ROOT / "configs" / "exo_1dof_sim.yaml")
    return dataclasses.replace(cfg, estimator=dataclasses.replace(cfg.estimator, **est))


def test_the_akf_is_valid_only_with_a_term_for_its_model_error(passive):
    log = passive.estimation.slice(0, 700)
    res = replay(log, make_estimator("akf", _cfg(), dt=log.dt))
    err = np.abs(res.tau_h_act_hat - res.tau_h_act)[:, 0]
    # its bound does not hold the model error it makes (the unmodelled arm and friction) ...
    assert np.mean(err[20:] > res.tau_h_act_bound[20:, 0]) > 0.5
    # ... so none of its estimates is valid, and the summary says why
    assert not res.valid.any()
    s = summarize(res)
    assert s["valid_samples"] == 0 and s["invalid_reasons"]["no_model_error_term"] > 0.9 * len(log)
    assert set(s["invalid_reasons"]) <= {"startup", "no_model_error_term"}
    # a declared bound on the model's torque error enters the Theorem-1 bound: valid, and it holds
    res2 = replay(log, make_estimator("akf", _cfg(model_error=6.0), dt=log.dt))
    v = res2.valid
    assert v[50:].all()
    err2 = np.abs(res2.tau_h_act_hat - res2.tau_h_act)[:, 0]
    assert np.mean(err2[v] <= res2.tau_h_act_bound[v, 0]) >= 0.95
    assert np.all(res2.tau_h_act_bound[v, 0] > res.tau_h_act_bound[v, 0])
    # the spring torque's bound has no such term either
    sp = replay(log, make_estimator("spring", _cfg(), dt=log.dt))
    assert not sp.valid.any() and set(sp.reason[10:]) == {NO_MODEL_ERROR_TERM}


def test_a_bound_at_the_covariance_cap_is_never_valid(passive):
    """A GP error bound far beyond anything physical (configured β 1e5) drives the set of means to
    the caps of bounded P, where it is held (no longer an outer set): never valid, reason
    covariance_cap (the start-up gate alone would open at once, ρ being far above its transient)."""
    cfg = _cfg(gp_beta=1e5)
    est = make_estimator("gp-akf", cfg, dt=cfg.dt, train=passive.training.slice(0, 600))
    log = passive.estimation.slice(0, 300)
    res = replay(log, est)
    assert est.bound.saturated_ > 0 and est.converged
    cap = np.sqrt(est.P_max[-1])
    assert res.tau_h_act_bound[:, 0].max() >= cap
    assert not res.valid.any()
    assert np.all(res.reason[res.tau_h_act_bound[:, 0] >= cap] == COVARIANCE_CAP)
    assert summarize(res)["invalid_reasons"]["covariance_cap"] > 0.9 * len(log)


def test_the_cap_transient_must_decay_before_the_estimate_is_valid_again():
    """After a capped step the estimate stays invalid until |Φ_k|_τ √(s P_max) ≤ 10 % of ρ_k."""
    from sea_daemon.core.estimators.validity import BoundValidity
    n, d = 1, 5
    H = np.hstack([np.eye(4), np.zeros((4, 1))])
    P_max = np.array([1.0, 1.0, 2500.0, 2500.0, 1e4])
    v = BoundValidity(n, H, 11.07, P_max, True, 10.0)
    P = np.eye(d) * 1e-4
    K = np.zeros((d, 4))
    F = np.eye(d) * 0.5                      # contracts by 2 per step
    rho = np.array([1.0])
    assert v.reason(P, True, K, F, rho, 1) == COVARIANCE_CAP
    got = [v.reason(P, False, K, F, rho, k) for k in range(2, 40)]
    first = got.index(0)
    # √(11.07 · 1e4) = 333 N m box, halved every step: ≤ 0.1 N m after 12 steps
    assert 10 <= first <= 13 and all(g == COVARIANCE_CAP for g in got[:first]) and not any(got[first:])
    # a variance of P at its cap counts as the set of means at its caps
    Pc = P.copy()
    Pc[4, 4] = 1e4
    assert v.reason(Pc, False, K, F, rho, 50) == COVARIANCE_CAP


def test_a_bound_above_the_usefulness_limit_is_not_valid(passive):
    log = passive.estimation.slice(0, 500)
    train = passive.training.slice(0, 600)
    est = make_estimator("gp-akf", _cfg(), dt=log.dt, train=train)
    res = replay(log, est)
    rho = res.tau_h_act_bound[:, 0]
    lim = float(np.median(rho[res.valid]))
    est2 = make_estimator("gp-akf", _cfg(bound_limit=lim), dt=log.dt, train=train)
    res2 = replay(log, est2)
    assert np.allclose(res2.tau_h_act_bound, res.tau_h_act_bound)        # the bound itself is unchanged
    above = res.valid & (rho > lim)
    assert above.sum() > 50
    assert not res2.valid[above].any() and np.all(res2.reason[above] == ABOVE_LIMIT)
    assert np.array_equal(res2.valid, res.valid & (rho <= lim))
    assert summarize(res2)["invalid_reasons"]["above_limit"] == int(above.sum())
    # the default limit is estimator.tau_h_act_max (hardware.torque_limit)
    assert est.validity.limit == est.tau_h_act_max == _cfg().hardware.torque_limit


def test_the_new_keys_are_checked():
    from sea_daemon.core.config import EstimatorConfig
    for key, bad in (("bound_limit", 0.0), ("bound_limit", 2e6), ("model_error", -1.0), ("model_error", "x")):
        with pytest.raises(ConfigError, match=key):
            EstimatorConfig.from_dict({key: bad}, 1, "<t>")
    c = EstimatorConfig.from_dict({"bound_limit": 2.0, "model_error": 0.5}, 1, "<t>")
    assert (c.bound_limit, c.model_error) == (2.0, 0.5)
    assert EstimatorConfig.from_dict(c.to_dict(), 1, "<t>").bound_limit == 2.0
    assert REASONS[STARTUP] == "startup"


def test_the_gp_error_is_held_as_long_in_seconds_at_every_rate():
    """The GP-AKF's residual variance enters Q as a torque error held over GP_HOLD_S, whatever
    Sigma_nom_dt says (a calibration at 1 kHz writes 1 ms): per second the filter believes the GP
    as much at 1 kHz as at 100 Hz (per cycle it believed it ten times more there, and at the
    standstills the set of means ran away to the caps)."""
    from sea_daemon.core.estimators.akf import AKF
    from sea_daemon.core.rates import at_rate
    GP_HOLD_S = 0.01
    cfg = _cfg(Sigma_nom_dt=0.001)
    per_second = {}
    for rate in (100.0, 1000.0):
        akf = AKF(at_rate(cfg, rate))
        assert akf._gp_var_scale == max(1.0, GP_HOLD_S * rate)
        # Γ_μ σ² Γ_μᵀ per step ≈ (dt/M)² σ² × scale; per second: × rate
        per_second[rate] = akf._gp_var_scale * akf.dt ** 2 * rate
    assert per_second[1000.0] == pytest.approx(per_second[100.0])
