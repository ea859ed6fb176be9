"""Compiled kernels of the exact local GP (:class:`sea_daemon.core.gp.exact.IncrementalGP`).

Layout (see :mod:`sea_daemon.core.gp.exact`): inputs centred, ``x̄ = x − c``; row i of ``A`` is
``[x̄_i / l², h_i, 1]`` with ``h_i = log σ_f² − ½ Σ_j x̄_ij² / l_j²``; for the augmented query
``a(x) = [x̄, 1, −½ Σ_j x̄_j² / l_j²]`` the kernel vector is ``k_i = exp(A_i · a(x))`` (eq:SE).
The lower Cholesky factor L of ``K + σ_on² I`` is packed row by row (row i starts at
``i(i+1)/2``), so appending a point appends one row.

* :func:`se_r2`, :func:`se_matrix` — eq:SE in its direct form, k(a, b) = σ_f² exp(−½ r²),
  r² = Σ_j (a_j − b_j)² / l_j² (the public :func:`sea_daemon.core.gp.exact.se_kernel`, the
  extrapolation term); :func:`query` / :func:`kernel_vector` are its expanded form above.
* :func:`add_point` — one new factor row, O(N²) (one forward substitution).
* :func:`predict`, :func:`predict_with_grad` — eq:GPmean, eq:GPvariance, eq:moejac with
  eq:kernelderivative, and optionally ∂σ²/∂x.
* :func:`fill_rows`, :func:`kernel_exponent`, :func:`cholesky_packed`, :func:`solve_lower`,
  :func:`solve_upper` — a refactorisation with new hyperparameters, O(N³/6).
* :func:`lml_grad` — log marginal likelihood and its gradient w.r.t. ``log θ`` from the packed
  factor (Rasmussen & Williams 2006, eq. 2.30 and 5.9), with ``K⁻¹`` from the inverse factor.

Plain loops (inner loops over contiguous memory), compiled with the :data:`~sea_daemon.core.jit.FAST`
flags (reassociated, vectorised sums; no NaN/inf assumptions), deterministic.
"""
from __future__ import annotations

import math

import numpy as np

from sea_daemon.core.jit import njit

_LOG2PI = math.log(2.0 * math.pi)


@njit(fast=True)
def se_r2(a, B, i, il2):
    """r² = Σ_j (a_j − B_ij)² / l_j², the scaled squared distance of eq:SE between a and row i of B."""
    r2 = 0.0
    for j in range(a.shape[0]):
        t = a[j] - B[i, j]
        r2 += il2[j] * t * t
    return r2


@njit(fast=True)
def se_matrix(A, B, il2, sf2, K):
    """K_ij = k(a_i, b_j) = σ_f² exp(−½ r²(a_i, b_j)) (eq:SE) for the rows of A and B."""
    for i in range(A.shape[0]):
        a = A[i]
        for j in range(B.shape[0]):
            K[i, j] = sf2 * math.exp(-0.5 * se_r2(a, B, j, il2))


@njit
def clip_into(x, lo, hi, xc) -> bool:
    """xc ← x clipped into the box [lo, hi] (a leaf's training box, clip_mean); whether any
    coordinate changed."""
    out = False
    for i in range(x.shape[0]):
        v = min(max(x[i], lo[i]), hi[i])
        xc[i] = v
        if v != x[i]:
            out = True
    return out


@njit(fast=True)
def query(x, c, il2, a):
    """a = a(x) = [x̄, 1, −½ Σ_j x̄_j² / l_j²] (length ρ + 2)."""
    d = x.shape[0]
    s = 0.0
    for j in range(d):
        xb = x[j] - c[j]
        a[j] = xb
        s += il2[j] * xb * xb
    a[d] = 1.0
    a[d + 1] = -0.5 * s


@njit(fast=True)
def kernel_vector(A, n, a, k):
    """k_i = exp(A_i · a) for i < n (eq:SE)."""
    p = a.shape[0]
    for i in range(n):
        s = 0.0
        for j in range(p):
            s += A[i, j] * a[j]
        k[i] = math.exp(s)


