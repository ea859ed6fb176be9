"""The Theorem-1 bound's step compiled in one call (:class:`~sea_daemon.core.bounds.akf_bound.AKFTheoremBound`).

:meth:`AKFTheoremBound.step` is a few dozen small numpy operations per step (≈ 0.7 ms at
100 Hz and 1 kHz alike on a 2-vCPU virtual machine, several times the filter step).  For the
configuration the daemon runs — nominal model without declared effects (the gravity term
bounded analytically), zonotope set of means, the ``scalar`` projection, a plain AKF or a
GP-AKF whose LoG-GPs are frozen (learning off) — this module does the same step in one
compiled call, :func:`bound_step`, with the same formulas in the same order:

1. the gravity term's linearisation-error box b (half-widths of C_{k−1} along e_θm + e_θs,
   :func:`gravity_remainder`; :func:`_gravity_stage`);
2. the GP part: the projection of C_{k−1} on (q, q̇) (zonotope_shape of the mapped generators
   ⊕ E(0, s_z T P Tᵀ)), its deterministic points (ellipsoid_points), at each point the merged
   LoG-GP prediction (routing, leaf means with ``clip_mean``, variance, local scale and
   extrapolation term, as :class:`~sea_daemon.core.bounds.gp_bound.LocalScale` or
   :meth:`~sea_daemon.core.gp.loggp.LoGGP.predict_many`; each leaf's predictions for all the
   points that reach it at once, :func:`~sea_daemon.core.gp.pack.gp_points`), the GP mean's
   linearisation error against the filter's own μ(ẑ), ∂μ/∂z, and η = max over the points of the
   sum (:func:`_gp_stage`);
3. X⁻ = F X̂ Fᵀ ⊕ Γ box(η) ⊕ Φ box(b) (predict_generators, order reduction) and, with a GP, the
   range form (F + Γ_μ J T) X̂ ⊕ Γ box(η_B) ⊕ Φ box(b) (AKFTheoremBound._gp_range_candidate);
   the one with the narrower τ_h,act half-width after (I − KH) is kept; X̂ = (I − KH) X⁻
   (:func:`_prior_stage`), ρ_k (shifted_gaussian_halfwidth).

Its arguments are named structures: the filter's step (:class:`FilterStep`, the fields of the
AKF's :class:`~sea_daemon.core.estimators.record.StepRecord`), the bound's constants
(:class:`SetConstants`), the GP's (:class:`GPTerms`) and the declared human-torque rate's
(:class:`RateTerm`), the frozen LoG-GPs (:class:`~sea_daemon.core.gp.pack.PackArrays`) and the
outputs (:class:`BoundOutputs`).

The frozen LoG-GPs are flattened once (:class:`~sea_daemon.core.gp.pack.GPPack`: the trees and
every leaf's factor, data and hyperparameters in a few arrays); a pack is rebuilt when the GP
changed (``GPPack.stale``).  Everything else (ellipsoid sets, other projections, declared effects, a
GP that is learning) stays on the Python path of :mod:`.akf_bound`, which is the reference:
``tests/test_akf_bound.py`` checks that both give the same ρ_k (to rounding).
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from sea_daemon.core.jit import njit, warmer
from sea_daemon.core.model_core import lin_error_boxes
from sea_daemon.core.gp.pack import GPPack, empty_pack, gp_points, warm_up_loggp
from sea_daemon.core.bounds.setmember import points_of_ellipsoid, shifted_halfwidth_into
from sea_daemon.core.bounds.zonotope import outer_ellipsoid_shape, predict_generators


class FilterStep(NamedTuple):
    """The filter's step k → what the bound reads of it (StepRecord's fields; d = 5n, m = 4n)."""

    x_prev: np.ndarray     # x̂_{k−1} (d,)
    P_prev: np.ndarray     # P_{k−1} (d, d)
    z: np.ndarray          # ẑ_{k−1} (3n,)
    mu: np.ndarray         # μ(ẑ_{k−1}) (n,)
    dmu_dz: np.ndarray     # ∂μ/∂z at ẑ_{k−1} (n, 3n), of which the (q, q̇) columns are used
    F_k: np.ndarray        # discrete transition (d, d)
    K_k: np.ndarray        # Kalman gain (d, m)
    Gamma_mu: np.ndarray   # Γ_μ = ∫₀^dt e^{As} ds I_μ M⁻¹ (d, n)
    P: np.ndarray          # P_k (d, d)


class SetConstants(NamedTuple):
    """The bound's constants: the filter's H, the model's M, M⁻¹, |g|; the Gaussian part's
    quantile s_z of the coordinates the errors depend on and the sampling margin; T (2n, d) the
    map x → (q, q̇), E_q (n, d) the map x → q; the gravity grid on [−1, 1] and its step; the
    directions of the points on the projected set (Uz); δ_N per τ component and its quantile."""

    H: np.ndarray
    M: np.ndarray
    Minv: np.ndarray
    g: np.ndarray
    s_z: float
    margin: float
    T: np.ndarray
    E_q: np.ndarray
    grid: np.ndarray
    grid_step: float
    Uz: np.ndarray
    delta_tau: float
    z_tau: float
    box_given: bool = False    # the linearisation-error box is the caller's (a rigid body's, rigid_box)


class GPTerms(NamedTuple):
    """The GP error's constants (eq:gpmeanbounds): with a GP, the local scale (or σ), the
    extrapolation scale c, √β_j and γ_j per nested box and joint (levels, n), the nested input
    boxes (levels, dz) (``has_box``; calibration.BoxLevels: each step takes the smallest box
    holding its GP input set, level 0 without a box)."""

    has_gp: bool
    local: bool
    c_ext: float
    sqrt_beta: np.ndarray
    gamma: np.ndarray
    box_lo: np.ndarray
    box_hi: np.ndarray
    has_box: bool


class RateTerm(NamedTuple):
    """The bounded inputs besides the GP: the declared human-torque rate r (docs/bounds.md §6),
    Γ_τ (d, n) of the step and r; with a plain AKF's declared model error e (§7) the columns
    [Γ_μ e | Γ_τ r] already scaled and ``rate`` 1."""

    Gam_tau: np.ndarray
    rate: float
    has_rate: bool


class BoundOutputs(NamedTuple):
    """What the step writes: ρ_k (n,), the GP error alone (n,), the GP mean's linearisation
    error (n,), the linearisation-error box b (d,)."""

    rho: np.ndarray
    eta: np.ndarray
    gp_lin_err: np.ndarray
    lin_err_box: np.ndarray


@njit
def _abs_row_sum(M, i):
    """Σ_c |M[i, c]|: the half-width of a zonotope with generators M along coordinate i (or
    along the row i of a map applied to them)."""
    s = 0.0
    for c in range(M.shape[1]):
        s += abs(M[i, c])
    return s


@njit
def _gravity_stage(G, st, c, b):
    """1. eq:linerrsetdx for the gravity term into ``b`` (its θ̈_s rows): r_j = half-width of
    C_{k−1} along e_θm,j + e_θs,j (SetMembershipBound.half_widths), then the remainder."""
    x0, P0, g, E_q = st.x_prev, st.P_prev, c.g, c.E_q
    d = x0.shape[0]
    n = g.shape[0]
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
            for cc in range(d):
                q += EP[j, cc] * E_q[j, cc]
            r[j] = hx + math.sqrt(max(c.s_z * q, 0.0))
            qh[j] = x0[j] + x0[n + j]
        v = np.empty(n)
        gravity_remainder(qh, r, g, c.grid, c.grid_step, v)
        bb = np.abs(c.Minv) @ v
        for j in range(n):
            b[3 * n + j] = bb[j]


@njit
def _gp_stage(G, st, c, gpt, pack, out):
    """2. The GP part: the projection of C_{k−1} on (q, q̇) and its points
    (SetMembershipBound.confidence_set), the merged LoG-GP there, η (GP error + the GP mean's
    linearisation error, max over the points of the sum), η_B of the range form, J T; and
    whether the projected set leaves the GP constants' input box."""
    x0, P0, zhat, mu0, J0, T = st.x_prev, st.P_prev, st.z, st.mu, st.dmu_dz, c.T
    d = x0.shape[0]
    n = mu0.shape[0]
    s_z, margin = c.s_z, c.margin
    cz = T @ x0
    sP = s_z * (T @ P0 @ T.T)
    Xc = outer_ellipsoid_shape(np.ascontiguousarray(T @ G), sP, True)
    Xc = 0.5 * (Xc + Xc.T)
    pts = points_of_ellipsoid(cz, Xc, c.Uz)
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
    gp_points(Z, gpt.local, gpt.c_ext, pack, MU, S, XT)
    lev, leaves_box = _box_level(Xc, Z[0], n, gpt)
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
            h = gpt.sqrt_beta[lev, j] * S[p, j] + gpt.gamma[lev, j] + XT[p, j]
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
        out.eta[j] = hbest
        out.gp_lin_err[j] = lbest
        q = 0.0
        for cc in range(d):
            q += JTP[j, cc] * JT[j, cc]
        eta_b[j] = bbest + math.sqrt(max(s_z * q, 0.0))
    return eta, eta_b, JT, leaves_box


