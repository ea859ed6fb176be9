"""The AKF's estimation error with the model before and after (docs/interfaces.md §4)."""
from __future__ import annotations

import numpy as np

from sea_daemon.core.config import ModelConfig
from sea_daemon.errors import EstimatorFault
from sea_daemon.core.estimators import make_estimator
from sea_daemon.core.log import MeasuredLog
from sea_daemon.core.replay import replay


def akf_estimates(log: MeasuredLog, cfg: ModelConfig) -> np.ndarray:
    """τ̂_h,act (N, n) of the AKF (Alg. 1) run over the log with model ``cfg``."""
    # only the estimate is used: no Theorem-1 bound (it costs time with declared effects)
    return replay(log, make_estimator("akf", cfg, dt=log.dt, bound=False)).tau_h_act_hat


def estimate_rmse(log: MeasuredLog, cfg_before: ModelConfig, cfg_after: ModelConfig | None) -> dict:
    """RMS error [N m] of the AKF's τ̂_h,act against the log's tau_h_act (zero when absent).

    ``cfg_after`` None: the model is unchanged, after = before.  ``None`` values for a model
    whose filter faults on this log (no estimate can be formed)."""
    truth = log.tau_h_act if log.tau_h_act is not None else np.zeros_like(log.q)
    out: dict = {}
    for key, c in (("before", cfg_before), ("after", cfg_after)):
        if c is None:
            out[key], out[f"{key}_series"] = out["before"], out["before_series"]
            continue
        try:
            est = akf_estimates(log, c)
        except (EstimatorFault, np.linalg.LinAlgError, FloatingPointError):
            est = None
        if est is None or not np.all(np.isfinite(est)):
            out[key], out[f"{key}_series"] = None, None
        else:
            out[key] = float(np.sqrt(np.mean((est - truth) ** 2)))
            out[f"{key}_series"] = est
    return out