@njit(fast=True)
def solve_lower(ap, n, b):
    """b ← L⁻¹ b (forward substitution, L packed row by row)."""
    for i in range(n):
        off = i * (i + 1) // 2
        s = b[i]
        for k in range(i):
            s -= ap[off + k] * b[k]
        b[i] = s / ap[off + i]


@njit(fast=True)
def solve_upper(ap, n, b):
    """b ← L⁻ᵀ b (back substitution with Lᵀ, column-oriented over L's packed rows)."""
    for i in range(n - 1, -1, -1):
        off = i * (i + 1) // 2
        w = b[i] / ap[off + i]
        b[i] = w
        for k in range(i):
            b[k] -= ap[off + k] * w


@njit(fast=True)
def add_point(x, y, X, A, yv, beta, ap, c, il2, n, sf2, sn2, jitter, log_sf2):
    """Append (x, y) as point n: the new factor row L c = k, d = sqrt(k(x,x) + σ_on² − cᵀc),
    and β_n = (y − cᵀβ)/d so that β = L⁻¹ y stays current (O(N²))."""
    d = x.shape[0]
    a = np.empty(d + 2)
    query(x, c, il2, a)
    off = n * (n + 1) // 2
    d2 = sf2 + sn2 + jitter
    bc = 0.0
    if n > 0:
        row = ap[off:off + n]
        # eq:SE: k_i = exp(A_i a(x)); new factor row: L c = k
        kernel_vector(A, n, a, row)
        solve_lower(ap, n, row)
        for i in range(n):
            d2 -= row[i] * row[i]
            bc += row[i] * beta[i]
    dd = math.sqrt(max(d2, sn2 * 1e-6 + jitter))
    ap[off + n] = dd
    # β_n = (y − cᵀβ) / d  (forward substitution, last row)
    beta[n] = (y - bc) / dd
    for j in range(d):
        X[n, j] = x[j]
        A[n, j] = a[j] * il2[j]
    A[n, d] = log_sf2 + a[d + 1]
    A[n, d + 1] = 1.0
    yv[n] = y


@njit(fast=True)
def predict(A, ap, beta, c, il2, n, sf2, x):
    """(μ, σ²) at x: v = L⁻¹k, μ = vᵀβ (eq:GPmean), σ² = k(x,x) − vᵀv (eq:GPvariance)."""
    d = x.shape[0]
    a = np.empty(d + 2)
    query(x, c, il2, a)
    v = np.empty(n)
    kernel_vector(A, n, a, v)
    solve_lower(ap, n, v)
    mu = 0.0
    vv = 0.0
    for i in range(n):
        mu += v[i] * beta[i]
        vv += v[i] * v[i]
    var = sf2 - vv
    return mu, (var if var > 0.0 else 0.0)


@njit(fast=True)
def predict_many(A, ap, beta, c, il2, n, sf2, Xq, mu, var):
    """:func:`predict` at every row of ``Xq`` (m, ρ) into ``mu``, ``var`` (m,): one compiled
    call for a batch of inputs (the Theorem-1 bound's points of the confidence set)."""
    for i in range(Xq.shape[0]):
        mu[i], var[i] = predict(A, ap, beta, c, il2, n, sf2, Xq[i])


@njit(fast=True)
def extrapolation_many(X, n, alpha, il2, sf2, Xq, out):
    """e(x) = Σ_j |∂μ/∂x_j| |x_j − x*_j| at every row x of ``Xq`` into ``out``: x* the stored
    input nearest x in the length-scale metric, ∂μ/∂x by eq:moejac with eq:kernelderivative
    (∂μ/∂x_j = Σ_i α_i k_i (x_ij − x_j)/l_j², raw inputs ``X``)."""
    d = Xq.shape[1]
    x = np.empty(d)
    g = np.empty(d)
    for r in range(Xq.shape[0]):
        for j in range(d):
            x[j] = Xq[r, j]
            g[j] = 0.0
        best = np.inf
        near = 0
        for i in range(n):
            r2 = se_r2(x, X, i, il2)
            if r2 < best:
                best = r2
                near = i
            # eq:SE k_i and eq:kernelderivative
            w = alpha[i] * sf2 * math.exp(-0.5 * r2)
            for j in range(d):
                g[j] += w * (X[i, j] - x[j]) * il2[j]
        e = 0.0
        for j in range(d):
            e += abs(g[j]) * abs(x[j] - X[near, j])
        out[r] = e


