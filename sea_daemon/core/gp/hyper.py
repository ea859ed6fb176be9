"""Online GP hyperparameter adaptation in bounded slices (Sec. V-B, gradient-based as cited).

Each slice is one Adam ascent step (Kingma & Ba 2015) on the log marginal likelihood of one
local GP, in log space ``log θ = [log σ_f, log l_1 … log l_ρ, log σ_on]``, with the analytic
gradient of :func:`log_marginal_likelihood`; then the GP's Cholesky factor is
rebuilt with the new values and swapped in (:meth:`IncrementalGP.set_log_theta`).  The work of
one slice is O(N̄³) for a local model of at most N̄ points — bounded, independent of how much
data the tree holds — and the whole slice happens inside one call, so a caller never sees a
half-updated model.  The loop calls one slice every ``hyper_every`` updates
(:class:`sea_daemon.core.gp.loggp.LoGGP`), which bounds the added work per step.  Inside the loop a
slice is cut in two phases that run on two consecutive updates — :meth:`AdamHyper.propose`
(gradient + Adam step, the model untouched) and :meth:`AdamHyper.apply` (rebuild and swap) —
so no single step carries both.  The slices are deterministic (no randomness, no clock), so replays reproduce them exactly.

Off the loop.  Instead of in-loop slices, a caller may run the adaptation in another process:
:meth:`LoGGP.hyper_request` takes a JSON-able snapshot of one leaf (data, log θ, Adam state),
:func:`adam_steps` (pure, picklable-free: plain dicts in and out) runs any number of Adam steps
on it wherever the caller likes, and :meth:`LoGGP.hyper_apply` swaps the result in at a step
boundary in one call (one O(N̄³) rebuild), if that leaf still exists.  With ``steps=1`` the
result equals one synchronous slice on the same data.

Batch: :func:`log_marginal_likelihood` (and its analytic gradient w.r.t. ``log θ``, Rasmussen &
Williams 2006, eq. 2.30 and 5.9) and :func:`fit_hyperparameters` (L-BFGS-B) for a whole data set.

Log-space bounds keep a slice from driving a leaf to a degenerate model (σ_on → 0 makes the
factor ill-conditioned; l → 0 or ∞ make the GP useless).
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from sea_daemon.core.jit import njit, warmer
from sea_daemon.errors import EstimatorFault, Fault, InputError
from sea_daemon.core.gp import gp_core
from sea_daemon.core.gp.exact import IncrementalGP, kernel_from_rows, packed_order


def log_marginal_likelihood(X, y, sigma_f: float, lengthscales, sigma_n: float, *,
                            grad: bool = True, jitter: float = 1e-10,
                            L: np.ndarray | None = None):
    """Log marginal likelihood ``log p(y | X, θ)`` and its gradient w.r.t. ``log θ``.

    ``log θ = [log σ_f, log l_1 … log l_ρ, log σ_on]``.  Returns ``lml`` or ``(lml, grad)``.
    ``L`` (lower Cholesky factor of ``K + (σ_on² + jitter) I``, zeros above the diagonal) may
    be passed when already known.  Cost: one kernel matrix and the inverse factor (O(N³/3),
    compiled: :func:`sea_daemon.core.gp.gp_core.lml_grad`) — no per-dimension N×N arrays.
    """
    X = np.atleast_2d(np.asarray(X, dtype=float))
    y = np.ascontiguousarray(np.asarray(y, dtype=float).ravel())
    n, d = X.shape
    il2 = np.ascontiguousarray(1.0 / np.broadcast_to(np.asarray(lengthscales, dtype=float), (d,)) ** 2)
    Xb = np.ascontiguousarray(X - X[0])
    ap = np.empty(n * (n + 1) // 2)
    # eq:SE: K_f
    A = np.empty((n, d + 2))
    log_sf2 = 2.0 * math.log(sigma_f)
    c = np.zeros(d)
    gp_core.fill_rows(Xb, n, c, il2, log_sf2, A)
    K = kernel_from_rows(Xb, A, n, c, log_sf2)
    if L is None:
        # the packed factor of K_f + (σ_on² + jitter) I
        info = gp_core.cholesky_packed(K, n, sigma_n ** 2 + jitter, ap)
        if info != 0:
            raise EstimatorFault(f"K + σ_on² I is not positive definite (Cholesky pivot {info}); "
                                 f"σ_on = {sigma_n} must be > 0", fault=Fault.COVARIANCE_NOT_PD)
    else:
        ap[:] = np.asarray(L, dtype=float)[packed_order(n)]
    g = np.empty(d + 2)
    # R&W eq. 2.30 and 5.9 (gp_core.lml_grad)
    lml = gp_core.lml_grad(Xb, y, n, il2, float(sigma_n) ** 2, ap, K, bool(grad), g)
    return (lml, g) if grad else lml



def fit_hyperparameters(X, y, sigma_f: float = 1.0, lengthscales=1.0, sigma_n: float = 0.1, *,
                        bounds: Sequence[tuple[float, float]] | None = None,
                        maxiter: int = 200) -> tuple[float, np.ndarray, float]:
    """Maximise the log marginal likelihood over ``log θ`` (L-BFGS-B, analytic gradient).

    Returns ``(sigma_f, lengthscales, sigma_n)``.
    """
    from scipy.optimize import minimize

    X = np.atleast_2d(np.asarray(X, dtype=float))
    d = X.shape[1]
    t0 = np.concatenate(([math.log(sigma_f)], np.log(np.broadcast_to(lengthscales, (d,))),
                         [math.log(sigma_n)]))

    def nll(t):
        try:
            lml, g = log_marginal_likelihood(X, y, math.exp(t[0]), np.exp(t[1:d + 1]),
                                             math.exp(t[d + 1]))
        except EstimatorFault:
            return 1e25, np.zeros_like(t)
        return -lml, -g

    res = minimize(nll, t0, jac=True, method="L-BFGS-B", bounds=bounds,
                   options={"maxiter": maxiter})
    t = res.x
    return math.exp(t[0]), np.exp(t[1:d + 1]), math.exp(t[d + 1])



class AdamHyper:
    """Adam ascent on a local GP's log marginal likelihood, one step per call.

    Parameters
    ----------
    input_dim: ρ.
    lr: step size in log space (0.05 = about 5 % change of a hyperparameter per step).
    beta1, beta2, eps: Adam constants.
    bounds: ``{"sigma_f": (lo, hi), "lengthscales": (lo, hi), "sigma_n": (lo, hi)}``.
    """

    DEFAULT_BOUNDS = {"sigma_f": (1e-3, 1e3), "lengthscales": (1e-3, 1e4), "sigma_n": (1e-4, 1e2)}

    def __init__(self, input_dim: int, lr: float = 0.05, beta1: float = 0.9,
                 beta2: float = 0.999, eps: float = 1e-8, bounds: dict | None = None):
        if not (isinstance(lr, (int, float)) and math.isfinite(lr) and lr > 0):
            raise InputError(f"hyper_lr must be a finite number > 0, got {lr!r}")
        self.input_dim = int(input_dim)
        self.lr, self.beta1, self.beta2, self.eps = float(lr), float(beta1), float(beta2), float(eps)
        b = dict(self.DEFAULT_BOUNDS)
        b.update(bounds or {})
        d = self.input_dim
        self.lo = np.log(np.array([b["sigma_f"][0]] + [b["lengthscales"][0]] * d + [b["sigma_n"][0]]))
        self.hi = np.log(np.array([b["sigma_f"][1]] + [b["lengthscales"][1]] * d + [b["sigma_n"][1]]))

    # state: [t, m (ρ+2), v (ρ+2)] as one array
    def new_state(self) -> np.ndarray:
        return np.zeros(1 + 2 * (self.input_dim + 2))

    @staticmethod
    def copy_state(st: np.ndarray) -> np.ndarray:
        return st.copy()

    @staticmethod
    def state_to_dict(st: np.ndarray) -> list[float]:
        return st.tolist()

    @staticmethod
    def state_from_dict(d) -> np.ndarray:
        return np.asarray(d, dtype=float)

    def propose(self, gp: IncrementalGP, st: np.ndarray,
                points: int | None = None) -> tuple[float, np.ndarray | None]:
        """Phase 1: LML gradient of ``gp`` and one Adam ascent step on ``st`` (in place).

        ``points``: the gradient of the LML of the oldest ``points`` points only (cheaper; see
        :meth:`IncrementalGP.log_marginal_likelihood`).

        Returns ``(lml, new log θ)``; the model itself is not touched.  ``None`` for log θ when
        the gradient is not finite (the step is skipped).
        """
        lml, g = gp.log_marginal_likelihood(grad=True, points=points)
        theta = gp.log_theta
        # Adam moments in place in the state array, then the clipped ascent step (compiled)
        if not _adam_step(lml, g, st, theta, self.lr, self.beta1, self.beta2, self.eps, self.lo, self.hi):
            return lml, None
        return lml, theta

    @staticmethod
    def apply(gp: IncrementalGP, theta: np.ndarray) -> bool:
        """Phase 2: swap ``theta`` into ``gp`` and rebuild its factor (O(N̄³), one dpotrf).

        The new factor is computed before anything is replaced; if it fails the model keeps its
        previous hyperparameters.  Returns whether the swap happened.
        """
        old = gp.log_theta
        try:
            gp.set_log_theta(theta)
        except EstimatorFault:
            gp.set_log_theta(old)            # keep the last good model
            return False
        return True

    def step(self, gp: IncrementalGP, st: np.ndarray, points: int | None = None) -> float:
        """Both phases at once; returns the LML before the step."""
        lml, theta = self.propose(gp, st, points)
        if theta is not None:
            self.apply(gp, theta)
        return lml


def adam_steps(request: dict, steps: int = 1, lr: float = 0.05, bounds: dict | None = None) -> dict:
    """Run ``steps`` Adam ascent steps on the leaf snapshot ``request`` (see
    :meth:`sea_daemon.core.gp.loggp.LoGGP.hyper_request`); pure, plain dicts in and out, so it can run
    in a worker process.  Returns ``{"node", "log_theta", "adam", "lml"}`` for
    :meth:`LoGGP.hyper_apply` (``lml``: the LML before each step).
    """
    d = int(request["input_dim"])
    X = np.asarray(request["X"], dtype=float).reshape(-1, d)
    t = np.asarray(request["log_theta"], dtype=float)
    gp = IncrementalGP(d, math.exp(t[0]), np.exp(t[1:d + 1]), math.exp(t[d + 1]),
                       capacity=max(1, X.shape[0]), jitter=float(request.get("jitter", 1e-10)))
    gp.fit(X, request["y"], request.get("center"))
    hyp = AdamHyper(d, lr=lr, bounds=bounds)
    st = hyp.new_state() if request.get("adam") is None else np.asarray(request["adam"], dtype=float)
    lmls = [hyp.step(gp, st) for _ in range(int(steps))]
    return {"node": int(request["node"]), "log_theta": gp.log_theta.tolist(),
            "adam": st.tolist(), "lml": lmls}


@njit
def _adam_step(lml, g, st, theta, lr, beta1, beta2, eps, lo, hi) -> bool:
    """One Adam ascent step (Kingma & Ba 2015, Alg. 1) on ``theta`` in place, state
    ``st = [t, m, v]`` in place; nothing changes (returns False) if lml or g is not finite."""
    p = g.shape[0]
    if not math.isfinite(lml):
        return False
    for i in range(p):
        if not math.isfinite(g[i]):
            return False
    t = st[0] + 1.0
    st[0] = t
    c1 = 1.0 - beta1 ** t
    c2 = 1.0 - beta2 ** t
    for i in range(p):
        m = beta1 * st[1 + i] + (1.0 - beta1) * g[i]
        v = beta2 * st[1 + p + i] + (1.0 - beta2) * g[i] * g[i]
        st[1 + i] = m
        st[1 + p + i] = v
        th = theta[i] + lr * (m / c1) / (math.sqrt(v / c2) + eps)
        theta[i] = min(max(th, lo[i]), hi[i])
    return True


@warmer
def _warm() -> None:
    _Xw = np.random.default_rng(0).normal(size=(6, 3))
    log_marginal_likelihood(_Xw, _Xw[:, 0], 1.0, 1.0, 0.1)
    h = AdamHyper(3)
    _adam_step(0.0, np.zeros(5), h.new_state(), np.zeros(5), h.lr, h.beta1, h.beta2, h.eps, h.lo, h.hi)
