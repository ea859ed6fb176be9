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

from scipy.special import ndtri

from sea_daemon.core.effects import COULOMB, STRIBECK, evaluate as effect_torque
from sea_daemon.core.bounds.measurement_strip import cut_generators, strip_halfwidths
from sea_daemon.core.linalg import discretize
from sea_daemon.core.model_core import lin_error_boxes

#: sub-intervals of :meth:`FrictionRange.deviation` (its looseness is at most κ·2r/PIECES)
PIECES = 16
#: the slopes κ_g the range form may keep in its transition: 0 (the range alone), the secant's over
#: the interval, or this share of the filter's slope s_g (:meth:`FrictionRange.candidate`)
SLOPE_RULES = (0.0, "secant", 1 / 64, 1 / 32, 1 / 16, 1 / 8, 1 / 4, 1 / 2, 1.0)
#: steps of the fixed point r = r_g + L_v w(r) of :meth:`FrictionRange._choose`
FIXED_POINT_STEPS = 6
#: a velocity half-width [rad/s] beyond which the fixed point counts as none (:meth:`FrictionRange._choose`)
R_RUNAWAY = 1e3
#: a rule is chosen again at once when a width w_g grew by this factor since it was chosen
REGROW = 1.5
#: the slowest time constant [s] of the set's transition a rule may give (:meth:`FrictionRange._choose`)
SETTLE_S = 0.1
#: the horizon [s] of the ℓ1 norm of a friction-torque pulse's τ_h,act response that rates a rule
HORIZON_S = 0.5


