"""The Gaussian part of the Theorem-1 bound (docs/bounds.md §3, "The Gaussian part").

The bound splits x − x̂ = a + g: a in the set of means (the bounded inputs: GP error,
linearisation error, the declared human-torque rate), g Gaussian.  g must carry only what is
Gaussian noise, so its covariance P_g is propagated with the filter's gain but without what the
set of means already holds — the GP's variance in Q (eq:GPvarfwd) and, when a rate is declared,
the τ_h,act random walk:

    P_g,k = (I − K_k H)(F_k P_g,k−1 F_kᵀ + Q_g,k)(I − K_k H)ᵀ + K_k R K_kᵀ,   P_g,0 = P₀,

Q_g,k = Σ_nom,k (``StepRecord.Sigma_nom``) with its τ_h,act rows and columns zero when a rate
is declared (:func:`~sea_daemon.core.bounds.bound_core.gaussian_part`).  Without a GP and
without a rate it is the filter's own P.  Pure numerics.
"""
from __future__ import annotations

import numpy as np

from sea_daemon.core.bounds.bound_core import gaussian_part


class GaussianPart:
    """P_g of one filter (module docstring): ``own`` whether it differs from the filter's P
    (a GP, or ``drop_tau``: a declared rate), ``drop_tau`` whether the walk stays out of Q_g."""

    def __init__(self, akf, own: bool, drop_tau: bool):
        self.akf = akf
        self.own = bool(own)
        self.drop_tau = bool(drop_tau)
        d = akf.d
        self.P = np.zeros((d, d))              # P_g,k
        self.P_prev = np.zeros((d, d))         # P_g,k−1

    def reset(self, P0: np.ndarray) -> None:
        """A reset of the filter: P_g = P₀."""
        self.P[:] = P0

    def step(self, record) -> tuple[np.ndarray, np.ndarray]:
        """(P_g,k−1, P_g,k) of the step ``record``: the filter's P_{k−1}, P_k unless :attr:`own`."""
        if not self.own:
            return record.P_prev, record.P
        self.P_prev[:] = self.P
        akf = self.akf
        gaussian_part(record.F_k, record.K_k, akf.H, akf.R, record.Sigma_nom, 4 * akf.n, self.drop_tau,
                      self.P_prev, self.P)
        return self.P_prev, self.P
