"""Exact Gaussian-process regression (Sec. III-B) with an incremental Cholesky factor.

* :func:`se_kernel` — the squared-exponential ARD kernel (``eq:SE``).
* :class:`IncrementalGP` — posterior mean and variance (``eq:GPmean``, ``eq:GPvariance``), the
  mean's Jacobian (``eq:moejac`` with ``eq:kernelderivative``) and, optionally, the variance's,
  with the Cholesky factor of ``K + σ_on² I`` grown one row per point in O(N²).  It is the local
  model of every LoG-GP leaf (:mod:`sea_daemon.core.gp.loggp`).

Storage.  The lower Cholesky factor ``L`` is kept *packed*, row by row (the first ``n(n+1)/2``
entries hold rows ``0 … n-1``): appending a point appends one row at the end, and every
triangular solve runs on a prefix of one contiguous buffer, without copies.  Inputs are
stored scaled, ``x̃ = (x − c) / l`` around a centre ``c`` (the first point), so a kernel
vector is one matrix–vector product and one ``exp``:
``k_i(x) = exp(h_i + x̃_i·x̃ − |x̃|²/2)`` with ``h_i = log σ_f² − |x̃_i|²/2`` (eq:SE expanded).

The numerics are compiled (:mod:`sea_daemon.core.gp.gp_core`, numba): per call a prediction with
gradient costs a few µs at N = 100 instead of tens of µs of numpy/BLAS call overhead.

Learned state ends in ``_`` (``X_``, ``y_``, ``n_``, ``alpha_``, ``L_``).  No I/O, no clock.
"""
from __future__ import annotations

import math

import numpy as np

from sea_daemon.core.gp import gp_core
from sea_daemon.core.jit import warmer
from sea_daemon.errors import EstimatorFault, Fault, InputError

_PACKED_ORDER: dict[int, tuple[np.ndarray, np.ndarray]] = {}
_EMPTY = np.empty((0, 0))


