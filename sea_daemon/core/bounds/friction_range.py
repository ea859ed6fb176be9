"""The range form of the Theorem-1 bound for declared Coulomb/Stribeck friction (docs/bounds.md §4).

The filter linearises a declared friction τ_g(v) at v̂ with its slope s_g; where the set of means
spans v = 0 that slope ((F_c + F_s)/ε) times the set's extent is a large linearisation error.  The
range form linearises the friction at zero slope instead and bounds its error by the range of
τ_g over the set (interval arithmetic, :meth:`FrictionRange.range`), which contains the same set
of means (:meth:`FrictionRange.candidate`).  Used by
:class:`~sea_daemon.core.bounds.akf_bound.AKFTheoremBound`, which keeps whichever form gives the
narrower τ_h,act half-width.  Pure numerics.
"""
from __future__ import annotations

import math

import numpy as np

from sea_daemon.core.effects import COULOMB, STRIBECK, evaluate as effect_torque
from sea_daemon.core.linalg import discretize
from sea_daemon.core.model_core import lin_error_boxes


class FrictionRange:
    """The declared friction's groups of one model and the range form's step (module docstring).

    ``groups``: [(side, ℓ, c, [(code, p)])] (empty: the range form does not apply); ``arrays``:
    the same for :func:`~sea_daemon.core.model_core.lin_error_boxes`.
    """

    def __init__(self, model, tables, sets: str):
        """The declared Coulomb/Stribeck effects grouped per (side, joint): [(ℓ, c, [(code, p)])]
        with v = ℓᵀx the group's velocity (load: q̇_j = θ̇_m,j + θ̇_s,j; motor: θ̇_m,j) and c the
        column through which its torque τ_g(v) enters ẋ (load: −I_θ̈s M⁻¹e_j, eq:unknwn_load with
        eq:xsdd; motor: (−I_θ̈m + I_θ̈s) J⁻¹e_j, eq:thetadd), so f_nom = f_smooth + Σ_g c τ_g(ℓᵀx).
        Also the same as arrays for :func:`~sea_daemon.core.model_core.lin_error_boxes`.  ([], None) when
        the range candidate does not apply (no such effect, ellipsoid sets, effects outside the
        compiled vocabulary: ``tables`` None)."""
        self.groups, self.arrays = [], None
        self.tables = tables
        if sets != "zonotope" or tables is None:
            return
        n, d = model.n, 5 * model.n
        groups = {}
        for side, effs in (("load", model.load_effects), ("motor", model.motor_effects)):
            for e in effs:
                if e.code in (COULOMB, STRIBECK):
                    groups.setdefault((side, e.joint), []).append((int(e.code), np.asarray(e.vector, dtype=float)))
        if not groups:
            return
        out = []
        for (side, j), effs in sorted(groups.items()):
            ell = np.zeros(d)
            c = np.zeros(d)
            ell[2 * n + j] = 1.0
            if side == "load":
                ell[3 * n + j] = 1.0
                c[3 * n:4 * n] = -model.Minv[:, j]
            else:
                c[2 * n:3 * n] = -model.Jinv[:, j]
                c[3 * n:4 * n] = model.Jinv[:, j]
            out.append((side, ell, c, effs))
        # the same as arrays for model_core.lin_error_boxes (one f_nom per point for both boxes)
        self.arrays = (np.array([g[1] for g in out]), np.array([g[2] for g in out]),
                       np.array([i for i, g in enumerate(out) for _ in g[3]], dtype=np.int64),
                       np.array([code for g in out for code, _ in g[3]], dtype=np.int64),
                       np.ascontiguousarray([p for g in out for _, p in g[3]], dtype=float))
        self.groups = out

    @staticmethod
    def range(effs, lo: float, hi: float) -> tuple[float, float]:
        """[L, U] ⊇ {τ_g(v) : lo ≤ v ≤ hi} for τ_g = Σ p₀ m(v) tanh(v/ε), m ≡ 1 (Coulomb) or
        exp(−(v/v_s)²) (Stribeck), by interval arithmetic — rigorous: tanh is increasing, and m > 0
        lies between its values at the interval's largest and smallest |v|.  With one ε for all
        (the estimator's ``sign_eps``) τ_g = tanh(v/ε)·Σ p₀ m(v) is bounded as one product, which
        keeps a Coulomb and a Stribeck term of opposite signs from adding their widths."""
        vmax = max(abs(lo), abs(hi))
        vmin = 0.0 if lo <= 0.0 <= hi else min(abs(lo), abs(hi))
        L = U = 0.0          # per-effect sum (any ε)
        hl = hu = 0.0        # Σ p₀ m(v) over the interval (shared ε)
        eps0 = None
        shared = True
        for code, p in effs:
            eps = p[1] if code == COULOMB else p[2]          # the smoothing ε (effects.evaluate)
            if code == STRIBECK:
                m_lo, m_hi = math.exp(-(vmax / p[1]) ** 2), math.exp(-(vmin / p[1]) ** 2)
            else:
                m_lo = m_hi = 1.0
            a, b = (p[0] * m_lo, p[0] * m_hi) if p[0] >= 0.0 else (p[0] * m_hi, p[0] * m_lo)
            hl += a
            hu += b
            t_lo, t_hi = math.tanh(lo / eps), math.tanh(hi / eps)
            # [a, b]·[t_lo, t_hi]: the extreme corner products
            c = (a * t_lo, a * t_hi, b * t_lo, b * t_hi)
            L += min(c)
            U += max(c)
            shared = shared and (eps0 is None or eps == eps0)
            eps0 = eps
        if shared and eps0 is not None:
            t_lo, t_hi = math.tanh(lo / eps0), math.tanh(hi / eps0)
            c = (hl * t_lo, hl * t_hi, hu * t_lo, hu * t_hi)
            L, U = max(L, min(c)), min(U, max(c))
        return L, U

    def candidate(self, x0, u, P0, pts: np.ndarray, A_nom: np.ndarray, dt: float, A_k: np.ndarray,
                  Gamma_mu: np.ndarray, sm, phi):
        """The set of means' step with the friction linearised at zero slope (module docstring).

        The filter's drift error splits as ε = ε_smooth + Σ_g c (τ_g(v) − τ_g(v̂) − s_g ℓᵀ(x − x̂)),
        s_g the filter's slope at v̂.  With x − x̂ = a + g (a in the set of means, g ~ N(0, P) the
        Gaussian part) the step of a (eq:predwLinErrsetandGPerrset, ε held over the step) is

            a⁺ = F a + Φ ε = (F − Σ_g Φc s_g ℓᵀ) a + Φ ε_smooth + Σ_g Φc [τ_g(v) − τ_g(v̂) − s_g ℓᵀg],

        exactly; F g is the filter's own Gaussian part and stays with P.  So the set of means may
        be propagated with F_B = F − Σ Φc s_g ℓᵀ (the filter's transition without the friction's
        slope) and the bounded inputs Φ box(b_smooth) and Φc·[−w_g, w_g] with
        w_g = max|τ_g(v) − τ_g(v̂)| over v ∈ ℓᵀC_{k−1} (interval arithmetic, :meth:`range`)
        + |s_g| √(s ℓᵀP ℓ) (g on its χ² set, the same event as x ∈ C_{k−1}).  Both this and the
        filter-slope step contain a⁺ under Theorem 1's assumptions, so either may be taken.
        ``pts``: the point set of C_{k−1}; ``A_k``, ``Gamma_mu``: the filter's step (StepRecord);
        ``sm`` the set of means; ``phi(A, b, dt, Gamma_mu)`` Φ on the columns of b.  Returns (F_B − F, Γ columns Φc (d, groups), w, b_smooth,
        Φ of b_smooth, b) with b the filter-slope form's sampled box (both from one pass)."""
        d = x0.shape[0]
        n = d // 5
        nf = len(self.groups)
        dF = np.zeros((d, d))
        GamF = np.empty((d, nf))
        w = np.empty(nf)
        slopes = np.empty(nf)
        Phi_full = None
        s_set = sm.s_state
        for i, (side, ell, c, effs) in enumerate(self.groups):
            v0 = float(ell @ x0)
            t0 = sl = 0.0
            for code, p in effs:
                t_, _, dv, _ = effect_torque(code, p, 0.0, v0, 0.0)
                t0 += t_
                sl += dv
            r = float(sm.half_widths(ell[None, :], P0, s=s_set)[0])   # |v − v̂| ≤ r on C_{k−1}
            L, U = self.range(effs, v0 - r, v0 + r)
            rg = math.sqrt(max(s_set * float(ell @ P0 @ ell), 0.0))         # |ℓᵀg| on E(0, s P)
            w[i] = max(U - t0, t0 - L) + abs(sl) * rg
            if side == "load":
                # Φ's θ̈_s columns are Γ_μ M (Γ_μ = Φ I_μ M⁻¹): Φ c = −Γ_μ e_j
                j = int(np.flatnonzero(ell[3 * n:4 * n])[0])
                GamF[:, i] = -Gamma_mu[:, j]
            else:
                if Phi_full is None:
                    Phi_full = discretize(A_k, np.eye(d), dt)[1]
                GamF[:, i] = Phi_full @ c
            # F_B = F − Φc s_g ℓᵀ; A_smooth = A_nom − c s_g ℓᵀ
            dF -= sl * np.outer(GamF[:, i], ell)
            slopes[i] = sl
        # both sampled boxes in one pass: the filter-slope form's b (f_nom with A_nom) and
        # b_smooth (f_nom without the friction groups, with A_nom minus their slopes)
        b = np.zeros(d)
        b_s = np.zeros(d)
        ell_a, col_a, eg, ec, ep = self.arrays
        lin_error_boxes(np.ascontiguousarray(pts, dtype=float), np.ascontiguousarray(u, dtype=float),
                        np.ascontiguousarray(x0, dtype=float), np.ascontiguousarray(A_nom, dtype=float),
                        self.tables.dynamics, ell_a, col_a, slopes, eg, ec, ep, b, b_s)
        b_s *= 1.0 + sm.margin
        return dF, GamF, w, b_s, phi(A_k, b_s, dt, Gamma_mu), (1.0 + sm.margin) * b

