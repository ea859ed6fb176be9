"""The compiled numerics of one AKF / GP-AKF step (Alg. 1, Alg. 2), called by :class:`AKF`.

:func:`nominal_affine` — F_nom and f_nom of the plain nominal model (no declared effects)
from its constant blocks, and :func:`residual_affine`, its training target, are the
dynamics kernels :func:`sea_daemon.core.dynamics.nominal_affine` and
:func:`~sea_daemon.core.dynamics.residual_affine` (imported here for the filter's step);
:func:`filter_step` — everything after the nominal Jacobian: the
GP terms, the local-linearisation discretisation (one matrix exponential), the covariance
prediction, the Cholesky-based gain, NIS, the Joseph update, the symmetrisation and the
finiteness check.  Models with declared effects compute F_nom / f_nom with
:class:`~sea_daemon.core.model_core.ModelTables` (the same kernels) and share :func:`filter_step`.

All arrays are the AKF's own preallocated per-step attributes, written in place.  Errors are
returned as a status code (the caller raises the project's exceptions with their messages):
:data:`OK`, :data:`PRIOR_NONFINITE`, :data:`S_NOT_PD`, :data:`POSTERIOR_NONFINITE`.
Pure numerics: no I/O, no clock, no threads.
"""
from __future__ import annotations

import math

import numpy as np

from sea_daemon.core.dynamics import nominal_affine, residual_affine
from sea_daemon.core.jit import njit, warmer
from sea_daemon.core.linalg import cho_solve, cholesky, matmul, matmul_t, zoh

OK, PRIOR_NONFINITE, S_NOT_PD, POSTERIOR_NONFINITE = 0, 1, 2, 3

#: the dynamics kernels of the filter's step without declared effects (core.dynamics)
__all__ = ["nominal_affine", "residual_affine", "buffer_size", "views", "filter_step", "fill_estimate",
           "input_noise", "cap_covariance", "STEP_FIELDS", "OK", "PRIOR_NONFINITE", "S_NOT_PD",
           "POSTERIOR_NONFINITE"]


#: the arrays of one filter step, in the order :func:`views` lays them out in one flat float64
#: buffer (shapes with d = 5n, m = 4n, r = 3n, a = d + 1 + n): inputs A (d, d), xdot (d), μ (n),
#: ∂μ/∂z (n, r), ∂z/∂x (r, d), σ² (n), G_μ = I_μ M⁻¹ (d, n), Σ_nom (d, d), R (m, m), y (m); state
#: and outputs x (d), P (d, d), F (d, d), Γ_μ (d, n), Q (d, d), x̂⁻ (d), P⁻ (d, d), S (m, m),
#: K (d, m), ν (m); work aug and E (a, a), Bx (d, 1 + n), L (m, m), rhs (m, d + 1), IKH (d, d),
#: work (d, d), KR (d, m)
STEP_FIELDS = ("A", "xdot", "mu", "dmu_dz", "dz_dx", "sigma2", "G_mu", "Sigma_nom", "R", "y",
               "x", "P", "F", "Gamma_mu", "Q", "x_prior", "P_prior", "S", "K", "innovation",
               "aug", "E", "Bx", "L", "rhs", "IKH", "work", "KR")


@njit
def buffer_size(d: int, m: int, n: int) -> int:
    """Length of the flat buffer :func:`views` lays out."""
    r, a = 3 * n, d + 1 + n
    # 8 d×d, 3 d, 2 n, n×r, r×d, 2 d×n, 3 m×m, 2 m, 2 d×m, 2 a×a, d×(1+n), m×(d+1)
    return (8 * d * d + 3 * d + 2 * n + n * r + r * d + 2 * d * n + 3 * m * m + 2 * m + 2 * d * m
            + 2 * a * a + d * (1 + n) + m * (d + 1))


