"""Spring-torque estimate of the interaction torque: τ̂_h,act = τ_s(θ_s, θ̇_s) (eq:spring_torque).

The usual "SEA as a torque sensor" baseline of the paper (Sec. V-B, Table I/II): it ignores
the load-side dynamics M q̈ + C(q) + f(z) of eq:unknwn_load.  θ_s = q − θ_m from the encoders
(declared offsets removed), θ̇_s from the same causal differentiator as the AKF; the
nominal spring model (with declared spring effects) from :class:`SEAModel`.

Uncertainty: the measurement noise R propagated to first order,
σ² = J_y R J_yᵀ with J_y = ∂τ_s/∂y = [0, ∂τ_s/∂θ_s, 0, D_s] for y = [θ_m, θ_s, θ̇_m, θ̇_s];
bound = sqrt(χ²_{1−δ}(1))·σ per joint (a Gaussian confidence interval; no model error is
accounted for, so it is not a guarantee).
"""
from __future__ import annotations

import math

import numpy as np

from sea_daemon.core.config import ModelConfig
from sea_daemon.core.jit import warm_up
from sea_daemon.core.kinematics import CausalDifferentiator
from sea_daemon.core.model import SEAModel
from sea_daemon.core.bounds.ellipsoid import chi2_quantile
from sea_daemon.core.estimators.validity import NO_MODEL_ERROR_TERM, STARTUP
from sea_daemon.core.estimators.base import Estimate


class SpringTorqueEstimator:
    """τ̂_h,act = τ_s(θ_s, θ̇_s) with the nominal spring model; see module docstring."""

    name = "spring"

    def __init__(self, cfg: ModelConfig, dt: float | None = None, model: SEAModel | None = None):
        self.cfg = cfg
        self.model = model if model is not None else SEAModel.from_config(cfg)
        n = self.n = self.model.n
        self.dt = float(dt) if dt else cfg.dt
        self.R = np.array(cfg.estimator.R, dtype=float)
        # eq:gaussianellipsoid with one degree of freedom: s = χ²_1(1 − δ)
        self.s = chi2_quantile(1.0 - cfg.estimator.delta, 1)
        kin = cfg.kinematics
        self.kin = CausalDifferentiator(self.dt, kin.window, 2 * n, kin.method, kin.degree)
        self._ang = np.zeros(2 * n)
        self._Jy = np.zeros((n, 4 * n))
        self._Jy[:, 3 * n:] = self.model.D_s
        self.est = Estimate.zeros(n)
        self._ready = False
        warm_up()            # the compiled differentiator ready before the first sample

    def reset(self, q=None, theta_m=None, tau_m=None) -> Estimate:
        """Restart the differentiator at this sample (``reset()``: at the next update)."""
        self.kin.forget()
        if q is None or theta_m is None:
            self._ready = False
            self.est.k = 0
            return self.est
        self._ready = True
        self.est.k = -1
        return self.update(q, theta_m, tau_m)

    def update(self, q, theta_m, tau_m=None, dt: float | None = None) -> Estimate:
        if not self._ready:
            return self.reset(q, theta_m, tau_m)
        n = self.n
        qc, thc = self.model.correct_measurement(np.asarray(q, dtype=float), np.asarray(theta_m, dtype=float))
        self._ang[:n] = qc
        self._ang[n:] = thc
        ang, vel, _ = self.kin.update(self._ang)
        th_m, dth_m = ang[n:], vel[n:]
        # θ_s = q − θ_m
        th_s = ang[:n] - th_m
        dth_s = vel[:n] - dth_m
        # eq:spring_torque
        tau_s = self.model.spring_torque(th_s, dth_s)
        e = self.est
        e.tau_h_act_hat[:] = tau_s
        # σ² = J_y R J_yᵀ (first-order propagation of the measurement noise)
        self._Jy[:, n:2 * n] = self.model.spring_torque_jac(th_s)
        cov = self._Jy @ self.R @ self._Jy.T
        np.sqrt(np.maximum(np.diagonal(cov), 0.0), out=e.tau_h_act_sigma)
        np.multiply(e.tau_h_act_sigma, math.sqrt(self.s), out=e.tau_h_act_bound)
        x = e.x_hat
        x[:n] = th_m
        x[n:2 * n] = th_s
        x[2 * n:3 * n] = dth_m
        x[3 * n:4 * n] = dth_s
        x[4 * n:] = tau_s
        e.P[:4 * n, :4 * n] = self.R
        e.P[4 * n:, 4 * n:] = cov
        e.k += 1
        # never valid: τ_s is the spring torque, and its bound (the sensors' noise through the spring)
        # has no term for everything else that acts on the load (friction, gravity, inertia)
        e.valid = False
        e.invalid_reason = STARTUP if e.k < self.kin.L - 1 else NO_MODEL_ERROR_TERM
        return e
