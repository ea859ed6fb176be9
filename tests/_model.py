"""A model file without a calibration run: a small residual GP fitted to seeded random points."""
from __future__ import annotations

from pathlib import Path

import numpy as np


def small_model(cfg, path: Path, residual: float = 0.0, points: int = 30):
    """Write a model file for ``cfg`` at ``path``: a residual GP (no hyperparameter search) of
    ``points`` seeded random inputs, each with the residual ``residual``; returns the GP."""
    # local import: the learning module loads numba's kernels, only for the tests that need a model
    from sea_daemon.core.learning import ResidualGP
    from sea_daemon.io.gpmodel import save_gp_model
    res = ResidualGP(1, cfg.learning, hyperopt=False)
    rng = np.random.default_rng(0)
    for _ in range(points):
        res.update(rng.uniform(-1, 1, 3), np.array([residual]))
    save_gp_model(path, cfg, res, {"test": True})
    return res
