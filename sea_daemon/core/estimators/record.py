"""The seam between a filter step and its bound: :class:`StepRecord` and :class:`BoundConsumer`.

Each reset and each filter step of an :class:`~sea_daemon.core.estimators.akf.AKF` fills one
:class:`StepRecord` — the filter's public per-step quantities that the Theorem-1 bound needs,
named as the paper and filterpy name them — and hands it to its bound:

* in the step itself (:meth:`AKF.finish_step`: the :class:`~sea_daemon.core.estimators.base.Bound`'s
  ``step(est, record)``, then the start-up gate), or
* to a :class:`BoundConsumer` attached with :meth:`AKF.attach` (the daemon's bound worker,
  :mod:`sea_daemon.runtime.bound_worker`, which copies the record into shared memory and runs
  :meth:`AKF.finish_step` on a copy of the filter in another process).

Theorem 1 (step k−1 → k) uses, from the filter:

* C_{k−1} = E(x̂_{k−1}, X̂_{k−1}) ⊕ E(0, s P_{k−1}): ``x_prev``, ``P_prev``;
* the linearisation error over C_{k−1} (eq:linerrsetdx, bounded per dimension,
  eq:linearerrellipsoid) of the drift linearised at x̂_{k−1} with input ``u`` held over ``dt``:
  ``A_k`` (continuous Jacobian, eq:linearization), ``z`` (ẑ_{k−1}, where the GP was evaluated),
  ``mu`` = μ(ẑ), ``dmu_dz`` = ∂μ/∂z (eq:moejac);
* the set of prior means (eq:predwLinErrsetandGPerrset): ``F_k`` (discrete transition), ``Gamma_mu``
  (Γ_μ = ∫₀^dt e^{A s} ds I_μ M⁻¹, the map of a torque error held over the step, eq:Dmuhat);
* the filter step on the set and ρ_k: ``K_k`` (gain), ``P`` (posterior P_k), and ``Sigma_nom``
  (Σ_nom,k, the step's process noise without the GP's variance: what the bound's Gaussian part
  propagates, docs/bounds.md §3), ``innovation`` (y_k − H x̂⁻_k) and ``S_k`` (its covariance
  H P⁻ Hᵀ + R): the measurement's strips on the prior set (docs/bounds.md §4).

and, for the start-up gate (:class:`~sea_daemon.core.estimators.gate.StartupGate`), ``gate_box``
b₀ and ``gate_starts`` (how often the gate started).  ``kind`` is :data:`STEP` or :data:`RESET`
(the filter was initialised: ``ready`` says whether from a sample; ``P`` is P₀ then).

The arrays of the filter's own record are views of the filter's arrays (nothing is copied in
the step); a record of the same shapes made with :meth:`StepRecord.zeros` receives a copy
(:meth:`StepRecord.copy_from`).  Pure data: no I/O, no clock, no threads.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar, Protocol, runtime_checkable

import numpy as np

#: :attr:`StepRecord.kind`: a filter step / a reset of the filter
STEP, RESET = "step", "reset"


@dataclass(eq=False)
class StepRecord:
    """What one filter step (or reset) hands its bound (module docstring); d = 5n, m = 4n."""

    #: :data:`STEP` or :data:`RESET`
    kind: str
    #: step count k (0 at a reset)
    k: int
    #: length of the step [s]
    dt: float
    #: the filter was initialised from a sample (False after a reset without one)
    ready: bool
    #: how often the start-up gate started (a copy of the filter follows it, :meth:`StartupGate.follow`)
    gate_starts: int
    #: u_{k−1} (n,) [N m], the input held over the step
    u: np.ndarray
    #: x̂_{k−1} (d,), the previous posterior mean
    x_prev: np.ndarray
    #: P_{k−1} (d, d), the previous posterior covariance
    P_prev: np.ndarray
    #: ẑ_{k−1} = [q̂, q̂̇, q̈] (3n,), where the residual was evaluated
    z: np.ndarray
    #: A_k (d, d), the continuous Jacobian of the drift at x̂_{k−1} (eq:linearization)
    A_k: np.ndarray
    #: F_k (d, d), the discrete transition
    F_k: np.ndarray
    #: Γ_μ (d, n) = ∫₀^dt e^{A s} ds I_μ M⁻¹ (eq:Dmuhat)
    Gamma_mu: np.ndarray
    #: K_k (d, m), the Kalman gain
    K_k: np.ndarray
    #: P_k (d, d), the posterior covariance (P₀ at a reset)
    P: np.ndarray
    #: μ(ẑ_{k−1}) (n,) [N m], the residual's mean
    mu: np.ndarray
    #: ∂μ/∂z at ẑ_{k−1} (n, 3n) (eq:moejac)
    dmu_dz: np.ndarray
    #: b₀ (d,), the box of the error the filter started with (the start-up gate)
    gate_box: np.ndarray
    #: Σ_nom,k (d, d), the step's process noise without the GP's variance (Q_k = Σ_nom,k + Γ_μ σ² Γ_μᵀ)
    Sigma_nom: np.ndarray
    #: y_k − H x̂⁻_k (m,), the step's innovation
    innovation: np.ndarray
    #: S_k (m, m) = H P⁻ Hᵀ + R, the innovation's covariance
    S_k: np.ndarray

    #: the array fields, in the order a copy lays them out
    ARRAYS: ClassVar[tuple[str, ...]] = ("u", "x_prev", "P_prev", "z", "A_k", "F_k", "Gamma_mu", "K_k", "P",
                                         "mu", "dmu_dz", "gate_box", "Sigma_nom", "innovation", "S_k")

    @classmethod
    def zeros(cls, n: int, d: int | None = None) -> "StepRecord":
        """A record of n joints with arrays of its own (d = 5n unless given, m = 4n)."""
        d, m = (5 * n if d is None else int(d)), 4 * n
        return cls(STEP, 0, 0.0, False, 0, np.zeros(n), np.zeros(d), np.zeros((d, d)), np.zeros(3 * n),
                   np.zeros((d, d)), np.zeros((d, d)), np.zeros((d, n)), np.zeros((d, m)), np.zeros((d, d)),
                   np.zeros(n), np.zeros((n, 3 * n)), np.zeros(d), np.zeros((d, d)), np.zeros(m), np.zeros((m, m)))

    def arrays(self) -> tuple[tuple[str, np.ndarray], ...]:
        """(name, array) of the array fields, in :attr:`ARRAYS` order."""
        return tuple((name, getattr(self, name)) for name in self.ARRAYS)

    def copy_from(self, other: "StepRecord") -> None:
        """Every field of ``other`` into this record (the arrays copied into this record's own)."""
        self.kind, self.k, self.dt, self.ready, self.gate_starts = (other.kind, other.k, other.dt, other.ready,
                                                                    other.gate_starts)
        for name, a in self.arrays():
            a[...] = getattr(other, name)


@runtime_checkable
class BoundConsumer(Protocol):
    """What takes a filter's records in place of its in-step bound (:meth:`AKF.attach`).

    ``take(est, record)`` is called at the end of every reset and filter step with the filter's
    :class:`StepRecord`; for a step it fills ``est.tau_h_act_bound`` with the newest ρ it has and
    ``est.valid`` with whether the estimate may be used (the start-up gate runs where ρ_k is
    computed, :meth:`AKF.finish_step`).  For a reset it leaves ``est`` as the filter made it.
    """

    def take(self, est, record: StepRecord) -> None: ...
