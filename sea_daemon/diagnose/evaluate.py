"""The AKF's estimation error with the model before and after (contracts §4)."""
from __future__ import annotations

import numpy as np

from ..config import ModelConfig
from ..logio import MeasuredLog


def akf_estimates(log: MeasuredLog, cfg: ModelConfig) -> np.ndarray | None:
    """τ̂_h,act (N, n) of the AKF (Alg. 1) over the log with model ``cfg``; None without an AKF."""
    try:
        from ..estimators.akf import AKF
    except ImportError:  # the estimator is not installed in this build
        return None
    est = AKF(cfg, dt=log.dt)
    N, n = log.q.shape
    out = np.zeros((N, n))
    e = est.reset(log.q[0], log.theta_m[0], log.tau_m[0])
    out[0] = e.tau_h_act_hat
    for k in range(1, N):
        e = est.update(log.q[k], log.theta_m[k], log.tau_m[k], float(log.t[k] - log.t[k - 1]))
        out[k] = e.tau_h_act_hat
    return out


def estimate_rmse(log: MeasuredLog, cfg_before: ModelConfig, cfg_after: ModelConfig) -> dict:
    """RMS error [N m] of the AKF's τ̂_h,act against the log's tau_h_act (zero when absent)."""
    truth = log.tau_h_act if log.tau_h_act is not None else np.zeros_like(log.q)
    out = {}
    for key, c in (("before", cfg_before), ("after", cfg_after)):
        try:
            est = akf_estimates(log, c)
        except Exception:  # an estimator fault on this log: no estimate can be formed
            est = None
        if est is None or not np.all(np.isfinite(est)):
            out[key] = None
        else:
            out[key] = float(np.sqrt(np.mean((est - truth) ** 2)))
        out[f"{key}_series"] = est
    return out
