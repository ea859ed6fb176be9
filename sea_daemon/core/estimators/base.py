"""The estimator interface shared by the AKF, the GP-AKF and the spring-torque estimate."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from sea_daemon.core.estimators.validity import STARTUP


@dataclass
class Estimate:
    """One step's estimate; estimators own one preallocated instance and overwrite it.

    ``tau_h_act_hat`` (n,) [N m] estimate of the active human torque; ``tau_h_act_sigma``
    (n,) its standard deviation from P; ``tau_h_act_bound`` (n,) the error bound ρ at the
    configured δ (eq:bounds); ``x_hat`` (5n,) the state estimate; ``P`` (5n, 5n) its
    covariance; ``k`` the step counter (0 after reset); ``valid`` whether this is an estimate of
    τ_h,act that users may act on, inside its published bound: False while the estimator starts
    (the reset sample, the differentiator's window) and until the filter's start-up transient
    has decayed (the AKF's start-up gate, :class:`~sea_daemon.core.estimators.gate.StartupGate`), and while
    a GP-AKF learns (training phase, subject assumed passive), and while the bound is no real
    estimate (:mod:`~sea_daemon.core.estimators.validity`); ``invalid_reason`` says why not
    (0 when valid; a code of :data:`~sea_daemon.core.estimators.validity.REASONS`).
    """

    tau_h_act_hat: np.ndarray
    tau_h_act_sigma: np.ndarray
    tau_h_act_bound: np.ndarray
    x_hat: np.ndarray
    P: np.ndarray
    k: int = 0
    valid: bool = False
    invalid_reason: int = STARTUP

    @classmethod
    def zeros(cls, n: int, d: int | None = None) -> "Estimate":
        """n joints, a state of d (default 5n; 6n with τ̇_h,act, core.model.StateLayout)."""
        d = 5 * n if d is None else int(d)
        return cls(np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(d), np.zeros((d, d)))

    def copy(self) -> "Estimate":
        return Estimate(self.tau_h_act_hat.copy(), self.tau_h_act_sigma.copy(), self.tau_h_act_bound.copy(),
                        self.x_hat.copy(), self.P.copy(), self.k, self.valid, self.invalid_reason)


@runtime_checkable
class Estimator(Protocol):
    """Online estimator of τ_h,act from the encoders and the motor torque.

    ``reset(q, theta_m, tau_m)`` initialises from the first sample (``reset()`` without a
    sample: the next ``update`` initialises); ``update(q, theta_m,
    tau_m, dt)`` consumes one sample (raw encoder angles, joint side; motor torque; time
    since the previous sample, default the configured period) and returns the estimator's
    preallocated :class:`Estimate` (overwritten by the next call).
    """

    n: int
    name: str

    def reset(self, q=None, theta_m=None, tau_m=None) -> Estimate: ...

    def update(self, q, theta_m, tau_m, dt: float | None = None) -> Estimate: ...


@runtime_checkable
class Residual(Protocol):
    """A learned load-side residual f(z) (eq:unknwn_load), e.g. the LoG-GP (:mod:`sea_daemon.core.learning`).

    ``predict(z)`` with z = [q, q̇, q̈] (3n,) returns ``(mu (n,), dmu_dz (n, 3n), var (n,))``:
    the mean μ(z) [N m], its Jacobian (eq:moejac) and the posterior variance σ²(z) [N² m²].
    """

    def predict(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]: ...


@runtime_checkable
class Bound(Protocol):
    """The error bound an AKF publishes as ``tau_h_act_bound`` (eq:bounds), a component the
    AKF calls at the end of its :meth:`reset` and of every filter step with the step's
    :class:`~sea_daemon.core.estimators.record.StepRecord` (:meth:`AKF.finish_step`).

    ``reset(est, record)``: the filter was (re)initialised (``est`` its estimate; ``record.ready``
    tells whether from a sample, ``record.P`` is P₀).  ``step(est, record)``: the filter stepped
    from (x̂_{k−1}, P_{k−1}) = (``record.x_prev``, ``record.P_prev``) with the input ``record.u``
    held over ``record.dt``; the record's other fields hold step k.  Both overwrite
    ``est.tau_h_act_bound``.  A bound computed elsewhere takes the records through a
    :class:`~sea_daemon.core.estimators.record.BoundConsumer` attached to the AKF
    (:meth:`AKF.attach`; the daemon's bound worker, :mod:`sea_daemon.runtime.bound_worker`).
    """

    def reset(self, est: Estimate, record) -> None: ...

    def step(self, est: Estimate, record) -> None: ...
