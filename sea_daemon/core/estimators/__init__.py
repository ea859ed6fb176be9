"""Estimators of the active human torque τ_h,act (pure: no I/O, clock or threads).

* :class:`~sea_daemon.core.estimators.akf.AKF` — augmented-state EKF of Park et al. (Alg. 1),
  with a hook for a learned residual f(z) that turns it into the GP-AKF (Alg. 2).
* :class:`~sea_daemon.core.estimators.spring.SpringTorqueEstimator` — τ̂_h,act = τ_s(θ_s, θ̇_s).

All follow :class:`~sea_daemon.core.estimators.base.Estimator`; :func:`make_estimator` builds
one by name.
"""
from __future__ import annotations

from sea_daemon.core.estimators.akf import AKF
from sea_daemon.core.estimators.base import Estimate, Estimator, Residual
from sea_daemon.core.estimators.spring import SpringTorqueEstimator

#: names accepted by :func:`make_estimator` (gp-akf needs a learned residual; see
#: :func:`make_estimator`)
NAMES = ("akf", "spring")


def make_estimator(name: str, cfg, dt: float | None = None, residual=None,
                   theorem_bound: bool = True) -> Estimator:
    """Build the estimator ``name`` ('akf', 'spring') for configuration ``cfg``.

    ``theorem_bound``: the AKF publishes the Theorem-1 bound ρ_k as ``tau_h_act_bound``
    (:func:`sea_daemon.core.bounds.akf_bound.attach_default_bound`).
    """
    if name == "akf":
        akf = AKF(cfg, dt=dt, residual=residual)
        if theorem_bound:
            from sea_daemon.core.bounds.akf_bound import attach_default_bound
            attach_default_bound(akf)
        return akf
    if name == "spring":
        return SpringTorqueEstimator(cfg, dt=dt)
    raise ValueError(f"unknown estimator {name!r}; allowed: {', '.join(NAMES)}")


__all__ = ["AKF", "Estimate", "Estimator", "Residual", "SpringTorqueEstimator", "make_estimator", "NAMES"]