def packed_order(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Row-major lower-triangle indices of an n×n matrix: the order in which the factor ``L``
    is packed (``L[packed_order(n)]`` is the packed factor, cached per n)."""
    t = _PACKED_ORDER.get(n)
    if t is None:
        t = _PACKED_ORDER[n] = np.tril_indices(n)
    return t


def _vec(name: str, v, d: int, positive: bool = True) -> np.ndarray:
    a = np.asarray(v, dtype=float)
    if a.ndim == 0:
        a = np.full(d, float(a))
    if a.shape != (d,) or not np.all(np.isfinite(a)) or (positive and np.any(a <= 0)):
        raise InputError(f"{name} must be {'a positive' if positive else 'a finite'} number or "
                         f"{d} of them, got {v!r}")
    return a


def _pos(name: str, v) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float, np.floating, np.integer)) \
            or not math.isfinite(float(v)) or float(v) <= 0:
        raise InputError(f"{name} must be a finite number > 0, got {v!r}")
    return float(v)


def se_kernel(A, B, lengthscales, sigma_f: float) -> np.ndarray:
    """Squared-exponential ARD kernel matrix ``k(a_i, b_j)`` (``eq:SE``).

    ``A``: (m, ρ), ``B``: (p, ρ) (1-D arrays are one point), ``lengthscales``: scalar or (ρ,).
    """
    A = np.ascontiguousarray(np.atleast_2d(np.asarray(A, dtype=float)))
    B = np.ascontiguousarray(np.atleast_2d(np.asarray(B, dtype=float)))
    l = np.broadcast_to(np.asarray(lengthscales, dtype=float), (A.shape[1],))
    K = np.empty((A.shape[0], B.shape[0]))
    # eq:SE: σ_f² exp(−Σ_i (x_i − x'_i)² / (2 l_i²))  (gp_core.se_matrix)
    gp_core.se_matrix(A, B, np.ascontiguousarray(1.0 / (l * l)), float(sigma_f) ** 2, K)
    return K


def kernel_from_rows(X: np.ndarray, A: np.ndarray, n: int, c: np.ndarray, log_sf2: float) -> np.ndarray:
    """Noise-free kernel matrix of the first n rows of X (eq:SE), from the rows A of
    :func:`gp_core.fill_rows` (centre ``c``, ``log σ_f²``): the exponents compiled, the
    exponential by numpy."""
    K = np.empty((n, n))
    gp_core.kernel_exponent(X, A, n, c, log_sf2, K)
    return np.exp(K, out=K)


class IncrementalGP:
    """Exact GP posterior with an O(N²) rank-one-row update of its Cholesky factor.

    Parameters
    ----------
    input_dim: ρ, the input dimension.
    sigma_f, lengthscales, sigma_n: hyperparameters of ``eq:SE`` and the target noise σ_on.
    capacity: initial storage (grows by 1.5× when full, never beyond ``max_capacity``).
    jitter: added to the diagonal on top of σ_on² for numerical safety.
    clip_mean: evaluate the mean (and ∂μ/∂x) at x clipped into the box ``[lo_, hi_]`` of the
        stored inputs, the variance at x itself: beyond its data the mean stays at its value on
        the box's face (∂μ/∂x = 0 in the clipped coordinates) instead of extrapolating, while σ
        still grows with the distance (docs/learning.md, "Novelty").  Default False.

    Internals (for speed at N ≈ 100, where numpy's per-call overhead dominates): with
    ``x̄ = x − c`` (c: the first point), row i of ``A_`` is ``[x̄_i / l², h_i, 1]`` with
    ``h_i = log σ_f² − ½ Σ_j x̄_ij² / l_j²``, so for the augmented query
    ``a(x) = [x̄, 1, −½ Σ_j x̄_j² / l_j²]`` the kernel vector is ``k = exp(A a(x))`` (eq:SE).
    """

    __slots__ = ("input_dim", "n_", "X_", "y_", "A_", "beta_", "ap_", "_alpha", "_alpha_ok",
                 "center_", "clip_mean", "lo_", "hi_", "_il2", "_log_sf2", "_sf2", "_sn2",
                 "sigma_f", "lengthscales", "sigma_n", "jitter", "max_capacity", "_cap")

    def __init__(self, input_dim: int, sigma_f: float = 1.0, lengthscales=1.0,
                 sigma_n: float = 0.1, *, capacity: int = 16, max_capacity: int | None = None,
                 jitter: float = 1e-10, clip_mean: bool = False):
        if isinstance(input_dim, bool) or not isinstance(input_dim, (int, np.integer)) or input_dim < 1:
            raise InputError(f"input_dim must be an integer >= 1, got {input_dim!r}")
        self.input_dim = int(input_dim)
        self.max_capacity = None if max_capacity is None else int(max_capacity)
        self.jitter = float(jitter)
        self.n_ = 0
        self.center_: np.ndarray | None = None
        self.clip_mean = bool(clip_mean)
        self.lo_ = np.full(self.input_dim, np.inf)      # box of the stored inputs
        self.hi_ = np.full(self.input_dim, -np.inf)
        cap = max(1, int(capacity))
        if self.max_capacity is not None:
            cap = min(cap, self.max_capacity)
        self._alloc(cap)
        self._set_hyp(sigma_f, lengthscales, sigma_n)

    # ------------------------------------------------------------------ storage
    def _alloc(self, cap: int) -> None:
        d = self.input_dim
        self._cap = cap
        self.X_ = np.empty((cap, d))
        self.A_ = np.empty((cap, d + 2))
        self.y_ = np.empty(cap)
        self.beta_ = np.empty(cap)
        self.ap_ = np.empty(cap * (cap + 1) // 2)
        self._alpha = np.empty(cap)
        self._alpha_ok = False

    def _grow(self, need: int) -> None:
        cap = max(need, self._cap + max(8, self._cap // 2))
        if self.max_capacity is not None:
            if need > self.max_capacity:
                raise InputError(f"GP holds {self.n_} points; capacity {self.max_capacity} is the limit")
            cap = min(cap, self.max_capacity)
        old = (self.X_, self.A_, self.y_, self.beta_, self.ap_)
        n, m = self.n_, self.n_ * (self.n_ + 1) // 2
        self._alloc(cap)
        self.X_[:n], self.A_[:n], self.y_[:n] = old[0][:n], old[1][:n], old[2][:n]
        self.beta_[:n], self.ap_[:m] = old[3][:n], old[4][:m]

    @property
    def capacity(self) -> int:
        return self._cap

    def nbytes(self) -> int:
        """Bytes held by this model's arrays."""
        return sum(a.nbytes for a in (self.X_, self.A_, self.y_, self.beta_, self.ap_, self._alpha))

    # ------------------------------------------------------------------ hyperparameters
    def _set_hyp(self, sigma_f, lengthscales, sigma_n) -> None:
        self.sigma_f = _pos("sigma_f", sigma_f)
        self.lengthscales = _vec("lengthscales", lengthscales, self.input_dim)
        self.sigma_n = _pos("sigma_n", sigma_n)
        self._il2 = 1.0 / (self.lengthscales * self.lengthscales)
        self._sf2 = self.sigma_f ** 2
        self._log_sf2 = math.log(self._sf2)
        self._sn2 = self.sigma_n ** 2

    @property
    def sf2(self) -> float:
        """``σ_f²``, the prior variance of eq:SE (read-only)."""
        return self._sf2

    @property
    def il2(self) -> np.ndarray:
        """``1 / l_j²`` per input dimension, the inverse squared length scales of eq:SE
        (a read-only view)."""
        v = self._il2.view()
        v.flags.writeable = False
        return v

    @property
    def log_theta(self) -> np.ndarray:
        """``[log σ_f, log l_1 … log l_ρ, log σ_on]``."""
        return np.concatenate(([math.log(self.sigma_f)], np.log(self.lengthscales),
                               [math.log(self.sigma_n)]))

    def set_hyperparameters(self, sigma_f: float, lengthscales, sigma_n: float) -> None:
        """Swap in new hyperparameters and rebuild the factor (O(N³), one LAPACK dpotrf)."""
        self._set_hyp(sigma_f, lengthscales, sigma_n)
        self._rebuild()

    def set_log_theta(self, log_theta) -> None:
        t = np.asarray(log_theta, dtype=float)
        d = self.input_dim
        self.set_hyperparameters(math.exp(t[0]), np.exp(t[1:d + 1]), math.exp(t[d + 1]))

    # ------------------------------------------------------------------ data
    def _set_center(self, c) -> None:
        self.center_ = np.array(c, dtype=float)

    def fit(self, X, y, center=None) -> "IncrementalGP":
        """Replace the data by ``X`` (N, ρ), ``y`` (N,) and factorise (O(N³)).

        ``center``: the centre ``c`` of the stored inputs (default: the first point); a model
        rebuilt from a snapshot passes the centre it was saved with, so that it predicts to
        the last bit as the saved one.
        """
        X = np.atleast_2d(np.asarray(X, dtype=float))
        y = np.asarray(y, dtype=float).ravel()
        if X.shape[1] != self.input_dim or X.shape[0] != y.shape[0]:
            raise InputError(f"fit needs X of shape (N, {self.input_dim}) and y of shape (N,), "
                             f"got {X.shape} and {y.shape}")
        n = X.shape[0]
        if n > self._cap:
            if self.max_capacity is not None and n > self.max_capacity:
                raise InputError(f"fit got {n} points; capacity {self.max_capacity} is the limit")
            self._alloc(n if self.max_capacity is None else max(n, min(self.max_capacity, n + 8)))
        self.n_ = n
        self.X_[:n], self.y_[:n] = X, y
        if center is not None:
            self._set_center(center)
        elif n:
            self._set_center(X[0])
        self._rebuild()
        return self

    def kernel_matrix(self, X) -> np.ndarray:
        """Noise-free kernel matrix ``k(x_a, x_b)`` of the rows of ``X`` (eq:SE, compiled)."""
        X = np.ascontiguousarray(X, dtype=float)
        m = X.shape[0]
        c = self.center_ if self.center_ is not None else np.zeros(self.input_dim)
        A = np.empty((m, self.input_dim + 2))
        gp_core.fill_rows(X, m, c, self._il2, self._log_sf2, A)
        # eq:SE expanded: k(x_a, x_b) = σ_f² exp(x̄_aᵀ diag(l⁻²) x̄_b − ½|x̄_a|²_l − ½|x̄_b|²_l)
        return kernel_from_rows(X, A, m, c, self._log_sf2)

    def spawn(self, X: np.ndarray, y: np.ndarray, K: np.ndarray | None = None,
              capacity: int | None = None) -> "IncrementalGP":
        """A new model with this one's hyperparameters on data ``(X, y)`` (no re-validation).

        ``K``: the noise-free kernel matrix of ``X`` under these hyperparameters, if known
        (e.g. a sub-matrix of the parent's at a LoG-GP split).
        """
        n = X.shape[0]
        child = IncrementalGP.__new__(IncrementalGP)
        child.input_dim, child.max_capacity, child.jitter = self.input_dim, self.max_capacity, self.jitter
        child.clip_mean = self.clip_mean
        child.lo_ = np.full(self.input_dim, np.inf)
        child.hi_ = np.full(self.input_dim, -np.inf)
        for a in ("sigma_f", "lengthscales", "sigma_n", "_il2", "_sf2", "_log_sf2", "_sn2"):
            setattr(child, a, getattr(self, a))
        cap = max(n, 1) if capacity is None else max(n, 1, int(capacity))
        if child.max_capacity is not None:
            cap = max(n, min(cap, child.max_capacity))
        child._alloc(cap)
        child.n_ = n
        child.center_ = None
        if n:
            child.X_[:n], child.y_[:n] = X, y
            child._set_center(X[0])
            child._rebuild(K)
        return child

    def _rebuild(self, K: np.ndarray | None = None) -> None:
        """Refactorise ``K + σ_on² I`` from the stored data with the current hyperparameters.

        ``K``: the noise-free kernel matrix of the stored inputs, if already known.
        """
        n = self.n_
        self._alpha_ok = False
        if n == 0:
            self.lo_[:] = np.inf
            self.hi_[:] = -np.inf
            return
        X = self.X_
        np.min(X[:n], axis=0, out=self.lo_)
        np.max(X[:n], axis=0, out=self.hi_)
        gp_core.fill_rows(X, n, self.center_, self._il2, self._log_sf2, self.A_)
        if K is None:
            # eq:SE expanded: k(x_i, x_j) = exp(x̄_iᵀ diag(l⁻²) x̄_j + h_i + h_j − log σ_f²)
            K = kernel_from_rows(X, self.A_, n, self.center_, self._log_sf2)
        else:
            K = np.ascontiguousarray(K)
        jit = self.jitter
        for _ in range(8):
            info = gp_core.cholesky_packed(K, n, self._sn2 + jit, self.ap_)
            if info == 0:
                break
            jit = max(10.0 * jit, 1e-10 * self._sf2)
        else:
            raise EstimatorFault(f"GP kernel matrix not positive definite with jitter {jit:g} "
                                 f"(sigma_n = {self.sigma_n:g} must be > 0)", fault=Fault.COVARIANCE_NOT_PD)
        # β = L⁻¹ y, so that μ = (L⁻¹k)ᵀβ (eq:GPmean)
        self.beta_[:n] = self.y_[:n]
        gp_core.solve_lower(self.ap_, n, self.beta_)

    def add(self, x, y: float) -> None:
        """Append one training pair; O(N²): one triangular solve for the new factor row."""
        n = self.n_
        if n == self._cap:
            self._grow(n + 1)
        x = np.ascontiguousarray(x, dtype=float)
        if self.center_ is None:
            self._set_center(x)
        # eq:SE kernel vector, new factor row L c = k, d = sqrt(k(x,x) + σ_on² − cᵀc), β_n
        gp_core.add_point(x, float(y), self.X_, self.A_, self.y_, self.beta_, self.ap_, self.center_,
                          self._il2, n, self._sf2, self._sn2, self.jitter, self._log_sf2)
        self.n_ = n + 1
        self._alpha_ok = False
        np.minimum(self.lo_, x, out=self.lo_)
        np.maximum(self.hi_, x, out=self.hi_)

    def remove_oldest(self, m: int = 1) -> None:
        """Drop the ``m`` oldest points and refactorise (O(N³) once; amortise over ≥ m adds)."""
        n = self.n_
        m = max(0, min(int(m), n))
        if m == 0:
            return
        for a in (self.X_, self.y_):
            a[: n - m] = a[m:n]
        self.n_ = n - m
        self._rebuild()

    # ------------------------------------------------------------------ read-outs
    @property
    def alpha_(self) -> np.ndarray:
        """``(K + σ_on² I)⁻¹ y`` (eq:GPmean), computed lazily from ``β`` (one triangular solve)."""
        n = self.n_
        if not self._alpha_ok:
            gp_core.update_alpha(self.ap_, self.beta_, n, self._alpha)
            self._alpha_ok = True
        return self._alpha[:n]

    @property
    def L_(self) -> np.ndarray:
        """Dense lower Cholesky factor of ``K + σ_on² I`` (a copy)."""
        n = self.n_
        L = np.zeros((n, n))
        L[packed_order(n)] = self.ap_[: n * (n + 1) // 2]
        return L

    def predict(self, x) -> tuple[float, float]:
        """Posterior mean and variance at one input ``x`` (ρ,) (eq:GPmean, eq:GPvariance)."""
        n = self.n_
        if n == 0:
            return 0.0, self._sf2
        x = np.ascontiguousarray(x, dtype=float)
        # eq:SE, v = L⁻¹ k, eq:GPmean μ = vᵀβ, eq:GPvariance σ² = k(x,x) − vᵀv
        mu, var = gp_core.predict(self.A_, self.ap_, self.beta_, self.center_, self._il2, n, self._sf2, x)
        if self.clip_mean:
            xc = np.minimum(np.maximum(x, self.lo_), self.hi_)
            if not np.array_equal(xc, x):
                # clip_mean: μ at the clipped input, σ² at x
                mu = gp_core.predict(self.A_, self.ap_, self.beta_, self.center_, self._il2, n, self._sf2, xc)[0]
        return mu, var

    def predict_many(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`predict` at every row of ``X`` (m, ρ), in one compiled call: (μ (m,), σ² (m,))."""
        X = np.ascontiguousarray(X, dtype=float)
        m = X.shape[0]
        n = self.n_
        if n == 0:
            return np.zeros(m), np.full(m, self._sf2)
        mu, var = np.empty(m), np.empty(m)
        # eq:GPmean, eq:GPvariance per row (gp_core.predict)
        gp_core.predict_many(self.A_, self.ap_, self.beta_, self.center_, self._il2, n, self._sf2, X, mu, var)
        if self.clip_mean:
            Xc = np.minimum(np.maximum(X, self.lo_), self.hi_)
            out = np.flatnonzero(np.any(Xc != X, axis=1))
            if out.size:
                # clip_mean: μ at the clipped inputs, σ² at X
                Xo = np.ascontiguousarray(Xc[out])
                mo, vo = np.empty(out.size), np.empty(out.size)
                gp_core.predict_many(self.A_, self.ap_, self.beta_, self.center_, self._il2, n, self._sf2,
                                     Xo, mo, vo)
                mu[out] = mo
        return mu, var

    def extrapolation_many(self, X: np.ndarray) -> np.ndarray:
        """First-order extrapolation of the mean at every row of ``X`` (m, ρ):
        ``e(x) = Σ_j |∂μ/∂x_j(x)| |x_j − x*_j|``, x* the training input nearest x in the
        length-scale metric ‖(x − x_i)/l‖.  It is how far the mean has moved, at its own local
        slope, away from the closest point where data pinned it: ≈ 0 on the data, growing with
        the distance from it where the mean is steep (eq:moejac with eq:kernelderivative for
        ∂μ/∂x).  Always of the unclipped mean, also with ``clip_mean``: its slope is the data's
        estimate of how fast f moves away from them.  Zeros without data.  O(m N ρ), compiled."""
        X = np.ascontiguousarray(np.atleast_2d(np.asarray(X, dtype=float)))
        n = self.n_
        out = np.zeros(X.shape[0])
        if n == 0:
            return out
        # compiled (gp_core.extrapolation_many); the unclipped mean's slope also with clip_mean
        gp_core.extrapolation_many(self.X_, n, self.alpha_, self._il2, self._sf2, X, out)
        return out

    def _predict_with_grad_clipped(self, x, xc, var_grad, dmu, dvar):
        """clip_mean outside the box: μ and ∂μ/∂x at the clipped input ``xc`` (∂μ/∂x = 0 in
        the clipped coordinates), σ² (and ∂σ²/∂x) at ``x``."""
        n = self.n_
        if var_grad:
            # eq:GPvariance and its gradient at x (the ∂μ/∂x written here is replaced below)
            _, var = gp_core.predict_with_grad(self.A_, self.ap_, self.beta_, self._alpha, self._alpha_ok,
                                               self.center_, self._il2, n, self._sf2, x, True, dmu, dvar)
            self._alpha_ok = True
        else:
            # eq:GPvariance at x
            var = gp_core.predict(self.A_, self.ap_, self.beta_, self.center_, self._il2, n, self._sf2, x)[1]
        # eq:GPmean, eq:moejac at the clipped input
        mu, _ = gp_core.predict_with_grad(self.A_, self.ap_, self.beta_, self._alpha, self._alpha_ok, self.center_,
                                          self._il2, n, self._sf2, xc, False, dmu, dmu)
        self._alpha_ok = True
        dmu[xc != x] = 0.0
        return (mu, var, dmu, dvar) if var_grad else (mu, var, dmu)

    def predict_with_grad(self, x, var_grad: bool = False, out: np.ndarray | None = None):
        """``(μ, σ², ∂μ/∂x)`` or, with ``var_grad``, ``(μ, σ², ∂μ/∂x, ∂σ²/∂x)`` at ``x``;
        ``out`` (ρ,): where to write ∂μ/∂x (default a new array)."""
        n = self.n_
        d = self.input_dim
        dmu = np.empty(d) if out is None else out
        if n == 0:
            dmu[:] = 0.0
            return (0.0, self._sf2, dmu, np.zeros(d)) if var_grad else (0.0, self._sf2, dmu)
        dvar = np.empty(d) if var_grad else dmu
        x = np.ascontiguousarray(x, dtype=float)
        if self.clip_mean:
            xc = np.minimum(np.maximum(x, self.lo_), self.hi_)
            if not np.array_equal(xc, x):
                return self._predict_with_grad_clipped(x, xc, var_grad, dmu, dvar)
        # eq:GPmean, eq:GPvariance, eq:moejac with eq:kernelderivative (gp_core.predict_with_grad;
        # α = (K + σ_on² I)⁻¹ y refreshed there after an append)
        mu, var = gp_core.predict_with_grad(self.A_, self.ap_, self.beta_, self._alpha, self._alpha_ok,
                                            self.center_, self._il2, n, self._sf2,
                                            x, bool(var_grad), dmu, dvar)
        self._alpha_ok = True
        return (mu, var, dmu, dvar) if var_grad else (mu, var, dmu)

    def log_marginal_likelihood(self, grad: bool = True, points: int | None = None):
        """LML of the stored data (and its gradient w.r.t. ``log θ``), reusing the factor.

        ``points``: use only the oldest ``points`` points, whose factor is the leading block of
        the stored one (free); the cubic cost then shrinks by ``(points / N)³``.
        """
        n = self.n_ if points is None else max(0, min(int(points), self.n_))
        if n == 0:
            return (0.0, np.zeros(self.input_dim + 2)) if grad else 0.0
        g = np.empty(self.input_dim + 2)
        # the oldest n points' factor is the leading block of the packed factor; eq:SE K_f
        Kf = kernel_from_rows(self.X_, self.A_, n, self.center_, self._log_sf2) if grad else _EMPTY
        lml = gp_core.lml_grad(self.X_[:n] - self.center_, self.y_, n, self._il2, self._sn2,
                               self.ap_, Kf, bool(grad), g)
        return (lml, g) if grad else lml

    # ------------------------------------------------------------------ persistence
    def to_dict(self) -> dict:
        """JSON-serialisable state (data and hyperparameters); the factor is rebuilt on load."""
        n = self.n_
        return {"input_dim": self.input_dim, "sigma_f": self.sigma_f,
                "lengthscales": self.lengthscales.tolist(), "sigma_n": self.sigma_n,
                "jitter": self.jitter, "max_capacity": self.max_capacity,
                "center": None if self.center_ is None else self.center_.tolist(),
                "X": self.X_[:n].tolist(), "y": self.y_[:n].tolist()}

    @classmethod
    def from_dict(cls, d: dict) -> "IncrementalGP":
        n = len(d["y"])
        gp = cls(d["input_dim"], d["sigma_f"], d["lengthscales"], d["sigma_n"],
                 capacity=max(n, 1), max_capacity=d.get("max_capacity"), jitter=d["jitter"])
        return gp.fit(np.asarray(d["X"], dtype=float).reshape(n, gp.input_dim), d["y"], d.get("center"))


@warmer
def _warm() -> None:
    """Every compiled call of this module, with the argument types it uses (see _jit)."""
    rng = np.random.default_rng(0)
    X = rng.standard_normal((6, 3))
    gp = IncrementalGP(3, 1.0, [1.0, 1.0, 1.0], 0.1, capacity=4)
    for x in X:
        gp.add(x, float(x.sum()))
    gp.predict(X[0])
    gp.predict_many(X[:2])
    gp.predict_with_grad(X[1], var_grad=True)
    gp.extrapolation_many(X[:2])
    gp.log_marginal_likelihood(grad=True)
    gp.set_hyperparameters(1.1, [1.0, 0.9, 1.2], 0.1)
    gp.spawn(X[:3], X[:3, 0].copy(), gp.kernel_matrix(X[:3]))
    se_kernel(X, X[:2], 1.0, 1.0)
