"""Set-membership propagation of Theorem 1 (Noack et al. 2010) and the torque bound ρ_k.

The state is a set of Gaussians (eq:gaussianset): x_k ~ N(m, P_k) with unknown mean
m ∈ x̂_k + X̂_k.  The centre x̂_k is the (GP-)AKF estimate; this class tracks the shape
X̂_k of the set of means next to the filter and never touches the filter itself.  X̂_k is a
zonotope by default (generators G_: Minkowski sums of mapped boxes and affine maps are
exact, order reduction is the only outer approximation) or, with sets="ellipsoid", the
paper's ellipsoid E(0, X̂_k) (trace-minimal outer ellipsoid at every sum).

One step k → k+1 (proof of Theorem 1):

1. C_k = E(x̂_k, X̂_k) ⊕ E(0, s_d P_k)                         (eq:confidenceset; outer ellipsoid)
2. linearisation error ε = f(x) − f̄(x) over x ∈ C_k, per dimension:
   b_i = max_{x ∈ C_k} |ε_i(x)|                                 (eq:linerrsetdx, eq:linearerrellipsoid)
3. prior set of means (eq:predwLinErrsetandGPerrset)
   X⁻ = F X̂ Fᵀ ⊕ [GP error: segments Γ_j η_j] ⊕ [lin. error: segments Φ_i b_i]
   as ONE n-ary trace-minimal Minkowski sum (Kurzhanski/Maksarov family, ellipsoid.py);
4. filter step on the set: X̂⁺ = (I − K H) X⁻ (I − K H)ᵀ (affine, exact); the centre
   x̂⁻ + K(y − H x̂⁻) is the filter's posterior estimate.
5. ρ_{k+1} from the set of means' exact half-width along the τ_h,act axis, h_j = Σ|G_j·|
   (zonotope) or sqrt(X̂_jj) (ellipsoid), and the Gaussian part: by default (projection=
   "scalar") the exact worst-case quantile of a Gaussian shifted anywhere in ±h_j
   (shifted_gaussian_halfwidth); "marginal"/"state": h_j + sqrt(s P_jj) (support functions
   add over a Minkowski sum).

Probability levels.  δ is split into δ_GP (the GP uniform bound, eq:gpmeanbounds, whose
constants the caller computes with gp_bound.error_bound) and δ_N = δ − δ_GP for the
Gaussian part: s_d = χ²_d(1 − δ_N) for the set C_k (on which the linearisation error is
bounded); for ρ by default (projection="scalar") δ_N/n_τ per joint in the shifted-Gaussian
quantile (valid for the scalar eq:bounds, simultaneous over joints by Bonferroni);
"marginal": s_τ = χ²_{n_τ}(1 − δ_N); "state": s_d (the paper's projection of C_k).  With
the union bound Pr(|τ̂ − τ| ≤ ρ) ≥ 1 − δ_GP − δ_N = 1 − δ at each step, conditional on the
previous step's x_k ∈ C_k (as in the paper's theorem).

Linearisation-error bound (step 2) — how it is computed and where it is approximate:
the maximum of |ε_i| over the ellipsoid C_k is taken over a deterministic point set of C_k
(centre; the 2d principal-axis points c ± √λ_j v_j; the 2d coordinate-extreme points
c ± X e_i/√X_ii; 2m fixed quasi-random boundary points and the same directions at half
radius), then inflated by a relative margin (default 25 %).  This is exact when ε is a
quadratic form in a principal direction of C_k (e.g. the gravity term sin q in 1-D) and
approximate otherwise: a sharp nonlinearity between the points (Coulomb friction, a
backlash corner) can be under-sampled.  A caller with an analytic bound passes
``lin_err_box`` instead (the AKF adapter does so for the gravity term, akf_bound.py).  The residual is evaluated either
in discrete time (ε = f_d(x) − f_d(x̂) − F_d(x − x̂), Φ = I: exact for the discrete model)
or in continuous time (ε_c = f(x) − f(x̂) − A(x − x̂) mapped by Φ = ∫₀^dt e^{As} ds, the
zero-order-hold approximation: exact if ε_c is constant over the step).
"""
from __future__ import annotations

import math
from typing import Callable

import numpy as np
from scipy.special import ndtri