@njit
def _box_level(Xc, z0, n, gpt):
    """(level, outside): the smallest nested box of ``gpt`` holding the projected set's bounding box
    (half-widths √Xc_ii about z0 in the 2n state-dependent inputs) and the measured q̈; the largest
    and True if none does (calibration.box_level); (0, False) without a box."""
    if not gpt.has_box:
        return 0, False
    dz = z0.shape[0]
    levels = gpt.box_lo.shape[0]
    for k in range(levels):
        inside = True
        for i in range(dz):
            hw = math.sqrt(max(Xc[i, i], 0.0)) if i < 2 * n else 0.0
            if z0[i] - hw < gpt.box_lo[k, i] or z0[i] + hw > gpt.box_hi[k, i]:
                inside = False
                break
        if inside:
            return k, False
    return levels - 1, True


@njit
def _prior_stage(G, max_gen, st, c, rt, has_gp, eta, eta_b, JT, b):
    """3. eq:predwLinErrsetandGPerrset: the bounded inputs [Γ_μ η | Γ_τ r] and Φ b
    (AKFTheoremBound._phi: θ̈_s columns Γ_μ M), X⁻ (and with a GP the range form, if its τ
    half-width after (I − KH) is narrower), then the filter step on the set X̂ = (I − KH) X⁻.
    Returns (generators of X̂, whether the range form was taken)."""
    F, K, H, Gam_mu = st.F_k, st.K_k, c.H, st.Gamma_mu
    d = F.shape[0]
    n = Gam_mu.shape[1]
    ng = n if has_gp else 0
    nt = rt.Gam_tau.shape[1] if rt.has_rate else 0
    Gam = np.empty((d, ng + nt))
    et = np.empty(ng + nt)
    for i in range(d):
        for j in range(ng):
            Gam[i, j] = Gam_mu[i, j]
        for j in range(nt):
            Gam[i, ng + j] = rt.Gam_tau[i, j]
    for j in range(ng):
        et[j] = eta[j]
    for j in range(nt):
        et[ng + j] = rt.rate
    any_b = False
    for i in range(d):
        if b[i] != 0.0:
            any_b = True
    if any_b:
        Phi = np.zeros((d, d))
        GM = Gam_mu @ c.M
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
    return IKH @ Gp, took_range


