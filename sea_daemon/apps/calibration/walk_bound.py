"""The τ_h,act walk for the estimate, or for the bound as well (docs/calibration.md step 5, docs/bounds.md §9).

By default (``calibration.walk_for: estimate``) the calibration keeps the smoothest estimate the
data do not contradict: the smallest q_τ whose RMS of τ̂_h,act on the synthetic sessions is within
:data:`RMSE_RULE_TOL` of the best (per joint on that joint's own RMS).  With ``walk_for: bound``:

The walk scan (:class:`~.pipeline._WalkScan`) rates each q_τ by the RMS of τ̂_h,act on the
synthetic active sessions (the identified model as the plant, a subject of the declared band and
size).  That RMS is flat over decades once the walk is fast enough, and its smallest q_τ is the
slowest filter of that plateau: the largest lag, and the lag is the Theorem-1 bound's largest
term for a wearer declared by a rate (|τ̇_h,act| ≤ r: r times the filter's lag).  So among the
walks whose synthetic RMS is within :data:`RMSE_TOL` of the best, the calibration takes the one
whose Theorem-1 bound (the GP-AKF's, guaranteed β; the AKF's with its declared model error) on
those same sessions is smallest: the mean ρ over the valid samples, averaged over the sessions,
with the bound covering ≥ :data:`MIN_COVERAGE` of the valid samples and ≥ :data:`MIN_VALID` of the
samples valid in each session (their true τ_h,act is known).  When no walk of the plateau
qualifies, the smallest q_τ within 2 % of the best RMS (the estimate's rule) is kept.  Per joint,
the same rule on each joint's own RMS and ρ, the walks kept only if together they bound tighter than
the estimate's rule's walks.

RMSE_TOL was set on the development seeds of ``bench generalize`` (1-DoF 0, 2-DoF 2) only.
"""
from __future__ import annotations

import math
from typing import Callable

import numpy as np

from sea_daemon.core.bounds.akf_bound import theorem_bound
from sea_daemon.core.replay import replay
from sea_daemon.errors import EstimatorFault

#: the walks the bound chooses from: synthetic RMS at most (1 + RMSE_TOL) × the best
RMSE_TOL = 0.10
#: of each synthetic session, the bound's coverage of the valid samples and the valid share, at least
MIN_COVERAGE = 0.95
MIN_VALID = 0.95
#: the estimate's rule: the smallest q_τ within this share of the best RMS
RMSE_RULE_TOL = 0.02


def bound_figures(res, truth: np.ndarray) -> dict:
    """Per joint: mean ρ and coverage over the valid samples of a replay ``res`` against ``truth``
    (N, n), and the valid share; ρ inf where no sample is valid."""
    v = np.asarray(res.valid, dtype=bool)
    rho, err = res.tau_h_act_bound, np.abs(res.tau_h_act_hat - truth)
    if not v.any() or not np.all(np.isfinite(rho[v])):
        return {"rho": [math.inf] * truth.shape[1], "coverage": [0.0] * truth.shape[1], "valid": float(np.mean(v))}
    return {"rho": np.mean(rho[v], axis=0).tolist(), "coverage": np.mean(err[v] <= rho[v], axis=0).tolist(),
            "valid": float(np.mean(v))}


def scan_bound(scan, row: dict, eps: float, logs: dict) -> dict:
    """The Theorem-1 bound's figures (:func:`bound_figures`) of ``row``'s filter on each of
    ``logs``, kept in ``row['bound']`` (each filter run once; None where it faulted)."""
    b = row.setdefault("bound", {})
    for name, lg in logs.items():
        if name in b:
            continue
        try:
            res = replay(lg, scan.estimator(row["q_tau"], eps, lg.dt, bound=theorem_bound))
            b[name] = bound_figures(res, lg.tau_h_act)
        except EstimatorFault:
            b[name] = None
        scan.ran()
    return b


def bound_score(b: dict, logs, j: int | None = None) -> float:
    """The mean over ``logs`` of the mean ρ over the valid samples (joint ``j``'s, or the mean over
    the joints), inf when any session's bound covers less than :data:`MIN_COVERAGE` of its valid
    samples or is valid on less than :data:`MIN_VALID` of them."""
    out = []
    for k in logs:
        f = b.get(k)
        if f is None or f["valid"] < MIN_VALID:
            return math.inf
        cov, rho = (f["coverage"], f["rho"]) if j is None else ([f["coverage"][j]], [f["rho"][j]])
        if min(cov) < MIN_COVERAGE:
            return math.inf
        out.append(float(np.mean(rho)))
    return float(np.mean(out)) if out else math.inf


def choose(rows: list, rms: Callable[[dict], float], score: Callable[[dict], float]) -> tuple[float | None, float]:
    """(q_τ, its score) of the walk with the smallest bound ``score`` among ``rows`` whose ``rms`` is
    within :data:`RMSE_TOL` of the best; (None, inf) when none qualifies."""
    best = min(rms(r) for r in rows)
    near = [r for r in rows if rms(r) <= (1.0 + RMSE_TOL) * best]
    scored = [(score(r), float(r["q_tau"])) for r in near]
    s, q = min(scored, default=(math.inf, None))
    return (q, s) if math.isfinite(s) else (None, math.inf)


