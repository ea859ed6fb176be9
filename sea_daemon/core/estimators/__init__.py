"""Estimators of the active human torque τ_h,act (pure: no I/O, clock or threads).

* :class:`~sea_daemon.core.estimators.akf.AKF` — augmented-state EKF of Park et al. (Alg. 1),
  with a hook for a learned residual f(z) that turns it into the GP-AKF (Alg. 2).
* :class:`~sea_daemon.core.estimators.gpakf.GPAKF` — the AKF with a per-joint LoG-GP residual
  learned online (Alg. 2).
* :class:`~sea_daemon.core.estimators.spring.SpringTorqueEstimator` — τ̂_h,act = τ_s(θ_s, θ̇_s).

All follow :class:`~sea_daemon.core.estimators.base.Estimator`; the AKFs take an optional
:class:`~sea_daemon.core.estimators.base.Bound` component (the Theorem-1 ρ_k by default).
:func:`~sea_daemon.core.estimators.factory.make_estimator` builds every one of them by name.
"""
from __future__ import annotations

from sea_daemon.core.estimators.akf import AKF
from sea_daemon.core.estimators.base import Bound, Estimate, Estimator, Residual
from sea_daemon.core.estimators.factory import NAMES, make_estimator
from sea_daemon.core.estimators.gpakf import GPAKF
from sea_daemon.core.estimators.spring import SpringTorqueEstimator

__all__ = ["AKF", "GPAKF", "Bound", "Estimate", "Estimator", "Residual", "SpringTorqueEstimator",
           "make_estimator", "NAMES"]