class FrictionRange:
    """The declared friction's groups of one model and the range form's step (module docstring).

    ``groups``: [(side, ℓ, c, [(code, p)])] (empty: the range form does not apply); ``arrays``:
    the same for :func:`~sea_daemon.core.model_core.lin_error_boxes`.
    """

    def __init__(self, model, tables, sets: str, state_extra: int = 0):
        """The declared Coulomb/Stribeck effects grouped per (side, joint): [(ℓ, c, [(code, p)])]
        with v = ℓᵀx the group's velocity (load: q̇_j = θ̇_m,j + θ̇_s,j; motor: θ̇_m,j) and c the
        column through which its torque τ_g(v) enters ẋ (load: −I_θ̈s M⁻¹e_j, eq:unknwn_load with
        eq:xsdd; motor: (−I_θ̈m + I_θ̈s) J⁻¹e_j, eq:thetadd), so f_nom = f_smooth + Σ_g c τ_g(ℓᵀx).
        Also the same as arrays for :func:`~sea_daemon.core.model_core.lin_error_boxes`.  ([], None) when
        the range candidate does not apply (no such effect, ellipsoid sets, effects outside the
        compiled vocabulary: ``tables`` None for a model without a rigid body).  A rigid body's
        (``model.urdf``) M(q) varies: its load groups' c is taken at q̂ each step and its boxes are
        sampled on f_nom in Python (``tables`` None, :meth:`_rigid_boxes`).  ``state_extra``: the
        states after the 5n (n with τ̇_h,act, core.model.StateLayout), which no friction enters."""
        self.groups, self.arrays = [], None
        self.tables = tables
        self.model = model
        self.kappa_ = np.zeros(0)         # the slope κ_g each group kept in the last candidate
        self.choose_every = 1             # steps between two choices of the slope rule (_choose)
        self.rule_ = 1                    # index into SLOPE_RULES of the rule in use
        self._steps = 0
        self._w_chosen = np.zeros(0)      # the widths w_g when the rule was chosen
        if sets != "zonotope" or (tables is None and getattr(model, "rigid", None) is None):
            return
        n, d = model.n, 5 * model.n + int(state_extra)
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
        self.kappa_ = np.zeros(len(out))
        self._w_chosen = np.full(len(out), np.inf)
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

    @classmethod
    def deviation(cls, effs, v0: float, r: float, t0: float, kappa: float, pieces: int = PIECES) -> float:
        """An upper bound of max |τ_g(v) − t0 − κ (v − v0)| over v ∈ [v0 − r, v0 + r] (κ ≥ 0),
        rigorous: on each of ``pieces`` equal sub-intervals τ_g lies in its :meth:`range` and
        κ (v − v0) between its values at the ends.  κ = 0: the range of the whole interval."""
        if kappa == 0.0 or r <= 0.0:
            L, U = cls.range(effs, v0 - r, v0 + r)
            return max(U - t0, t0 - L)
        worst = 0.0
        h = 2.0 * r / pieces
        for i in range(pieces):
            a = -r + i * h
            L, U = cls.range(effs, v0 + a, v0 + a + h)
            worst = max(worst, U - t0 - kappa * a, t0 + kappa * (a + h) - L)
        return worst

    @staticmethod
    def secant(effs, v0: float, r: float, slope: float) -> float:
        """The slope of τ_g's secant over [v0 − r, v0 + r], within [0, ``slope``] (the filter's)."""
        if r <= 0.0:
            return 0.0
        t = [sum(effect_torque(code, p, 0.0, v, 0.0)[0] for code, p in effs) for v in (v0 - r, v0 + r)]
        return min(max((t[1] - t[0]) / (2.0 * r), 0.0), max(slope, 0.0))

    def reset(self) -> None:
        """A new run: the slope rule is chosen again at the next step."""
        self._steps = 0
        self.rule_ = 1

    def cut(self, sm, record, H: np.ndarray) -> None:
        """With declared friction, the prior set of means ``sm.Gprior_`` cut by the step's
        measurement strips |h_iᵀa⁻| ≤ |e_i| + z √S_ii, z = z_{1−δ_N/(2m)}
        (:mod:`.measurement_strip`): the measured velocities hold the set's velocity extent where
        the filter's gain leaves it to the friction's slope (docs/bounds.md §4).  The angles' strips
        always; a velocity's strip only if its cut does not widen the τ_h,act half-width after
        (I − KH)."""
        if not self.groups or sm.sets != "zonotope":
            return
        m = H.shape[0]
        z = float(ndtri(1.0 - sm.delta_noise / (2 * m)))
        keep = -(record.K_k[sm.tau_idx] @ H)           # the τ_h,act rows of I − KH
        keep[np.arange(sm.tau_idx.size), sm.tau_idx] += 1.0
        c = strip_halfwidths(record.innovation, record.S_k, z)
        a = m // 2                                     # the angles' channels, then the velocities'
        G = cut_generators(sm.Gprior_, H[:a], c[:a])
        sm.Gprior_ = cut_generators(G, H[a:], c[a:], keep)

    def _widths(self, par, rule: int, w: np.ndarray) -> None:
        """w_g of every group under ``rule`` into ``w``, its κ_g into :attr:`kappa_`."""
        for i, (side, ell, c, effs) in enumerate(self.groups):
            v0, t0, sl, r, rg = par[i]
            kap = self._slope(rule, effs, v0, r, sl)
            w[i] = self.deviation(effs, v0, r, t0, kap) + abs(sl - kap) * rg
            self.kappa_[i] = kap

    @classmethod
    def _slope(cls, rule, effs, v0: float, r: float, sl: float) -> float:
        """κ_g of ``SLOPE_RULES[rule]`` for a group at v̂ = ``v0`` with half-width ``r`` and the filter's slope ``sl``."""
        if sl <= 0.0:
            return 0.0
        k = SLOPE_RULES[rule]
        if k == "secant":
            return cls.secant(effs, v0, r, sl)
        return float(k) * sl

    def _choose(self, par, GamF: np.ndarray, loop, dt: float) -> int:
        """The rule of :data:`SLOPE_RULES` whose set of means holds the friction narrowest in the
        long run.  Per rule, the ℓ1 norms over :data:`HORIZON_S` of the response of
        (I − KH)(F + ΔF) to the pulse (I − KH) Φc_g along τ_h,act (L_τ) and along the group's
        velocity ℓ (L_v) give the steady state the friction's inputs would build if they stayed:
        the velocity half-width r = r_g + L_v w_g(r) (a few fixed-point steps from the present r;
        w_g grows with r, κ_g r for a steep κ_g: no fixed point is an infinite cost) and the τ
        half-width Σ_g L_τ w_g(r).  ``loop`` = (F, I − KH) of the step."""
        F, IKH = loop
        d = F.shape[0]
        n = d // 5
        nr, ng = len(SLOPE_RULES), len(self.groups)
        Ms = np.empty((nr, d, d))
        for k in range(nr):
            dF = np.zeros((d, d))
            for i, (side, ell, c, effs) in enumerate(self.groups):
                v0, t0, sl, r, rg = par[i]
                dF -= (sl - self._slope(k, effs, v0, r, sl)) * np.outer(GamF[:, i], ell)
            Ms[k] = IKH @ (F + dF)
        ells = np.array([g[1] for g in self.groups])            # (ng, d)
        V = np.broadcast_to(IKH @ GamF, (nr,) + GamF.shape).copy()
        lt = np.zeros((nr, ng))
        lv = np.zeros((nr, ng))
        for _ in range(max(1, int(round(HORIZON_S / dt)))):
            lt += np.abs(V[:, 4 * n:, :]).sum(axis=1)
            lv += np.abs(np.einsum("gd,kdg->kg", ells, V))
            V = Ms @ V
            if not np.all(np.isfinite(V)) or np.max(np.abs(V)) > 1e12:
                lt[:] = np.where(np.isfinite(lt), lt, np.inf)
                break
        # a loop slower than SETTLE_S only if no other settles: its response outlasts the horizon
        slow = np.max(np.abs(np.linalg.eigvals(Ms)), axis=1) > math.exp(-dt / SETTLE_S)
        costs = np.full(nr, np.inf)
        for k in range(nr):
            cost = 0.0
            for i, (side, ell, c, effs) in enumerate(self.groups):
                v0, t0, sl, r, rg = par[i]
                if not (np.isfinite(lt[k, i]) and np.isfinite(lv[k, i])):
                    cost = np.inf
                    break
                rr, w = r, np.inf
                for _ in range(FIXED_POINT_STEPS):
                    kap = self._slope(k, effs, v0, rr, sl)
                    w = self.deviation(effs, v0, rr, t0, kap) + abs(sl - kap) * rg
                    rr_new = rg + lv[k, i] * w
                    settled = abs(rr_new - rr) <= 1e-3 * rr_new
                    rr = rr_new
                    if settled or rr > R_RUNAWAY:
                        break
                if rr > R_RUNAWAY:
                    w = np.inf                 # r grows with w: no fixed point
                cost += lt[k, i] * w
            costs[k] = cost
        # the cheapest loop that settles within SETTLE_S; if none does, the cheapest; if no rule
        # has a fixed point, the rule in use
        for c in (np.where(slow, np.inf, costs), costs):
            if np.isfinite(c).any():
                return int(np.argmin(c))
        return self.rule_

    def _groups_at(self, x0, P0, sm, GamF: np.ndarray, slopes: np.ndarray, Gamma_mu, A_k, dt: float) -> list:
        """Per group (v̂, τ_g(v̂), s_g, r, r_g) — r the half-width of C_{k−1} along ℓ_g, r_g its
        Gaussian part's — with Φc_g into the columns of ``GamF`` and s_g into ``slopes``."""
        d = x0.shape[0]
        n = d // 5
        s_set = sm.s_state
        Phi_full = None
        par = []
        for i, (side, ell, c, effs) in enumerate(self.groups):
            v0 = float(ell @ x0)
            t0 = sl = 0.0
            for code, p in effs:
                t_, _, dv, _ = effect_torque(code, p, 0.0, v0, 0.0)
                t0 += t_
                sl += dv
            r = float(sm.half_widths(ell[None, :], P0, s=s_set)[0])   # |v − v̂| ≤ r on C_{k−1}
            rg = math.sqrt(max(s_set * float(ell @ P0 @ ell), 0.0))         # |ℓᵀg| on E(0, s P)
            par.append((v0, t0, sl, r, rg))
            if side == "load":
                # Φ's θ̈_s columns are Γ_μ M (Γ_μ = Φ I_μ M⁻¹): Φ c = −Γ_μ e_j
                j = int(np.flatnonzero(ell[3 * n:4 * n])[0])
                GamF[:, i] = -Gamma_mu[:, j]
            else:
                if Phi_full is None:
                    Phi_full = discretize(A_k, np.eye(d), dt)[1]
                GamF[:, i] = Phi_full @ c
            slopes[i] = sl
        return par

    def candidate(self, x0, u, P0, pts: np.ndarray, A_nom: np.ndarray, dt: float, A_k: np.ndarray,
                  Gamma_mu: np.ndarray, sm, phi, loop=None):
        """The set of means' step with the friction linearised at zero slope (module docstring).

        The filter's drift error splits as ε = ε_smooth + Σ_g c (τ_g(v) − τ_g(v̂) − s_g ℓᵀ(x − x̂)),
        s_g the filter's slope at v̂.  With x − x̂ = a + g (a in the set of means, g ~ N(0, P) the
        Gaussian part) the step of a (eq:predwLinErrsetandGPerrset, ε held over the step) is

            a⁺ = F a + Φ ε = (F − Σ_g Φc s_g ℓᵀ) a + Φ ε_smooth + Σ_g Φc [τ_g(v) − τ_g(v̂) − s_g ℓᵀg],

        exactly; F g is the filter's own Gaussian part and stays with P.  For any slope κ_g the
        bracket may keep −κ_g ℓᵀa out and the transition take it in:

            a⁺ = (F − Σ_g Φc (s_g − κ_g) ℓᵀ) a + Φ ε_smooth + Σ_g Φc [τ_g(v) − τ_g(v̂) − κ_g ℓᵀa − s_g ℓᵀg].

        So the set of means may be propagated with F_B = F − Σ Φc (s_g − κ_g) ℓᵀ and the bounded
        inputs Φ box(b_smooth) and Φc·[−w_g, w_g] with w_g = max |τ_g(v) − τ_g(v̂) − κ_g (v − v̂)|
        over v ∈ ℓᵀC_{k−1} (interval arithmetic, :meth:`deviation`) + |s_g − κ_g| √(s ℓᵀP ℓ) (g on
        its χ² set, the same event as x ∈ C_{k−1}).  κ_g = 0 is the range of τ_g; κ_g = the secant's
        slope over the interval (:meth:`secant`) is kept when its w_g is not larger: with κ_g = 0
        the filter's gain, made for the steep slope s_g, leaves F_B's closed loop ringing (on a
        still arm the τ_h,act response to a friction-torque pulse had an ℓ1 norm of 4.2 against 1.1
        with the filter's own F) and the set of means adds the friction's range up over that
        ringing; the secant's slope damps it.  Both this and the
        filter-slope step contain a⁺ under Theorem 1's assumptions, so either may be taken.
        ``pts``: the point set of C_{k−1}; ``A_k``, ``Gamma_mu``: the filter's step (StepRecord);
        ``sm`` the set of means; ``phi(A, b, dt, Gamma_mu)`` Φ on the columns of b; ``loop`` (F, I − KH)
        of the step, to choose the slope rule every :attr:`choose_every` steps (:meth:`_choose`;
        None: the rule in use).  Returns (F_B − F, Γ columns Φc (d, groups), w, b_smooth,
        Φ of b_smooth, b) with b the filter-slope form's sampled box (both from one pass)."""
        d = x0.shape[0]
        nf = len(self.groups)
        dF = np.zeros((d, d))
        GamF = np.empty((d, nf))
        w = np.empty(nf)
        slopes = np.empty(nf)
        par = self._groups_at(x0, P0, sm, GamF, slopes, Gamma_mu, A_k, dt)
        self._widths(par, self.rule_, w)
        # the rule chosen every 50 ms, and at once when its widths grew by half since (its
        # error grows with the set, κ r for a steep κ: the set would run away before the next choice)
        if loop is not None and (self._steps % self.choose_every == 0 or np.any(w > REGROW * self._w_chosen + 1e-6)):
            self.rule_ = self._choose(par, GamF, loop, dt)
            self._widths(par, self.rule_, w)
            self._w_chosen = w.copy()
        self._steps += 1
        for i, (side, ell, c, effs) in enumerate(self.groups):
            kap = self.kappa_[i]
            sl = par[i][2]
            # F_B = F − Φc (s_g − κ_g) ℓᵀ; A_smooth = A_nom − c s_g ℓᵀ
            dF -= (sl - kap) * np.outer(GamF[:, i], ell)
        # both sampled boxes in one pass: the filter-slope form's b (f_nom with A_nom) and
        # b_smooth (f_nom without the friction groups, with A_nom minus their slopes)
        b = np.zeros(d)
        b_s = np.zeros(d)
        if self.tables is None:
            self._rigid_boxes(pts, u, x0, A_nom, slopes, b, b_s)
        else:
            ell_a, col_a, eg, ec, ep = self.arrays
            lin_error_boxes(np.ascontiguousarray(pts, dtype=float), np.ascontiguousarray(u, dtype=float),
                            np.ascontiguousarray(x0, dtype=float), np.ascontiguousarray(A_nom, dtype=float),
                            self.tables.dynamics, ell_a, col_a, slopes, eg, ec, ep, b, b_s)
        b_s *= 1.0 + sm.margin
        return dF, GamF, w, b_s, phi(A_k, b_s, dt, Gamma_mu), (1.0 + sm.margin) * b


    def _group_torques(self, v: np.ndarray) -> np.ndarray:
        """τ_g(v_g) of every group at its velocity v_g."""
        return np.array([sum(effect_torque(code, p, 0.0, v[i], 0.0)[0] for code, p in g[3])
                         for i, g in enumerate(self.groups)])

    def _rigid_boxes(self, pts, u, x0, A_nom, slopes, b, b_s) -> None:
        """:func:`~sea_daemon.core.model_core.lin_error_boxes` for a model with a rigid body: b and
        b_smooth over the rows of ``pts``, f_nom in Python (Pinocchio's ABA per point).  A load
        group's torque enters ẋ as c_g(q) τ_g, c_g(q) = −I_θ̈s M(q)⁻¹ e_j: f_smooth = f_nom − Σ_g c_g(q̂) τ_g
        (M⁻¹ at x̂_{k−1}, :meth:`~sea_daemon.core.model.SEAModel.at`) has the Jacobian
        A_nom − Σ_g c_g(q̂) s_g ℓᵀ at x̂ and keeps (c_g(q) − c_g(q̂)) τ_g(v), sampled at the points as
        the rest of f_nom is."""
        model = self.model
        n = model.n
        ells = np.array([g[1] for g in self.groups])
        cols = np.array([g[2] for g in self.groups])
        for i, (side, ell, c, effs) in enumerate(self.groups):
            if side == "load":
                j = int(np.flatnonzero(ell[3 * n:4 * n])[0])
                cols[i, 3 * n:4 * n] = -model.Minv[:, j]
        v0 = ells @ x0
        t0 = self._group_torques(v0)
        f0 = model.f_nom(x0, u)
        for x in np.asarray(pts, dtype=float):
            fx = model.f_nom(x, u)
            lin = A_nom @ (x - x0)
            e = fx - f0 - lin
            v = ells @ x
            es = e - cols.T @ (self._group_torques(v) - t0 - slopes * (v - v0))
            # the rounding floor, so an exactly linear drift gives exactly 0
            tol = 1e-12 * (np.abs(fx) + np.abs(f0) + np.abs(lin))
            np.maximum(b, np.where(np.abs(e) <= tol, 0.0, np.abs(e)), out=b)
            np.maximum(b_s, np.where(np.abs(es) <= tol, 0.0, np.abs(es)), out=b_s)
