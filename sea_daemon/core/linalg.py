"""Compiled dense linear algebra for the filter's small matrices (5n × 5n, 4n × 4n).

At these sizes a call into numpy/scipy costs more than the arithmetic (scipy's ``expm`` of a
7 × 7 matrix: ~100 µs, of which the Padé core is ~14 µs), so the AKF step is compiled
(:mod:`sea_daemon.core.estimators.akf_core`) on top of these loops:

* :func:`expm` — matrix exponential by scaling and squaring with a diagonal Padé
  approximant, N. J. Higham, "The scaling and squaring method for the matrix exponential
  revisited", SIAM J. Matrix Anal. Appl. 26(4), 2005, Algorithm 2.3 (the algorithm of
  ``scipy.linalg.expm`` before its 2009 refinements; both agree to rounding, tested).
* :func:`cholesky` / :func:`cho_solve` — Cholesky factorisation with an ``info`` code like
  LAPACK ``dpotrf`` (0, or the 1-based order of the first non-positive pivot) and the
  two triangular solves (Golub & Van Loan, Matrix Computations, 4th ed., Alg. 4.2.1).
* :func:`lu_solve` — Gaussian elimination with partial pivoting, in place (G&VL Alg. 3.4.1).
* :func:`zoh` — the zero-order-hold discretisation of ẋ = A x + B u, one :func:`expm` of
  [[A, B], [0, 0]]·dt (Van Loan 1978), for every discretisation of the estimator core (the
  AKF's local linearisation, the held-input maps of the process noise and of the Theorem-1
  bound); :func:`discretize` is its numpy form for offline callers.

Plain loops, no allocation except :func:`expm`'s few work matrices; IEEE arithmetic (no
fastmath), so results are deterministic.
"""
from __future__ import annotations

import math

import numpy as np

from sea_daemon.core.jit import njit, warmer

# Higham (2005) Table 2.3: largest ‖A‖₁ for which the [m/m] Padé approximant is accurate to
# unit roundoff (double precision), m = 3, 5, 7, 9, 13
_THETA = np.array([1.495585217958292e-2, 2.539398330063230e-1, 9.504178996162932e-1,
                   2.097847961257068e0, 5.371920351148152e0])
# Padé coefficients b_0 … b_m of the [m/m] approximant of e^x (Higham 2005, eq. 2.2)
_B3 = np.array([120., 60., 12., 1.])
_B5 = np.array([30240., 15120., 3360., 420., 30., 1.])
_B7 = np.array([17297280., 8648640., 1995840., 277200., 25200., 1512., 56., 1.])
_B9 = np.array([17643225600., 8821612800., 2075673600., 302702400., 30270240., 2162160.,
                110880., 3960., 90., 1.])
_B13 = np.array([64764752532480000., 32382376266240000., 7771770303897600., 1187353796428800.,
                 129060195264000., 10559470521600., 670442572800., 33522128640., 1323241920.,
                 40840800., 960960., 16380., 182., 1.])


@njit
def matmul(A, B, out):
    """out = A B (out must not alias A or B)."""
    p, q = A.shape
    r = B.shape[1]
    for i in range(p):
        for j in range(r):
            s = 0.0
            for k in range(q):
                s += A[i, k] * B[k, j]
            out[i, j] = s


@njit
def matmul_t(A, B, out):
    """out = A Bᵀ (out must not alias A or B)."""
    p, q = A.shape
    r = B.shape[0]
    for i in range(p):
        for j in range(r):
            s = 0.0
            for k in range(q):
                s += A[i, k] * B[j, k]
            out[i, j] = s


@njit
def norm1(A) -> float:
    """‖A‖₁, the largest absolute column sum."""
    p, q = A.shape
    best = 0.0
    for j in range(q):
        s = 0.0
        for i in range(p):
            s += abs(A[i, j])
        if s > best:
            best = s
    return best


