"""Ellipsoids E(c, X) = {x : (x − c)ᵀ X⁻¹ (x − c) ≤ 1} with PSD, possibly degenerate, shape X.

Paper notation (footnote of Sec. II): E(c, X) with centre c and shape matrix X.  A
degenerate X (rank-deficient, e.g. a segment or a point) is read through its support
function h(e) = eᵀc + sqrt(eᵀ X e), which stays well defined; every operation here works
with support functions and never inverts X unless a containment test asks for it.

Operations
----------
* affine map            A·E(c, X) + b = E(Ac + b, A X Aᵀ)                        (exact)
* Minkowski sum         ⊕_i E(c_i, X_i) ⊆ E(Σ c_i, X*)                 (outer approximation)
  with the trace-minimal member of the Kurzhanski–Vályi / Maksarov family
      X(p) = Σ_i X_i / p_i,   p_i > 0,  Σ p_i = 1,
  i.e. p_i ∝ sqrt(tr(W X_i)), which gives X* = (Σ_j sqrt(tr W X_j)) Σ_i X_i / sqrt(tr W X_i).
  For two ellipsoids this is X = (1 + 1/p) X_1 + (1 + p) X_2 with p = sqrt(tr X_1 / tr X_2).
  W = I by default (plain trace); a weight W ≻ 0 makes the criterion unit-free (tr(W X)).
* half-width along e    sqrt(eᵀ X e) (support function minus eᵀc)
* interval → ellipsoid  lem:interval_bound, eq:GPboundsellipse: the box Π[−η_i, η_i] is the
  Minkowski sum of the n segments E(0, η_i² e_i e_iᵀ); its trace-minimal outer ellipsoid is
  E(0, (Σ_j η_j) diag(η_i)), which passes through every corner of the box.
* Gaussian confidence ellipsoid  Pr(ξ ∈ E(ξ̄, s C)) = p for ξ ~ N(ξ̄, C) of dimension m with
  s = χ²_m(p) (eq:gaussianellipsoid): :func:`chi2_quantile`, the χ² quantile of the
  estimators' and the bounds' confidence sets and of the NIS band.

Why the family contains the sum: for every direction e, Cauchy–Schwarz gives
Σ_i sqrt(eᵀX_i e) = Σ_i sqrt(p_i)·sqrt(eᵀX_i e / p_i) ≤ sqrt(Σ p_i)·sqrt(Σ_i eᵀX_i e / p_i),
i.e. h_sum(e) ≤ h_{X(p)}(e); support functions decide containment of convex sets.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable, Sequence

import numpy as np
from scipy.special import gammaincinv

_EIG_TOL = 1e-12


def chi2_quantile(p: float, dof: int) -> float:
    """χ²_dof quantile at probability p: s with Pr(ξ ∈ E(ξ̄, s C)) = p for a Gaussian ξ of
    dimension dof (eq:gaussianellipsoid)."""
    # 2·P⁻¹(dof/2, p), P⁻¹ the inverse regularised lower incomplete gamma function
    return float(2.0 * gammaincinv(0.5 * dof, p))


def _sym(X: np.ndarray) -> np.ndarray:
    return 0.5 * (X + X.T)


@dataclass(frozen=True)
class Ellipsoid:
    """E(c, X): centre ``c`` (d,), shape ``X`` (d, d) symmetric PSD (degenerate allowed)."""

    c: np.ndarray
    X: np.ndarray

    def __post_init__(self):
        c = np.atleast_1d(np.asarray(self.c, dtype=float))
        X = np.atleast_2d(np.asarray(self.X, dtype=float))
        if c.ndim != 1 or X.shape != (c.shape[0], c.shape[0]):
            raise ValueError(f"Ellipsoid: centre of shape {c.shape} needs a square shape matrix of the same size, "
                             f"got {X.shape}")
        if not (np.all(np.isfinite(c)) and np.all(np.isfinite(X))):
            raise ValueError("Ellipsoid: centre and shape must be finite")
        object.__setattr__(self, "c", c)
        object.__setattr__(self, "X", _sym(X))

    # ------------------------------------------------------------------ basics

    @property
    def dim(self) -> int:
        return self.c.shape[0]

    @classmethod
    def point(cls, c: np.ndarray) -> "Ellipsoid":
        c = np.atleast_1d(np.asarray(c, dtype=float))
        return cls(c, np.zeros((c.size, c.size)))

    def is_psd(self, tol: float = 1e-9) -> bool:
        """True when X is positive semi-definite (relative tolerance ``tol``)."""
        w = np.linalg.eigvalsh(self.X)
        return bool(w.min() >= -tol * max(1.0, abs(w).max()))

    def half_width(self, e: np.ndarray) -> float:
        """Half-width along direction ``e`` (not normalised): sqrt(eᵀ X e) = h(e) − eᵀc."""
        e = np.asarray(e, dtype=float)
        return float(np.sqrt(max(e @ self.X @ e, 0.0)))

    def support(self, e: np.ndarray) -> float:
        """Support function h(e) = max_{x∈E} eᵀx = eᵀc + sqrt(eᵀ X e)."""
        e = np.asarray(e, dtype=float)
        return float(e @ self.c) + self.half_width(e)

    def axis_half_widths(self) -> np.ndarray:
        """sqrt(diag X): the half-widths of the bounding box, per coordinate."""
        return np.sqrt(np.clip(np.diag(self.X), 0.0, None))

    # ------------------------------------------------------------------ maps

    def affine(self, A: np.ndarray, b: np.ndarray | None = None) -> "Ellipsoid":
        """A·E + b = E(A c + b, A X Aᵀ) — exact (Noack et al. 2010; A may be rectangular)."""
        A = np.atleast_2d(np.asarray(A, dtype=float))
        c = A @ self.c
        if b is not None:
            c = c + np.asarray(b, dtype=float)
        return Ellipsoid(c, A @ self.X @ A.T)

    def scaled(self, s: float) -> "Ellipsoid":
        """E(c, s X): the same centre, the shape scaled by s ≥ 0 (e.g. a χ² quantile)."""
        if s < 0:
            raise ValueError(f"scale must be >= 0, got {s}")
        return Ellipsoid(self.c, s * self.X)

    def __add__(self, other: "Ellipsoid") -> "Ellipsoid":
        """Trace-minimal outer approximation of the Minkowski sum (see :func:`minkowski_sum`)."""
        return minkowski_sum([self, other])

    # ------------------------------------------------------------------ membership

    def contains(self, x: np.ndarray, tol: float = 1e-9) -> np.ndarray:
        """Membership of points ``x`` (d,) or (m, d); works for degenerate X.

        x ∈ E  ⇔  x − c ∈ range(X)  and  (x − c)ᵀ X⁺ (x − c) ≤ 1, with X⁺ the pseudo-inverse
        (eigen-decomposition, eigenvalues below tol·λ_max treated as zero).
        """
        x = np.asarray(x, dtype=float)
        single = x.ndim == 1
        D = np.atleast_2d(x) - self.c
        w, V = np.linalg.eigh(self.X)
        lam_max = max(w.max(), 0.0)
        keep = w > _EIG_TOL * max(lam_max, 1e-300)
        Z = D @ V
        # components outside range(X) must vanish (up to rounding: square roots of PSD matrices
        # carry ~sqrt(eps)·|X|^{1/2} noise in null directions)
        scale = 1.0 + np.sqrt(lam_max) + np.linalg.norm(D, axis=1)
        inside_range = np.all(np.abs(Z[:, ~keep]) <= max(tol, 1e-6) * scale[:, None], axis=1)
        q = np.sum(Z[:, keep] ** 2 / w[keep], axis=1) if np.any(keep) else np.zeros(len(D))
        out = inside_range & (q <= 1.0 + tol)
        return bool(out[0]) if single else out

    def contains_ellipsoid(self, other: "Ellipsoid", n_dirs: int = 0, rng=None, tol: float = 1e-9) -> bool:
        """Containment other ⊆ self, by support functions.

        Exact for non-degenerate ``self``: other ⊆ self ⇔ max_e [h_other(e) − h_self(e)] ≤ 0,
        checked on the generalised eigen-directions of (other.X, self.X) plus the centre offset
        direction and ``n_dirs`` random directions.  The eigen-direction test is exact when
        the centres coincide; with distinct centres the extra directions make it a test.
        """
        dirs = [np.eye(self.dim)[i] for i in range(self.dim)]
        w, V = np.linalg.eigh(self.X)
        if w.min() > _EIG_TOL * max(w.max(), 1e-300):
            # whiten self: self → unit ball; then the worst directions are eigenvectors of other
            S = V / np.sqrt(w)
            w2, V2 = np.linalg.eigh(S.T @ other.X @ S)
            # e = S v: eᵀX_self e = |v|², eᵀX_other e = vᵀ(SᵀX_other S)v, extremal at its eigenvectors
            dirs += [S @ v for v in V2.T]
            dc = S.T @ (other.c - self.c)
            if np.linalg.norm(dc) > 0:
                dirs.append(S @ dc)
        if n_dirs:
            rng = np.random.default_rng(rng)
            dirs += list(rng.standard_normal((n_dirs, self.dim)))
        for e in dirs:
            for sgn in (1.0, -1.0):
                ee = sgn * np.asarray(e)
                if other.support(ee) > self.support(ee) + tol * (1.0 + abs(self.support(ee))):
                    return False
        return True

    # ------------------------------------------------------------------ sampling

    def boundary_points(self, U: np.ndarray) -> np.ndarray:
        """Points c + X^{1/2} u for the unit vectors u in the rows of ``U`` (m, d)."""
        return self.c + U @ sqrtm_psd(self.X).T

    def sample(self, m: int, rng=None, boundary: bool = False) -> np.ndarray:
        """m points uniform in the ellipsoid (or on its boundary), for tests."""
        rng = np.random.default_rng(rng)
        d = self.dim
        U = rng.standard_normal((m, d))
        U /= np.linalg.norm(U, axis=1, keepdims=True)
        if not boundary:
            U *= rng.uniform(size=(m, 1)) ** (1.0 / d)
        return self.boundary_points(U)


# ---------------------------------------------------------------------------- helpers

def sqrtm_psd(X: np.ndarray) -> np.ndarray:
    """Symmetric square root of a PSD matrix (negative rounding eigenvalues clipped to 0)."""
    w, V = np.linalg.eigh(_sym(np.asarray(X, dtype=float)))
    return (V * np.sqrt(np.clip(w, 0.0, None))) @ V.T


def minkowski_shape(shapes: Sequence[np.ndarray], weight: np.ndarray | None = None) -> np.ndarray:
    """Shape of the tr(W·)-minimal outer ellipsoid of ⊕_i E(0, X_i).

    Kurzhanski & Vályi (1997) / Maksarov: X(p) = Σ X_i / p_i with Σ p_i = 1 contains the
    sum for every p > 0; minimising tr(W X(p)) = Σ tr(W X_i)/p_i under Σ p_i = 1 (Lagrange)
    gives p_i = t_i / Σ t_j with t_i = sqrt(tr(W X_i)), hence
        X* = (Σ_j t_j) · Σ_i X_i / t_i,      tr(W X*) = (Σ_j t_j)².
    Shapes with t_i = 0 (points, or directions W ignores) are handled: a true point
    contributes nothing; a shape that is non-zero but invisible to W (tr(W X_i) = 0 with
    X_i ≠ 0) falls back to the plain trace for that term so containment is kept.
    """
    if not shapes:
        raise ValueError("minkowski_shape needs at least one shape")
    d = np.shape(shapes[0])[0]
    W = None if weight is None else np.asarray(weight, dtype=float)
    t = []
    keep = []
    for X in shapes:
        X = np.asarray(X, dtype=float)
        tr = float(np.trace(X))
        if tr <= 0.0 and not np.any(X):
            continue  # a point: adds only to the centre
        ti = tr if W is None else float(np.sum(W * X))
        ti = float(np.sqrt(max(ti, 0.0)))
        if ti <= 1e-300:
            ti = float(np.sqrt(max(tr, 0.0)))  # invisible to W: use the trace for it
        if ti <= 1e-300:
            continue
        t.append(ti)
        keep.append(X)
    if not keep:
        return np.zeros((d, d))
    if len(keep) == 1:
        return _sym(keep[0])
    T = sum(t)
    out = keep[0] * (T / t[0])
    for X, ti in zip(keep[1:], t[1:]):
        out += X * (T / ti)
    return _sym(out)


def minkowski_sum(ellipsoids: Iterable[Ellipsoid], weight: np.ndarray | None = None) -> Ellipsoid:
    """Outer approximation E(Σ c_i, X*) ⊇ ⊕_i E(c_i, X_i), X* trace-minimal (see :func:`minkowski_shape`).

    The n-ary optimum is at least as tight (in tr W X) as any nesting of pairwise sums,
    because nested pairwise parameters are a sub-family of the n-ary family.
    """
    ells = list(ellipsoids)
    if not ells:
        raise ValueError("minkowski_sum needs at least one ellipsoid")
    c = np.sum([e.c for e in ells], axis=0)
    return Ellipsoid(c, minkowski_shape([e.X for e in ells], weight))


def minkowski_half_width(ellipsoids: Iterable[Ellipsoid], e: np.ndarray) -> float:
    """Exact half-width of the Minkowski sum along e: Σ_i sqrt(eᵀ X_i e) (support functions add)."""
    return float(sum(E.half_width(e) for E in ellipsoids))


def box_shape(half_widths: np.ndarray) -> np.ndarray:
    """Trace-minimal outer ellipsoid shape of the box Π[−η_i, η_i]: (Σ_j η_j) diag(η_i).

    lem:interval_bound turns |f_i − μ_i| ≤ η_i into the 1-D ellipsoid E(μ_i, η_i²), i.e. the
    degenerate ellipsoid E(μ̃_i, diag(0..η_i²..0)) in R^n; eq:GPboundsellipse encloses their
    Minkowski sum by one ellipsoid, here the trace-minimal one (Σ η)·diag(η) (tr = (Σ η)²,
    never larger than the alternative n·diag(η²), tr = n Σ η², by Cauchy–Schwarz).
    Zero half-widths give zero rows/columns (the box is flat there).
    """
    eta = np.abs(np.atleast_1d(np.asarray(half_widths, dtype=float)))
    return np.sum(eta) * np.diag(eta)


def interval_ellipsoid(mu: np.ndarray, eta: np.ndarray) -> Ellipsoid:
    """E(μ̃, X̃) ⊇ Π_i [μ_i − η_i, μ_i + η_i]   (lem:interval_bound, eq:GPboundsellipse)."""
    return Ellipsoid(np.atleast_1d(np.asarray(mu, dtype=float)), box_shape(eta))


def segments_shapes(G: np.ndarray, eta: np.ndarray) -> list[np.ndarray]:
    """Shapes of the segments G[:, i]·[−η_i, η_i] (degenerate ellipsoids η_i² g_i g_iᵀ).

    The image G·box of a box is their Minkowski sum (a zonotope); summing the segments
    together with the other terms in one n-ary trace-minimal sum is tighter than mapping
    the box's outer ellipsoid through G.
    """
    G = np.atleast_2d(np.asarray(G, dtype=float))
    eta = np.abs(np.atleast_1d(np.asarray(eta, dtype=float)))
    return [eta[i] ** 2 * np.outer(G[:, i], G[:, i]) for i in range(G.shape[1]) if eta[i] > 0]
