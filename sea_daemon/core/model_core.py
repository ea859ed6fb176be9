"""The compiled f_nom, F_nom and training residual of a model WITH declared effects, for the filter.

:class:`~sea_daemon.core.model.SEAModel` holds its parameters and declared effects as a
:class:`~sea_daemon.core.dynamics.Dynamics` (the vocabulary's effects as arrays: code, joint,
parameter vector); :class:`ModelTables` hands that to the kernels of
:mod:`sea_daemon.core.dynamics` (:func:`~sea_daemon.core.dynamics.nominal`,
:func:`~sea_daemon.core.dynamics.residual`), where the equations are written once:

    eq:thetadd    θ̈_m = J⁻¹ (κ τ_m + τ_s − D_m θ̇_m − Σ_motor e)
    eq:unknwn_load q̈ = M⁻¹ (τ_h,act − C(q) − Σ_load e − τ_s),   θ̈_s = q̈ − θ̈_m   (eq:xsdd)
    eq:spring_torque τ_s = K_s g(θ_s) + D_s θ̇_s + Σ_spring e(θ_s)

and :func:`lin_error_boxes` samples the linearisation error of f_nom for the bound.
:class:`RigidTables` does the same for a model whose load side is a rigid body of n coupled
joints (a URDF), with G_μ = I_μ M(q)⁻¹ of each step.  Encoder offsets (measurement) and the
delay (input history) stay with the AKF; inertia effects are folded into M and J by SEAModel
(into the body's armature with a URDF).  Effects that evaluate themselves in Python (outside
the vocabulary) are not supported by :class:`ModelTables` (:meth:`ModelTables.supports`).

Pure numerics: no I/O, no clock, no threads.
"""
from __future__ import annotations

import numpy as np

from sea_daemon.core.dynamics import example, load_side_torques, nominal, residual, rigid_lin_error_box
from sea_daemon.core.effects import MAX_PARAMS, Effect, evaluate
from sea_daemon.core.jit import njit, warmer


class ModelTables:
    """The compiled dynamics of a :class:`~sea_daemon.core.model.SEAModel` for the filter."""

    def __init__(self, model):
        #: the model's :class:`~sea_daemon.core.dynamics.Dynamics` (named fields)
        self.params = model.dynamics
        #: the same in the packed form the kernels take
        self.dynamics = model.kernel

    @staticmethod
    def supports(model) -> bool:
        """Every declared effect has its formula in :func:`~sea_daemon.core.effects.evaluate`."""
        return all(type(e).evaluate is Effect.evaluate for e in model.effects)

    def f_and_F(self, x, u, A, xdot) -> None:
        """A = F_nom(x, u), xdot = f_nom(x, u) (in place)."""
        nominal(self.dynamics, x, u, A, xdot, True)

    def lin_error_box(self, X, u, x0, A0) -> np.ndarray:
        """max over the rows of X of |f_nom(x) − f_nom(x0) − A0 (x − x0)| per state (a rounding
        floor makes an exactly linear drift give exactly 0)."""
        b = np.zeros(x0.shape[0])
        lin_error_box(np.ascontiguousarray(X, dtype=float), np.ascontiguousarray(u, dtype=float),
                      np.ascontiguousarray(x0, dtype=float), np.ascontiguousarray(A0, dtype=float),
                      self.dynamics, b)
        return b

    def residual(self, q, dq, ddq, th, dth, ddth, tau, out) -> None:
        """out = f of eq:loadsidewmotor (τ_h,act = 0) with the declared effects."""
        residual(self.dynamics, q, dq, ddq, th, dth, ddth, tau, out)


class RigidTables:
    """The filter's f_nom, F_nom and G_μ = I_μ M⁻¹(q) of a model whose load side is a rigid body of n
    coupled joints (``model.urdf``; :class:`~sea_daemon.core.model.SEAModel` with ``rigid``).

    Per step one call of Pinocchio's ABA derivatives (q̈, ∂q̈/∂q, ∂q̈/∂q̇, M⁻¹ at x̂_{k−1}), around the compiled SEA kernels (:func:`~sea_daemon.core.dynamics.rigid_state`):
    :meth:`f_and_F` writes A = F_nom, ẋ = f_nom and the θ̈_s rows of ``G_mu`` (the filter's
    I_μ M⁻¹) in place; the bound sets the model's ``M``, ``Minv`` at its step's x̂_{k−1}
    (:meth:`~sea_daemon.core.model.SEAModel.at`).  Same interface as :class:`ModelTables`;
    effects outside the vocabulary are included (their Python ``evaluate`` per step).
    """

    def __init__(self, model, G_mu: np.ndarray):
        self.model = model
        self.G_mu = G_mu
        n = self.n = model.n
        self._zero = np.zeros(n)

    def f_and_F(self, x, u, A, xdot) -> None:
        """A = F_nom(x, u), xdot = f_nom(x, u), G_μ = I_μ M(q)⁻¹ (in place)."""
        m, n = self.model, self.n
        q = x[:n] + x[n:2 * n]
        if m.outside_effects:
            f, f_q, f_v = m.outside_torque(q, x[2 * n:3 * n] + x[3 * n:4 * n])
        else:
            f = f_q = f_v = self._zero
        self.G_mu[3 * n:4 * n] = m.rigid_f_and_F(x, u, f, f_q, f_v, A, xdot)

    def lin_error_box(self, X, u, x0, A0) -> np.ndarray:
        """max over the rows x of X of |f_nom(x) − f_nom(x0) − A0 (x − x0)| per state: one ABA per
        point, the rest compiled (:func:`~sea_daemon.core.dynamics.rigid_lin_error_box`; with effects
        outside the vocabulary :func:`sampled_box`)."""
        m, n = self.model, self.n
        if m.outside_effects:
            return sampled_box(m.f_nom, X, u, x0, A0)
        Xa = np.vstack([np.asarray(x0, dtype=float).reshape(1, -1), np.asarray(X, dtype=float)])
        tau = np.empty((Xa.shape[0], n))
        load_side_torques(m.kernel, Xa, tau)
        ddq = m.rigid.forward_many(Xa[:, :n] + Xa[:, n:2 * n], Xa[:, 2 * n:3 * n] + Xa[:, 3 * n:4 * n], tau)
        b = np.zeros(Xa.shape[1])
        rigid_lin_error_box(m.kernel, Xa, np.ascontiguousarray(u, dtype=float), np.ascontiguousarray(A0, dtype=float),
                            ddq, b)
        return b

    def residual(self, q, dq, ddq, th, dth, ddth, tau, out) -> None:
        """out = f of eq:loadsidewmotor (τ_h,act = 0) with the rigid body's inverse dynamics."""
        out[:] = self.model.residual_from_kinematics(q, dq, ddq, th, dth, ddth, tau)