@njit
def views(buf, d: int, m: int, n: int):
    """The arrays of :data:`STEP_FIELDS` as views of ``buf`` (the AKF keeps them as its attributes)."""
    r, a = 3 * n, d + 1 + n
    o = 0
    A = buf[o:o + d * d].reshape((d, d)); o += d * d                 # noqa: E702
    xdot = buf[o:o + d]; o += d                                      # noqa: E702
    mu = buf[o:o + n]; o += n                                        # noqa: E702
    dmu_dz = buf[o:o + n * r].reshape((n, r)); o += n * r            # noqa: E702
    dz_dx = buf[o:o + r * d].reshape((r, d)); o += r * d             # noqa: E702
    sigma2 = buf[o:o + n]; o += n                                    # noqa: E702
    G_mu = buf[o:o + d * n].reshape((d, n)); o += d * n              # noqa: E702
    Sigma_nom = buf[o:o + d * d].reshape((d, d)); o += d * d         # noqa: E702
    R = buf[o:o + m * m].reshape((m, m)); o += m * m                 # noqa: E702
    y = buf[o:o + m]; o += m                                         # noqa: E702
    x = buf[o:o + d]; o += d                                         # noqa: E702
    P = buf[o:o + d * d].reshape((d, d)); o += d * d                 # noqa: E702
    F = buf[o:o + d * d].reshape((d, d)); o += d * d                 # noqa: E702
    Gam = buf[o:o + d * n].reshape((d, n)); o += d * n               # noqa: E702
    Q = buf[o:o + d * d].reshape((d, d)); o += d * d                 # noqa: E702
    x_prior = buf[o:o + d]; o += d                                   # noqa: E702
    P_prior = buf[o:o + d * d].reshape((d, d)); o += d * d           # noqa: E702
    S = buf[o:o + m * m].reshape((m, m)); o += m * m                 # noqa: E702
    K = buf[o:o + d * m].reshape((d, m)); o += d * m                 # noqa: E702
    innovation = buf[o:o + m]; o += m                                # noqa: E702
    aug = buf[o:o + a * a].reshape((a, a)); o += a * a               # noqa: E702
    E = buf[o:o + a * a].reshape((a, a)); o += a * a                 # noqa: E702
    Bx = buf[o:o + d * (1 + n)].reshape((d, 1 + n)); o += d * (1 + n)  # noqa: E702
    L = buf[o:o + m * m].reshape((m, m)); o += m * m                 # noqa: E702
    rhs = buf[o:o + m * (d + 1)].reshape((m, d + 1)); o += m * (d + 1)  # noqa: E702
    IKH = buf[o:o + d * d].reshape((d, d)); o += d * d               # noqa: E702
    work = buf[o:o + d * d].reshape((d, d)); o += d * d              # noqa: E702
    KR = buf[o:o + d * m].reshape((d, m))
    return (A, xdot, mu, dmu_dz, dz_dx, sigma2, G_mu, Sigma_nom, R, y, x, P, F, Gam, Q, x_prior, P_prior, S, K,
            innovation, aug, E, Bx, L, rhs, IKH, work, KR)


@njit
def filter_step(buf, d: int, m: int, n: int, use_gp: bool, dt: float):
    """One predict + update of the AKF in place on the arrays of ``buf`` (:data:`STEP_FIELDS`);
    returns ``(status, nis)``.

    In: A = F_nom, xdot = f_nom at (x̂_{k−1}, u_{k−1}) (overwritten with the GP-corrected
    values when ``use_gp``); μ, ∂μ/∂z, σ² of the GP at ẑ_{k−1}; ∂z/∂x; G_μ = I_μ M⁻¹;
    Σ_nom (this step's); R; dt; y.  Out: x, P (posterior), F, Γ_μ, Q, x̂⁻, P⁻, S, K, ν.
    """
    (A, xdot, mu, dmu_dz, dz_dx, sigma2, G_mu, Sigma_nom, R, y, x, P, F, Gam, Q, x_prior, P_prior, S, K,
     innovation, aug, E, Bx, L, rhs, IKH, work, KR) = views(buf, d, m, n)
    if use_gp:
        r = dz_dx.shape[0]
        for i in range(d):
            for j in range(n):
                g = G_mu[i, j]
                if g != 0.0:
                    # eq:fwdynwtorqueresidual1: f = f_nom − I_μ M⁻¹ μ
                    xdot[i] -= g * mu[j]
                    # eq:linearization: F = F_nom − I_μ M⁻¹ F_GP, F_GP = ∂μ/∂z · ∂z/∂x
                    for k in range(d):
                        s = 0.0
                        for l in range(r):
                            s += dmu_dz[j, l] * dz_dx[l, k]
                        A[i, k] -= g * s
    # time discretisation (Sec. IV-B): local linearisation over dt with u and w held,
    # E = e^{[[A, f, G_μ], [0, 0, 0]] dt}: F_d = E[:d, :d], Δx = E[:d, d], Γ_μ = E[:d, d+1:]
    for i in range(d):
        Bx[i, 0] = xdot[i]
        for j in range(n):
            Bx[i, 1 + j] = G_mu[i, j]
    zoh(A, Bx, dt, aug, E)
    for i in range(d):
        # Alg. 2 line 7: x̂⁻ = x̂ + Δx
        x_prior[i] = x[i] + E[i, d]
        for j in range(d):
            F[i, j] = E[i, j]
        for j in range(n):
            Gam[i, j] = E[i, d + 1 + j]
    # Alg. 2 line 9 (eq:gpakf_covariance, eq:GPvarfwd): Q = Σ_nom + Γ_μ diag(σ²) Γ_μᵀ
    Q[:, :] = Sigma_nom
    if use_gp:
        for i in range(d):
            for j in range(d):
                s = 0.0
                for k in range(n):
                    s += Gam[i, k] * sigma2[k] * Gam[j, k]
                Q[i, j] += s
    # Alg. 2 line 10: P⁻ = F P Fᵀ + Q
    matmul(F, P, work)
    matmul_t(work, F, P_prior)
    P_prior += Q
    # Alg. 1 line 6: S = H P⁻ Hᵀ + R (H = [I 0]); Alg. 1 line 7: ν = y − H x̂⁻
    fin = 0.0
    for i in range(m):
        for j in range(m):
            S[i, j] = P_prior[i, j] + R[i, j]
            fin += S[i, j]
        innovation[i] = y[i] - x_prior[i]
        fin += innovation[i]
    if not math.isfinite(fin):          # one reduction: any NaN/inf makes it non-finite
        return PRIOR_NONFINITE, 0.0
    if cholesky(S, L) != 0:
        return S_NOT_PD, 0.0
    # one solve for both K = P⁻Hᵀ S⁻¹ = (S⁻¹ H P⁻)ᵀ and S⁻¹ν
    for i in range(m):
        for j in range(d):
            rhs[i, j] = P_prior[i, j]
        rhs[i, d] = innovation[i]
    cho_solve(L, rhs)
    # NIS νᵀ S⁻¹ ν (χ²_{4n} when the filter is consistent)
    nis = 0.0
    for i in range(m):
        nis += innovation[i] * rhs[i, d]
    for i in range(d):
        s = 0.0
        for j in range(m):
            K[i, j] = rhs[j, i]
            s += K[i, j] * innovation[j]
        x[i] = x_prior[i] + s
    # Alg. 1 line 8 in Joseph form: P = (I − KH) P⁻ (I − KH)ᵀ + K R Kᵀ (Bucy & Joseph 1968)
    for i in range(d):
        for j in range(d):
            IKH[i, j] = 1.0 if i == j else 0.0
        for j in range(m):
            IKH[i, j] -= K[i, j]
    matmul(IKH, P_prior, work)
    matmul_t(work, IKH, P)
    matmul(K, R, KR)
    fin = 0.0
    for i in range(d):
        for j in range(d):
            s = 0.0
            for k in range(m):
                s += KR[i, k] * K[j, k]
            P[i, j] += s
    # symmetrise; one reduction: a NaN or ±inf anywhere makes the sum non-finite
    for i in range(d):
        fin += x[i] + P[i, i]
        for j in range(i):
            v = 0.5 * (P[i, j] + P[j, i])
            P[i, j] = v
            P[j, i] = v
            fin += v
    if not math.isfinite(fin):
        return POSTERIOR_NONFINITE, nis
    return OK, nis


