"""The estimators' error with the model before and after, per time block.

The AKF is run over the whole log with each model (a filter needs its history); its error is
then scored over the whole log and over the blocks of a held-out validation.  The run is an
offline evaluation, not a control loop: the NIS divergence monitor, which would stop the
filter on exactly the poor models a diagnosis is about, is relaxed to catching a runaway
(:data:`EVAL_NIS_SCALE`), and the mean NIS is reported instead — how far the innovations
exceed what the filter's noise model expects, a consistency measure that needs no torque
truth.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from sea_daemon.core.config import ModelConfig
from sea_daemon.errors import EstimatorFault
from sea_daemon.core.estimators import make_estimator
from sea_daemon.core.estimators.gpakf import learn_from_log
from sea_daemon.core.log import MeasuredLog
from sea_daemon.core.replay import replay

#: NIS-divergence scale of the evaluation runs (the configured one stops a filter whose NIS
#: mean exceeds nis_scale × the χ² band; here only a runaway)
EVAL_NIS_SCALE = 1e8


def _eval_cfg(cfg: ModelConfig) -> ModelConfig:
    est = dataclasses.replace(cfg.estimator, nis_scale=max(cfg.estimator.nis_scale, EVAL_NIS_SCALE))
    return dataclasses.replace(cfg, estimator=est)


class _NISRecorder:
    """Wraps an estimator and keeps each update's NIS."""

    def __init__(self, est):
        self.est = est
        self.nis: list[float] = []
        self.name = getattr(est, "name", "akf")

    def reset(self, *a, **k):
        return self.est.reset(*a, **k)

    def update(self, *a, **k):
        e = self.est.update(*a, **k)
        self.nis.append(float(getattr(self.est, "nis", np.nan)))
        return e


def _spans(log: MeasuredLog, spans) -> list[tuple[int, int]]:
    return list(spans) if spans else [(0, len(log))]


def akf_run(log: MeasuredLog, cfg: ModelConfig, bound: bool = False, spans=None) -> dict:
    """The AKF (Alg. 1) over the log: τ̂_h,act (N, n), its bound (with ``bound``: Theorem 1),
    and the NIS per step.  ``spans``: (start, stop) segments of a joined long log
    (:func:`.prepare.segment_log`), each run from its own first sample."""
    est = make_estimator("akf", _eval_cfg(cfg), dt=log.dt, bound=bound)
    rec = _NISRecorder(est)
    hat, bnd = [], []
    for a, b in _spans(log, spans):
        res = replay(log.slice(a, b), rec)
        hat.append(res.tau_h_act_hat)
        bnd.append(res.tau_h_act_bound)
    return {"hat": np.concatenate(hat), "bound": np.concatenate(bnd), "nis": np.asarray(rec.nis)}


def akf_estimates(log: MeasuredLog, cfg: ModelConfig) -> np.ndarray:
    """τ̂_h,act (N, n) of the AKF (Alg. 1) run over the log with model ``cfg``."""
    return akf_run(log, cfg)["hat"]


def _rmse(err: np.ndarray, mask: np.ndarray | None) -> float:
    e = err if mask is None else err[mask]
    return float(np.sqrt(np.mean(e**2))) if e.size else float("nan")


def estimate_rmse(log: MeasuredLog, cfg_before: ModelConfig, cfg_after,
                  blocks: dict[str, np.ndarray] | None = None, spans=None,
                  score: np.ndarray | None = None) -> dict:
    """RMS error [N m] of the AKF's τ̂_h,act against the log's tau_h_act (zero when absent).

    ``cfg_after`` None: the model is unchanged, after = before; a dict name → config (or None)
    scores several models (keys ``after`` and others).  ``None`` values for a model whose
    filter faults on this log (no estimate can be formed).  ``blocks``: name → (N,) mask;
    adds ``{block}_{model}`` over each block, and the mean NIS (``nis_{model}``).  ``spans``:
    the segments of a joined long log (each run separately); ``score``: (N,) mask of the
    samples scored (default all)."""
    truth = log.tau_h_act if log.tau_h_act is not None else np.zeros_like(log.q)
    blocks = blocks or {}
    after = cfg_after if isinstance(cfg_after, dict) else {"after": cfg_after}
    out: dict = {}
    for key, c in [("before", cfg_before)] + list(after.items()):
        if c is None:
            for k in [key, f"{key}_series", f"nis_{key}"] + [f"{b}_{key}" for b in blocks]:
                out[k] = out[k.replace(key, "before")]
            continue
        try:
            run = akf_run(log, c, spans=spans)
            est = run["hat"]
        except (EstimatorFault, np.linalg.LinAlgError, FloatingPointError):
            est, run = None, None
        if est is None or not np.all(np.isfinite(est)):
            out[key], out[f"{key}_series"], out[f"nis_{key}"] = None, None, None
            for b in blocks:
                out[f"{b}_{key}"] = None
        else:
            out[key] = _rmse(est - truth, score)
            out[f"{key}_series"] = est
            out[f"nis_{key}"] = float(np.mean(run["nis"])) if run["nis"].size else None
            for b, m in blocks.items():
                out[f"{b}_{key}"] = _rmse(est - truth, m)
    return out


def gpakf_rmse(log: MeasuredLog, cfgs: dict, train_mask: np.ndarray, blocks: dict[str, np.ndarray],
               spans=None) -> dict:
    """GP-AKF (Alg. 2) per model: the residual learned on the samples of ``train_mask`` (a
    leading block, passive subject; of each segment of a joined long log, ``spans``), then
    frozen and run over the whole log; RMS error of τ̂_h,act against the log's truth (0 when
    absent) per block.  {model: {block: rmse}}."""
    truth = log.tau_h_act if log.tau_h_act is not None else np.zeros_like(log.q)
    train = []
    for a, b in _spans(log, spans):
        idx = np.flatnonzero(train_mask[a:b])
        if idx.size > 1:
            train.append(log.slice(a, a + int(idx[-1]) + 1))
    out: dict = {}
    for key, c in cfgs.items():
        if c is None:
            continue
        try:
            est = make_estimator("gp-akf", _eval_cfg(c), dt=log.dt, bound=False)
            for tr in train:
                learn_from_log(est, tr)
            est.learning = False
            hat = np.concatenate([replay(log.slice(a, b), est).tau_h_act_hat for a, b in _spans(log, spans)])
        except (EstimatorFault, np.linalg.LinAlgError, FloatingPointError):
            out[key] = None
            continue
        out[key] = {b: _rmse(hat - truth, m) for b, m in blocks.items()} if np.all(np.isfinite(hat)) else None
    return out
