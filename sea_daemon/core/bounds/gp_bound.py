"""Uniform GP error bound |f(x) − μ(x)| ≤ √β σ(x) + γ on a compact box (eq:gpmeanbounds).

Lederer, Umlauft & Hirche, "Uniform error bounds for Gaussian process regression with
application to safe control", NeurIPS 2019 (LUH19):

Theorem 3.1.  f ~ GP(0, k), k with Lipschitz constant L_k on a compact X, f Lipschitz with
L_f, N noisy observations (noise N(0, σ_n²)).  Then μ_N is Lipschitz with
    L_μ ≤ L_k √N ‖(K + σ_n² I)⁻¹ y‖      (we use the tighter L_k ‖α‖₁ ≤ L_k √N ‖α‖₂),
σ_N has modulus of continuity
    ω_σ(τ) ≤ sqrt(2 τ L_k (1 + N ‖(K + σ_n² I)⁻¹‖ max_{x,x'} k(x, x'))),
and we take ω_σ(τ) = min(that, σ_f τ) (the SE kernel in normalised coordinates): with
e(x) = f(x) − μ_N(x) under the posterior, σ_N(x) = ‖e(x)‖ in L², so by the triangle inequality
|σ_N(x) − σ_N(x')| ≤ ‖e(x) − e(x')‖ = √Var_post(f(x) − f(x')) ≤ √Var_prior(f(x) − f(x'))
= σ_f √(2 − 2 e^{−‖x̃ − x̃'‖²/2}) ≤ σ_f ‖x̃ − x̃'‖ (conditioning on Gaussian data never raises
a variance).  It does not grow with N/σ_n² as LUH19's does, so a larger τ (a smaller β) pays;
and for δ ∈ (0, 1), τ > 0, with β(τ) = 2 log(M(τ, X)/δ) (M = τ-covering number of X) and
γ(τ) = (L_μ + L_f) τ + √β(τ) ω_σ(τ):
    P(|f(x) − μ_N(x)| ≤ √β(τ) σ_N(x) + γ(τ)  ∀x ∈ X) ≥ 1 − δ.
The paper's eq:gpmeanbounds writes β σ; its β is our √β(τ), and γ(τ) is the (small)
discretisation remainder that eq:gpmeanbounds drops — we keep it.

Theorem 3.2 (probabilistic Lipschitz constant of a sample f when none is known from
physics).  With the partial-derivative kernels k^∂i(x,x') = ∂²k/∂x_i∂x'_i, their Lipschitz
constants L_k^∂i and r = max_{x,x'∈X} ‖x − x'‖, with probability ≥ 1 − δ_L
    L_f = ‖( √(2 log(2d/δ_L)) max_x √k^∂i(x,x) + 12 √(6d) max{max_x √k^∂i(x,x), √(r L_k^∂i)} )_i‖₂.

SE kernel constants (derivation in docs/bounds.md).  All the analysis is done in the
length-scale-normalised coordinates x̃ = x / l (elementwise), where the SE kernel of
eq:SE is isotropic with unit length scale, k = σ_f² exp(−‖x̃ − x̃'‖²/2).  The theorems hold
for any compact set and norm, so this is a valid reparametrisation and it is tighter than
working in raw units with l_min:
    L_k     = σ_f² e^{−1/2}                        (max_t t e^{−t²/2} at t = 1)
    k^∂i(x,x) = σ_f²,   L_k^∂i = c* σ_f²,  c* = √6 √(3 − √6) e^{−(3 − √6)/2} ≈ 1.3801
    M(τ, box) ≤ Π_i ⌈ w̃_i √d / (2τ) ⌉  (grid with cell half-diagonal τ; w̃ = scaled widths)
    r       = ‖w̃‖₂

Choice of τ: τ is picked on a fixed log grid of G values after seeing the data, so the
bound is made uniform over the grid by a union bound (δ → δ/G, costs 2 log G in β).

LoG-GP (merged prediction, mixture of experts).  The prediction is μ̃ = Σ_i w_i μ_i with
w_i ≥ 0, Σ w_i = 1, over the leaves i active at x.  With a union bound over the L leaves
(δ_i = δ_GP / L) every leaf bound holds at once with probability ≥ 1 − δ_GP, and then
    |f − μ̃| = |Σ w_i (f − μ_i)| ≤ Σ w_i (√β σ_i + γ_i) ≤ √β Σ w_i σ_i + max_i γ_i
            ≤ √β σ̃ + max_i γ_i,
because Σ w_i σ_i ≤ (Σ w_i σ_i²)^{1/2} (Jensen) ≤ (Σ w_i (σ_i² + (μ_i − μ̃)²))^{1/2}: the
merged standard deviation σ̃ may be either the weighted-variance or the full mixture
standard deviation (not Σ w_i² σ_i², which can be smaller than Σ w_i σ_i).  β is the same
for every leaf because all leaves share δ_i, τ and the covering of the same box X; γ_i
differs through ‖α_i‖₁ and ‖(K_i + σ_n² I)⁻¹‖.  L is the number of leaves that ever make
a prediction under the bound; while the tree still grows use its cap (max_leaves).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Iterable, Sequence

import numpy as np

from sea_daemon.core.gp.exact import se_kernel

# sup over r of ‖∇_x k^∂i(x, x')‖ / σ_f² for the unit-length-scale SE kernel (docs/bounds.md)
C_STAR = math.sqrt(6.0) * math.sqrt(3.0 - math.sqrt(6.0)) * math.exp(-(3.0 - math.sqrt(6.0)) / 2.0)
TAU_GRID = np.geomspace(1e-12, 1e-1, 23)


def se_lipschitz(sigma_f: float, lengthscales: np.ndarray | None = None) -> float:
    """Lipschitz constant of x ↦ k(x, x') for the SE kernel: σ_f² e^{−1/2} / l_min.

    In normalised coordinates (lengthscales=None) it is σ_f² e^{−1/2}: ‖∇_x k‖ =
    σ_f² t e^{−t²/2} with t = ‖x̃ − x̃'‖, maximal at t = 1.  In raw coordinates
    ‖∇_x k‖ = σ_f² e^{−t²/2} ‖D⁻¹ (x̃ − x̃')‖ ≤ σ_f² t e^{−t²/2} / l_min (no √d factor).
    """
    L = sigma_f ** 2 * math.exp(-0.5)
    if lengthscales is not None:
        L /= float(np.min(lengthscales))
    return L


def log_covering_number(widths: np.ndarray, tau: float) -> float:
    """log M(τ, box) for a box with edge lengths ``widths`` in the Euclidean norm.

    A regular grid with spacing h = 2τ/√d has cells of half-diagonal τ, so
    M ≤ Π_i max(1, ⌈w_i / h⌉).
    """
    w = np.asarray(widths, dtype=float)
    d = w.size
    h = 2.0 * tau / math.sqrt(d)
    return float(np.sum(np.log(np.maximum(1.0, np.ceil(w / h)))))


def covering_grid(lo: np.ndarray, hi: np.ndarray, tau: float) -> np.ndarray:
    """The grid of :func:`log_covering_number` (cell centres), for tests on small boxes."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    d = lo.size
    h = 2.0 * tau / math.sqrt(d)
    axes = []
    for a, b in zip(lo, hi):
        m = max(1, int(math.ceil((b - a) / h)))
        step = (b - a) / m
        axes.append(a + step * (np.arange(m) + 0.5))
    return np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, d)


def sample_lipschitz_se(sigma_f: float, scaled_widths: np.ndarray, delta_L: float) -> float:
    """LUH19 Theorem 3.2 for the SE kernel in normalised coordinates (prob. ≥ 1 − δ_L)."""
    w = np.asarray(scaled_widths, dtype=float)
    d = w.size
    r = float(np.linalg.norm(w))
    root_kd = sigma_f                      # √k^∂i(x, x) = σ_f (unit length scale)
    L_kd = C_STAR * sigma_f ** 2           # Lipschitz constant of k^∂i
    entry = (math.sqrt(2.0 * math.log(2.0 * d / delta_L)) * root_kd
             + 12.0 * math.sqrt(6.0 * d) * max(root_kd, math.sqrt(r * L_kd)))
    return math.sqrt(d) * entry            # every component equal → ‖·‖₂ = √d · entry


@dataclass(frozen=True)
class LeafGP:
    """What the bound needs from one (leaf) GP: α = (K + σ_n² I)⁻¹ y and its hyperparameters.

    ``Kinv_norm`` is ‖(K + σ_n² I)⁻¹‖₂ = 1/(λ_min(K) + σ_n²); None uses its upper bound 1/σ_n².
    """

    alpha: np.ndarray
    sigma_f: float
    lengthscales: np.ndarray
    sigma_n: float
    Kinv_norm: float | None = None

    @property
    def N(self) -> int:
        return int(np.size(self.alpha))

    @classmethod
    def from_data(cls, X: np.ndarray, y: np.ndarray, sigma_f: float, lengthscales, sigma_n: float) -> "LeafGP":
        """Exact GP posterior pieces (eq:GPmean) for a data set — for tests and small leaves."""
        ls = np.asarray(lengthscales, dtype=float)
        K = se_kernel(X, X, ls, sigma_f) + sigma_n ** 2 * np.eye(len(X))
        w = np.linalg.eigvalsh(K)
        return cls(np.linalg.solve(K, np.asarray(y, float)), sigma_f, ls, sigma_n, float(1.0 / w.min()))


@dataclass(frozen=True)
class BoundConstants:
    """|f − μ| ≤ sqrt_beta·s(x) + gamma on the box, with probability ≥ 1 − delta.

    ``scale`` names s: "sigma" — the posterior standard deviation σ (LUH19,
    :func:`error_bound`: the paper's β σ plus γ); "local" — s = √(σ² + s_loc²) with s_loc the
    LoG-GP's local residual scale (:class:`LocalScale`; split conformal,
    :func:`conformal_constants`, and a configured β).
    """

    sqrt_beta: float
    gamma: float
    tau: float
    L_f: float          # Lipschitz constant of f used (normalised coordinates)
    L_mu: float         # max over leaves of the posterior-mean Lipschitz constant
    omega_sigma: float  # max over leaves of ω_σ(τ)
    delta: float
    n_leaves: int
    scale: str = "sigma"
    method: str = "lederer"

    def eta(self, s: np.ndarray | float) -> np.ndarray:
        """Error half-width η = √β s + γ (the interval of lem:interval_bound), s the scale
        named by ``scale`` (σ for LUH19)."""
        return self.sqrt_beta * np.asarray(s, dtype=float) + self.gamma


class LocalScale:
    """s(z) = √(σ(z)² + s_loc(z)²), s_loc(z) = Σ_i w_i(z) r_i for a LoG-GP: r_i is the RMS of
    leaf i's in-sample residuals y − μ_i(X_i) = σ_n,i² α_i (exact for a GP posterior mean), w_i the
    merged prediction's leaf weights at z.  It is large where the leaf's data were badly fitted
    (e.g. friction reversals), and fixed by the training data alone — so a split-conformal
    quantile of |y − μ|/s on held-out pairs keeps its validity (normalised / locally adaptive
    conformal, Lei et al. 2018 §5.2).

    Extrapolation term (``LoGGP(extrapolation_scale=c)``, ``learning.extrapolation_scale``; off
    at c = 0): x(z) = c e(z) with e(z) = Σ_i w_i Σ_j |∂μ_i/∂z_j| |z_j − x*_ij|, x*_i the training
    input of leaf i nearest z (length-scale metric).  By the mean value theorem
    |f(z) − μ_i(z)| ≤ |f(x*) − μ_i(x*)| + Σ_j (|∂f/∂z_j| + |∂μ_i/∂z_j|) |z_j − x*_j| (slopes
    along the segment): the first term is what s_loc and σ measure near the data, the second is
    the LUH19 remainder (L_μ + L_f) τ at the distance τ from the data, with the mean's local
    slope standing in for the unknown ones.  It is large exactly where a leaf mean extrapolates
    steeply off its data — where σ, bounded by σ_f and shrunk by long length scales, stays small
    (docs/learning.md, "Novelty").  It is *added* to the error bound, η = β s + x
    (:meth:`predict_many_ext`), not scaled with β: β is calibrated where the GP has data (e ≈ 0
    there), and says nothing about how fast the error grows away from it (docs/bounds.md §2d).
    Fixed by the training data too, so the conformal argument is unchanged."""

    def __init__(self, gp):
        self.gp = gp
        self.c_ext = float(getattr(gp, "extrapolation_scale", 0.0))
        self.r_ = {}
        for node in gp.leaves():
            lf = gp.leaf(node)
            if lf.n_:
                res = float(lf.sigma_n) ** 2 * np.asarray(lf.alpha_, dtype=float)[:lf.n_]
                self.r_[node] = float(np.sqrt(np.mean(res * res)))

    def local(self, z) -> float:
        """s_loc(z) (leaf routing of the LoG-GP's merged prediction)."""
        return float(sum(w * self.r_.get(node, 0.0) for node, w, _ in self.gp.route(z)))

    def predict_many(self, Z: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(μ̃, σ̃², s) at every row of ``Z`` (m, input_dim), one routing per row: the LoG-GP's
        merged mean and mixture variance (as :meth:`sea_daemon.core.gp.loggp.LoGGP.predict`) and the
        local scale; each leaf reached predicts its rows in one compiled call."""
        return self._predict(Z, False)[:3]

    def predict_many_ext(self, Z: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(μ̃, σ̃², s, x) at every row of ``Z``: :meth:`predict_many` and the extrapolation term
        x(z) = c e(z) (zeros when c = 0), from the same routing."""
        return self._predict(Z, True)

    def _predict(self, Z, ext: bool):
        Z = np.ascontiguousarray(Z, dtype=float)
        idx, nodes, w, m, v = self.gp.leaf_predictions(Z)
        rows = int(Z.shape[0])
        r = np.array([self.r_.get(node, 0.0) for node in nodes.tolist()])
        # μ̃ = Σ ω_i μ_i, σ̃² = Σ ω_i (σ_i² + μ_i²) − μ̃², s_loc = Σ ω_i r_i (routing order)
        # (bincount adds each row's terms in order, from 0)
        mu = np.bincount(idx, w * m, rows)
        m2 = np.bincount(idx, w * (v + m * m), rows)
        sl = np.bincount(idx, w * r, rows)
        var = np.maximum(m2 - mu * mu, 0.0)
        x = np.zeros(rows)
        if ext and self.c_ext > 0.0:
            # c e(z), e = Σ ω_i Σ_j |∂μ_i/∂z_j| |z_j − x*_ij| (the extrapolation term above)
            x = self.c_ext * self.gp.extrapolation_rows(Z, idx, nodes, w)
        return mu, var, np.sqrt(var + sl * sl), x

    def predict(self, z) -> tuple[float, float, float]:
        """(μ̃(z), σ̃²(z), s(z)) at one input (:meth:`predict_many` of one row)."""
        mu, var, s = self.predict_many(np.asarray(z, dtype=float)[None])
        return float(mu[0]), float(var[0]), float(s[0])

    def __call__(self, z, var: float) -> float:
        """s(z) given the merged σ²(z) (without the extrapolation term, which is added, not scaled)."""
        s = self.local(z)
        return float(np.sqrt(max(var, 0.0) + s * s))


def conformal_quantile(scores: np.ndarray, alpha: float) -> float:
    """Split-conformal quantile (Vovk et al. 2005; Lei et al. 2018): the ⌈(m + 1)(1 − α)⌉-th
    smallest of m calibration scores.  For a new point exchangeable with the calibration
    points, Pr(score_new ≤ q) ≥ 1 − α.  Needs m ≥ 1/α − 1 scores (else no finite q exists)."""
    sc = np.sort(np.asarray(scores, dtype=float).ravel())
    m = sc.size
    if not 0 < alpha < 1:
        raise ValueError(f"alpha must be in (0, 1), got {alpha}")
    r = int(math.ceil((m + 1) * (1.0 - alpha)))
    if r > m:
        raise ValueError(f"split conformal at alpha = {alpha:g} needs at least {int(math.ceil(1 / alpha)) - 1} "
                         f"calibration scores, got {m}")
    return float(sc[r - 1])


def conformal_constants(scores: np.ndarray, delta: float, n_leaves: int = 1) -> BoundConstants:
    """|f(z) − μ(z)| ≤ q s(z) with probability ≥ 1 − δ for a new z exchangeable with the
    calibration pairs, s = :class:`LocalScale` (docs/bounds.md §2b).

    ``scores`` are |y_i − μ(z_i)| / s(z_i) of held-out pairs (z_i, y_i = f(z_i) + ε_i)
    that the GP never learned.  The targets are noisy; with ε symmetric and independent of the
    rest, {|f − μ| > t} implies {|y − μ| > t} with probability ≥ 1/2, so
    Pr(|f − μ| > t) ≤ 2 Pr(|y − μ| > t): the y-quantile is taken at α = δ/2.
    """
    q = conformal_quantile(scores, 0.5 * delta)
    return BoundConstants(float(q), 0.0, 0.0, float("nan"), float("nan"), 0.0, float(delta), int(n_leaves),
                          "local", "conformal")


def fixed_constants(beta: float, delta: float) -> BoundConstants:
    """A configured β (``estimator.gp_beta: <number>``): η = β s(z) with the local scale of
    the conformal bound, so a β printed by ``bench bounds --gp-beta conformal`` can be configured."""
    return BoundConstants(float(beta), 0.0, 0.0, float("nan"), float("nan"), 0.0, float(delta), 1,
                          "local", "fixed")


def _leaf_terms(leaf: LeafGP, L_k: float):
    L_mu = L_k * float(np.sum(np.abs(leaf.alpha)))                      # LUH19 Thm 3.1, ‖α‖₁ form
    Kn = leaf.Kinv_norm if leaf.Kinv_norm is not None else 1.0 / leaf.sigma_n ** 2
    c_sigma = 2.0 * L_k * (1.0 + leaf.N * Kn * leaf.sigma_f ** 2)        # LUH19: ω_σ(τ)² = c_sigma τ
    return L_mu, c_sigma


def omega_sigma(c_sigma: float, sigma_f: float, tau: float) -> float:
    """ω_σ(τ) = min(√(c_sigma τ), σ_f τ): LUH19's modulus of continuity of σ_N and the posterior
    standard deviation's Lipschitz constant σ_f in normalised coordinates (module docstring)."""
    return min(math.sqrt(c_sigma * tau), sigma_f * tau)


def error_bound(leaves: Sequence[LeafGP], lo: np.ndarray, hi: np.ndarray, delta: float, *,
                n_leaves: int | None = None, L_f: float | Sequence[float] | None = None,
                delta_lipschitz: float = 0.0, sigma_ref: float | None = None,
                tau_grid: np.ndarray = TAU_GRID) -> BoundConstants:
    """Constants of |f(x) − μ̃(x)| ≤ √β σ̃(x) + γ for all x in the box [lo, hi] (one output).

    leaves          the leaf GPs (one for a plain GP); leaves may have their own
                    hyperparameters: the bound then uses max_i √β_i and max_i γ_i
    delta           total failure probability of the statement (δ_GP + δ_L)
    n_leaves        L of the union bound; default len(leaves) (use max_leaves while growing)
    L_f             known Lipschitz bound of f: a scalar (raw-coordinate ‖∇f‖₂ bound) or one
                    |∂f/∂x_i| bound per input; None → LUH19 Thm 3.2 with δ_L = delta_lipschitz
    sigma_ref       σ at which η = √β σ + γ is minimised over τ (default: smallest σ_n)
    """
    leaves = list(leaves)
    if not leaves:
        raise ValueError("error_bound needs at least one leaf GP")
    if not 0 < delta < 1:
        raise ValueError(f"delta must be in (0, 1), got {delta}")
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    dim = np.size(leaves[0].lengthscales)
    if lo.shape != (dim,) or hi.shape != (dim,) or np.any(hi < lo):
        raise ValueError(f"box [lo, hi] must have {dim} entries with lo <= hi")
    L = int(n_leaves if n_leaves is not None else len(leaves))
    if L < len(leaves):
        raise ValueError(f"n_leaves={L} is smaller than the {len(leaves)} leaves given")
    if L_f is None and not 0 < delta_lipschitz < delta:
        raise ValueError("without a known L_f, delta_lipschitz must be in (0, delta) (LUH19 Thm 3.2)")
    d_gp = delta - (delta_lipschitz if L_f is None else 0.0)
    # per leaf (own hyperparameters allowed): normalised box, L_f, L_μ, ω_σ² / τ
    per = []
    for lf in leaves:
        ls = np.asarray(lf.lengthscales, dtype=float)
        widths = (hi - lo) / ls                                          # normalised box
        if L_f is None:
            Lf = sample_lipschitz_se(float(lf.sigma_f), widths, delta_lipschitz)
        else:
            Lv = np.atleast_1d(np.asarray(L_f, dtype=float))
            # |f(x) − f(x')| ≤ Σ|∂_i f||Δx_i| = Σ (l_i |∂_i f|)|Δx̃_i| ≤ ‖l ⊙ ∂f‖₂ ‖Δx̃‖₂
            Lf = float(np.linalg.norm(ls * Lv)) if Lv.size == ls.size else float(Lv[0] * ls.max())
        L_mu, c_sig = _leaf_terms(lf, se_lipschitz(float(lf.sigma_f)))
        per.append((widths, Lf, L_mu, c_sig, float(lf.sigma_f)))
    s_ref = sigma_ref if sigma_ref is not None else min(lf.sigma_n for lf in leaves)
    G = len(tau_grid)
    best = None
    for tau in tau_grid:
        sb_max = g_max = 0.0
        for widths, Lf, L_mu, c_sig, s_f in per:
            # β(τ) = 2 log(M(τ, X) / δ_i), δ_i = δ_GP / (L · G): union over leaves and the τ grid
            sb = math.sqrt(2.0 * (log_covering_number(widths, tau) + math.log(L * G / d_gp)))
            # γ(τ) = (L_μ + L_f) τ + √β ω_σ(τ)
            g = (L_mu + Lf) * tau + sb * omega_sigma(c_sig, s_f, tau)
            sb_max, g_max = max(sb_max, sb), max(g_max, g)
        # merged bound: √β_max Σ w σ_i + max γ_i  (module docstring)
        val = sb_max * s_ref + g_max
        if best is None or val < best[0]:
            best = (val, float(tau), sb_max, g_max)
    _, tau, sb, g = best
    return BoundConstants(float(sb), float(g), tau, float(max(p[1] for p in per)),
                          float(max(p[2] for p in per)), float(max(omega_sigma(p[3], p[4], tau) for p in per)),
                          float(delta), L)


def loggp_leaves(gp) -> list[LeafGP]:
    """LeafGP records of every leaf of a :class:`sea_daemon.core.gp.loggp.LoGGP` (leaf GPs are
    :class:`sea_daemon.core.gp.exact.IncrementalGP` with ``alpha_``, ``L_`` (Cholesky of K + σ_n² I),
    ``sigma_f``, ``lengthscales``, ``sigma_n``)."""
    out = []
    for node in gp.leaves():
        g = gp.leaf(node)
        if g.n_ == 0:
            continue
        Lc = np.asarray(g.L_)
        # ‖(K + σ_n² I)⁻¹‖₂ = 1/λ_min(K + σ_n² I) = 1/σ_min(L)²
        smin = float(np.linalg.svd(Lc, compute_uv=False).min())
        out.append(LeafGP(np.asarray(g.alpha_, dtype=float).copy(), float(g.sigma_f),
                          np.asarray(g.lengthscales, dtype=float).copy(), float(g.sigma_n),
                          1.0 / smin ** 2 if smin > 0 else None))
    return out


def merged_sigma(weights: np.ndarray, sigmas: np.ndarray, mus: np.ndarray | None = None) -> float:
    """A σ̃ valid for the merged bound: the mixture std (with ``mus``) or the weighted-variance std.

    Both dominate Σ w_i σ_i (Jensen), which is what the merged bound needs.
    """
    w = np.asarray(weights, float)
    s = np.asarray(sigmas, float)
    if mus is None:
        return float(np.sqrt(np.sum(w * s ** 2)))
    m = np.asarray(mus, float)
    mu = np.sum(w * m)
    return float(np.sqrt(np.sum(w * (s ** 2 + (m - mu) ** 2))))


def input_box(Z: np.ndarray, margin: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
    """Axis box around data Z (m, d), widened by ``margin`` of the range on each side.

    The bound is only claimed on this box; states outside it have no guarantee.
    """
    Z = np.atleast_2d(Z)
    lo, hi = Z.min(0), Z.max(0)
    w = np.maximum(hi - lo, 1e-9)
    return lo - margin * w, hi + margin * w


def outputs_eta(consts: Iterable[BoundConstants], sigmas: np.ndarray) -> np.ndarray:
    """η_i = √β_i σ_i + γ_i for the n independent output GPs (Sec. IV-A)."""
    return np.array([c.eta(s) for c, s in zip(consts, np.atleast_1d(sigmas))], dtype=float)
