"""The linearisation-error box of a rigid body of n coupled joints (``model.urdf``) for the Theorem-1 bound.

A model whose load side is a URDF's rigid body and has no declared effects is non-linear only in
q̈ = φ(w) = M(q)⁻¹ (τ − C(q, q̇) q̇ − g(q)) (Pinocchio's ABA, eq:loadside), a function of
w = W x = (q, q̇, τ) ∈ R^{3n} (q = θ_m + θ_s, q̇ = θ̇_m + θ̇_s, τ = τ_h,act − τ_s the load-side
torque besides the body's own, linear in x).  The filter's drift is linear in x elsewhere, and
its Jacobian's q̈ rows are ∂φ/∂w · W (chain rule), so the linearisation error
ε(x) = f_nom(x) − f_nom(x̂) − A (x − x̂) sits in the θ̈_s rows only (θ̈_s = q̈ − θ̈_m, θ̈_m linear) and
equals φ(w) − φ(ŵ) − ∂φ/∂w (w − ŵ), a function of w alone.  It is therefore bounded over the
projection W·C_{k−1} = W X̂ ⊕ E(0, s W P Wᵀ) with s = χ²_{3n}(1 − δ_N): one event,
Pr(W g ∈ E(0, s W P Wᵀ)) = 1 − δ_N for the Gaussian part g ~ N(0, P), which also holds the GP's
input (q, q̇) = T x (a part of w), instead of the 5n-dimensional χ²_5n set.

:func:`rigid_points` gives the deterministic points of that projection (compiled: the
trace-minimal outer ellipsoid of the zonotope ⊕ the Gaussian part, as
:meth:`~sea_daemon.core.bounds.setmember.SetMembershipBound.confidence_set`, and its
:func:`~sea_daemon.core.bounds.setmember.points_of_ellipsoid`); Pinocchio's ABA at all of them
(:meth:`~sea_daemon.core.rigid.RigidBody.forward_columns`, one call for all of them); :func:`rigid_error_box` the maximum
|ε| over them, (1 + margin) times, into the θ̈_s rows.  Sampled, so approximate in the same sense
as the sampled box of declared effects (docs/bounds.md §4).
"""
from __future__ import annotations

import numpy as np

from sea_daemon.core.bounds.ellipsoid import chi2_quantile
from sea_daemon.core.bounds.setmember import points_of_ellipsoid, unit_directions
from sea_daemon.core.bounds.zonotope import outer_ellipsoid_shape
from sea_daemon.core.dynamics import load_side_torque
from sea_daemon.core.jit import njit, warmer


def applies(model) -> bool:
    """Whether the model's only non-linearity is its rigid body (URDF, no declared effects)."""
    return (getattr(model, "rigid", None) is not None
            and not (model.load_effects or model.motor_effects or model.spring_effects or model.backlash))


def rigid_map(model, d: int | None = None) -> np.ndarray:
    """W (3n, d): x → w = (q, q̇, τ), τ = :func:`~sea_daemon.core.dynamics.load_side_torque` (linear
    in x without declared effects: its columns are its values at the unit vectors); d = 5n, or 6n
    with τ̇_h,act (which w does not depend on: zero columns)."""
    n = model.n
    d5 = 5 * n
    W = np.zeros((3 * n, d5 if d is None else int(d)))
    W[:n, :n] = W[:n, n:2 * n] = np.eye(n)
    W[n:2 * n, 2 * n:3 * n] = W[n:2 * n, 3 * n:4 * n] = np.eye(n)
    f = np.zeros(n)
    t0 = load_side_torque(model.kernel, np.zeros(d5), f)
    for i in range(d5):
        e = np.zeros(d5)
        e[i] = 1.0
        W[2 * n:, i] = load_side_torque(model.kernel, e, f) - t0
    return W


@njit
def rigid_points(G, x0, P0, W, s, U):
    """The points of the outer ellipsoid of W·(x̂ + Z(G) ⊕ E(0, s P)) (rows (m, 3n)); row 0 is ŵ."""
    sP = s * (W @ P0 @ W.T)
    Xw = outer_ellipsoid_shape(np.ascontiguousarray(W @ G), sP, True)
    Xw = 0.5 * (Xw + Xw.T)
    return points_of_ellipsoid(W @ x0, Xw, U)


