"""Frozen LoG-GPs as flat arrays for compiled consumers: :class:`GPPack` and :func:`gp_points`.

A residual's LoG-GPs (one per joint, :class:`~sea_daemon.core.gp.loggp.LoGGP`) whose learning
is off are flattened once into a few arrays (:class:`PackArrays`): per joint its tree
(:attr:`LoGGP.tree`), per leaf its data, factor and hyperparameters.  Two compiled
consumers read them: the Theorem-1 bound's step (:func:`~sea_daemon.core.bounds.bound_core.bound_step`,
through :func:`gp_points`) and the GP-AKF's residual hook
(:func:`~sea_daemon.core.estimators.gp_hook.hook_predict`).  A pack is made again when the GPs
changed (:meth:`GPPack.stale`).  Pure numerics.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from sea_daemon.core.jit import njit
from sea_daemon.core.gp import gp_core
from sea_daemon.core.gp.loggp import LoGGP
from sea_daemon.core.gp.routing import route


class PackArrays(NamedTuple):
    """The arrays of a :class:`GPPack` (J joints, L leaves, N points in all, d inputs).

    Per joint j: ``links[j]`` (3, nodes) split dimension, left, right; ``span[j]`` (2, nodes)
    overlap lo, hi (padded with leaves); ``leaf_of[j, node]`` the node's leaf index (−1 for a
    split node).  Per leaf l: ``nn[l]`` points in rows ``row[l] .. row[l] + nn[l]`` of ``A``
    (kernel features, (N, d + 2)), ``X`` (inputs), ``beta``, ``alpha`` (α = L⁻ᵀβ, eq:GPmean); the
    packed Cholesky factor at ``ap[apo[l]:]``; ``center`` (L, d), ``il2`` (L, d) 1/l², ``sf2`` σ_f²,
    the input box ``lo``, ``hi`` and ``clip`` (clip_mean), ``r`` the local residual scale.
    """

    links: np.ndarray
    span: np.ndarray
    leaf_of: np.ndarray
    nn: np.ndarray
    row: np.ndarray
    apo: np.ndarray
    A: np.ndarray
    X: np.ndarray
    beta: np.ndarray
    alpha: np.ndarray
    ap: np.ndarray
    center: np.ndarray
    il2: np.ndarray
    sf2: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    clip: np.ndarray
    r: np.ndarray


class GPPack:
    """The LoG-GPs of a residual (one per joint) as flat arrays (:class:`PackArrays`).

    ``local_r``: per joint, the local residual scale r of each leaf node (gp_bound.LocalScale),
    or None (zeros).  ``sn2``: σ_on² per leaf (the residual hook's noise).  ``c_ext``: the
    extrapolation scale of the LoG-GPs (``learning.extrapolation_scale``).
    """

    def __init__(self, gps, local_r: list[dict] | None = None):
        self.gps = list(gps)
        self.signature = self._signature()
        n = len(self.gps)
        d = self.gps[0].input_dim
        trees = [g.tree for g in self.gps]
        nodes = max(t.links.shape[1] for t in trees)
        self.links = np.full((n, 3, nodes), -1, dtype=np.int64)
        self.span = np.zeros((n, 2, nodes))
        self.leaf_of = np.full((n, nodes), -1, dtype=np.int64)
        leaves = []
        for j, (g, t) in enumerate(zip(self.gps, trees)):
            m = t.links.shape[1]
            self.links[j, :, :m] = t.links
            self.span[j, :, :m] = t.span
            for node in g.leaves():
                self.leaf_of[j, node] = len(leaves)
                r = 0.0 if local_r is None else float(local_r[j].get(node, 0.0))
                leaves.append((g.leaf(node), r))
        self._fill_leaves(leaves, d)
        self.c_ext = float(getattr(self.gps[0], "extrapolation_scale", 0.0))

    def _fill_leaves(self, leaves: list, d: int) -> None:
        """Every leaf's rows, factor and hyperparameters into the flat arrays."""
        L = len(leaves)
        self.nn = np.array([lf.n_ for lf, _ in leaves], dtype=np.int64)
        self.row = np.zeros(L, dtype=np.int64)
        self.apo = np.zeros(L, dtype=np.int64)
        rows = int(self.nn.sum())
        self.A = np.zeros((max(rows, 1), d + 2))
        self.X = np.zeros((max(rows, 1), d))
        self.beta = np.zeros(max(rows, 1))
        self.alpha = np.zeros(max(rows, 1))
        self.ap = np.zeros(max(int(np.sum(self.nn * (self.nn + 1) // 2)), 1))
        self.center = np.zeros((L, d))
        self.il2 = np.zeros((L, d))
        self.sf2 = np.zeros(L)
        self.lo = np.zeros((L, d))
        self.hi = np.zeros((L, d))
        self.clip = np.zeros(L, dtype=np.bool_)
        self.r = np.zeros(L)
        # σ_on² per leaf (the GP-AKF's compiled hook, gp_hook.hook_predict)
        self.sn2 = np.array([lf.sigma_n ** 2 for lf, _ in leaves], dtype=float)
        ro = po = 0
        for i, (lf, r) in enumerate(leaves):
            m = lf.n_
            self.row[i], self.apo[i] = ro, po
            self.sf2[i] = lf.sf2
            self.il2[i] = lf.il2
            self.clip[i] = lf.clip_mean
            self.r[i] = r
            if m:
                self.A[ro:ro + m] = lf.A_[:m]
                self.X[ro:ro + m] = lf.X_[:m]
                self.beta[ro:ro + m] = lf.beta_[:m]
                self.alpha[ro:ro + m] = lf.alpha_
                self.ap[po:po + m * (m + 1) // 2] = lf.ap_[:m * (m + 1) // 2]
                self.center[i] = lf.center_
                self.lo[i], self.hi[i] = lf.lo_, lf.hi_
            ro += m
            po += m * (m + 1) // 2

    def _signature(self) -> tuple:
        """What changes when a LoG-GP learns: its node count and every leaf's point count."""
        return tuple((g.n_nodes, tuple(g.leaf(k).n_ for k in g.leaves())) for g in self.gps)

    def stale(self) -> bool:
        """The GPs changed since the pack was made (learning, a split, a load)."""
        return self._signature() != self.signature

    def arrays(self) -> PackArrays:
        """The pack's arrays, named."""
        return PackArrays(self.links, self.span, self.leaf_of, self.nn, self.row, self.apo, self.A, self.X,
                          self.beta, self.alpha, self.ap, self.center, self.il2, self.sf2, self.lo, self.hi,
                          self.clip, self.r)

    def args(self) -> tuple:
        """The pack's arrays as a plain tuple (the residual hook's positional arguments)."""
        return tuple(self.arrays())


def empty_pack() -> PackArrays:
    """A pack's argument types without a GP (the plain AKF's call of the bound's step)."""
    i1, i2, i3 = np.zeros(1, np.int64), np.full((1, 1), -1, np.int64), np.full((1, 3, 1), -1, np.int64)
    f1, f2 = np.zeros(1), np.zeros((1, 1))
    return PackArrays(i3, np.zeros((1, 2, 1)), i2, i1, i1, i1, f2, f2, f1, f1, f1, f2, f2, f1, f2, f2,
                      np.zeros(1, np.bool_), f1)


@njit
def _leaf_extrapolation(l, x, p, e1, xq):
    """e(x) of leaf l of pack ``p`` (IncrementalGP.extrapolation_many's row)."""
    m = p.nn[l]
    if m == 0:
        return 0.0
    r0 = p.row[l]
    for i in range(x.shape[0]):
        xq[0, i] = x[i]
    gp_core.extrapolation_many(p.X[r0:r0 + m], m, p.alpha[r0:r0 + m], p.il2[l], p.sf2[l], xq, e1)
    return e1[0]


@njit(fast=True)
def _solve_lower_many(ap, n, B, k):
    """B[c, :n] ← L⁻¹ B[c, :n] for c < k (forward substitution, L packed row by row, as
    :func:`~sea_daemon.core.gp.gp_core.solve_lower`), four right-hand sides at a time: one pass
    over L for four of them, their substitutions side by side (independent, so they overlap in
    the CPU instead of each waiting for its own chain of divisions)."""
    c0 = 0
    while c0 + 4 <= k:
        b0, b1, b2, b3 = B[c0], B[c0 + 1], B[c0 + 2], B[c0 + 3]
        for i in range(n):
            off = i * (i + 1) // 2
            s0, s1, s2, s3 = b0[i], b1[i], b2[i], b3[i]
            for c in range(i):
                lic = ap[off + c]
                s0 -= lic * b0[c]
                s1 -= lic * b1[c]
                s2 -= lic * b2[c]
                s3 -= lic * b3[c]
            dii = ap[off + i]
            b0[i] = s0 / dii
            b1[i] = s1 / dii
            b2[i] = s2 / dii
            b3[i] = s3 / dii
        c0 += 4
    for c in range(c0, k):
        gp_core.solve_lower(ap, n, B[c])


@njit
def _leaf_predict_many(l, Z, idx, cols, k, p, xc, a, kv, B, lm, lv):
    """(μ, σ²) of leaf l of pack ``p`` at the rows ``idx[cols[c]]`` of ``Z``, c < k, into
    ``lm[cols[c]]``, ``lv[cols[c]]`` (IncrementalGP.predict_many's rows, with clip_mean):
    σ² = k(x,x) − ‖L⁻¹k‖² (eq:GPvariance, the O(N²) solves of the rows together,
    :func:`_solve_lower_many`), μ = kᵀα (eq:GPmean with α = L⁻ᵀβ, O(N); at the clipped input with
    clip_mean outside the leaf's box)."""
    m = p.nn[l]
    if m == 0:
        for c in range(k):
            lm[cols[c]] = 0.0
            lv[cols[c]] = p.sf2[l]
        return
    r0, p0 = p.row[l], p.apo[l]
    Al = p.A[r0:r0 + m]
    al = p.alpha[r0:r0 + m]
    for c in range(k):
        x = Z[idx[cols[c]]]
        gp_core.query(x, p.center[l], p.il2[l], a)
        gp_core.kernel_vector(Al, m, a, kv)
        mu = 0.0
        for i in range(m):
            mu += kv[i] * al[i]
            B[c, i] = kv[i]
        if p.clip[l] and gp_core.clip_into(x, p.lo[l], p.hi[l], xc):
            gp_core.query(xc, p.center[l], p.il2[l], a)
            gp_core.kernel_vector(Al, m, a, kv)
            mu = 0.0
            for i in range(m):
                mu += kv[i] * al[i]
        lm[cols[c]] = mu
    _solve_lower_many(p.ap[p0:p0 + m * (m + 1) // 2], m, B, k)
    for c in range(k):
        vv = 0.0
        for i in range(m):
            vv += B[c, i] * B[c, i]
        var = p.sf2[l] - vv
        lv[cols[c]] = var if var > 0.0 else 0.0


@njit
def gp_points(Z, local, c_ext, p, MU, S, XT):
    """Merged LoG-GP prediction of pack ``p`` per row of ``Z`` and joint j into MU[:, j], S[:, j],
    XT[:, j]: with ``local`` the mean, the scale √(σ̃² + s_loc²) and the extrapolation term
    c e(z) (LocalScale.predict_many_ext), else the mean and σ̃ (LoGGP.predict_many, XT zero).
    The leaves and weights of each row are the LoG-GP's own routing (:func:`routing.route`).
    The leaves' predictions are made leaf by leaf, for all the rows that reach a leaf at once
    (:func:`_leaf_predict_many`), then merged row by row in the routing's order."""
    P, dz = Z.shape
    xc = np.empty(dz)
    xq = np.empty((1, dz))
    e1 = np.empty(1)
    a = np.empty(dz + 2)
    nmax = max(1, np.max(p.nn)) if p.nn.shape[0] else 1
    kv = np.empty(nmax)
    B = np.empty((P, nmax))
    for j in range(p.links.shape[0]):
        idx, nodes, ws, _ = route(Z, p.links[j], p.span[j], False)
        ne = idx.shape[0]
        lm = np.empty(ne)
        lv = np.empty(ne)
        leaf = np.empty(ne, dtype=np.int64)
        for i in range(ne):
            leaf[i] = p.leaf_of[j, nodes[i]]
        taken = np.zeros(ne, dtype=np.bool_)
        cols = np.empty(ne, dtype=np.int64)
        for i0 in range(ne):                      # each leaf once, with every row that reaches it
            if taken[i0]:
                continue
            l = leaf[i0]
            k = 0
            for i in range(i0, ne):
                if not taken[i] and leaf[i] == l:
                    taken[i] = True
                    cols[k] = i
                    k += 1
            _leaf_predict_many(l, Z, idx, cols, k, p, xc, a, kv, B, lm, lv)
        i = 0
        for q in range(P):
            x = Z[q]
            mu = m2 = sl = ex = 0.0
            count = 0
            m_one = v_one = 0.0
            while i < ne and idx[i] == q:            # row q's leaves, in routing order
                l = leaf[i]
                w = ws[i]
                m, v = lm[i], lv[i]
                mu += w * m
                m2 += w * (v + m * m)
                if local:
                    sl += w * p.r[l]
                    if c_ext > 0.0:
                        ex += w * _leaf_extrapolation(l, x, p, e1, xq)
                count += 1
                m_one, v_one = m, v
                i += 1
            var = m2 - mu * mu
            if var < 0.0:
                var = 0.0
            if local:
                MU[q, j] = mu
                S[q, j] = math.sqrt(var + sl * sl)
                XT[q, j] = c_ext * ex if c_ext > 0.0 else 0.0
            else:
                if count == 1:                      # one leaf: its prediction as is (LoGGP.predict_many)
                    mu, var = m_one, v_one
                MU[q, j] = mu
                S[q, j] = math.sqrt(var if var > 0.0 else 0.0)
                XT[q, j] = 0.0


def warm_up_loggp():
    """A one-joint LoG-GP of four points: the argument types of the compiled GP calls, for
    their warm-up (:mod:`sea_daemon.core.bounds.bound_core`, :mod:`sea_daemon.core.estimators.gp_hook`)."""
    gpm = LoGGP(3)
    rng = np.random.default_rng(0)
    for _ in range(4):
        gpm.update(rng.standard_normal(3), 0.1)
    return gpm