@njit
def bound_step(G, max_gen, st, c, gpt, rt, pack, out):
    """One step of the set of means (module docstring) from its generators ``G`` (at most
    ``max_gen`` after the step): ``st`` :class:`FilterStep`, ``c`` :class:`SetConstants`, ``gpt``
    :class:`GPTerms`, ``rt`` :class:`RateTerm`, ``pack`` the frozen LoG-GPs
    (:class:`~sea_daemon.core.gp.pack.PackArrays`), ``out`` :class:`BoundOutputs` (ρ_k, the GP
    error alone, the GP mean's linearisation error, the linearisation-error box).  Returns (new
    generators, GP box left, whether the range form was taken)."""
    n = out.rho.shape[0]
    b = out.lin_err_box
    # 1. eq:linerrsetdx / eq:linearerrellipsoid, gravity (analytic), unless the caller gave b
    if not c.box_given:
        _gravity_stage(G, st, c, b)
    out_of_box = False
    eta = np.zeros(0)
    eta_b = np.zeros(0)
    JT = np.zeros((0, b.shape[0]))
    if gpt.has_gp:
        # 2. the GP error and the GP mean's linearisation error at the points of the set
        eta, eta_b, JT, out_of_box = _gp_stage(G, st, c, gpt, pack, out)
    # 3. eq:predwLinErrsetandGPerrset, then the filter step on the set
    Gn, took_range = _prior_stage(G, max_gen, st, c, rt, gpt.has_gp, eta, eta_b, JT, b)
    # ρ_k: the set's τ half-widths h and the Gaussian part's σ (Theorem 1's confidence set)
    h = np.empty(n)
    sd = np.empty(n)
    for j in range(n):
        h[j] = _abs_row_sum(Gn, 4 * n + j)
        sd[j] = math.sqrt(max(st.P[4 * n + j, 4 * n + j], 0.0))
    shifted_halfwidth_into(h, sd, c.delta_tau, c.z_tau, 8, out.rho)
    return Gn, out_of_box, took_range