@njit
def rigid_error_box(Wp, ddq, D, margin, b):
    """b's θ̈_s rows (3n:4n of 5n) = (1 + margin) max over the points w (rows of Wp, row 0 = ŵ) of
    |φ(w) − φ(ŵ) − D (w − ŵ)|, φ(w) the rows of ``ddq``, D = ∂φ/∂w at ŵ (n, 3n); other rows 0."""
    n = ddq.shape[1]
    b[:] = 0.0
    for p in range(1, Wp.shape[0]):
        for j in range(n):
            e = ddq[p, j] - ddq[0, j]
            for i in range(3 * n):
                e -= D[j, i] * (Wp[p, i] - Wp[0, i])
            e = abs(e)
            # the rounding floor: an exactly linear φ gives 0
            if e <= 1e-12 * (abs(ddq[p, j]) + abs(ddq[0, j])):
                e = 0.0
            b[3 * n + j] = max(b[3 * n + j], e)
    for j in range(n):
        b[3 * n + j] *= 1.0 + margin


class RigidBox:
    """The box of one model (module docstring): W, the point directions, work arrays."""

    def __init__(self, model, U: np.ndarray, margin: float, s_z: float = 0.0, d: int | None = None):
        self.model = model
        self.n = model.n
        self.W = rigid_map(model, d)
        self.U = np.ascontiguousarray(U, dtype=float)
        self.margin = float(margin)
        self.s_z = float(s_z)          # χ²_3n(1 − δ_N): the Gaussian part's quantile of W·C
        self._D = np.empty((self.n, 3 * self.n))
        self._ddq = None                   # q̈ at the points, (n, points) in Fortran order

    @classmethod
    def of(cls, model, sm, n_dirs: int, seed: int) -> RigidBox | None:
        """The box of ``model`` for a :class:`~sea_daemon.core.bounds.setmember.SetMembershipBound`
        ``sm`` (zonotope sets), or None where it does not apply (:func:`applies`)."""
        if not (applies(model) and sm.sets == "zonotope"):
            return None
        n = model.n
        return cls(model, unit_directions(3 * n, n_dirs, seed), sm.margin,
                   chi2_quantile(1.0 - sm.delta_noise, 3 * n), sm.d)

    def box(self, x0, G, P0, s: float, b: np.ndarray) -> np.ndarray:
        """The θ̈_s rows of ``b`` (5n,) over the set x̂ + Z(G) ⊕ E(0, s P_{k−1}) projected by W; returns b."""
        n = self.n
        Wp = rigid_points(np.ascontiguousarray(G), x0, np.ascontiguousarray(P0), self.W, float(s), self.U)
        out = self._ddq
        if out is None or out.shape[1] != Wp.shape[0]:
            out = self._ddq = np.empty((n, Wp.shape[0]), order="F")
        WT = Wp.T                          # (3n, points): the points as columns, one batched ABA
        ddq = self.model.rigid.forward_columns(WT[:n], WT[n:2 * n], WT[2 * n:], out).T
        _, dq_q, dq_v, Minv = self.model.rigid.forward_derivatives(Wp[0, :n], Wp[0, n:2 * n], Wp[0, 2 * n:])
        D = self._D
        D[:, :n] = dq_q
        D[:, n:2 * n] = dq_v
        D[:, 2 * n:] = Minv
        rigid_error_box(Wp, ddq, D, self.margin, b)
        return b

    def at(self, x0, G, P0, b: np.ndarray) -> None:
        """The model's M(q̂), M⁻¹ at x̂_{k−1} (:meth:`~sea_daemon.core.model.SEAModel.at`) and :meth:`box`
        with s = :attr:`s_z` into ``b``: what the compiled bound step needs of the rigid body."""
        self.model.at(x0)
        self.box(x0, G, P0, self.s_z, b)


@warmer
def _warm() -> None:
    """The kernels with the types :meth:`RigidBox.box` passes (2 joints: d = 10, W·x ∈ R⁶)."""
    n, d = 2, 10
    W = np.zeros((3 * n, d))
    W[:, :3 * n] = np.eye(3 * n)
    Wp = rigid_points(np.eye(d)[:, :3].copy(), np.zeros(d), np.eye(d), W, 1.0, unit_directions(3 * n, 4, 0))
    rigid_error_box(Wp, np.zeros((Wp.shape[0], n)), np.zeros((n, 3 * n)), 0.1, np.zeros(5 * n))
