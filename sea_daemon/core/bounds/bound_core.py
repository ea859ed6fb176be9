"""The Theorem-1 bound's step compiled in one call (:class:`~sea_daemon.core.bounds.akf_bound.AKFTheoremBound`).

:meth:`AKFTheoremBound.step` is a few dozen small numpy operations per step (≈ 0.7 ms at
100 Hz and 1 kHz alike on the 2-core test machine, several times the filter step).  For the
configuration the daemon runs — nominal model without declared effects (the gravity term
bounded analytically), zonotope set of means, the ``scalar`` projection, a plain AKF or a
GP-AKF whose LoG-GPs are frozen (learning off) — this module does the same step in one
compiled call, :func:`bound_step`, with the same formulas in the same order:

1. the gravity term's linearisation-error box b (half-widths of C_{k−1} along e_θm + e_θs,
   :func:`~sea_daemon.core.bounds.akf_bound._gravity_remainder`);
2. the GP part: the projection of C_{k−1} on (q, q̇) (zonotope_shape of the mapped generators
   ⊕ E(0, s_z T P Tᵀ)), its deterministic points (ellipsoid_points), at each point the merged
   LoG-GP prediction (routing, leaf means with ``clip_mean``, variance, local scale and
   extrapolation term, as :class:`~sea_daemon.core.bounds.gp_bound.LocalScale` or
   :meth:`~sea_daemon.core.gp.loggp.LoGGP.predict_many`), the GP mean's linearisation error
   against the filter's own μ(ẑ), ∂μ/∂z, and η = max over the points of the sum;
3. X⁻ = F X̂ Fᵀ ⊕ Γ box(η) ⊕ Φ box(b) (predict_generators, order reduction) and, with a GP, the
   range form (F + Γ_μ J T) X̂ ⊕ Γ box(η_B) ⊕ Φ box(b) (AKFTheoremBound._gp_range_candidate);
   the one with the narrower τ_h,act half-width after (I − KH) is kept; X̂ = (I − KH) X⁻,
   ρ_k (shifted_gaussian_halfwidth).

The frozen LoG-GPs are flattened once (:class:`GPPack`: the trees and every leaf's factor,
data and hyperparameters in a few arrays); a pack is rebuilt when the GP changed
(``GPPack.stale``).  Everything else (ellipsoid sets, other projections, declared effects, a
GP that is learning) stays on the Python path of :mod:`.akf_bound`, which is the reference:
``tests/test_akf_bound.py`` checks that both give the same ρ_k (to rounding).
"""
from __future__ import annotations

import math

import numpy as np

from sea_daemon.core.jit import njit, warmer
from sea_daemon.core.model_core import lin_error_boxes
from sea_daemon.core.gp import gp_core
from sea_daemon.core.gp.routing import route
from sea_daemon.core.bounds.setmember import _ellipsoid_points, _shifted_halfwidth
from sea_daemon.core.bounds.zonotope import _zonotope_shape, predict_generators


class GPPack:
    """The LoG-GPs of a residual (one per joint) as flat arrays for :func:`bound_step`.

    Per joint j: its tree (``links[j]`` dim/left/right, ``span[j]`` lo/hi, padded with leaves)
    and, per node, the index of its leaf in the leaf arrays (``leaf_of[j, node]``, −1 for a
    split node).  Per leaf: rows ``row[l] .. row[l] + nn[l]`` of ``A`` (kernel features), ``X``
    (inputs), ``beta``, ``alpha``; the packed Cholesky factor at ``apo[l]``; centre, inverse
    squared length scales, σ_f², the input box (``clip_mean``) and the local residual scale r.
    """

    def __init__(self, gps, local_r: list[dict] | None = None):
        self.gps = list(gps)
        self.signature = self._signature()
        n = len(self.gps)
        d = self.gps[0].input_dim
        nodes = max(len(g._dim) for g in self.gps)
        self.links = np.full((n, 3, nodes), -1, dtype=np.int64)
        self.span = np.zeros((n, 2, nodes))
        self.leaf_of = np.full((n, nodes), -1, dtype=np.int64)
        leaves = []
        for j, g in enumerate(self.gps):
            m = len(g._dim)
            self.links[j, 0, :m] = g._dim
            self.links[j, 1, :m] = g._left
            self.links[j, 2, :m] = g._right
            self.span[j, 0, :m] = g._lo
            self.span[j, 1, :m] = g._hi
            for node in g.leaves():
                self.leaf_of[j, node] = len(leaves)
                r = 0.0 if local_r is None else float(local_r[j].get(node, 0.0))
                leaves.append((g.leaf(node), r))
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
            self.sf2[i] = lf._sf2
            self.il2[i] = lf._il2
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
        self.c_ext = float(getattr(self.gps[0], "extrapolation_scale", 0.0))

    def _signature(self) -> tuple:
        """What changes when a LoG-GP learns: its node count and every leaf's point count."""
        return tuple((len(g._dim), tuple(g.leaf(k).n_ for k in g.leaves())) for g in self.gps)

    def stale(self) -> bool:
        """The GPs changed since the pack was made (learning, a split, a load)."""
        return self._signature() != self.signature

    def args(self) -> tuple:
        return (self.links, self.span, self.leaf_of, self.nn, self.row, self.apo, self.A, self.X, self.beta,
                self.alpha, self.ap, self.center, self.il2, self.sf2, self.lo, self.hi, self.clip, self.r)


