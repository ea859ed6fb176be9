"""β of the GP error calibrated on the torque error itself (docs/bounds.md §2c).

:func:`torque_calibrated_beta` — the smallest β (η = β s(z)) whose Theorem-1 ρ_k covers the
τ̂_h,act error of a frozen GP-AKF on a held-out log (split conformal on the statement of
eq:bounds); :func:`torque_coverage` — the coverage of one β.  Pure numerics: no I/O, no clock,
no threads.
"""
from __future__ import annotations

import math

import numpy as np

from sea_daemon.core.bounds.akf_bound import AKFTheoremBound
from sea_daemon.core.bounds.calibration import gp_constants, residual_gps
from sea_daemon.core.bounds.gp_bound import fixed_constants


def torque_coverage(est, log, beta: float, truth: np.ndarray | None = None) -> tuple[float, int]:
    """Fraction of the steps of ``log`` where the Theorem-1 ρ_k with η = β s(z) (local scale,
    :func:`~sea_daemon.core.bounds.gp_bound.fixed_constants`) covers the τ̂_h,act error of the frozen
    GP-AKF ``est``; ``truth`` τ_h,act per sample (default 0: a passive subject,
    ass:passive_human).  No human-torque rate: the subject is passive; the Gaussian part is the
    filter's P, as in estimation with a configured β.  ``est`` must have no
    bound component; it is left as it was (learning restored, no bound).  Returns (coverage, steps)."""
    if est.bound is not None:
        raise ValueError("torque_coverage needs a GP-AKF without a bound component")
    gps = residual_gps(est)
    if gps is None:
        raise ValueError("torque_coverage needs a GP-AKF backed by LoG-GPs")
    n = len(gps)
    truth = np.zeros((len(log), n)) if truth is None else np.asarray(truth, dtype=float).reshape(len(log), n)
    _, box = gp_constants(gps, 0.5 * est.delta, beta=1.0)
    consts = [fixed_constants(float(beta), 0.5 * est.delta / n) for _ in range(n)]
    learning, est.learning = est.learning, False
    # the Gaussian part a configured β is used with: the filter's P (docs/bounds.md §3)
    est.bound = AKFTheoremBound(est, gp_constants=consts, gp_box=box, tau_h_act_rate=0.0, filter_gaussian=True)
    covered = steps = 0
    try:
        e = est.reset(log.q[0], log.theta_m[0], log.tau_m[0])
        for k in range(1, len(log)):
            e = est.update(log.q[k], log.theta_m[k], log.tau_m[k], log.t[k] - log.t[k - 1])
            # eq:bounds, per step and joint: |τ̂_h,act − τ_h,act| ≤ ρ_k
            covered += int(np.all(np.abs(e.tau_h_act_hat - truth[k]) <= e.tau_h_act_bound))
            steps += 1
    finally:
        est.learning = learning
        est.bound = None
    return covered / max(steps, 1), steps


def torque_calibrated_beta(est, log, delta: float | None = None, *, truth: np.ndarray | None = None,
                           iters: int = 8, progress=None) -> dict:
    """The smallest β (η = β s(z), the configured-β form of ``estimator.gp_beta``) whose
    Theorem-1 ρ_k covers the τ̂_h,act error of the frozen GP-AKF ``est`` on a held-out log in at
    least ⌈(m + 1)(1 − δ)⌉ of its m steps (split conformal on the torque error itself, the
    statement of eq:bounds; docs/bounds.md §2c).  ``log`` is a session the GP never learned,
    with a passive subject (τ_h,act = 0) unless ``truth`` is given.

    Coverage grows with β.  The search runs β = 1, then the end of the range [2⁻¹², 2¹²] on
    the side the target lies (returning it if β = 2⁻¹² already covers: the filter's own part
    does; failing if 2¹² does not), then bisects ``iters`` times in log β (12 octaves / 2⁸:
    3 % resolution) and returns the upper end.  ``progress(beta, coverage)`` is called after
    each replay.  Returns a dict with ``beta``, ``coverage`` (at beta), ``steps``, ``target``
    and ``runs`` [(β, coverage)].
    """
    delta = est.delta if delta is None else float(delta)
    if not 0 < delta < 1:
        raise ValueError(f"delta must be in (0, 1), got {delta}")
    runs: list[tuple[float, float]] = []

    def cov(b):
        c, m = torque_coverage(est, log, b, truth)
        runs.append((b, c))
        if progress is not None:
            progress(b, c)
        return c, m

    b_min, b_max = 2.0 ** -12, 2.0 ** 12
    c1, m = cov(1.0)
    # the ⌈(m + 1)(1 − δ)⌉-th of m steps exists only for m ≥ (1 − δ)/δ: a shorter log has no
    # finite split-conformal quantile (a β "covering" its few steps would guarantee nothing)
    need = math.ceil((1.0 - delta) / delta - 1e-9)
    if m < need or math.ceil((m + 1) * (1.0 - delta)) > m:
        raise ValueError(f"the log has {m} steps, split conformal at delta = {delta:g} needs at least "
                         f"{need} (a longer held-out log)")
    target = math.ceil((m + 1) * (1.0 - delta)) / m
    if c1 >= target:
        lo, (hi, c_hi) = b_min, (1.0, c1)
        c, _ = cov(b_min)
        if c >= target:
            return {"beta": b_min, "coverage": c, "steps": m, "target": target, "runs": runs}
    else:
        lo, hi = 1.0, b_max
        c_hi, _ = cov(b_max)
        if c_hi < target:
            raise ValueError(f"the bound covers only {max(c for _, c in runs):.3f} of {m} steps even with "
                             f"beta = {b_max:g}; the target is {target:.3f} (1 - delta = {1 - delta:g})")
    for _ in range(int(iters)):
        b = math.sqrt(lo * hi)
        c, _ = cov(b)
        if c >= target:
            hi, c_hi = b, c
        else:
            lo = b
    return {"beta": hi, "coverage": c_hi, "steps": m, "target": target, "runs": runs}