@njit
def gaussian_part(F, K, H, R, S, tau0, drop_tau, P_prev, out):
    """The Gaussian part of the next step into ``out`` (docs/bounds.md §3, "The Gaussian part"):
    P_g,k = (I − KH)(F P_g,k−1 Fᵀ + Q_g)(I − KH)ᵀ + K R Kᵀ with the filter's F, K, H, R and
    Q_g = Σ_nom,k (``S``), its τ_h,act rows and columns (from ``tau0`` on) zero when ``drop_tau``
    (the declared rate holds the human torque's change)."""
    d = F.shape[0]
    Q = S.copy()
    if drop_tau:
        for i in range(d):
            for j in range(tau0, d):
                Q[i, j] = 0.0
                Q[j, i] = 0.0
    Pp = F @ P_prev @ F.T + Q
    IKH = -(K @ H)
    for i in range(d):
        IKH[i, i] += 1.0
    Pn = IKH @ Pp @ IKH.T + K @ R @ K.T
    for i in range(d):
        for j in range(d):
            out[i, j] = 0.5 * (Pn[i, j] + Pn[j, i])


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


@njit
def generators_check(G, caps) -> int:
    """The compiled step's new generators (AKFTheoremBound's check after :func:`bound_step`): 1 when one is not finite, 2 when a half-width of the
    set of means (Σ_j |G_ij|) may exceed its cap (within 1e-12 relative: the exact test is
    SetMembershipBound.saturate's), else 0."""
    over = False
    for i in range(G.shape[0]):
        s = 0.0
        for j in range(G.shape[1]):
            v = G[i, j]
            if not math.isfinite(v):
                return 1
            s += abs(v)
        if s > caps[i] * (1.0 - 1e-12):
            over = True
    return 2 if over else 0


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
    # the friction candidate's one-pass boxes (friction_range.FrictionRange.candidate), one load group
    e, P, I, v = np.zeros(0, dtype=np.int64), np.zeros((0, 3)), np.eye(1), np.zeros(1)
    # the packed Dynamics (core.dynamics): M, M⁻¹, J, J⁻¹, D_m, K_s, D_s, gravity, κ, half band, one load effect
    dyn = (I, I, I, I, I, I, I, v, np.ones(1), np.full(1, -1.0),
           (np.array([1], np.int64), np.zeros(1, np.int64), np.array([[0.1, 0.01, 0.0]])), (e, e, P), (e, e, P))
    lin_error_boxes(np.zeros((2, d)), v, np.zeros(d), np.zeros((d, d)), dyn, np.ones((1, d)), np.ones((1, d)),
                    np.ones(1), np.zeros(1, np.int64), np.array([1], np.int64), np.array([[0.1, 0.01, 0.0]]),
                    np.zeros(d), np.zeros(d))
    st = FilterStep(np.zeros(d), np.eye(d), np.zeros(3), np.zeros(1), np.zeros((1, 3)), np.eye(d),
                    np.zeros((d, 4)), np.ones((d, 1)), np.eye(d))
    c = SetConstants(np.zeros((4, d)), np.eye(1), np.eye(1), np.ones(1), 4.0, 0.25, T, E_q, np.linspace(-1.0, 1.0, 5),
                     0.5, np.ones((2, 2)) / np.sqrt(2.0), 0.025, 2.0)
    out = BoundOutputs(np.empty(1), np.empty(1), np.empty(1), np.empty(d))
    for has_gp, local, has_rate in ((True, True, True), (True, False, False), (False, False, False)):
        gpt = GPTerms(has_gp, local, 0.5, np.ones((2, 1)), np.zeros((2, 1)), -np.ones((2, 3)), np.ones((2, 3)), True)
        rt = RateTerm(np.ones((d, 1)), 1.0, has_rate)
        bound_step(np.zeros((d, 2)), 40, st, c, gpt, rt, pack.arrays() if has_gp else empty_pack(), out)
    # the Python step's calls (AKFTheoremBound._gravity_box, the check after the compiled step)
    gravity_remainder(np.zeros(1), np.ones(1), np.ones(1), np.linspace(-1.0, 1.0, 5), 0.5, np.empty(1))
    gaussian_part(np.eye(d), np.zeros((d, 4)), np.zeros((4, d)), np.eye(4), np.eye(d), 4, True, np.eye(d),
                  np.empty((d, d)))
    generators_check(np.zeros((5, 3)), np.ones(5))
