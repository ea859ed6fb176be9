"""bench generalize scores the Theorem-1 bound of the estimator it is given (sea_daemon.apps.bench.generalize.score_replay)."""
import numpy as np

from sea_daemon.apps.bench.generalize import score_replay as _run
from sea_daemon.core.bounds.akf_bound import theorem_bound
from sea_daemon.core.config import ModelConfig
from sea_daemon.core.estimators import AKF
from sea_daemon.core.model import SEAModel

from synth import simulate


def test_run_scores_the_theorem_bound_of_the_estimator():
    cfg = ModelConfig.from_dict({"joints": 1, "rate_hz": 100, "model": {
        "M": 0.12, "J": 0.08, "D_m": 0.6, "K_s": 110.0, "D_s": 0.25, "gravity": 1.5}})
    log = simulate(SEAModel.from_config(cfg), T=1.0, tau_h=lambda t: np.array([0.3 * np.sin(3 * t)]), seed=1)
    out = _run(log, AKF(cfg, bound=theorem_bound), bound=True)
    assert "bound" in out, out
    b = out["bound"]
    assert 0.0 < b["mean_rho"] and np.isfinite(b["ratio"]) and b["saturated_share"] == 0.0
    # what it scores is the bound the estimator publishes (a second run of the same estimator)
    from sea_daemon.core.replay import replay
    rho = replay(log, AKF(cfg, bound=theorem_bound)).tau_h_act_bound
    assert b["mean_rho"] == float(np.mean(rho))
    assert "bound" not in _run(log, AKF(cfg), bound=False)