@njit
def fill_estimate(x, P, sqrt_s, x_hat, P_hat, tau_hat, tau_sigma, tau_bound):
    """The published estimate: x̂, P, τ̂_h,act = x̂[4n:], σ = sqrt(P_ττ) and the bound
    ρ = sqrt(s P_ττ) (eq:gaussianellipsoid projected on each τ_h,act component)."""
    d = x.shape[0]
    n = tau_hat.shape[0]
    for i in range(d):
        x_hat[i] = x[i]
        for j in range(d):
            P_hat[i, j] = P[i, j]
    for i in range(n):
        k = 4 * n + i
        tau_hat[i] = x[k]
        sd = math.sqrt(max(P[k, k], 0.0))
        tau_sigma[i] = sd
        tau_bound[i] = sd * sqrt_s


@njit
def input_noise(A, B, dt, var_u, S_base, Gam_u, S):
    """Γ_u = ∫₀^dt e^{As} ds B (:func:`~sea_daemon.core.linalg.zoh`) into ``Gam_u`` and
    S = S_base + Γ_u σ_u² Γ_uᵀ: a motor-torque error of variance σ_u² held over the step
    (AKF.fill_sigma_nom)."""
    d = A.shape[0]
    r = B.shape[1]
    aug = np.empty((d + r, d + r))
    E = np.empty((d + r, d + r))
    zoh(A, B, dt, aug, E)
    for i in range(d):
        for j in range(r):
            Gam_u[i, j] = E[i, d + j]
    for i in range(d):
        for j in range(d):
            s = 0.0
            for k in range(r):
                s += Gam_u[i, k] * Gam_u[j, k]
            S[i, j] = S_base[i, j] + var_u * s


@njit
def cap_covariance(P, P_max) -> int:
    """Bounded P: where a variance exceeds its cap, scale its row and column so that it equals
    the cap, P ← D P D with D = diag(min(1, √(P_max,i / P_ii))) (symmetric, positive
    semi-definite and with its correlations kept).  Returns how many variances were capped
    (0 in normal operation: the caps are physical limits of the state)."""
    d = P.shape[0]
    n_cap = 0
    D = np.ones(d)
    for i in range(d):
        if P[i, i] > P_max[i]:
            D[i] = math.sqrt(P_max[i] / P[i, i])
            n_cap += 1
    if n_cap:
        for i in range(d):
            for j in range(d):
                P[i, j] *= D[i] * D[j]
    return n_cap


@warmer
def _warm() -> None:
    """Compile with the types the AKF passes (1 joint; shapes do not change the types)."""
    n, d, m = 1, 5, 4
    x = np.zeros(d)
    buf = np.zeros(buffer_size(d, m, n))
    views(buf, d, m, n)
    filter_step(buf, d, m, n, True, 0.01)
    v = np.zeros(n)
    fill_estimate(x, np.eye(d), 1.0, np.zeros(d), np.zeros((d, d)), v, v.copy(), v.copy())
    input_noise(np.eye(d), np.ones((d, n)), 0.01, 1e-4, np.eye(d), np.zeros((d, n)), np.zeros((d, d)))
    cap_covariance(np.eye(d), np.ones(d))