@njit(fast=True)
def update_alpha(ap, beta, n, alpha):
    """α = (K + σ_on² I)⁻¹ y = L⁻ᵀ β (eq:GPmean)."""
    for i in range(n):
        alpha[i] = beta[i]
    solve_upper(ap, n, alpha)


@njit(fast=True)
def predict_with_grad(A, ap, beta, alpha, alpha_ok, c, il2, n, sf2, x, var_grad, dmu, dvar):
    """(μ, σ²) at x; ∂μ/∂x into ``dmu`` and, with ``var_grad``, ∂σ²/∂x into ``dvar``.

    ``alpha``: α = L⁻ᵀβ, recomputed here first unless ``alpha_ok`` (:func:`update_alpha`).
    eq:moejac with eq:kernelderivative: ∂μ/∂x = Σ_i α_i k_i (x_i − x)/l²
    = Σ_i α_i k_i A_i[:ρ] − μ x̄/l² with μ = Σ_i α_i k_i (A's column of ones).
    """
    if not alpha_ok:
        update_alpha(ap, beta, n, alpha)
    d = x.shape[0]
    p = d + 2
    a = np.empty(p)
    query(x, c, il2, a)
    k = np.empty(n)
    kernel_vector(A, n, a, k)
    v = k.copy()
    solve_lower(ap, n, v)
    vv = 0.0
    for i in range(n):
        vv += v[i] * v[i]
    var = sf2 - vv
    if var < 0.0:
        var = 0.0
    g = np.zeros(p)
    for i in range(n):
        w = alpha[i] * k[i]
        for j in range(p):
            g[j] += w * A[i, j]
    mu = g[d + 1]
    for j in range(d):
        dmu[j] = g[j] - mu * il2[j] * a[j]
    if var_grad:
        # ∂σ²/∂x = −2 Σ_i w_i ∂k_i/∂x with w = (K+σ²I)⁻¹k = L⁻ᵀv, and Σ_i w_i k_i = vᵀv
        solve_upper(ap, n, v)
        g[:] = 0.0
        for i in range(n):
            w = v[i] * k[i]
            for j in range(p):
                g[j] += w * A[i, j]
        for j in range(d):
            dvar[j] = -2.0 * (g[j] - vv * il2[j] * a[j])
    return mu, var


@njit(fast=True)
def fill_rows(X, n, c, il2, log_sf2, A):
    """Rows ``A_i = [x̄_i / l², h_i, 1]`` of the first n inputs for the current hyperparameters."""
    d = X.shape[1]
    for i in range(n):
        s = 0.0
        for j in range(d):
            xb = X[i, j] - c[j]
            A[i, j] = xb * il2[j]
            s += xb * A[i, j]
        A[i, d] = log_sf2 - 0.5 * s
        A[i, d + 1] = 1.0


@njit(fast=True)
def kernel_exponent(X, A, n, c, log_sf2, E):
    """E_ij = log k(x_i, x_j) = x̄_iᵀ diag(l⁻²) x̄_j + h_i + h_j − log σ_f² (eq:SE expanded),
    from the rows of :func:`fill_rows`; both triangles.  The caller takes ``np.exp`` of it
    (numpy's vectorised exp is ~4× faster than a compiled scalar loop)."""
    d = X.shape[1]
    XT = np.empty((d, n))
    for i in range(n):
        for l in range(d):
            XT[l, i] = X[i, l] - c[l]
    for i in range(n):
        Ei = E[i]
        hi = A[i, d] - log_sf2
        for j in range(n):
            Ei[j] = hi + A[j, d]
        for l in range(d):
            a = A[i, l]
            xl = XT[l]
            for j in range(n):
                Ei[j] += a * xl[j]


@njit(fast=True)
def cholesky_packed(K, n, diag_add, ap) -> int:
    """Packed lower Cholesky factor of ``K + diag_add·I`` (K's lower triangle is read);
    returns 0 or, like LAPACK dpotrf, the 1-based order of the first non-positive pivot."""
    for i in range(n):
        oi = i * (i + 1) // 2
        for j in range(i + 1):
            oj = j * (j + 1) // 2
            s = K[i, j]
            for k in range(j):
                s -= ap[oi + k] * ap[oj + k]
            if i == j:
                s += diag_add
                if not s > 0.0:
                    return i + 1
                ap[oi + i] = math.sqrt(s)
            else:
                ap[oi + j] = s / ap[oj + j]
    return 0


