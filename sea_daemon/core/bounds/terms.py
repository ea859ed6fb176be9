"""Where ρ_k comes from: the set of means' τ_h,act half-width per bounded input (docs/bounds.md,
"Which term dominates").

The set of means is a zonotope whose generators each come from one bounded input of one step
(eq:predwLinErrsetandGPerrset): the GP error Γ_μ box(η) (or a plain AKF's declared model error),
the declared human-torque rate Γ_τ box(r), the declared friction's range Φc box(w) (the range
form, docs/bounds.md §4) and the rest of the model's linearisation error Φ box(b).  The maps are
linear, so the half-width along τ_h,act, h = Σ_i |e_τᵀ g_i|, is the sum of the half-widths of the
generators of each input: :class:`TermShadow` propagates one zonotope per input with the
transition and the gain the bound took at each step (the filter-slope or the range form) and
reduces each the way the bound does (Girard, every ``reduce_every`` steps), so its terms add up to
the bound's h up to the order reduction (which boxes generators of different inputs together in
the bound, apart here) — and, with declared friction, up to the measurement's strips that cut the
bound's prior set (docs/bounds.md §4): the terms are then each input's half-width before the cuts,
and ``cut`` = h − their sum (≤ 0 up to the reduction) what the strips took off.  The rest of ρ_k, ρ_k − h, is the Gaussian part (√(s P_g,ττ) and its
combination with h, docs/bounds.md §3).  A diagnostic: ρ_k is unchanged.  Pure numerics.
"""
from __future__ import annotations

import numpy as np

from sea_daemon.core.bounds.zonotope import reduce_generators

#: the bounded inputs, in the order of :attr:`TermShadow.h_`
TERMS = ("gp", "rate", "friction", "linearisation")


class TermShadow:
    """One zonotope per bounded input of the set of means (module docstring).

    ``d`` states, ``n`` joints, ``tau_idx`` the τ_h,act indices; ``gp_cols`` whether the first n
    columns of a step's Γ are the GP error (or a declared model error), ``rate_cols`` whether the
    next n are the declared rate (the rest: the declared friction's columns).  ``h_`` (terms, n):
    the half-widths along each τ_h,act axis after the last step.
    """

    def __init__(self, d: int, n: int, tau_idx, gp_cols: bool, rate_cols: bool, reduce_every: int,
                 max_generators: int = 40):
        self.d, self.n = int(d), int(n)
        self.tau_idx = np.asarray(tau_idx)
        self.gp_cols, self.rate_cols = bool(gp_cols), bool(rate_cols)
        self.reduce_every = max(1, int(reduce_every))
        self.max_generators = int(max_generators)
        self.h_ = np.zeros((len(TERMS), self.n))
        self.reset()

    def reset(self) -> None:
        """The set of means back to a point."""
        self._G = [np.zeros((self.d, 0)) for _ in TERMS]
        self._k = 0
        self.h_[:] = 0.0

    def _split(self, Gamma, eta, b, Phi) -> list:
        """The new generators of one step, per input."""
        new = [[] for _ in TERMS]
        n = self.n
        if Gamma is not None and eta is not None and Gamma.shape[1]:
            Gs = np.asarray(Gamma, dtype=float) * np.asarray(eta, dtype=float)
            c = 0
            if self.gp_cols:
                new[0].append(Gs[:, :n])
                c = n
            if self.rate_cols:
                new[1].append(Gs[:, c:c + n])
                c += n
            if Gs.shape[1] > c:
                new[2].append(Gs[:, c:])
        if b is not None and np.any(b):
            Ph = np.eye(self.d) if Phi is None else np.asarray(Phi, dtype=float)
            new[3].append(Ph * np.asarray(b, dtype=float))
        return new

    def step(self, F, Gamma, eta, b, Phi, IKH) -> np.ndarray:
        """One step: (I − KH)(F·Z ⊕ Γ box(η) ⊕ Φ box(b)) per input, with the transition ``F`` and the
        inputs of the form the bound took.  Returns :attr:`h_`."""
        new = self._split(Gamma, eta, b, Phi)
        reduce = self._k % self.reduce_every == 0
        self._k += 1
        for i in range(len(TERMS)):
            G = IKH @ np.hstack([F @ self._G[i]] + new[i])
            if reduce and G.shape[1] > self.max_generators:
                G = reduce_generators(G, self.max_generators)
            self._G[i] = G
            self.h_[i] = np.abs(G[self.tau_idx]).sum(axis=1)
        return self.h_


class TermsRecorder:
    """A bound component (``AKF(cfg, bound=TermsRecorder)``, ``res.estimator(bound=TermsRecorder)``):
    the Theorem-1 bound of :func:`~sea_daemon.core.bounds.akf_bound.theorem_bound`, run in its
    Python step (the compiled step does not hand out its inputs), publishing the same ρ_k, and
    per step a row of :data:`COLUMNS` in :attr:`rows_` (joint 1).  Everything else is the bound's."""

    #: the columns of :attr:`rows_`: ρ_k, the set of means' τ half-width h, its terms, √P_g,ττ, and
    #: h minus the terms' sum (the measurement's strips, module docstring)
    COLUMNS = ("rho", "h") + TERMS + ("sigma_g", "cut")

    def __init__(self, akf):
        # local import: akf_bound builds on this package's modules; a recorder is a diagnostic on top
        from sea_daemon.core.bounds.akf_bound import theorem_bound
        self.bound = theorem_bound(akf)
        if self.bound is None:
            raise ValueError("no Theorem-1 bound for this estimator's residual")
        b = self.bound
        b.compiled = False
        self.akf = akf
        self.shadow = TermShadow(akf.d, akf.n, b.sm.tau_idx, b.model_error_term, b.tau_h_act_rate > 0,
                                 b.sm.reduce_every, b.sm.max_generators)
        self.rows_: list = []

    def __getattr__(self, name):
        return getattr(self.bound, name)

    def reset(self, est, record) -> None:
        self.bound.reset(est, record)
        self.shadow.reset()
        self.rows_ = []

    def step(self, est, record) -> None:
        b = self.bound
        b.step(est, record)
        IKH = np.eye(self.akf.d) - record.K_k @ self.akf.H
        h = self.shadow.step(*b.prior_inputs_, IKH)
        tau = int(b.sm.tau_idx[0])
        Pg = b.gauss.P if b.gauss.own else record.P
        hw = float(b.sm.means_half_widths()[tau])
        self.rows_.append((float(est.tau_h_act_bound[0]), hw, *(float(v) for v in h[:, 0]),
                           float(np.sqrt(max(Pg[tau, tau], 0.0))), hw - float(h[:, 0].sum())))

    def table(self, valid: np.ndarray | None = None) -> dict:
        """Means of :data:`COLUMNS` over the steps (those with ``valid`` true, aligned with the
        last steps), and ``gaussian`` = mean of ρ_k − h."""
        R = np.asarray(self.rows_, dtype=float).reshape(-1, len(self.COLUMNS))
        if valid is not None:
            v = np.asarray(valid, dtype=bool)[-len(R):]
            R = R[v] if v.any() else R[:0]
        if not len(R):
            return {}
        out = {c: float(R[:, i].mean()) for i, c in enumerate(self.COLUMNS)}
        out["gaussian"] = out["rho"] - out["h"]
        return out