def empty_args() -> tuple:
    """A pack's argument types without a GP (the plain AKF's call of :func:`bound_step`)."""
    i1, i2, i3 = np.zeros(1, np.int64), np.full((1, 1), -1, np.int64), np.full((1, 3, 1), -1, np.int64)
    f1, f2 = np.zeros(1), np.zeros((1, 1))
    return (i3, np.zeros((1, 2, 1)), i2, i1, i1, i1, f2, f2, f1, f1, f1, f2, f2, f1, f2, f2,
            np.zeros(1, np.bool_), f1)


@njit
def _leaf_predict(l, x, nn, row, apo, A, X, beta, alpha, ap, center, il2, sf2, lo, hi, clip, xc, a, kv):
    """(μ, σ²) of leaf l at x (IncrementalGP.predict_many's row, with clip_mean): σ² = k(x,x) −
    ‖L⁻¹k‖² (eq:GPvariance, one O(N²) solve), μ = kᵀα (eq:GPmean with α = L⁻ᵀβ, O(N); at the
    clipped input with clip_mean outside the leaf's box)."""
    m = nn[l]
    if m == 0:
        return 0.0, sf2[l]
    r0, p0 = row[l], apo[l]
    Al = A[r0:r0 + m]
    al = alpha[r0:r0 + m]
    gp_core.query(x, center[l], il2[l], a)
    gp_core.kernel_vector(Al, m, a, kv)
    mu = 0.0
    for i in range(m):
        mu += kv[i] * al[i]
    gp_core.solve_lower(ap[p0:p0 + m * (m + 1) // 2], m, kv)
    vv = 0.0
    for i in range(m):
        vv += kv[i] * kv[i]
    var = sf2[l] - vv
    if var < 0.0:
        var = 0.0
    if clip[l] and gp_core.clip_into(x, lo[l], hi[l], xc):
        gp_core.query(xc, center[l], il2[l], a)
        gp_core.kernel_vector(Al, m, a, kv)
        mu = 0.0
        for i in range(m):
            mu += kv[i] * al[i]
    return mu, var


@njit
def _leaf_extrapolation(l, x, nn, row, X, alpha, il2, sf2, e1, xq):
    """e(x) of leaf l (IncrementalGP.extrapolation_many's row)."""
    m = nn[l]
    if m == 0:
        return 0.0
    r0 = row[l]
    for i in range(x.shape[0]):
        xq[0, i] = x[i]
    gp_core.extrapolation_many(X[r0:r0 + m], m, alpha[r0:r0 + m], il2[l], sf2[l], xq, e1)
    return e1[0]


@njit
def gp_points(Z, local, c_ext, links, span, leaf_of, nn, row, apo, A, X, beta, alpha, ap, center, il2, sf2,
              lo, hi, clip, r, MU, S, XT):
    """Merged LoG-GP prediction per row of ``Z`` and joint j into MU[:, j], S[:, j], XT[:, j]:
    with ``local`` the mean, the scale √(σ̃² + s_loc²) and the extrapolation term c e(z)
    (LocalScale.predict_many_ext), else the mean and σ̃ (LoGGP.predict_many, XT zero).  The
    leaves and weights of each row are the LoG-GP's own routing (:func:`routing.route`)."""
    P, dz = Z.shape
    xc = np.empty(dz)
    xq = np.empty((1, dz))
    e1 = np.empty(1)
    a = np.empty(dz + 2)
    kv = np.empty(max(1, np.max(nn)) if nn.shape[0] else 1)
    for j in range(links.shape[0]):
        idx, nodes, ws, _ = route(Z, links[j], span[j], False)
        i = 0
        for p in range(P):
            x = Z[p]
            mu = m2 = sl = ex = 0.0
            count = 0
            m_one = v_one = 0.0
            while i < idx.shape[0] and idx[i] == p:           # row p's leaves, in routing order
                l = leaf_of[j, nodes[i]]
                w = ws[i]
                m, v = _leaf_predict(l, x, nn, row, apo, A, X, beta, alpha, ap, center, il2, sf2, lo, hi, clip, xc,
                                     a, kv)
                mu += w * m
                m2 += w * (v + m * m)
                if local:
                    sl += w * r[l]
                    if c_ext > 0.0:
                        ex += w * _leaf_extrapolation(l, x, nn, row, X, alpha, il2, sf2, e1, xq)
                count += 1
                m_one, v_one = m, v
                i += 1
            var = m2 - mu * mu
            if var < 0.0:
                var = 0.0
            if local:
                MU[p, j] = mu
                S[p, j] = math.sqrt(var + sl * sl)
                XT[p, j] = c_ext * ex if c_ext > 0.0 else 0.0
            else:
                if count == 1:                      # one leaf: its prediction as is (LoGGP.predict_many)
                    mu, var = m_one, v_one
                MU[p, j] = mu
                S[p, j] = math.sqrt(var if var > 0.0 else 0.0)
                XT[p, j] = 0.0


@njit
def _abs_row_sum(M, i):
    """Σ_c |M[i, c]|: the half-width of a zonotope with generators M along coordinate i (or
    along the row i of a map applied to them)."""
    s = 0.0
    for c in range(M.shape[1]):
        s += abs(M[i, c])
    return s


@njit
def bound_step(G, x0, P0, zhat, mu0, J0, F, K, H, Gam_mu, M, Minv, P, g, s_z, margin, T, E_q, grid, grid_step,
               Uz, has_gp, local, c_ext, sqrt_beta, gamma, box_lo, box_hi, has_box, Gam_tau, rate, has_rate,
               max_gen, delta_tau, z_tau, gp, rho, eta_out, lin_out, b_out):
    """One step of the set of means (module docstring); returns (new generators, GP box left,
    whether the range form was taken).

    ``J0``: the filter's ∂μ/∂z at ẑ (n, 3n), of which the (q, q̇) columns are used.
    ``gp``: the tuple of :meth:`GPPack.args`.  Writes ρ_k into ``rho``, the GP error alone
    and the GP mean's linearisation error (per joint) into ``eta_out`` / ``lin_out``, the
    linearisation-error box into ``b_out``."""
    d = x0.shape[0]
    n = rho.shape[0]
    # 1. gravity: r_j = half-width of C_{k−1} along e_θm,j + e_θs,j (SetMembershipBound.half_widths)
    b = b_out
    b[:] = 0.0
    any_g = False
    for j in range(n):
        if g[j] != 0.0:
            any_g = True
    if any_g:
        EG = E_q @ G
        EP = E_q @ P0
        r = np.empty(n)
        qh = np.empty(n)
        for j in range(n):
            hx = _abs_row_sum(EG, j)
            q = 0.0
            for c in range(d):
                q += EP[j, c] * E_q[j, c]
            r[j] = hx + math.sqrt(max(s_z * q, 0.0))
            qh[j] = x0[j] + x0[n + j]
        v = np.empty(n)
        gravity_remainder(qh, r, g, grid, grid_step, v)
        bb = np.abs(Minv) @ v
        for j in range(n):
            b[3 * n + j] = bb[j]
    out = False
    ng = 0
    eta = np.zeros(0)
    eta_b = np.zeros(0)
    JT = np.zeros((0, d))
    if has_gp:
        # 2. the projection of C_{k−1} on (q, q̇) and its points (SetMembershipBound.confidence_set)
        c = T @ x0
        sP = s_z * (T @ P0 @ T.T)
        Xc = _zonotope_shape(np.ascontiguousarray(T @ G), sP, True)
        Xc = 0.5 * (Xc + Xc.T)
        pts = _ellipsoid_points(c, Xc, Uz)
        npt = pts.shape[0]
        dz = zhat.shape[0]
        Z = np.empty((npt, dz))
        for p in range(npt):
            for i in range(2 * n):
                Z[p, i] = pts[p, i]
            for i in range(2 * n, dz):
                Z[p, i] = zhat[i]
        MU = np.empty((npt, n))
        S = np.empty((npt, n))
        XT = np.empty((npt, n))
        (links, span, leaf_of, nn, row, apo, A, X, beta, alpha, ap, center, il2, sf2, lo, hi, clip, rr) = gp
        gp_points(Z, local, c_ext, links, span, leaf_of, nn, row, apo, A, X, beta, alpha, ap, center, il2, sf2,
                  lo, hi, clip, rr, MU, S, XT)
        DJ = np.zeros((npt, n))                  # (z − ẑ) ∂μ/∂z over the (q, q̇) columns of J0 (n, 3n)
        for p in range(npt):
            for j in range(n):
                acc = 0.0
                for i in range(2 * n):
                    acc += (pts[p, i] - zhat[i]) * J0[j, i]
                DJ[p, j] = acc
        eta = np.empty(n)
        eta_b = np.empty(n)
        # the range form (AKFTheoremBound._gp_range_candidate): J T (n, d) and √(s_z J T P Tᵀ Jᵀ)
        JT = np.ascontiguousarray(J0[:, :2 * n]) @ T
        JTP = JT @ P0
        for j in range(n):
            best = -np.inf
            hbest = -np.inf
            lbest = -np.inf
            bbest = -np.inf
            for p in range(npt):
                e = abs(MU[p, j] - mu0[j] - DJ[p, j])
                h = sqrt_beta[j] * S[p, j] + gamma[j] + XT[p, j]
                lm = (1.0 + margin) * e
                t = h + lm
                if t > best:
                    best = t
                if h > hbest:
                    hbest = h
                if lm > lbest:
                    lbest = lm
                tb = h + (1.0 + margin) * abs(MU[p, j] - mu0[j])
                if tb > bbest:
                    bbest = tb
            eta[j] = best
            eta_out[j] = hbest
            lin_out[j] = lbest
            q = 0.0
            for c in range(d):
                q += JTP[j, c] * JT[j, c]
            eta_b[j] = bbest + math.sqrt(max(s_z * q, 0.0))
        if has_box:
            for i in range(dz):
                hw = math.sqrt(max(Xc[i, i], 0.0)) if i < 2 * n else 0.0
                if Z[0, i] - hw < box_lo[i] or Z[0, i] + hw > box_hi[i]:
                    out = True
        ng = n
    # 3. the bounded inputs [Γ_μ η | Γ_τ r] and Φ b (AKFTheoremBound._phi: θ̈_s columns Γ_μ M)
    nt = n if has_rate else 0
    Gam = np.empty((d, ng + nt))
    et = np.empty(ng + nt)
    for i in range(d):
        for j in range(ng):
            Gam[i, j] = Gam_mu[i, j]
        for j in range(nt):
            Gam[i, ng + j] = Gam_tau[i, j]
    for j in range(ng):
        et[j] = eta[j]
    for j in range(nt):
        et[ng + j] = rate
    any_b = False
    for i in range(d):
        if b[i] != 0.0:
            any_b = True
    if any_b:
        Phi = np.zeros((d, d))
        GM = Gam_mu @ M
        for i in range(d):
            for j in range(n):
                Phi[i, 3 * n + j] = GM[i, j]
        bb2 = b.copy()
    else:
        Phi = np.zeros((d, 0))
        bb2 = np.zeros(0)
    Gp = predict_generators(F, G, Gam, et, Phi, bb2, max_gen)
    IKH = -(K @ H)
    for i in range(d):
        IKH[i, i] += 1.0
    took_range = False
    if has_gp:
        # the range form: F + Γ_μ J T with η_B, if its τ half-width after (I − KH) is narrower
        # (AKFTheoremBound._predict_best_of_two; both contain the set of means)
        for j in range(ng):
            et[j] = eta_b[j]
        GpB = predict_generators(F + Gam_mu @ JT, G, Gam, et, Phi, bb2, max_gen)
        hA = 0.0
        hB = 0.0
        for j in range(n):
            hA += _abs_row_sum(IKH[4 * n + j:4 * n + j + 1] @ Gp, 0)
            hB += _abs_row_sum(IKH[4 * n + j:4 * n + j + 1] @ GpB, 0)
        if hB < hA:
            Gp = GpB
            took_range = True
    Gn = IKH @ Gp
    h = np.empty(n)
    sd = np.empty(n)
    for j in range(n):
        h[j] = _abs_row_sum(Gn, 4 * n + j)
        sd[j] = math.sqrt(max(P[4 * n + j, 4 * n + j], 0.0))
    _shifted_halfwidth(h, sd, delta_tau, z_tau, 8, rho)
    return Gn, out, took_range


@njit
def gravity_remainder(qh, r, g, grid, grid_step, v):
    """v_j = g_j max_{|Δ| ≤ r_j} |sin(q̂_j + Δ) − sin q̂_j − cos q̂_j Δ| (AKFTheoremBound._gravity_box)."""
    for j in range(qh.shape[0]):
        s0, c0 = math.sin(qh[j]), math.cos(qh[j])
        hmax = 0.0
        # h(Δ) = sin(q̂+Δ) − sin q̂ − cos q̂·Δ on a grid of |Δ| ≤ r, plus the grid's worst gap:
        # |h'(Δ)| = |cos(q̂+Δ) − cos q̂| ≤ min(2, |Δ|) ≤ min(2, r), spacing δ → + min(2, r)·δ/2
        for D0 in grid:
            D = D0 * r[j]
            hmax = max(hmax, abs(math.sin(qh[j] + D) - s0 - c0 * D))
        # never above the Lagrange bound max|sin|·r²/2 ≤ r²/2
        v[j] = g[j] * min(hmax + min(2.0, r[j]) * r[j] * grid_step / 2.0, r[j] * r[j] / 2.0)


def warm_up_loggp():
    """A one-joint LoG-GP of four points: the argument types of the compiled GP calls, for
    their warm-up (here and in :mod:`sea_daemon.core.estimators.gp_hook`)."""
    from sea_daemon.core.gp.loggp import LoGGP
    gpm = LoGGP(3)
    rng = np.random.default_rng(0)
    for _ in range(4):
        gpm.update(rng.standard_normal(3), 0.1)
    return gpm


@warmer
def _warm() -> None:
    """:func:`bound_step` with the argument types the bound passes (one joint, d = 5)."""
    gpm = warm_up_loggp()
    pack = GPPack([gpm], [{k: 0.01 for k in gpm.leaves()}])
    d = 5
    E_q = np.zeros((1, d))
    E_q[0, 0] = E_q[0, 1] = 1.0
    T = np.zeros((2, d))
    T[0, 0] = T[0, 1] = T[1, 2] = T[1, 3] = 1.0
    # the friction candidate's one-pass boxes (AKFTheoremBound._friction_candidate), one load group
    e, P, I, v = np.zeros(0, dtype=np.int64), np.zeros((0, 3)), np.eye(1), np.zeros(1)
    # the packed Dynamics (core.dynamics): M, M⁻¹, J, J⁻¹, D_m, K_s, D_s, gravity, κ, half band, one load effect
    dyn = (I, I, I, I, I, I, I, v, np.ones(1), np.full(1, -1.0),
           (np.array([1], np.int64), np.zeros(1, np.int64), np.array([[0.1, 0.01, 0.0]])), (e, e, P), (e, e, P))
    lin_error_boxes(np.zeros((2, d)), v, np.zeros(d), np.zeros((d, d)), dyn, np.ones((1, d)), np.ones((1, d)),
                    np.ones(1), np.zeros(1, np.int64), np.array([1], np.int64), np.array([[0.1, 0.01, 0.0]]),
                    np.zeros(d), np.zeros(d))
    for has_gp, local, has_rate in ((True, True, True), (True, False, False), (False, False, False)):
        bound_step(np.zeros((d, 2)), np.zeros(d), np.eye(d), np.zeros(3), np.zeros(1), np.zeros((1, 3)), np.eye(d),
                   np.zeros((d, 4)), np.zeros((4, d)), np.ones((d, 1)), np.eye(1), np.eye(1), np.eye(d), np.ones(1),
                   4.0, 0.25, T, E_q, np.linspace(-1.0, 1.0, 5), 0.5, np.ones((2, 2)) / np.sqrt(2.0), has_gp, local,
                   0.5, np.ones(1), np.zeros(1), -np.ones(3), np.ones(3), True, np.ones((d, 1)), 1.0, has_rate, 40,
                   0.025, 2.0, pack.args() if has_gp else empty_args(), np.empty(1), np.empty(1), np.empty(1),
                   np.empty(d))