def rmse_rule(rows: list, rms: Callable[[dict], float]) -> float:
    """The estimate's rule: the smallest q_τ of ``rows`` within :data:`RMSE_RULE_TOL` of the best ``rms``."""
    best = min(rms(r) for r in rows)
    return min(float(r["q_tau"]) for r in rows if rms(r) <= (1.0 + RMSE_RULE_TOL) * best)


def common_walk(scan, eps: float, active: dict, grid: np.ndarray) -> tuple[float, dict]:
    """(q_τ, record): the common walk by ``scan.opts.walk_for``'s rule (module docstring), from
    ``scan``'s rows at ``eps`` (for the bound, the grid's half-decades around the chosen one are
    tried as well)."""
    def rows():
        return [r for (q, e), r in scan.table.items()
                if e == eps and np.ndim(r["q_tau"]) == 0 and all(k in r for k in active)]

    def rms(r):
        return scan.objective(r, active)
    fallback = rmse_rule(rows(), rms)
    if scan.opts.walk_for != "bound":
        return fallback, {"rule": "rmse", "rmse_tolerance": RMSE_RULE_TOL}
    tried: set = set()
    q = None
    while True:
        best = min(rms(r) for r in rows())
        for r in rows():
            if rms(r) <= (1.0 + RMSE_TOL) * best and float(r["q_tau"]) not in tried:
                scan_bound(scan, r, eps, active)
                tried.add(float(r["q_tau"]))
        q, s = choose(rows(), rms, lambda r: bound_score(r.get("bound", {}), active))
        if q is None:
            break
        i = int(np.argmin(np.abs(grid - q)))
        new = [grid[j] for j in (i - 1, i + 1) if 0 <= j < len(grid) and float(grid[j]) not in tried
               and (float(grid[j]), float(eps)) not in scan.table]
        if not new:
            break
        for g in new:
            scan.evaluate(g, eps, active)
    rec = {"rmse_tolerance": RMSE_TOL, "rmse_rule_walk": fallback}
    if q is None:
        return fallback, {"rule": "rmse", "why": "no walk's bound covers the synthetic sessions", **rec}
    return q, {"rule": "bound", "mean_rho": s, **rec}


def walk_per_joint(scan, eps: float, active: dict, common: float, n: int) -> tuple[list[float], dict]:
    """Each joint's walk by ``scan.opts.walk_for``'s rule (module docstring) on that joint's own RMS
    (and, for the bound, ρ: the bound run on every row within :data:`RMSE_TOL` of a joint's best;
    the estimate's rule on a joint where no walk qualifies), from the common scan's rows at
    ``eps``; ``common`` where no row has every session's figures."""
    rows = [r for (q, e), r in scan.table.items()
            if e == eps and np.ndim(r["q_tau"]) == 0 and all(k in r.get("per_joint", {}) for k in active)]
    if not rows:
        return [float(common)] * n, {"rule": "common"}

    def rms_of(j):
        return lambda r: math.sqrt(float(np.mean([r["per_joint"][k][j] ** 2 for k in active])))
    if scan.opts.walk_for != "bound":
        return [rmse_rule(rows, rms_of(j)) for j in range(n)], {"rule": ["rmse"] * n, "rmse_tolerance": RMSE_RULE_TOL}
    out, rules, by_rmse = [], [], []
    for j in range(n):
        rms = rms_of(j)
        best = min(rms(r) for r in rows)
        for r in rows:
            if rms(r) <= (1.0 + RMSE_TOL) * best:
                scan_bound(scan, r, eps, active)
        q, _ = choose(rows, rms, lambda r, j=j: bound_score(r.get("bound", {}), active, j))
        by_rmse.append(rmse_rule(rows, rms))
        out.append(by_rmse[-1] if q is None else q)
        rules.append("rmse" if q is None else "bound")
    rec = {"rule": rules, "rmse_tolerance": RMSE_TOL, "rmse_rule_walks": by_rmse}
    if out == by_rmse:
        return out, rec
    # the joints' walks were rated on the common walk's rows; together (the joints couple) their
    # bound must beat the estimate's rule's walks on the same sessions, or those are kept
    score = {}
    for v in (out, by_rmse):
        r = scan.evaluate(v, eps, active)
        score[tuple(v)] = bound_score(scan_bound(scan, r, eps, active), active)
    rec["mean_rho"], rec["rmse_rule_mean_rho"] = score[tuple(out)], score[tuple(by_rmse)]
    if not score[tuple(out)] < score[tuple(by_rmse)]:
        return by_rmse, {**rec, "rule": ["rmse"] * n, "why": "the joints' walks together bound no tighter"}
    return out, rec