def sampled_box(f_nom, X, u, x0, A0) -> np.ndarray:
    """max over the rows x of X of |f_nom(x, u) − f_nom(x0, u) − A0 (x − x0)| per state, for an
    f_nom in Python (the rounding floor of :func:`lin_error_boxes`: an exactly linear drift gives 0)."""
    f0 = f_nom(x0, u)
    b = np.zeros(x0.shape[0])
    for x in np.asarray(X, dtype=float):
        fx = f_nom(x, u)
        lin = A0 @ (x - x0)
        r = np.abs(fx - f0 - lin)
        r[r <= 1e-12 * (np.abs(fx) + np.abs(f0) + np.abs(lin))] = 0.0
        np.maximum(b, r, out=b)
    return b


@njit
def lin_error_boxes(X, u, x0, A0, p, ell, col, slope, eff_group, eff_code, eff_p, b, b_smooth) -> None:
    """Over the rows x of X: b = max |ε(x)| with ε = f_nom(x) − f_nom(x0) − A0 (x − x0) (what
    :func:`lin_error_box` gives) and b_smooth = max |ε_smooth(x)|, the same for the model
    without the friction groups (the bound's friction candidate,
    AKFTheoremBound._friction_candidate):
    ε_smooth = ε − Σ_g col_g [τ_g(ℓ_gᵀx) − τ_g(ℓ_gᵀx0) − slope_g ℓ_gᵀ(x − x0)], τ_g the sum of the
    effects (eff_code, eff_p) with eff_group = g.  One f_nom evaluation per point for both;
    p the packed :class:`~sea_daemon.core.dynamics.Dynamics`."""
    d = x0.shape[0]
    ng = ell.shape[0]
    f0 = np.empty(d)
    fx = np.empty(d)
    Aw = np.empty((d, d))
    nominal(p, x0, u, Aw, f0, False)
    v0 = np.zeros(ng)
    t0 = np.zeros(ng)
    for g in range(ng):
        for i in range(d):
            v0[g] += ell[g, i] * x0[i]
    for e in range(eff_code.shape[0]):
        t0[eff_group[e]] += evaluate(eff_code[e], eff_p[e], 0.0, v0[eff_group[e]], 0.0)[0]
    fr = np.empty(ng)
    for r in range(X.shape[0]):
        x = X[r]
        nominal(p, x, u, Aw, fx, False)
        # the friction groups' bracket τ_g(v) − τ_g(v̂) − s_g ℓᵀ(x − x̂) at this point
        for g in range(ng):
            v = 0.0
            for i in range(d):
                v += ell[g, i] * x[i]
            fr[g] = -t0[g] - slope[g] * (v - v0[g])
        for e in range(eff_code.shape[0]):
            g = eff_group[e]
            v = 0.0
            for i in range(d):
                v += ell[g, i] * x[i]
            fr[g] += evaluate(eff_code[e], eff_p[e], 0.0, v, 0.0)[0]
        for i in range(d):
            lin = 0.0
            for k in range(d):
                lin += A0[i, k] * (x[k] - x0[k])
            e = fx[i] - f0[i] - lin
            es = e
            for g in range(ng):
                es -= col[g, i] * fr[g]
            # rounding floor, so an exactly linear drift gives exactly 0
            tol = 1e-12 * (abs(fx[i]) + abs(f0[i]) + abs(lin))
            ae = abs(e)
            if ae <= tol:
                ae = 0.0
            aes = abs(es)
            if aes <= tol:
                aes = 0.0
            if ae > b[i]:
                b[i] = ae
            if aes > b_smooth[i]:
                b_smooth[i] = aes


@njit
def lin_error_box(X, u, x0, A0, p, b) -> None:
    """b = max over the rows x of X of |f_nom(x) − f_nom(x0) − A0 (x − x0)| (module docstring):
    :func:`lin_error_boxes` without friction groups."""
    d = x0.shape[0]
    none = np.zeros(0, dtype=np.int64)
    lin_error_boxes(X, u, x0, A0, p, np.zeros((0, d)), np.zeros((0, d)), np.zeros(0), none, none,
                    np.zeros((0, MAX_PARAMS)), b, np.zeros(d))


@warmer
def _warm() -> None:
    """Compile with the types the AKF passes (1 joint; shapes do not change the types)."""
    n, d = 1, 5
    p = example(n).packed()
    lin_error_box(np.zeros((2, d)), np.zeros(n), np.zeros(d), np.zeros((d, d)), p, np.zeros(d))
