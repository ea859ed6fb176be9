"""The estimators on a calibrated model (:func:`sea_daemon.apps.calibration.pipeline.calibrate`).

* ``gp-akf``: :class:`CalibratedGPAKF` — the GP-AKF (Alg. 2) on the augmented physical model
  with the residual GP behind :class:`~sea_daemon.core.estimators.weighted.WeightedResidual` (its mean and Jacobian
  weighted by how much its variance has shrunk), learning off; the plain AKF when the
  calibration did not keep a GP;
* ``akf``: the AKF (Alg. 1) on the augmented model.

Both flag, per step, whether z = [q, q̇, q̈] lies in the region the calibration data covered
(:class:`~sea_daemon.core.excitation.Coverage`): ``z_outside`` (this step), ``n_outside`` (count since reset).
Off that region the model is less accurate (its effects extrapolated, the GP's weight gone to
zero): the step after a sample outside it predicts with the τ_h,act random walk at least
``estimator.tau_h_act_walk_outside`` when that is set (default 0: off; the calibration leaves it
as configured, docs/calibration.md), so the filter books the load side's larger model error
there as a faster-changing τ_h,act (a motor-side or spring error, which τ_h,act does not enter,
still ends in the NIS-divergence fault).
"""
from __future__ import annotations

import numpy as np

from sea_daemon.core.estimators.akf import AKF
from sea_daemon.core.estimators.gpakf import GPAKF
from sea_daemon.core.estimators.weighted import WeightedResidual


class _CoverageFlag:
    """Mixin (before the estimator in the bases): the coverage flag after every update."""

    def reset(self, *a, **k):
        self.n_outside = 0
        return super().reset(*a, **k)

    def update(self, q, theta_m, tau_m, dt=None):
        e = super().update(q, theta_m, tau_m, dt)
        self._flag()
        return e

    def _init_flag(self, coverage):
        self.coverage = coverage
        self.z_outside = False
        self.n_outside = 0
        self._zc = np.zeros(3 * self.n)
        # [N² m²/s] the τ_h,act walk off the covered region (0: none); Σ_nom is then filled every step
        self._q_out = float(self.cfg.estimator.tau_h_act_walk_outside) if coverage is not None else 0.0
        if self._q_out > 0:
            self._S_varies = True

    def fill_sigma_nom(self, dt):
        S = super().fill_sigma_nom(dt)
        if self._q_out > 0 and self.z_outside:
            # the τ_h,act block of Σ_nom,k (eq:unknown's random walk) at least q_out·dt off the data
            n = self.n
            for i in range(4 * n, 5 * n):
                S[i, i] = max(S[i, i], self._q_out * dt)
        return S

    def _flag(self):
        if self.coverage is None:
            return
        n = self.n
        # z of this sample from the state estimate and the measured q̈ (as the GP sees it)
        # (per joint j: z_j, n + j, 2n + j; a one-joint coverage reads the first three)
        for j in range(n):
            self._zc[j] = self.x[j] + self.x[n + j]
            self._zc[n + j] = self.x[2 * n + j] + self.x[3 * n + j]
            self._zc[2 * n + j] = self._ddq[j]
        self.z_outside = not self.coverage.covered(self._zc)
        self.n_outside += int(self.z_outside)


class CalibratedAKF(_CoverageFlag, AKF):
    name = "akf"

    def __init__(self, cfg, dt=None, coverage=None, bound=None):
        super().__init__(cfg, dt=dt, bound=bound)
        self._init_flag(coverage)


class CalibratedGPAKF(_CoverageFlag, GPAKF):
    name = "gp-akf"

    def __init__(self, cfg, gp, dt=None, coverage=None, power: float = 2.0, v_gate: float = 0.0, bound=None,
                 var_ref: float = 0.0):
        super().__init__(cfg, dt=dt, residual=gp, learning=False)
        # alg:torqueresidualAKF line 5 through the variance-weighted hook
        self.residual = WeightedResidual(gp, cfg.estimator.gp_input_margin, cfg.estimator.gp_noise_in_Q,
                                         power=power, M=self.model.M, dt=self.dt, v_gate=v_gate,
                                         var_ref=var_ref)
        self._init_flag(coverage)
        # the bound is built on the weighted hook (AKF builds it at the end of its constructor)
        if bound is not None:
            self.bound = bound(self)


def make_calibrated(cfg, gp, coverage, dt=None, kind: str = "gp-akf", power: float = 2.0, v_gate: float = 0.0,
                    bound=None, var_ref: float = 0.0):
    """The estimator ``kind`` on a calibrated model: 'gp-akf' (:class:`CalibratedGPAKF`; the
    AKF when ``gp`` is None) or 'akf' (:class:`CalibratedAKF`, physics alone).  ``bound``: a
    bound factory as :class:`~sea_daemon.core.estimators.akf.AKF` takes; ``v_gate``, ``var_ref``: the
    weighted hook's (:class:`~sea_daemon.core.estimators.weighted.WeightedResidual`)."""
    if kind == "gp-akf" and gp is not None:
        return CalibratedGPAKF(cfg, gp, dt=dt, coverage=coverage, power=power, v_gate=v_gate, bound=bound,
                               var_ref=var_ref)
    return CalibratedAKF(cfg, dt=dt, coverage=coverage, bound=bound)