@njit(fast=True)
def lml_grad(Xb, y, n, il2, sn2, ap, Kf, grad, g):
    """Log marginal likelihood of the first n points (and, with ``grad``, its gradient w.r.t.
    ``log θ = [log σ_f, log l_1 … log l_ρ, log σ_on]`` into ``g``) from the packed factor ``ap``
    of ``K + (σ_on² + jitter) I`` and (for the gradient) the noise-free kernel matrix ``Kf``.
    ``Xb``: centred inputs (any common centre)."""
    d = Xb.shape[1]
    alpha = np.empty(n)
    for i in range(n):
        alpha[i] = y[i]
    solve_lower(ap, n, alpha)
    quad = 0.0
    logdet = 0.0
    for i in range(n):
        quad += alpha[i] * alpha[i]
        logdet += math.log(ap[i * (i + 1) // 2 + i])
    # R&W eq. 2.30: −½ yᵀα − Σ log L_ii − n/2 log 2π
    lml = -0.5 * quad - logdet - 0.5 * n * _LOG2PI
    if not grad:
        return lml
    # α = (K + σ_on² I)⁻¹ y
    solve_upper(ap, n, alpha)
    # L⁻¹ row by row: row i = (e_i − Σ_{k<i} L_ik row k) / L_ii  (axpy form: contiguous,
    # vectorised), then K⁻¹ = L⁻ᵀ L⁻¹ = Σ_k (row k)ᵀ (row k), lower triangle
    Li = np.zeros((n, n))
    for i in range(n):
        oi = i * (i + 1) // 2
        row = Li[i]
        for k in range(i):
            c = ap[oi + k]
            rk = Li[k]
            for t in range(k + 1):
                row[t] -= c * rk[t]
        inv = 1.0 / ap[oi + i]
        for t in range(i):
            row[t] *= inv
        row[i] = inv
    Ki = np.zeros((n, n))
    for k in range(n):
        rk = Li[k]
        for a in range(k + 1):
            c = rk[a]
            Ka = Ki[a]
            for b in range(a + 1):
                Ka[b] += c * rk[b]
    # R&W eq. 5.9 with W = ααᵀ − K⁻¹ (symmetric):
    # ∂lml/∂log σ_f = Σ W∘K_f; ∂/∂log l_j = Σ_ab (W∘K_f)_ab (x_aj − x_bj)²/(2 l_j²);
    # ∂/∂log σ_on = σ_on² (αᵀα − tr K⁻¹)
    for j in range(d + 2):
        g[j] = 0.0
    tr = 0.0
    aa = 0.0
    kf = np.empty(n)            # K_f,ab (eq:SE), b ≤ a
    XT = np.empty((d, n))       # inputs by dimension (contiguous rows)
    for i in range(n):
        for j in range(d):
            XT[j, i] = Xb[i, j]
    for a in range(n):
        aa += alpha[a] * alpha[a]
        kin = Ki[a]                 # K⁻¹_ab, b ≤ a
        tr += kin[a]
        Kfa = Kf[a]
        for b in range(a + 1):
            kf[b] = Kfa[b]
        # (W∘K_f)_ab, each off-diagonal pair counted twice (symmetry)
        for b in range(a + 1):
            kf[b] *= alpha[a] * alpha[b] - kin[b]
        kf[a] *= 0.5
        s0 = 0.0
        for b in range(a + 1):
            s0 += kf[b]
        g[0] += 2.0 * s0            # ∂K/∂log σ_f = 2 K_f, times ½, both triangles
        for j in range(d):
            xa = Xb[a, j]
            xj = XT[j]
            s = 0.0
            for b in range(a + 1):
                dx = xa - xj[b]
                s += kf[b] * dx * dx
            g[1 + j] += s * il2[j]  # ½ Σ_ab (W∘K_f)_ab (x_aj − x_bj)²/l_j², both triangles
    g[d + 1] = sn2 * (aa - tr)
    return lml