from sea_daemon.core.jit import njit, warmer
from sea_daemon.core.bounds.ellipsoid import Ellipsoid, chi2_quantile, minkowski_shape, segments_shapes
from sea_daemon.core.bounds.zonotope import predict_generators, zonotope_shape


#: the zonotope's order reduction at most this often [s] (AKFTheoremBound sets
#: SetMembershipBound.reduce_every from its step): each reduction replaces the smallest generators
#: by their interval hull, and the hull of the last reduction, mapped by (I − K H) F, is boxed
#: again at the next.  The box of a rotated box grows by |(I − K H) F| (in the ∞-norm) even
#: where the map contracts (spectral radius < 1), so the map between two reductions must
#: contract in that norm: reduced every step, the passive 1 kHz demo's ρ_k grew without bound
#: (1e4 N m after 1 s); at 100 Hz the filter of a calibrated model (docs/calibration.md: the
#: passive demo's, measured velocities, a friction model) has a one-step map of spectral
#: radius 0.96 whose box grows ×1.5 per 0.15 s — reduced every step or every second step, its
#: ρ_k grows to the caps (100 N m) within 2 s of a move; every third step or less often it
#: stays at 0.43 N m.  Every 50 ms: 5 steps at 100 Hz, 50 at 1 kHz.
REDUCE_PERIOD_S = 0.05

#: the zonotope's generators kept at a reduction per joint (AKFTheoremBound's ``max_generators`` =
#: this × n: order 8 of the walk's 5n states, 40 for one joint).  The boxes of a reduction lose the
#: correlation of the states they box, and the more states, the more of it is lost at a fixed
#: count: on two joints (d = 10) with 40 generators ρ_k was 1.6× the nearly unreduced
#: propagation's (400), with 80 within 8 % of it (development plant 2, 100 Hz).
GENERATORS_PER_JOINT = 40


def shifted_gaussian_halfwidth(h: np.ndarray, sigma: np.ndarray, delta: float, iters: int = 8) -> np.ndarray:
    """Smallest ρ with max_{|a| ≤ h} Pr(|a + g| > ρ) ≤ δ for g ~ N(0, σ²), elementwise.

    |a + g| ≤ ρ is a symmetric interval shifted by a; its Gaussian probability decreases with
    |a| (g symmetric and unimodal), so the worst case is |a| = h:
        Φ((h − ρ)/σ) + Φ((−h − ρ)/σ) = δ.
    With t = ρ/σ, u = h/σ the root lies in [u + z_{1−δ}, u + z_{1−δ/2}] (one- to two-sided);
    F(t) = Φ(u − t) + Φ(−u − t) is convex and decreasing there, so Newton from the left end
    converges monotonically (quadratically) to it.  h = 0 gives the two-sided σ z_{1−δ/2}
    = √(χ²_1(1 − δ) σ²); h ≫ σ gives h + σ z_{1−δ}.
    """
    h = np.asarray(h, dtype=float)
    s = np.asarray(sigma, dtype=float)
    shape = np.broadcast_shapes(h.shape, s.shape)
    hb = np.ascontiguousarray(np.broadcast_to(h, shape), dtype=float).ravel()
    sb = np.ascontiguousarray(np.broadcast_to(s, shape), dtype=float).ravel()
    out = np.empty(hb.size)
    shifted_halfwidth_into(hb, sb, float(delta), float(ndtri(1.0 - delta)), int(iters), out)
    return out.reshape(shape)


@njit
def _ndtr(x):
    """Standard normal CDF Φ(x) (as scipy.special.ndtr: erf near 0, erfc in the tails)."""
    t = x / math.sqrt(2.0)
    if abs(t) < 1.0 / math.sqrt(2.0):
        return 0.5 + 0.5 * math.erf(t)
    if t > 0.0:
        return 1.0 - 0.5 * math.erfc(t)
    return 0.5 * math.erfc(-t)


@njit
def shifted_halfwidth_into(h, s, delta, z, iters, out):
    """The Newton iteration of :func:`shifted_gaussian_halfwidth` per element (z = z_{1−δ})."""
    c = 1.0 / math.sqrt(2.0 * math.pi)
    for i in range(h.shape[0]):
        if not s[i] > 0.0:
            out[i] = h[i]
            continue
        u = h[i] / s[i]
        t = u + z
        for _ in range(iters):
            F = _ndtr(u - t) + _ndtr(-u - t) - delta
            dF = -c * (math.exp(-0.5 * (t - u) ** 2) + math.exp(-0.5 * (t + u) ** 2))
            t = t - F / dF
        out[i] = s[i] * t


