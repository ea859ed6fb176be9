"""The start-up gate of an AKF: whether the filter's initial error has decayed (``Estimate.valid``).

The filter starts from x̂₀ (a reset, or the end of the differentiator's window); its initial error
e₀ lies in the box b₀.  The error of step k is Φ_k e₀ plus what the noise and the model error put
in since the start, with Φ_k = Π (I − K_i H) F_i the filter's closed-loop map.  The published
bound ρ_k (Theorem 1 with P_k, or sqrt(s P_ττ)) covers the second part; the first is at most
t_k = |Φ_k|_τ b₀ per joint.  The filter has converged once t_k ≤ :data:`TRANSIENT_SHARE` ρ_k for
every joint; from then on until the next start the estimate is valid (Φ_k only shrinks further,
it is no longer tracked).  Allocation-free per step.  Pure numerics.
"""
from __future__ import annotations

import numpy as np

#: the estimate is valid once what is left of the initial error is at most this share of the
#: published bound
TRANSIENT_SHARE = 0.1


class StartupGate:
    """The start-up gate of one filter of n joints (module docstring).

    ``H`` (m, d): the measurement matrix; ``s``: the χ² quantile of the filter's confidence set;
    ``tau_h_act_max``: the largest τ_h,act the subject may apply when the filter starts [N m].
    Public state: ``b0`` (the box of e₀), ``Phi`` (Φ_k), ``transient`` (t_k per joint, of the last
    step checked), ``converged``, ``converged_at`` (the step k at which the gate opened, −1 not
    yet) and ``starts`` (how often it started).
    """

    def __init__(self, n: int, H: np.ndarray, s: float, tau_h_act_max: float):
        d = H.shape[1]                       # 5n, or 6n with τ̇_h,act (core.model.StateLayout)
        self.n = n
        self.H = H
        self.s = float(s)
        self.tau_h_act_max = float(tau_h_act_max)
        self.Phi = np.eye(d)
        self.b0 = np.zeros(d)
        self.converged = False
        self.converged_at = -1
        self.starts = 0
        self._I_d = np.eye(d)
        self._W = np.zeros((d, d))
        self._M = np.zeros((d, d))
        self._absrow = np.zeros((n, d))
        self.transient = np.zeros(n)

    def start(self, P: np.ndarray) -> None:
        """The filter starts with covariance P: b₀ = sqrt(s P_ii) for the measured components, and
        for τ_h,act the larger of that and ``tau_h_act_max`` (the subject may push with up to that
        torque when the filter starts; τ̂_h,act,0 = 0); Φ = I."""
        n = self.n
        np.sqrt(self.s * np.maximum(np.diag(P), 0.0), out=self.b0)
        np.maximum(self.b0[4 * n:5 * n], self.tau_h_act_max, out=self.b0[4 * n:5 * n])
        self._restart()

    def start_box(self, b0: np.ndarray) -> None:
        """Start from the error box ``b0`` (d,) (e.g. what a covariance cap cut off); Φ = I."""
        self.b0[:] = b0
        self._restart()

    def follow(self, starts: int, b0: np.ndarray) -> None:
        """A copy of the filter's gate: start from the box ``b0`` when the filter's gate has started
        since (``starts`` differs from this gate's count)."""
        if starts != self.starts:
            self.b0[:] = b0
            self._restart()
            self.starts = starts

    def _restart(self) -> None:
        self.Phi[:] = 0.0
        np.fill_diagonal(self.Phi, 1.0)
        self.stop()
        self.starts += 1

    def stop(self) -> None:
        """Not converged (the filter was reset)."""
        self.converged, self.converged_at = False, -1

    def check(self, K: np.ndarray, F: np.ndarray, rho: np.ndarray, k: int) -> bool:
        """After step k with gain K and transition F and published bound ρ_k: whether the estimate
        is valid (Φ_k = (I − K H) F Φ_{k−1}, the transient against :data:`TRANSIENT_SHARE` ρ_k)."""
        if self.converged:
            return True
        n = self.n
        M, W = self._M, self._W
        np.dot(K, self.H, out=M)              # (I − K H) F Φ
        np.subtract(self._I_d, M, out=M)
        np.dot(M, F, out=W)
        np.dot(W, self.Phi, out=M)
        self.Phi[:] = M
        np.abs(self.Phi[4 * n:5 * n], out=self._absrow)
        np.dot(self._absrow, self.b0, out=self.transient)
        if np.all(self.transient <= TRANSIENT_SHARE * rho):
            self.converged, self.converged_at = True, k
        return self.converged
