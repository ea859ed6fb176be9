"""Assist-as-needed from the estimate, trusted only as far as its bound (docs/assist.md).

The paper's reason for estimating the active human torque τ_h,act is to know how much the
subject contributes, e.g. to assist as needed.  The estimator publishes τ̂ = τ̂_h,act with a
bound ρ = ρ_k: |τ_h,act − τ̂| ≤ ρ with probability 1 − δ (Theorem 1, eq:bounds).

:class:`AssistLaw` first averages τ̂ and ρ with the same first-order low-pass (time constant
``smoothing_s``): τ̄̂, ρ̄.  The low-pass has non-negative weights summing to one, so wherever
the bound held, |τ̄_h,act − τ̄̂| ≤ ρ̄ for the subject's torque averaged the same way.  Of τ̄̂,
only

    τ_cert = sign(τ̄̂) · max(|τ̄̂| − ρ̄ − τ_db, 0)

is certified: it has the sign of what the subject did over the last ``smoothing_s`` and is
no larger (|τ_cert| ≤ |τ̄_h,act|).  It is 0 while the current estimate certifies the other
direction (τ̂ τ̄̂ < 0 and |τ̂| > ρ + τ_db): a subject that reverses (the braking half of a move)
is not pushed on by the average of its past effort; a current estimate that certifies nothing
(its bound wider than it) leaves the averaged assistance as it is.  The assistance is

    τ_target = clip(α · τ_cert, ±τ_max)          (0 while ρ̄ > ρ_max)
    τ_assist → τ_target at most ``max_rate`` per second,

and 0 *in the same step* when the estimate is not valid (start-up, a latched fault: the loop
then gives no estimate) — the averages restart from the next valid estimate.  They restart too
when ρ̄ is above ρ_max and the estimate's bound falls below 1/:data:`RESTART_RATIO` of it (the
end of a standstill where the bound was wide): any average with non-negative weights summing to
one keeps the guarantee, and one that still carries the wide bounds of the past certifies
nothing of what the subject does now.  Each step
records per joint why the assistance is what it is (:attr:`AssistLaw.state`, counted in
:attr:`AssistLaw.counts`): :data:`ENGAGED` (τ_target ≠ 0), :data:`INVALID` (no valid estimate),
:data:`RHO_ABOVE_MAX` (ρ̄ > ρ_max), :data:`BELOW_BOUND` (|τ̄̂| ≤ ρ̄ + τ_db: the bound certifies
no effort of the subject).  So the
assistance points where the subject pushes, is at most α times the certified part of its
effort, and shrinks continuously when the bound grows (no switching).  α < 1 would never give
more than the subject does; α = 2 (the default) gives twice the certified part, so at rest the
subject's share of a task torque T is (T + α(ρ̄ + τ_db)) / (1 + α).

:class:`InnovationGuard` refuses a filter step whose normalised innovation νᵀS⁻¹ν is beyond
``innovation_max``: the encoders then disagree with the model by far more than their noise
(a sensor step or bias below the driver's jump detector, a knock), the kind of corruption the
bound cannot see because the filter absorbs it into τ̂ within a few steps.  It raises
:class:`InnovationOutlier`, a fault (``Fault.INNOVATION_OUTLIER``): zero torque in that cycle.

Pure numerics: preallocated, no I/O, no clock.
"""
from __future__ import annotations

import math

import numpy as np

from sea_daemon.core.estimators.validity import LEARNING, STARTUP
from sea_daemon.errors import EstimatorFault, Fault


#: why a joint's assistance is what it is in a step (:attr:`AssistLaw.state`), in the order of
#: :data:`STATES`: engaged (τ_target ≠ 0); no valid estimate; ρ̄ above ρ_max; the bound certifies
#: no effort (|τ̄̂| ≤ ρ̄ + deadband)
ENGAGED, INVALID, RHO_ABOVE_MAX, BELOW_BOUND = range(4)
STATES = ("engaged", "invalid", "rho_above_max", "below_bound")
#: with ρ̄ above ρ_max the averages restart from the current estimate when its bound is below 1/RESTART_RATIO of ρ̄
RESTART_RATIO = 2.0


class InnovationOutlier(EstimatorFault):
    """One filter step's normalised innovation beyond ``assist.innovation_max``."""

    fault = Fault.INNOVATION_OUTLIER


