"""Zonotopes ⊕_i G[:, i]·[−1, 1] (generator matrices G), the default set of means of the
Theorem-1 bound (:class:`~sea_daemon.core.bounds.setmember.SetMembershipBound`): their
trace-minimal outer ellipsoid, order reduction (Girard 2005) and the prediction step's
generators (exact Minkowski sums of mapped boxes).  Compiled; pure numerics.
"""
from __future__ import annotations

import math

import numpy as np

from sea_daemon.core.jit import njit, warmer


def zonotope_shape(G: np.ndarray, extra: np.ndarray | None = None) -> np.ndarray:
    """Trace-minimal outer ellipsoid shape of the zonotope ⊕_i G[:, i]·[−1, 1] (⊕ E(0, extra)).

    The segments' shapes are g gᵀ with t_i = ‖g_i‖ (ellipsoid.minkowski_shape), so
    X* = (Σ_j t_j) Σ_i g_i g_iᵀ / t_i (+ (Σ t_j) extra / t_extra) — without building the list.
    """
    G = np.ascontiguousarray(G, dtype=float)
    if extra is None:
        return outer_ellipsoid_shape(G, np.zeros((G.shape[0], G.shape[0])), False)
    return outer_ellipsoid_shape(G, np.ascontiguousarray(extra, dtype=float), True)


@njit
def outer_ellipsoid_shape(G, extra, has_extra):
    """:func:`zonotope_shape` (compiled; ``extra`` ignored unless ``has_extra``)."""
    d, k = G.shape
    t = np.empty(k)
    T = 0.0
    for j in range(k):
        s = 0.0
        for i in range(d):
            s += G[i, j] * G[i, j]
        t[j] = math.sqrt(s)
        if t[j] > 1e-300:
            T += t[j]
    te = 0.0
    if has_extra:
        tr = 0.0
        for i in range(d):
            tr += extra[i, i]
        te = math.sqrt(max(tr, 0.0))
    T += te
    X = np.zeros((d, d))
    if T <= 1e-300:
        return X
    for j in range(k):
        if t[j] > 1e-300:
            f = T / t[j]
            for a in range(d):
                ga = f * G[a, j]
                for b in range(d):
                    X[a, b] += ga * G[b, j]
    if te > 1e-300:
        f = T / te
        for a in range(d):
            for b in range(d):
                X[a, b] += f * extra[a, b]
    # symmetric part (rounding)
    for a in range(d):
        for b in range(a + 1, d):
            m = 0.5 * (X[a, b] + X[b, a])
            X[a, b] = m
            X[b, a] = m
    return X


def reduce_generators(G: np.ndarray, m: int) -> np.ndarray:
    """Zonotope order reduction (Girard 2005): keep the m − d generators with the largest
    ‖g‖₁ − ‖g‖∞ and replace the others by their interval hull diag(Σ|g_i|) (d axis-aligned
    generators; an outer approximation, exact when the removed ones are axis-aligned).

    The hull is re-boxed at later reductions; under a strongly contracting filter map
    (I − K H) F this costs little (on the simulated paper scenarios ρ with 40 generators
    equals the unreduced propagation to 4 digits), under slowly contracting rotations it can
    grow (tests/test_setmember.py)."""
    G = np.asarray(G, dtype=float)
    if G.shape[1] <= m:
        return G
    return _reduce_generators(np.ascontiguousarray(G), int(m))


@njit
def _reduce_generators(G, m):
    """:func:`reduce_generators` (compiled; G C-contiguous with more than m columns)."""
    d, k = G.shape
    score = np.empty(k)
    for j in range(k):
        s1 = 0.0
        mx = 0.0
        for i in range(d):
            a = abs(G[i, j])
            s1 += a
            mx = max(mx, a)
        score[j] = s1 - mx
    order = np.argsort(score, kind="mergesort")
    n_small = k - (m - d)
    box = np.zeros(d)
    for q in range(n_small):
        j = order[q]
        for i in range(d):
            box[i] += abs(G[i, j])
    n_box = 0
    for i in range(d):
        if box[i] > 0.0:
            n_box += 1
    out = np.zeros((d, (m - d) + n_box))
    for q in range(m - d):
        j = order[n_small + q]
        for i in range(d):
            out[i, q] = G[i, j]
    c = m - d
    for i in range(d):
        if box[i] > 0.0:
            out[i, c] = box[i]
            c += 1
    return out


@njit
def predict_generators(F, G, Gamma, eta, Phi, b, m):
    """Generators of F·Z ⊕ Γ·box(η) ⊕ Φ·box(b) without the zero ones, reduced to at most m
    (:meth:`~sea_daemon.core.bounds.setmember.SetMembershipBound.predict`, zonotope mode)."""
    d = F.shape[0]
    out = np.empty((d, G.shape[1] + Gamma.shape[1] + Phi.shape[1]))
    col = np.empty(d)
    c = 0
    for j in range(G.shape[1]):
        nz = False
        for i in range(d):
            s = 0.0
            for q in range(d):
                s += F[i, q] * G[q, j]
            col[i] = s
            nz = nz or s != 0.0
        if nz:
            out[:, c] = col
            c += 1
    for j in range(Gamma.shape[1] + Phi.shape[1]):
        nz = False
        for i in range(d):
            v = Gamma[i, j] * abs(eta[j]) if j < Gamma.shape[1] else \
                Phi[i, j - Gamma.shape[1]] * abs(b[j - Gamma.shape[1]])
            col[i] = v
            nz = nz or v != 0.0
        if nz:
            out[:, c] = col
            c += 1
    if c <= m:
        return out[:, :c].copy()
    return _reduce_generators(out[:, :c].copy(), m)


@warmer
def _warm() -> None:
    """The compiled kernels with the argument types the set-membership bound passes."""
    zonotope_shape(np.ones((2, 3)), np.eye(2))
    zonotope_shape(np.ones((2, 3)))
    predict_generators(np.eye(2), np.ones((2, 1)), np.ones((2, 1)), np.ones(1), np.eye(2), np.ones(2), 3)