@njit
def lu_solve(M, X) -> int:
    """Solve M Y = X in place (X ← Y, M ← its LU factors) by Gaussian elimination with
    partial pivoting (G&VL Alg. 3.4.1).  Returns 0, or k + 1 when pivot k is exactly zero."""
    n = M.shape[0]
    r = X.shape[1]
    for k in range(n):
        p = k
        best = abs(M[k, k])
        for i in range(k + 1, n):
            if abs(M[i, k]) > best:
                best = abs(M[i, k])
                p = i
        if best == 0.0:
            return k + 1
        if p != k:
            for j in range(n):
                t = M[k, j]
                M[k, j] = M[p, j]
                M[p, j] = t
            for j in range(r):
                t = X[k, j]
                X[k, j] = X[p, j]
                X[p, j] = t
        piv = M[k, k]
        for i in range(k + 1, n):
            f = M[i, k] / piv
            M[i, k] = f
            if f != 0.0:
                for j in range(k + 1, n):
                    M[i, j] -= f * M[k, j]
                for j in range(r):
                    X[i, j] -= f * X[k, j]
    # back substitution with the upper factor
    for i in range(n - 1, -1, -1):
        for j in range(r):
            s = X[i, j]
            for k in range(i + 1, n):
                s -= M[i, k] * X[k, j]
            X[i, j] = s / M[i, i]
    return 0


