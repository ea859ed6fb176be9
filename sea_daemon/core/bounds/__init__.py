"""Guaranteed error bounds of the GP-AKF (paper Sec. IV-C, Theorem 1).

* :mod:`.ellipsoid`  — ellipsoids, affine maps, trace-minimal Minkowski-sum outer approximation,
  interval → ellipsoid (lem:interval_bound, eq:GPboundsellipse).
* :mod:`.gp_bound`   — the GP uniform error bound |f − μ| ≤ √β σ + γ (eq:gpmeanbounds;
  Lederer, Umlauft & Hirche 2019) for the SE kernel and the merged LoG-GP prediction.
* :mod:`.setmember`  — the set-membership propagation of Theorem 1 (Noack et al. 2010) and
  the bound ρ_k on τ_h,act.

Derivations: docs/bounds.md.
"""
from sea_daemon.core.bounds.ellipsoid import (
    Ellipsoid, box_shape, chi2_quantile, interval_ellipsoid, minkowski_half_width, minkowski_shape, minkowski_sum,
    segments_shapes, sqrtm_psd)

__all__ = ["Ellipsoid", "box_shape", "chi2_quantile", "interval_ellipsoid", "minkowski_half_width", "minkowski_shape",
           "minkowski_sum", "segments_shapes", "sqrtm_psd"]
