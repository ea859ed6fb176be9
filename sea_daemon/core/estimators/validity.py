"""Whether a published bound ρ_k is a real estimate (``Estimate.valid``), and why not (``Estimate.invalid_reason``).

``valid`` is 1 only for an estimate inside its published bound by construction, with a bound
that says something.  An AKF step's estimate is withheld (``valid`` 0) for the first of these
reasons that applies (:data:`REASONS` names them; docs/estimators.md, "Validity"):

* ``startup`` — the reset sample, the differentiator's window, and until the filter's start-up
  transient has decayed (:class:`~sea_daemon.core.estimators.gate.StartupGate`);
* ``learning`` — a GP-AKF learning (its τ̂_h,act is the residual not learned yet);
* ``no_model_error_term`` — the bound has no term for the model error the estimator makes: a
  plain AKF puts every unmodelled effect into τ̂_h,act, and its bound (the filter's own
  √(s P_ττ), or Theorem 1 with the model's linearisation error only) does not hold it.  A GP-AKF
  (its GP error term) has one; an AKF has one only with a declared ``estimator.model_error``,
  which the Theorem-1 bound adds as a bounded load-side torque error (docs/bounds.md §7);
* ``covariance_cap`` — a variance of P_k or a half-width of the set of means sits at its cap
  (``AKF.P_max``; the set of means is then held at the caps, no longer an outer set), and
  after that until what the cap cut off can no longer matter: the cut part is at most the cap
  box b_cap = √(s P_max), it decays with the filter's closed-loop map like the start-up
  transient, and the estimate is valid again once |Φ_k|_τ b_cap ≤ 10 % of ρ_k (a second
  :class:`StartupGate` restarted at every capped step);
* ``above_limit`` — ρ_k above ``estimator.bound_limit`` (default ``estimator.tau_h_act_max``,
  i.e. ``hardware.torque_limit``: a wider bound says less than the torque limit does).

The daemon's loop adds ``bound_stale`` (the bound worker's newest ρ is older than
``estimator.bound_max_age``), ``fault`` (a fault latched) and ``no_sample`` (no sample or
estimate in that cycle).  Allocation-free per step.  Pure numerics.
"""
from __future__ import annotations

import numpy as np

from sea_daemon.core.estimators.gate import StartupGate

#: ``Estimate.invalid_reason``: valid, then the reasons of the module docstring, in this order
VALID, STARTUP, LEARNING, NO_MODEL_ERROR_TERM, COVARIANCE_CAP, ABOVE_LIMIT, BOUND_STALE, FAULT, NO_SAMPLE = range(9)
#: the names of the codes (the summaries' keys)
REASONS = ("valid", "startup", "learning", "no_model_error_term", "covariance_cap", "above_limit",
           "bound_stale", "fault", "no_sample")


def reason_counts(counts) -> dict:
    """{"valid": rows, "invalid": {reason: rows}} from counts per code (the reasons with rows only)."""
    c = [int(v) for v in counts]
    return {"valid": c[VALID], "invalid": {REASONS[i]: c[i] for i in range(1, len(REASONS)) if c[i]}}


class BoundValidity:
    """The checks of the module docstring after the start-up gate, for one filter.

    ``n`` joints, ``H``, ``s`` (the filter's χ² quantile), ``P_max`` (the caps of P's variances);
    ``model_error_term``: whether the published bound has a term for the estimator's model error;
    ``limit``: the usefulness limit of ρ [N m].  Public state: ``capped`` (a cap was hit since
    the last start and its transient has not decayed), ``cap_gate`` (its transient).
    """

    def __init__(self, n: int, H: np.ndarray, s: float, P_max: np.ndarray, model_error_term: bool, limit: float):
        self.n = n
        self.P_max = P_max
        self.model_error_term = bool(model_error_term)
        self.limit = float(limit)
        self.cap_gate = StartupGate(n, H, s, 0.0)
        self._b_cap = np.sqrt(s * P_max)
        self.capped = False

    def stop(self) -> None:
        """A reset: what a cap cut off before it no longer matters."""
        self.capped = False
        self.cap_gate.stop()

    def judge(self, e, record, has_gp: bool, bound) -> bool:
        """After step k with the start-up gate open: ``e.invalid_reason`` (:meth:`reason`) and
        whether ``e`` is valid.  ``record`` the step's StepRecord, ``has_gp`` whether the filter
        has a GP residual (its bound's GP error term), ``bound`` its bound component (or None): a
        plain AKF's bound has a model-error term only where it says so (``model_error_term``),
        ``at_cap_`` whether it held its set of means at the caps in this step."""
        self.model_error_term = has_gp or bool(getattr(bound, "model_error_term", False))
        e.invalid_reason = self.reason(record.P, bool(getattr(bound, "at_cap_", False)), record.K_k, record.F_k,
                                       e.tau_h_act_bound, e.k)
        return e.invalid_reason == VALID

    def reason(self, P: np.ndarray, at_cap: bool, K: np.ndarray, F: np.ndarray, rho: np.ndarray, k: int) -> int:
        """After step k, the gate open: :data:`VALID` or why not.  ``P`` the posterior covariance,
        ``at_cap`` whether the bound held its set of means at the caps in this step, ``K``, ``F``
        the step's gain and transition, ``rho`` the published ρ_k."""
        if not self.model_error_term:
            return NO_MODEL_ERROR_TERM
        if at_cap or self._p_at_cap(P):
            self.capped = True
            self.cap_gate.start_box(self._b_cap)
            return COVARIANCE_CAP
        if self.capped:
            if not self.cap_gate.check(K, F, rho, k):
                return COVARIANCE_CAP
            self.capped = False
        for j in range(self.n):
            if not rho[j] <= self.limit:
                return ABOVE_LIMIT
        return VALID

    def _p_at_cap(self, P: np.ndarray) -> bool:
        cap = self.P_max
        for i in range(cap.shape[0]):
            if P[i, i] >= cap[i] * (1.0 - 1e-9):
                return True
        return False