class AssistLaw:
    """τ_assist per joint from (τ̂, ρ, valid): the bound gate, the limits (module docstring).

    ``cfg``: :class:`sea_daemon.core.config.AssistConfig`; ``n`` joints; ``dt`` the step [s].
    :meth:`step` returns the preallocated τ_assist (n,) [N m]; :attr:`target` holds τ_target,
    :attr:`tau_hat_avg` / :attr:`rho_avg` the averaged estimate and bound, and :attr:`trust`
    the certified fraction |τ_cert| / |τ̄̂| ∈ [0, 1] of the last step.
    """

    def __init__(self, cfg, n: int, dt: float):
        if not dt > 0:
            raise ValueError(f"assist step dt must be > 0 s, got {dt!r}")
        self.cfg, self.n, self.dt = cfg, int(n), float(dt)
        # each joint's own settings (one number in the configuration: the same for every joint)
        self.gains = cfg.per_joint("gain", self.n)
        self.deadbands = cfg.per_joint("deadband", self.n)
        self.rho_maxes = cfg.per_joint("rho_max", self.n)
        self.max_torques = cfg.per_joint("max_torque", self.n)
        self.max_steps = cfg.per_joint("max_rate", self.n) * self.dt     # |Δτ_assist| per step
        self.beta = 1.0 - math.exp(-self.dt / cfg.smoothing_s) if cfg.smoothing_s > 0 else 1.0
        self.tau = np.zeros(self.n)          # τ_assist
        self.target = np.zeros(self.n)       # τ_target
        self.trust = np.zeros(self.n)        # |τ_cert| / |τ̄̂|
        self.tau_hat_avg = np.zeros(self.n)  # τ̄̂: the estimate averaged over smoothing_s
        self.rho_avg = np.zeros(self.n)      # ρ̄: the bound averaged the same way
        self._fresh = np.ones(self.n, dtype=bool)
        self.state = np.full(self.n, INVALID, dtype=np.int64)
        self.counts = np.zeros((self.n, len(STATES)), dtype=np.int64)
        self.rho_sum = np.zeros(self.n)

    def clear_counts(self) -> None:
        """Start counting the states afresh."""
        self.counts[:] = 0
        self.rho_sum[:] = 0.0

    def reset(self) -> None:
        """No assistance (start, fault, operator reset); the averages restart."""
        self.tau[:] = 0.0
        self.target[:] = 0.0
        self.trust[:] = 0.0
        self._fresh[:] = True

    def step(self, tau_hat, rho, valid: bool) -> np.ndarray:
        """One control step with the last estimate; ``valid`` False (or a non-finite value) gives 0 at once."""
        out, tgt, trust, tbar, rbar = self.tau, self.target, self.trust, self.tau_hat_avg, self.rho_avg
        state, counts = self.state, self.counts
        b = self.beta
        for j in range(self.n):
            th = float(tau_hat[j]) if valid else 0.0
            r = float(rho[j]) if valid else math.inf
            if not (valid and math.isfinite(th) and math.isfinite(r) and r >= 0.0):
                out[j] = tgt[j] = trust[j] = 0.0
                self._fresh[j] = True
                state[j] = INVALID
                counts[j, INVALID] += 1
                continue
            rho_max, deadband = self.rho_maxes[j], self.deadbands[j]
            if self._fresh[j] or (rbar[j] > rho_max and RESTART_RATIO * r < rbar[j]):
                tbar[j], rbar[j] = th, r
                self._fresh[j] = False
            else:
                tbar[j] += b * (th - tbar[j])
                rbar[j] += b * (r - rbar[j])
            mag = abs(tbar[j])
            cert = mag - rbar[j] - deadband
            # nothing while the current estimate certifies the other direction: the subject's
            # reversal stops the assistance at once
            if th * tbar[j] < 0.0 and abs(th) - r - deadband > 0.0:
                cert = min(cert, 0.0)
            self.rho_sum[j] += rbar[j]
            if rbar[j] > rho_max:
                st = RHO_ABOVE_MAX
            elif cert > 0.0:
                st = ENGAGED
            else:
                st = BELOW_BOUND
            if st == ENGAGED:
                trust[j] = cert / mag
                g = min(self.gains[j] * cert, self.max_torques[j])
                t = g if tbar[j] > 0.0 else -g
            else:
                trust[j] = 0.0
                t = 0.0
            state[j] = st
            counts[j, st] += 1
            tgt[j] = t
            step = self.max_steps[j]
            out[j] += max(-step, min(step, t - out[j]))
        return out


class InnovationGuard:
    """An estimator whose steps are refused when the normalised innovation is an outlier.

    Wraps an AKF / GP-AKF (anything with ``update`` and a per-step ``nis``): :meth:`update` runs
    the filter step and raises :class:`InnovationOutlier` when the step was a filter step (past
    the start-up transient, not learning) with ``nis > nis_max``.  Every other attribute is the estimator's.
    """

    def __init__(self, estimator, nis_max: float):
        if not nis_max > 0:
            raise ValueError(f"innovation limit must be > 0, got {nis_max!r}")
        self.estimator = estimator
        self.nis_max = float(nis_max)
        self.max_seen = 0.0                  # the largest accepted step's NIS since the last reset

    def __getattr__(self, name):
        return getattr(self.estimator, name)

    def reset(self, *args, **kw):
        self.max_seen = 0.0
        return self.estimator.reset(*args, **kw)

    def update(self, q, theta_m, tau_m, dt: float | None = None):
        est = self.estimator.update(q, theta_m, tau_m, dt)
        nis = float(getattr(self.estimator, "nis", 0.0))
        # a filter step: past the start-up transient and not learning, whether or not its bound
        # is published as valid (an AKF without a model-error term, a bound above its limit)
        if est.valid or getattr(est, "invalid_reason", STARTUP) not in (STARTUP, LEARNING):
            if not nis <= self.nis_max:
                raise InnovationOutlier(
                    f"innovation outlier at step {est.k}: normalised innovation {nis:.4g} above "
                    f"assist.innovation_max {self.nis_max:.4g} (the encoders disagree with the model far "
                    "beyond their noise: a sensor step or bias, a knock)")
            if nis > self.max_seen:
                self.max_seen = nis
        return est
