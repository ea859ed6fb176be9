"""The calibrated model's weighted residual hook linearises the GP as the GP-AKF does.

:class:`~sea_daemon.core.estimators.weighted.WeightedResidual` weights the GP's mean and
Jacobian by w(z); the Jacobian it weights is the GP-AKF's own (the experts' Σ ω_i ∂μ_i/∂z, on
the Python path and the compiled path of a frozen GP), not the merged mean's exact derivative,
whose routing ramp between two leaves that disagree is a slope of the tree (docs/learning.md).
Seeded: the two-leaf residual GP of ``test_gpakf`` (leaves 2 N m apart across q̇ = 0).
"""
from __future__ import annotations

import numpy as np
import pytest

from sea_daemon.core.estimators.gpakf import GPAKF
from sea_daemon.core.estimators.weighted import WeightedResidual
from sea_daemon.io.configfile import load_config

from test_gpakf import SETTINGS, _disagreeing_experts

#: inputs in the split's overlap (q̇ near 0) and beside it
POINTS = [np.array([0.5, v, 0.02]) for v in (0.0, 3e-4, -5e-4, 0.05, -0.1)]


@pytest.mark.parametrize("overlap", [0.01, 0.1])
def test_weighted_hook_takes_the_gp_akfs_jacobian(overlap):
    res = _disagreeing_experts(overlap)
    g = res.gps[0]
    cfg = load_config(SETTINGS)
    plain = GPAKF(cfg, residual=res, learning=False).residual
    # p = 0: w = 1 wherever the direction gate lets the GP act, so the weighted hook's Jacobian
    # is the one it weights
    full = WeightedResidual(res, cfg.estimator.gp_input_margin, False, power=0.0)
    weighted = WeightedResidual(res, cfg.estimator.gp_input_margin, False, power=2.0)
    ramp = 0
    for z in POINTS:
        _, J_full, _ = full.predict(z)
        plain.freeze(None)                       # the Python path
        _, J_py, _ = plain.predict(z)
        assert np.allclose(J_full, J_py, rtol=0, atol=1e-12), (z, J_full, J_py)
        plain.freeze(1)                          # the compiled path of the frozen GP
        _, J_jit, _ = plain.predict(z)
        assert np.allclose(J_full, J_jit, rtol=0, atol=1e-12), (z, J_full, J_jit)
        _, J_w, _ = weighted.predict(z)
        assert np.allclose(J_w, weighted.w[0] * J_py, rtol=0, atol=1e-12)
        # where the merged mean's exact derivative carries the ramp, the hook does not
        exact = g.predict_with_grad(np.ascontiguousarray(plain.box.clip(z)))[2]
        if abs(exact[1]) > 4.0 / overlap:
            ramp += 1
            assert abs(J_full[0, 1]) < 1.0, (z, J_full)
    assert ramp                                  # some point lies in the ramp