@warmer
def _warm() -> None:
    """The compiled kernels of this module, with the argument types the bound uses (see _jit)."""
    shifted_gaussian_halfwidth(np.array([0.1, 0.0]), np.array([1.0, 0.0]), 0.05)
    sm = SetMembershipBound(2, [1], 0.05, max_generators=3)
    sm.predict(np.eye(2), Gamma=np.ones((2, 1)), eta=np.ones(1), lin_err_box=np.ones(2), Phi=np.eye(2))
    sm.predict(np.eye(2), Gamma=np.ones((2, 1)), eta=np.ones(1), lin_err_box=np.ones(2))
    ellipsoid_points(Ellipsoid(np.zeros(2), np.eye(2)), np.ones((1, 2)) / np.sqrt(2.0))
    sm.rho(np.eye(2))


def unit_directions(d: int, m: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed + 7919 * d)
    U = rng.standard_normal((m, d))
    return U / np.linalg.norm(U, axis=1, keepdims=True)


def ellipsoid_points(C: Ellipsoid, U: np.ndarray) -> np.ndarray:
    """Deterministic points of C = E(c, X): the centre, c ± principal semi-axes, the
    coordinate-extreme points c ± X e_i/√X_ii, c ± X^{1/2} u and c ± ½ X^{1/2} u for the unit
    directions u in the rows of U ((m, dim); may be empty)."""
    d = C.dim
    return points_of_ellipsoid(C.c, C.X, np.ascontiguousarray(np.asarray(U, dtype=float).reshape(-1, d)))


@njit
def points_of_ellipsoid(c, X, U):
    """:func:`ellipsoid_points` (compiled): rows centre, +axes, −axes, +ext, −ext, +r, −r, +r/2, −r/2."""
    d = c.shape[0]
    m = U.shape[0]
    w, V = np.linalg.eigh(X)
    VS = np.empty((d, d))
    for j in range(d):
        sw = math.sqrt(w[j]) if w[j] > 0.0 else 0.0
        for i in range(d):
            VS[i, j] = V[i, j] * sw
    R = VS @ V.T                                                # X^{1/2} (symmetric root)
    out = np.empty((1 + 4 * d + 4 * m, d))
    out[0] = c
    for j in range(d):
        # principal semi-axes ±√λ_j v_j
        for i in range(d):
            out[1 + j, i] = c[i] + VS[i, j]
            out[1 + d + j, i] = c[i] - VS[i, j]
        # argmax_{x∈C} x_j − c_j = c + X e_j/√X_jj (the centre if X_jj = 0)
        sd = math.sqrt(X[j, j]) if X[j, j] > 0.0 else 0.0
        for i in range(d):
            e = X[i, j] / sd if sd > 0.0 else 0.0
            out[1 + 2 * d + j, i] = c[i] + e
            out[1 + 3 * d + j, i] = c[i] - e
    o = 1 + 4 * d
    for k in range(m):
        for i in range(d):
            r = 0.0
            for j in range(d):
                r += U[k, j] * R[j, i]
            out[o + k, i] = c[i] + r
            out[o + m + k, i] = c[i] - r
            out[o + 2 * m + k, i] = c[i] + 0.5 * r
            out[o + 3 * m + k, i] = c[i] - 0.5 * r
    return out