@njit
def _pade_low(A, A2, b, U, V):
    """U, V of the [m/m] Padé approximant for m = 3, 5, 7, 9 (len(b) = m + 1)."""
    n = A.shape[0]
    m = b.shape[0] - 1
    # U = A Σ_{j odd} b_j A^{j−1},  V = Σ_{j even} b_j A^j  (Higham 2005, eq. 2.2 split by parity)
    Pw = np.eye(n)            # A^{2i}
    T = np.zeros((n, n))      # Σ b_{2i+1} A^{2i}
    V[:, :] = 0.0
    tmp = np.empty((n, n))
    for i in range(m // 2 + 1):
        if 2 * i + 1 <= m:
            T += b[2 * i + 1] * Pw
        V += b[2 * i] * Pw
        if 2 * i + 2 <= m:
            matmul(Pw, A2, tmp)
            Pw[:, :] = tmp
    matmul(A, T, U)


@njit
def _pade13(A, A2, U, V):
    """U, V of the [13/13] Padé approximant (Higham 2005, eq. 2.5-2.6, 6 products):
    U = A [A6 (b13 A6 + b11 A4 + b9 A2) + b7 A6 + b5 A4 + b3 A2 + b1 I],
    V = A6 (b12 A6 + b10 A4 + b8 A2) + b6 A6 + b4 A4 + b2 A2 + b0 I."""
    n = A.shape[0]
    b = _B13
    A4 = np.empty((n, n))
    A6 = np.empty((n, n))
    matmul(A2, A2, A4)
    matmul(A4, A2, A6)
    T = np.empty((n, n))
    W = np.empty((n, n))
    for i in range(n):
        for j in range(n):
            T[i, j] = b[13] * A6[i, j] + b[11] * A4[i, j] + b[9] * A2[i, j]
    matmul(A6, T, W)
    for i in range(n):
        for j in range(n):
            W[i, j] += b[7] * A6[i, j] + b[5] * A4[i, j] + b[3] * A2[i, j]
        W[i, i] += b[1]
    matmul(A, W, U)
    for i in range(n):
        for j in range(n):
            T[i, j] = b[12] * A6[i, j] + b[10] * A4[i, j] + b[8] * A2[i, j]
    matmul(A6, T, V)
    for i in range(n):
        for j in range(n):
            V[i, j] += b[6] * A6[i, j] + b[4] * A4[i, j] + b[2] * A2[i, j]
        V[i, i] += b[0]


@njit
def expm(A, out):
    """out = e^A (Higham 2005, Algorithm 2.3: scaling and squaring, Padé degree by ‖A‖₁)."""
    n = A.shape[0]
    nrm = norm1(A)
    A2 = np.empty((n, n))
    U = np.empty((n, n))
    V = np.empty((n, n))
    s = 0
    if nrm <= _THETA[3]:
        matmul(A, A, A2)
        if nrm <= _THETA[0]:
            _pade_low(A, A2, _B3, U, V)
        elif nrm <= _THETA[1]:
            _pade_low(A, A2, _B5, U, V)
        elif nrm <= _THETA[2]:
            _pade_low(A, A2, _B7, U, V)
        else:
            _pade_low(A, A2, _B9, U, V)
    else:
        # scale A by 2^−s so that ‖A/2^s‖₁ ≤ θ_13
        s = max(0, int(math.ceil(math.log2(nrm / _THETA[4]))))
        As = np.empty((n, n))
        f = 0.5 ** s
        for i in range(n):
            for j in range(n):
                As[i, j] = A[i, j] * f
        matmul(As, As, A2)
        _pade13(As, A2, U, V)
    # r_m = (V − U)⁻¹ (V + U)  (Higham 2005, eq. 2.1)
    for i in range(n):
        for j in range(n):
            out[i, j] = V[i, j] + U[i, j]
            V[i, j] -= U[i, j]
    lu_solve(V, out)
    # undo the scaling: e^A = r_m(A/2^s)^{2^s}
    tmp = np.empty((n, n))
    for _ in range(s):
        matmul(out, out, tmp)
        out[:, :] = tmp


@njit
def zoh(A, B, dt, aug, E):
    """E = e^{[[A, B], [0, 0]] dt}: F_d = E[:d, :d] = e^{A dt} and Γ = E[:d, d:] = ∫₀^dt e^{As} ds B,
    the exact zero-order-hold discretisation x⁺ = F_d x + Γ u of ẋ = A x + B u with u held over
    dt (Van Loan 1978; Franklin, Powell & Workman, Digital Control, §4.3.3).  A column f(x, u)
    in B gives the local-linearisation step Δx = ∫₀^dt e^{As} ds f of ẋ = f(x, u).

    ``aug``, ``E``: work matrices of size (d + r)², r = B.shape[1]; E is the result."""
    d = A.shape[0]
    r = B.shape[1]
    aug[:, :] = 0.0
    for i in range(d):
        for j in range(d):
            aug[i, j] = A[i, j] * dt
        for j in range(r):
            aug[i, d + j] = B[i, j] * dt
    expm(aug, E)


def discretize(A: np.ndarray, B: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """(F_d, Γ) of :func:`zoh` as new arrays, for offline callers: F_d = e^{A dt},
    Γ = ∫₀^dt e^{As} ds B.  A 1-D ``B`` (a drift f) gives a 1-D Γ (the step Δx)."""
    A = np.ascontiguousarray(A, dtype=float)
    B = np.asarray(B, dtype=float)
    Bm = np.ascontiguousarray(B.reshape(B.shape[0], -1))
    d, r = Bm.shape
    aug = np.empty((d + r, d + r))
    E = np.empty((d + r, d + r))
    zoh(A, Bm, float(dt), aug, E)
    Gam = E[:d, d:].copy()
    return E[:d, :d].copy(), (Gam[:, 0] if B.ndim == 1 else Gam)


@njit
def cholesky(S, L) -> int:
    """Lower Cholesky factor L of S (only S's lower triangle is read; L's upper triangle is
    zeroed).  Returns 0, or (like LAPACK dpotrf) the 1-based order of the leading minor that
    is not positive definite (also for a NaN pivot)."""
    n = S.shape[0]
    for j in range(n):
        s = S[j, j]
        for k in range(j):
            s -= L[j, k] * L[j, k]
        if not s > 0.0:
            return j + 1
        d = math.sqrt(s)
        L[j, j] = d
        for i in range(j + 1, n):
            t = S[i, j]
            for k in range(j):
                t -= L[i, k] * L[j, k]
            L[i, j] = t / d
        for i in range(j):
            L[i, j] = 0.0
    return 0


@njit
def cho_solve(L, X):
    """Solve (L Lᵀ) Y = X in place (X ← Y) for the lower factor L (forward, then back)."""
    n = L.shape[0]
    r = X.shape[1]
    for c in range(r):
        for i in range(n):
            s = X[i, c]
            for k in range(i):
                s -= L[i, k] * X[k, c]
            X[i, c] = s / L[i, i]
        for i in range(n - 1, -1, -1):
            s = X[i, c]
            for k in range(i + 1, n):
                s -= L[k, i] * X[k, c]
            X[i, c] = s / L[i, i]


@njit
def is_pd(P) -> int:
    """The ``info`` of :func:`cholesky` of P (0: positive definite), without keeping L."""
    n = P.shape[0]
    L = np.zeros((n, n))
    return cholesky(P, L)


@warmer
def _warm() -> None:
    A = np.eye(3)
    out = np.empty((3, 3))
    for scale in (1e-3, 0.1, 0.5, 1.5, 4.0, 20.0):
        expm(A * scale, out)
    discretize(A, np.ones((3, 1)), 0.01)
    L = np.zeros((3, 3))
    cholesky(A, L)
    cho_solve(L, np.ones((3, 2)))
    is_pd(A)
