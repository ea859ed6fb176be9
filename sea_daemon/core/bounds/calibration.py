"""GP error constants of a trained GP-AKF for its Theorem-1 bound (docs/bounds.md §2).

* :func:`gp_constants` — LUH19 constants (eq:gpmeanbounds) per joint from the LoG-GPs' leaves,
  or a configured β;
* :func:`conformal_scores`, :func:`conformal_gp_constants` — split-conformal β of the GP error
  from a held-out passive-subject log.

The β calibrated on the torque error itself is :mod:`sea_daemon.core.bounds.torque_beta`.
Pure numerics: no I/O, no clock, no threads.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from sea_daemon.core.bounds.gp_bound import (
    LocalScale, conformal_constants, error_bound, fixed_constants, input_box, loggp_leaves)


def residual_gps(akf) -> list | None:
    """The per-joint LoG-GPs behind an AKF's residual: a ResidualGP (``.gps``), a hook over
    one (``.gp.gps``, the GP-AKF's), or the estimator's own ``.gp``; None if unknown."""
    for obj in (akf.residual, getattr(akf.residual, "gp", None), getattr(akf, "gp", None)):
        if obj is not None and hasattr(obj, "gps"):
            return list(obj.gps)
    return None


def union_leaves(gp, growth: int | None = None) -> int:
    """L of the union bound over a LoG-GP's leaves (docs/bounds.md §2): every leaf that can make
    a prediction while the constants are used.  ``growth`` None: the tree's ``max_leaves`` cap
    (valid however long it keeps learning; at least the leaves it has); a number: the leaves it has
    plus ``growth``, capped — each training pair splits at most one leaf, so ``growth`` is the
    number of pairs it may learn before the constants are made again (0: a frozen GP)."""
    have = int(getattr(gp, "n_leaves", 0) or len(gp.leaves()))
    cap = int(getattr(gp, "max_leaves", 0) or 0)
    if growth is None:
        return max(have, cap)
    if isinstance(growth, bool) or not isinstance(growth, (int, np.integer)) or growth < 0:
        raise ValueError(f"growth must be an integer >= 0 (training pairs), got {growth!r}")
    return have + int(growth) if cap <= 0 else max(have, min(cap, have + int(growth)))


def _gps(residual) -> list:
    """The LoG-GPs of a ResidualGP, or the list given."""
    return list(residual) if isinstance(residual, (list, tuple)) else residual.gps


def training_box(gps, box_margin: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi): the box of every training input of ``gps`` widened by ``box_margin`` of its range
    (:func:`~sea_daemon.core.bounds.gp_bound.input_box`), the box the GP constants are stated on."""
    Z = np.vstack([np.asarray(gp.leaf(node).X_[:gp.leaf(node).n_]) for gp in gps for node in gp.leaves()
                   if gp.leaf(node).n_ > 0])
    return input_box(Z, box_margin)


def gp_constants(residual, delta_gp: float, *, L_f=None, lipschitz_share: float = 0.1,
                 n_leaves: int | None = None, box_margin: float = 0.1, sigma_ref: float | None = None,
                 beta: str | float = "lederer", growth: int | None = None, box: tuple | None = None,
                 leaves: list | None = None):
    """GP error constants per joint for a :class:`sea_daemon.core.learning.ResidualGP` (one LoG-GP per
    joint) or a list of LoG-GPs.

    δ_GP is split over the n joints' GPs (union bound); within each, a share
    ``lipschitz_share`` goes to LUH19 Thm 3.2 (unless ``L_f`` is given) and the rest to the
    union over the leaves (``n_leaves``, default :func:`union_leaves` with ``growth``: the
    LoG-GP's ``max_leaves`` cap without it, so the constants stay valid while the tree grows; the
    leaves it has plus ``growth`` with it — 0 for a GP that learns no more).  The input box is the box of all training
    points widened by ``box_margin`` of its range (``box``: (lo, hi) given instead; ``leaves``: each
    GP's :func:`loggp_leaves`, made once for several calls).  ``beta``: 'lederer' (the above) or a
    number β (η = β √(σ² + σ_n²), e.g. a split-conformal β; :func:`conformal_gp_constants`).
    Returns (constants list, (lo, hi)).
    """
    gps = _gps(residual)
    n = len(gps)
    per_joint = delta_gp / n
    lo, hi = training_box(gps, box_margin) if box is None else (np.asarray(box[0], float), np.asarray(box[1], float))
    if beta != "lederer":
        return [fixed_constants(float(beta), per_joint) for gp in gps], (lo, hi)
    consts = []
    for j, gp in enumerate(gps):
        lv = loggp_leaves(gp) if leaves is None else leaves[j]
        L = n_leaves if n_leaves is not None else max(len(lv), union_leaves(gp, growth))
        kw = dict(L_f=L_f) if L_f is not None else dict(delta_lipschitz=lipschitz_share * per_joint)
        consts.append(error_bound(lv, lo, hi, per_joint, n_leaves=L, sigma_ref=sigma_ref, **kw))
    return consts, (lo, hi)


#: nested boxes of the guaranteed GP bound (docs/bounds.md §2, "The box"): X_k is X_0 widened
#: about its centre to 2^k times its widths, k < BOX_LEVELS, with the share 2^−(k+1) of δ_GP
BOX_LEVELS = 8


class BoxLevels(NamedTuple):
    """The GP error constants on each nested box: per level k, √β_k and γ_k per joint (K, n) and
    the box [lo_k, hi_k] (K, dz).  η = √β_k s + γ_k with k the smallest box holding the GP input
    set of the step (:func:`box_level`)."""

    sqrt_beta: np.ndarray
    gamma: np.ndarray
    lo: np.ndarray
    hi: np.ndarray


def levels_of(consts, box) -> BoxLevels:
    """One level: the constants ``consts`` (one per joint) on ``box`` ((lo, hi), or None: no box)."""
    lo, hi = box if box is not None else (np.full(1, -np.inf), np.full(1, np.inf))
    # (constants with an eta() of their own have no level arrays: the Python step calls their eta())
    return BoxLevels(np.array([[getattr(c, "sqrt_beta", np.nan) for c in consts]], dtype=float),
                     np.array([[getattr(c, "gamma", np.nan) for c in consts]], dtype=float),
                     np.asarray(lo, dtype=float)[None].copy(), np.asarray(hi, dtype=float)[None].copy())


def gp_constant_levels(residual, delta_gp: float, *, levels: int = BOX_LEVELS, beta: str | float = "lederer",
                       growth: int | None = None, box_margin: float = 0.1):
    """:func:`gp_constants` on :data:`BOX_LEVELS` nested boxes at once: X_0 the box of the training
    inputs widened by ``box_margin`` of its range, X_k the same centre and 2^k its widths, each
    with the share w_k = 2^−(k+1) / (1 − 2^−K) of δ_GP (Σ w_k = 1: by the union bound every level's
    statement holds at once with probability ≥ 1 − δ_GP, so each step may use the smallest box
    that holds its GP input set).  A configured β does not depend on the box: one level.
    Returns (constants of X_0, (lo, hi) of X_0, :class:`BoxLevels`)."""
    if beta != "lederer" or levels <= 1:
        consts, box = gp_constants(residual, delta_gp, beta=beta, growth=growth, box_margin=box_margin)
        return consts, box, levels_of(consts, box)
    gps = _gps(residual)
    lo, hi = training_box(gps, box_margin)                                   # X_0
    mid, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
    w = 0.5 ** np.arange(1, levels + 1)
    w /= w.sum()
    lv = [loggp_leaves(g) for g in gps]
    rows = [gp_constants(gps, delta_gp * w[k], growth=growth, box=(mid - 2.0 ** k * half, mid + 2.0 ** k * half),
                         leaves=lv) for k in range(levels)]
    out = BoxLevels(np.array([[c.sqrt_beta for c in cs] for cs, _ in rows], dtype=float),
                    np.array([[c.gamma for c in cs] for cs, _ in rows], dtype=float),
                    np.array([b[0] for _, b in rows], dtype=float), np.array([b[1] for _, b in rows], dtype=float))
    return rows[0][0], rows[0][1], out


def box_level(levels: BoxLevels, zl: np.ndarray, zh: np.ndarray) -> tuple[int, bool]:
    """(k, outside): the smallest level whose box holds [zl, zh]; the largest and True if none does."""
    inside = np.all((zl >= levels.lo) & (zh <= levels.hi), axis=1)
    k = int(np.argmax(inside)) if inside.any() else len(inside) - 1
    return k, not bool(inside.any())


def conformal_scores(est, log) -> np.ndarray:
    """Calibration scores |y − μ(z)| / s(z) of a frozen GP-AKF on a held-out log (s =
    :class:`~sea_daemon.core.bounds.gp_bound.LocalScale`, fixed by the training data).

    ``est`` is a :class:`~sea_daemon.core.estimators.gpakf.GPAKF` whose GP will not learn the
    pairs (learning is switched off here and restored); ``log`` a passive-subject log it
    never learned from (ass:passive_human: the training pair of each sample is (z, f(z) + noise),
    eq:loadsidewmotor, built by the GP-AKF's own causal kinematics).  μ and σ are evaluated
    at the unclipped z, as in the bound.  Returns (pairs, n).
    """
    gps = residual_gps(est)
    if gps is None:
        raise ValueError("conformal_scores needs a GP-AKF backed by LoG-GPs")
    scales = [LocalScale(g) for g in gps]
    learning, est.learning = est.learning, False
    out = []
    try:
        est.reset(log.q[0], log.theta_m[0], log.tau_m[0])
        for k in range(1, len(log)):
            est.update(log.q[k], log.theta_m[k], log.tau_m[k], log.t[k] - log.t[k - 1])
            if est.since_reset < est.kin.L:
                continue
            z, y = est.training_pair(log.tau_m[k])
            row = np.empty(len(gps))
            for j, g in enumerate(gps):
                mu, var = g.predict(z)
                row[j] = abs(y[j] - mu) / scales[j](z, var)
            out.append(row)
    finally:
        est.learning = learning
    return np.array(out)


def conformal_gp_constants(est, log, delta_gp: float, box_margin: float = 0.1):
    """Split-conformal GP constants per joint from a held-out log (:func:`conformal_scores`);
    δ_GP is split over the joints.  Returns (constants, (lo, hi) the training box, scores)."""
    gps = residual_gps(est)
    scores = conformal_scores(est, log)
    per_joint = delta_gp / len(gps)
    consts = [conformal_constants(scores[:, j], per_joint) for j in range(len(gps))]
    _, box = gp_constants(gps, delta_gp, beta=1.0, box_margin=box_margin)
    return consts, box, scores
