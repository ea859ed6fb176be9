"""The one way to build an estimator: :func:`make_estimator`."""
from __future__ import annotations

from typing import Callable

from sea_daemon.core.bounds.akf_bound import theorem_bound
from sea_daemon.core.config import ModelConfig
from sea_daemon.core.estimators.akf import AKF
from sea_daemon.core.estimators.base import Estimator
from sea_daemon.core.estimators.gpakf import GPAKF, learn_from_log
from sea_daemon.core.estimators.spring import SpringTorqueEstimator
from sea_daemon.core.log import MeasuredLog
from sea_daemon.errors import InputError, shown

#: names accepted by :func:`make_estimator`
NAMES = ("akf", "spring", "gp-akf")
#: the largest relative difference of two sample periods that count as one rate
RATE_TOLERANCE = 0.01


def make_estimator(name: str, cfg: ModelConfig, dt: float | None = None, *, residual=None,
                   train: MeasuredLog | None = None, learning: bool | None = None,
                   bound: bool | Callable = True) -> Estimator:
    """Build the estimator ``name`` for the configuration ``cfg`` (``dt``: its nominal period,
    default ``1/cfg.rate_hz``; for 'gp-akf' with ``train``, default the log's).

    * 'akf' — :class:`AKF` (Alg. 1); ``residual``: a learned f(z) hook (Alg. 2 with a
      residual of one's own).
    * 'spring' — :class:`SpringTorqueEstimator` (its bound is its own Gaussian interval).
    * 'gp-akf' — :class:`GPAKF` (Alg. 2): ``residual`` a
      :class:`~sea_daemon.core.learning.ResidualGP` (default: a new one from ``cfg.learning``);
      ``train`` a passive-subject log learned first, sample by sample (the paper's training
      phase); ``learning``: whether it keeps learning afterwards (default: on without
      ``train``, off after it).

    ``bound``: True — ``tau_h_act_bound`` is the Theorem-1 ρ_k
    (:func:`~sea_daemon.core.bounds.akf_bound.theorem_bound`); False — the filter's own χ²
    bound sqrt(s P_ττ); or a bound factory ``bound(akf) -> Bound`` (e.g.
    ``functools.partial(AKFTheoremBound, gp_beta=...)``).
    """
    factory = theorem_bound if bound is True else (bound or None)
    if name == "akf":
        return AKF(cfg, dt=dt, residual=residual, bound=factory)
    if name == "spring":
        return SpringTorqueEstimator(cfg, dt=dt)
    if name == "gp-akf":
        if train is not None:
            if train.n != cfg.joints:
                raise InputError(f"training log {train.path}: {train.n} joint(s), the configuration has "
                                 f"{cfg.joints}")
            if dt and abs(train.dt - dt) > RATE_TOLERANCE * dt:
                # the pairs the GP learns come from the differentiator at the filter's rate: a
                # training log at another rate teaches it other velocities and accelerations
                raise InputError(f"training log {shown(train.path)}: sample period {train.dt:.6g} s "
                                 f"({1 / train.dt:.4g} Hz), the estimation runs at {dt:.6g} s ({1 / dt:.4g} Hz); "
                                 f"allowed within {100 * RATE_TOLERANCE:g} % (record both at one rate)")
            dt = dt if dt else train.dt
        est = GPAKF(cfg, dt=dt, residual=residual, learning=train is None, bound=factory)
        if train is not None:
            learn_from_log(est, train)
            est.learning = False
        if learning is not None:
            est.learning = bool(learning)
        return est
    raise ValueError(f"unknown estimator {name!r}; allowed: {', '.join(NAMES)}")