class SetMembershipBound:
    """Theorem-1 set of means X̂_k next to an (GP-)AKF, and the bound ρ_k on τ_h,act.

    Parameters
    ----------
    d        state dimension (5n for the SEA AKF)
    tau_idx  indices of the τ_h,act states (4n … 5n−1)
    delta    total failure probability δ of eq:bounds
    delta_gp share of δ spent on the GP bound (the caller uses it in gp_bound.error_bound);
             0 when there is no GP (plain AKF)
    weight   W of the tr(W X)-minimal Minkowski sum (default I, the plain trace)
    n_dirs   extra quasi-random directions for the linearisation-error point set
    margin   relative inflation of the sampled linearisation error
    projection  "scalar" (default): per joint, the exact worst case of the scalar eq:bounds — ρ_j
             is the smallest ρ with max_{|a| ≤ h_j} Pr(|a + g| > ρ) ≤ δ_N/n_τ, g ~ N(0, P_jj), h_j the
             set of means' half-width (:func:`shifted_gaussian_halfwidth`; Bonferroni over the
             joints); h_j = 0 gives √(χ²_1 P_jj), h_j ≫ σ gives h_j + z_{1−δ_N/n_τ} σ;
             "marginal": s_τ = χ²_{n_τ}(1 − δ_N), ρ_j = h_j + √(s_τ P_jj), the confidence set of the τ
             marginal alone — valid for eq:bounds (union bound δ_GP + δ_N) and tighter (for one
             joint √χ²_1 = 1.96 instead of √χ²_5 = 3.33 at δ_N = 0.05); "state": ρ is the
             projection of the state confidence set C_k with s_d = χ²_d(1 − δ_N) (the paper's
             construction of Theorem 1's set statement)
    sets     representation of the set of means: "zonotope" (default; exact Minkowski sums and
             affine maps, outer approximation only when the generator count is reduced) or
             "ellipsoid" (the paper's: trace-minimal outer ellipsoid at every sum)
    reduce_every  zonotope order reduction at most every this many steps (default 1; the AKF's bound
             sets the steps of 50 ms, :data:`REDUCE_PERIOD_S`): in between the generators
             accumulate (exact)
    max_generators  zonotope order reduction: above this many generators the smallest are
             replaced by their interval hull (Girard 2005; an outer approximation)
    """

    def __init__(self, d: int, tau_idx, delta: float, *, delta_gp: float = 0.0,
                 weight: np.ndarray | None = None, n_dirs: int = 8, margin: float = 0.25, seed: int = 0,
                 projection: str = "scalar", sets: str = "zonotope", max_generators: int = 40):
        if not 0 < delta < 1:
            raise ValueError(f"delta must be in (0, 1), got {delta}")
        if not 0 <= delta_gp < delta:
            raise ValueError(f"delta_gp must be in [0, delta={delta}), got {delta_gp}")
        self.d = int(d)
        self.tau_idx = np.atleast_1d(np.asarray(tau_idx, dtype=int))
        self.delta, self.delta_gp = float(delta), float(delta_gp)
        self.delta_noise = self.delta - self.delta_gp
        # eq:gaussianellipsoid: s from the χ² quantile
        self.s_state = chi2_quantile(1.0 - self.delta_noise, self.d)
        if projection not in ("state", "marginal", "scalar"):
            raise ValueError(f"projection must be 'scalar', 'marginal' or 'state', got {projection!r}")
        self.projection = projection
        # s of the KF-only part √(s P_ττ) (what ρ is when the set of means is a point)
        self.s_tau = (self.s_state if projection == "state"
                      else chi2_quantile(1.0 - self.delta_noise, self.tau_idx.size) if projection == "marginal"
                      else chi2_quantile(1.0 - self.delta_noise / self.tau_idx.size, 1))
        # z_{1−δ_N/n_τ}, the start of shifted_gaussian_halfwidth's Newton iteration in rho
        self.z_tau = float(ndtri(1.0 - self.delta_noise / self.tau_idx.size))
        if sets not in ("zonotope", "ellipsoid"):
            raise ValueError(f"sets must be 'zonotope' or 'ellipsoid', got {sets!r}")
        self.sets = sets
        if int(max_generators) < self.d + 1:
            raise ValueError(f"max_generators must be >= d + 1 = {self.d + 1}, got {max_generators}")
        self.max_generators = int(max_generators)
        self.reduce_every = 1
        self._steps = 0                              # predictions since the reset (reduction phase)
        self.weight = weight
        self.margin = float(margin)
        self._U = unit_directions(self.d, n_dirs, seed)
        self._X = np.zeros((self.d, self.d))       # X̂_k, shape of the set of means (ellipsoid mode)
        self.Xprior_ = np.zeros((self.d, self.d))  # X⁻_{k+1} (ellipsoid mode)
        self.G_ = np.zeros((self.d, 0))            # generators of the set of means (zonotope mode)
        self.Gprior_ = np.zeros((self.d, 0))
        self.lin_err_ = np.zeros(self.d)           # last linearisation-error box b
        self.n_eval_ = 0                           # residual evaluations in the last box

    # ------------------------------------------------------------------ state

    def reset(self, X0: np.ndarray | None = None) -> None:
        """X̂_0 (default 0: x̂_0 measured, its uncertainty is in P_0 — Sec. V-B).

        Zonotope mode: E(0, X0) is replaced by its circumscribing parallelotope V diag(√λ)
        (principal axes; contains the ellipsoid)."""
        self._X = np.zeros((self.d, self.d)) if X0 is None else np.array(X0, dtype=float)
        self.Xprior_ = self._X.copy()
        self._steps = 0
        if X0 is None:
            self.G_ = np.zeros((self.d, 0))
        else:
            w, V = np.linalg.eigh(self._X)
            keep = w > 0
            self.G_ = V[:, keep] * np.sqrt(w[keep])
        self.Gprior_ = self.G_.copy()

    @property
    def X_(self) -> np.ndarray:
        """Shape of an outer ellipsoid of the set of means (zonotope mode: trace-minimal
        outer ellipsoid of the zonotope; all zero when the set of means is a point)."""
        if self.sets == "ellipsoid":
            return self._X
        return zonotope_shape(self.G_)

    @X_.setter
    def X_(self, X: np.ndarray) -> None:
        self.reset(X)

    # ------------------------------------------------------------------ sets

    def confidence_set(self, x_hat: np.ndarray, P: np.ndarray, T: np.ndarray | None = None,
                       s: float | None = None) -> Ellipsoid:
        """Outer ellipsoid of C_k = X̂_k ⊕ E(0, s_d P) (Theorem 1), trace-minimal; with ``T``
        the outer ellipsoid of its image T·C_k (computed from the mapped summands, which is
        tighter than mapping the outer ellipsoid).  ``s`` replaces s_d (e.g. χ²_m(1 − δ_N) for
        the m-dimensional image T·x, when only T·x matters)."""
        P = np.asarray(P)
        s = self.s_state if s is None else float(s)
        if T is None:
            T = None
            sP, c = s * P, x_hat
        else:
            T = np.asarray(T, dtype=float)
            sP, c = s * (T @ P @ T.T), T @ x_hat
        # eq:confidenceset
        if self.sets == "ellipsoid":
            X = self._X if T is None else T @ self._X @ T.T
            return Ellipsoid(c, minkowski_shape([X, sP], self.weight))
        G = self.G_ if T is None else T @ self.G_
        return Ellipsoid(c, zonotope_shape(G, extra=sP))

    def half_width(self, e: np.ndarray, P: np.ndarray, s: float | None = None) -> float:
        """Exact half-width of C_k = X̂_k ⊕ E(0, s_d P) along e (support functions add);
        ``s`` replaces s_d as in :meth:`confidence_set`."""
        return float(self.half_widths(np.asarray(e, dtype=float)[None], P, s)[0])

    def half_widths(self, E: np.ndarray, P: np.ndarray, s: float | None = None) -> np.ndarray:
        """:meth:`half_width` along every row of ``E`` (k, d)."""
        s = self.s_state if s is None else float(s)
        if self.sets == "ellipsoid":
            hx = np.sqrt(np.maximum(np.sum((E @ self._X) * E, axis=1), 0.0))
        else:
            hx = np.sum(np.abs(E @ self.G_), axis=1)
        return hx + np.sqrt(np.maximum(s * np.sum((E @ P) * E, axis=1), 0.0))

    def means_half_widths(self) -> np.ndarray:
        """Exact half-widths of the set of means X̂_k along every coordinate axis."""
        if self.sets == "ellipsoid":
            return np.sqrt(np.clip(np.diag(self._X), 0.0, None))
        return np.sum(np.abs(self.G_), axis=1)

    def saturate(self, caps: np.ndarray) -> bool:
        """Hold the set of means inside the box of half-widths ``caps`` (per state): every axis
        whose half-width exceeds its cap is scaled down to it (D X̂, D diagonal ≤ 1).  Not an
        outer approximation any more: the caller flags the step.  Returns whether it acted."""
        hw = self.means_half_widths()
        over = hw > caps
        if not np.any(over):
            return False
        D = np.where(over, caps / np.where(over, hw, 1.0), 1.0)
        if self.sets == "ellipsoid":
            self._X = self._X * D[:, None] * D[None, :]
        else:
            self.G_ = self.G_ * D[:, None]
        return True

    def rho(self, P: np.ndarray) -> np.ndarray:
        """ρ_k per τ state: exact half-width of X̂_k ⊕ E(0, s_τ P) along each τ axis."""
        i = self.tau_idx
        h = self.means_half_widths()[i]
        Ptt = np.clip(np.diag(np.asarray(P))[i], 0.0, None)
        if self.projection == "scalar":
            # eq:bounds per joint: worst case over the set of means of a shifted Gaussian
            out = np.empty(i.size)
            shifted_halfwidth_into(h, np.sqrt(Ptt), self.delta_noise / i.size, self.z_tau, 8, out)
            return out
        # support functions add over a Minkowski sum: h = h_X̂(e) + sqrt(s eᵀPe); for a zonotope
        # h_X̂(e) = Σ_g |eᵀg|, for an ellipsoid sqrt(eᵀX̂e)
        return h + np.sqrt(self.s_tau * Ptt)

    def sample_points(self, C: Ellipsoid) -> np.ndarray:
        """The deterministic point set of C on which the linearisation error is maximised."""
        return ellipsoid_points(C, self._U)

    def linearization_error_box(self, resid: Callable[[np.ndarray], np.ndarray], C: Ellipsoid) -> np.ndarray:
        """b_i ≈ max_{x∈C} |ε_i(x)| (eq:linerrsetdx), ε = resid(x) = f(x) − f̄(x).

        Sampled on :meth:`sample_points` and inflated by ``margin`` (approximate; see module
        docstring).  Residuals at rounding level are set to zero so a linear plant gives 0.
        """
        pts = self.sample_points(C)
        E = np.array([resid(x) for x in pts])
        self.n_eval_ = len(pts)
        b = np.max(np.abs(E), axis=0)
        return b * (1.0 + self.margin)

    # ------------------------------------------------------------------ Theorem 1 step

    def predict(self, F: np.ndarray, *, Gamma: np.ndarray | None = None, eta: np.ndarray | None = None,
                lin_err_box: np.ndarray | None = None, Phi: np.ndarray | None = None) -> np.ndarray:
        """X⁻_{k+1} = F X̂_k Fᵀ ⊕ Γ·box(η) ⊕ Φ·box(b)    (eq:predwLinErrsetandGPerrset).

        F      discrete linearisation F_d (A_k of the theorem)
        Gamma  d×n map of the GP error (N m) into the state (Γ of linalg.discretize(A, I_μ M⁻¹, dt))
        eta    (n,) GP error half-widths √β σ_i + γ (lem:interval_bound)
        lin_err_box (m,) linearisation-error half-widths b, mapped by Phi (default I)
        """
        F = np.asarray(F, dtype=float)
        self.lin_err_ = np.zeros(self.d) if lin_err_box is None else np.asarray(lin_err_box, float)
        if self.sets == "zonotope":
            # exact: F·Z ⊕ Γ·box(η) ⊕ Φ·box(b) is the zonotope with the union of the generators
            # (eq:Dmuhat, eq:GPboundsellipse: the GP error box, generators Γ_j η_j;
            # eq:linearerrellipsoid: the linearisation-error box, generators Φ_i b_i)
            self.Gprior_ = self.prior_generators(F, Gamma=Gamma, eta=eta, lin_err_box=lin_err_box, Phi=Phi,
                                                 limit=self.generator_limit())
            return self.Gprior_
        shapes = [F @ self._X @ F.T]
        if eta is not None and Gamma is not None:
            # eq:Dmuhat, eq:GPboundsellipse: the GP error box as n segments in state space
            shapes += segments_shapes(Gamma, eta)
        if lin_err_box is not None:
            # eq:linearerrellipsoid: the box of per-dimension maxima as segments
            shapes += segments_shapes(np.eye(self.d) if Phi is None else Phi, lin_err_box)
        self.Xprior_ = minkowski_shape(shapes, self.weight)
        return self.Xprior_

    def prior_generators(self, F: np.ndarray, *, Gamma: np.ndarray | None = None, eta: np.ndarray | None = None,
                         lin_err_box: np.ndarray | None = None, Phi: np.ndarray | None = None,
                         limit: int) -> np.ndarray:
        """The generators of F·Z ⊕ Γ·box(η) ⊕ Φ·box(b) (zonotope mode, :meth:`predict`) reduced to
        at most ``limit``, without storing them (a candidate step)."""
        d = self.d
        if eta is not None and Gamma is not None:
            Gam, et = np.ascontiguousarray(Gamma, dtype=float), np.asarray(eta, dtype=float)
        else:
            Gam, et = np.zeros((d, 0)), np.zeros(0)
        if lin_err_box is not None:
            Ph = np.eye(d) if Phi is None else np.ascontiguousarray(Phi, dtype=float)
            bb = np.asarray(lin_err_box, dtype=float)
        else:
            Ph, bb = np.zeros((d, 0)), np.zeros(0)
        return predict_generators(np.ascontiguousarray(F, dtype=float), np.ascontiguousarray(self.G_, dtype=float),
                                  Gam, et, Ph, bb, int(limit))

    def generator_limit(self) -> int:
        """The generator limit of this prediction (counts it): ``max_generators`` on a reduction
        step, else no limit (see ``reduce_every``)."""
        k = self._steps
        self._steps = k + 1
        return self.max_generators if k % self.reduce_every == 0 else 1 << 30

    def update(self, K: np.ndarray, H: np.ndarray) -> np.ndarray:
        """X̂_{k+1} = (I − K H) X⁻ (I − K H)ᵀ: the filter step on the set of means (affine, exact)."""
        IKH = np.eye(self.d) - np.asarray(K) @ np.asarray(H)
        if self.sets == "zonotope":
            self.G_ = IKH @ self.Gprior_
            return self.G_
        X = IKH @ self.Xprior_ @ IKH.T
        self._X = 0.5 * (X + X.T)
        return self._X

    def skip_update(self) -> np.ndarray:
        """No measurement this step: X̂_{k+1} = X⁻."""
        if self.sets == "zonotope":
            self.G_ = self.Gprior_.copy()
            return self.G_
        self._X = self.Xprior_.copy()
        return self._X

    def step(self, *, x_hat: np.ndarray, P: np.ndarray, F: np.ndarray, K: np.ndarray, H: np.ndarray,
             P_post: np.ndarray, resid: Callable[[np.ndarray], np.ndarray] | None = None,
             Phi: np.ndarray | None = None, Gamma: np.ndarray | None = None,
             eta: np.ndarray | None = None, lin_err_box: np.ndarray | None = None) -> np.ndarray:
        """One full Theorem-1 step from (x̂_k, P_k) to ρ_{k+1}.

        ``resid(x)`` = f(x) − f̄(x) about x̂_k (discrete: Φ = I; continuous: pass Φ); or pass
        ``lin_err_box`` directly.  K, H, P_post are the filter's K_{k+1}, H and P_{k+1}.
        """
        if lin_err_box is None and resid is not None:
            C = self.confidence_set(x_hat, P)
            lin_err_box = self.linearization_error_box(resid, C)
        self.predict(F, Gamma=Gamma, eta=eta, lin_err_box=lin_err_box, Phi=Phi)
        self.update(K, H)
        return self.rho(P_post)


def discrete_residual(fd: Callable[[np.ndarray], np.ndarray], x_hat: np.ndarray, F_d: np.ndarray):
    """ε(x) = f_d(x) − f_d(x̂) − F_d (x − x̂) (eq:ekf_linearization) with rounding noise removed."""
    f0 = np.asarray(fd(x_hat), dtype=float)

    def resid(x):
        fx = np.asarray(fd(x), dtype=float)
        lin = F_d @ (x - x_hat)
        r = fx - f0 - lin
        tol = 1e-12 * (np.abs(fx) + np.abs(f0) + np.abs(lin) + 1e-300)
        return np.where(np.abs(r) <= tol, 0.0, r)

    return resid


def continuous_residual(f: Callable[[np.ndarray], np.ndarray], x_hat: np.ndarray, A: np.ndarray):
    """ε_c(x) = f(x) − f(x̂) − A (x − x̂) for ẋ = f(x) (to be mapped with Φ = ∫e^{As}ds)."""
    return discrete_residual(f, x_hat, A)
