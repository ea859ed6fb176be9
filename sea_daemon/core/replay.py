"""Run an estimator over a measured log (the pure loop behind ``sea-daemon replay``).

:func:`replay` feeds every sample of a :class:`~sea_daemon.core.log.MeasuredLog` to an
:class:`~sea_daemon.core.estimators.base.Estimator` (first sample: ``reset``; then ``update``
with the log's own time steps) and returns the estimates as arrays, plus the per-step
compute time when a clock is given.  :func:`summarize` turns that into the JSON summary of
docs/interfaces.md §3; :func:`est_columns` into the columns of EST.csv.  No file I/O here.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from sea_daemon.errors import EstimatorFault
from sea_daemon.core.log import MeasuredLog, column_names
from sea_daemon.core.estimators.validity import REASONS, reason_counts

STATE_NAMES = ("theta_m_hat", "theta_s_hat", "dtheta_m_hat", "dtheta_s_hat")


@dataclass
class ReplayResult:
    """Per-sample estimates (N, n), state estimates (N, 5n), truth when the log has it."""

    t: np.ndarray
    tau_h_act_hat: np.ndarray
    tau_h_act_sigma: np.ndarray
    tau_h_act_bound: np.ndarray
    x_hat: np.ndarray
    tau_h_act: np.ndarray | None
    step_time_s: np.ndarray | None
    estimator: str
    valid: np.ndarray | None = None          # (N,) Estimate.valid per sample
    #: (N,) the sample whose ρ row k publishes (−1: none); None: each row's own (a bound computed
    #: in the step).  A daemon log of a bound worker: the log's ``bound_cycle`` as a sample index.
    bound_of: np.ndarray | None = None
    #: (N,) Estimate.invalid_reason per sample (0 where valid; validity.REASONS), or None
    reason: np.ndarray | None = None

    @property
    def n(self) -> int:
        return self.tau_h_act_hat.shape[1]


def replay(log: MeasuredLog, estimator, clock: Callable[[], float] | None = None) -> ReplayResult:
    """Run ``estimator`` over ``log``; ``clock`` (e.g. time.perf_counter) times each update.

    An :class:`EstimatorFault` is re-raised naming the log and the sample time; so is a numerical
    breakdown inside a step (LinAlgError, overflow, ...), as the estimator's divergence.
    """
    N, n = len(log), log.n
    hat = np.zeros((N, n))
    sig = np.zeros((N, n))
    bnd = np.zeros((N, n))
    xs = np.zeros((N, int(getattr(estimator, "d", 5 * n))))     # 5n, or 6n with τ̇_h,act (StateLayout)
    ok = np.zeros(N, dtype=bool)
    why = np.zeros(N, dtype=np.int64)
    times = np.zeros(max(N - 1, 0)) if clock is not None else None
    k = 0
    try:
        e = estimator.reset(log.q[0], log.theta_m[0], log.tau_m[0])
        hat[0], sig[0], bnd[0], xs[0] = e.tau_h_act_hat, e.tau_h_act_sigma, e.tau_h_act_bound, e.x_hat
        ok[0], why[0] = e.valid, getattr(e, "invalid_reason", 0)
        for k in range(1, N):
            dt = log.t[k] - log.t[k - 1]
            if clock is not None:
                t0 = clock()
                e = estimator.update(log.q[k], log.theta_m[k], log.tau_m[k], dt)
                times[k - 1] = clock() - t0
            else:
                e = estimator.update(log.q[k], log.theta_m[k], log.tau_m[k], dt)
            hat[k], sig[k], bnd[k], xs[k] = e.tau_h_act_hat, e.tau_h_act_sigma, e.tau_h_act_bound, e.x_hat
            ok[k], why[k] = e.valid, getattr(e, "invalid_reason", 0)
    except EstimatorFault as exc:
        raise EstimatorFault(f"{log.path}: sample {k} (t = {log.t[k]:.6g} s): {exc}", fault=exc.fault) from None
    except (np.linalg.LinAlgError, FloatingPointError, ZeroDivisionError, OverflowError) as exc:
        # numerical breakdown inside an estimator step is divergence (a typed fault), not an internal error
        raise EstimatorFault(f"{log.path}: sample {k} (t = {log.t[k]:.6g} s): the estimator diverged "
                             f"({type(exc).__name__}: {exc})") from None
    return ReplayResult(t=log.t.copy(), tau_h_act_hat=hat, tau_h_act_sigma=sig, tau_h_act_bound=bnd,
                        x_hat=xs, tau_h_act=None if log.tau_h_act is None else log.tau_h_act.copy(),
                        step_time_s=times, estimator=getattr(estimator, "name", type(estimator).__name__),
                        valid=ok, reason=np.where(ok, 0, why))


def bound_rows(cycle: np.ndarray, bound_cycle: np.ndarray) -> np.ndarray:
    """:attr:`ReplayResult.bound_of` of a daemon log: per row, the row of the sample its ρ
    belongs to (the log's ``bound_cycle`` as a row index of its ``cycle`` column; −1 where the
    row publishes none or that sample has no row)."""
    cycle = np.asarray(cycle, dtype=np.int64)
    bc = np.asarray(bound_cycle, dtype=np.int64)
    i = np.clip(np.searchsorted(cycle, bc), 0, max(cycle.size - 1, 0))
    return np.where((bc >= 0) & (cycle[i] == bc), i, -1)


def summarize(res: ReplayResult, **extra) -> dict:
    """JSON summary (docs/interfaces.md §3): estimator, samples, rmse (with truth), mean |error|,
    mean bound, coverage (fraction of samples × joints with |error| ≤ bound), step time."""
    out: dict = {"estimator": res.estimator, "samples": int(res.t.shape[0]), "joints": res.n}
    if res.tau_h_act is not None:
        err = res.tau_h_act_hat - res.tau_h_act
        out["rmse"] = float(np.sqrt(np.mean(err**2)))
        if res.n > 1:
            out["rmse_per_joint"] = [float(v) for v in np.sqrt(np.mean(err**2, axis=0))]
        out["mean_abs_error"] = float(np.mean(np.abs(err)))
        out["max_abs_error"] = float(np.max(np.abs(err)))
        out["coverage"] = float(np.mean(np.abs(err) <= res.tau_h_act_bound))
        if res.valid is not None and res.valid.any():
            # the promise of valid = 1: the estimate inside its bound (docs/estimators.md, "Validity")
            v = res.valid
            out["coverage_valid"] = float(np.mean(np.abs(err[v]) <= res.tau_h_act_bound[v]))
        if res.bound_of is not None and res.valid is not None:
            # a bound from a worker belongs to an earlier sample: each ρ against its own
            # sample's error (Theorem 1's claim), over the valid rows
            rows = np.flatnonzero(res.valid & (res.bound_of >= 0))
            if rows.size:
                own = np.abs(err[res.bound_of[rows]]) <= res.tau_h_act_bound[rows]
                out["coverage_own_sample"] = float(np.mean(own))
                out["bound_age_max"] = int(np.max(rows - res.bound_of[rows]))
    else:
        out["rmse"] = None
    if res.valid is not None:
        out["valid_samples"] = int(res.valid.sum())
        out["first_valid"] = int(np.argmax(res.valid)) if res.valid.any() else None
        if res.reason is not None:
            # why the other samples are not valid (docs/estimators.md, "Validity")
            out["invalid_reasons"] = reason_counts(np.bincount(res.reason, minlength=len(REASONS)))["invalid"]
        if res.valid.any():
            out["mean_bound_valid"] = float(np.mean(res.tau_h_act_bound[res.valid]))
    out["mean_bound"] = float(np.mean(res.tau_h_act_bound))
    out["mean_sigma"] = float(np.mean(res.tau_h_act_sigma))
    if res.step_time_s is not None and res.step_time_s.size:
        us = res.step_time_s * 1e6
        p50, p99 = np.percentile(us, [50, 99])
        out["step_time_us"] = {"median": round(float(p50), 2), "p99": round(float(p99), 2),
                               "max": round(float(us.max()), 2), "runs": int(us.size)}
    out.update(extra)
    return out


def est_columns(res: ReplayResult) -> dict[str, np.ndarray]:
    """Columns of EST.csv: t, tau_h_act_hat, tau_h_act_bound, tau_h_act_sigma, the truth
    tau_h_act when known, the state estimates (per-joint suffixes for n > 1) and ``valid``."""
    n = res.n
    cols: dict[str, np.ndarray] = {"t": res.t}

    def put(base, arr):
        for j, name in enumerate(column_names(base, n)):
            cols[name] = arr[:, j]

    put("tau_h_act_hat", res.tau_h_act_hat)
    put("tau_h_act_bound", res.tau_h_act_bound)
    put("tau_h_act_sigma", res.tau_h_act_sigma)
    if res.tau_h_act is not None:
        put("tau_h_act", res.tau_h_act)
    for b, base in enumerate(STATE_NAMES):
        put(base, res.x_hat[:, b * n:(b + 1) * n])
    if res.valid is not None:
        cols["valid"] = res.valid.astype(float)
    return cols
