"""Compiled f_nom, F_nom and training residual of a model WITH declared effects.

:class:`~sea_daemon.core.model.SEAModel` sums the declared effects in Python (one call of the
compiled :func:`~sea_daemon.core.effects.evaluate` per effect and side), ~100 µs per AKF step
once ``diagnose`` has added the effects a calibration finds.  :class:`ModelTables` packs each
side's additive effects into arrays (code, joint, parameter vector; :attr:`Effect.vector`) and
the structural ones that act in the dynamics (the backlash dead band, the torque scale κ);
the kernels below loop over them and call :func:`~sea_daemon.core.effects.evaluate` — every
effect's formula stays written once, there — to form exactly what ``SEAModel.f_nom``,
``SEAModel.F_nom`` and ``SEAModel.residual_from_kinematics`` form (tests check equality):

    eq:thetadd    θ̈_m = J⁻¹ (κ τ_m + τ_s − D_m θ̇_m − Σ_motor e)
    eq:unknwn_load q̈ = M⁻¹ (τ_h,act − C(q) − Σ_load e − τ_s),   θ̈_s = q̈ − θ̈_m   (eq:xsdd)
    eq:spring_torque τ_s = K_s g(θ_s) + D_s θ̇_s + Σ_spring e(θ_s)

Encoder offsets (measurement) and the delay (input history) stay with the AKF; inertia effects
are folded into M and J by SEAModel.  Effects that evaluate themselves in Python (outside the
vocabulary) are not supported here (:meth:`ModelTables.supports`).

Pure numerics: no I/O, no clock, no threads.
"""
from __future__ import annotations

import numpy as np

from sea_daemon.core.effects import MAX_PARAMS, Effect, deadband, evaluate
from sea_daemon.core.jit import njit, warmer


def _table(effects) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    codes = np.array([e.code for e in effects], dtype=np.int64).reshape(-1)
    joints = np.array([e.joint for e in effects], dtype=np.int64).reshape(-1)
    P = np.array([e.vector for e in effects], dtype=float).reshape(len(effects), MAX_PARAMS)
    return codes, joints, P


class ModelTables:
    """The declared effects of a :class:`~sea_daemon.core.model.SEAModel` as arrays for the kernels."""

    def __init__(self, model):
        self.load = _table(model.load_effects)
        self.motor = _table(model.motor_effects)
        self.spring = _table(model.spring_effects)
        n = model.n
        self.half_band = np.full(n, -1.0)          # backlash half-width per joint (−1: none)
        for j, e in model.backlash.items():
            self.half_band[j] = 0.5 * e.width
        self.kappa = np.asarray(model.kappa, dtype=float).copy()
        self.M, self.Minv = np.ascontiguousarray(model.M), np.ascontiguousarray(model.Minv)
        self.J, self.Jinv = np.ascontiguousarray(model.J), np.ascontiguousarray(model.Jinv)
        self.D_m, self.K_s, self.D_s = (np.ascontiguousarray(a, dtype=float) for a in (model.D_m, model.K_s, model.D_s))
        self.gravity = np.asarray(model.gravity, dtype=float).copy()
        self._args = (self.Minv, self.Jinv, self.D_m, self.K_s, self.D_s, self.gravity, self.kappa,
                      self.half_band, *self.load, *self.motor, *self.spring)

    @staticmethod
    def supports(model) -> bool:
        """Every declared effect has its formula in :func:`~sea_daemon.core.effects.evaluate`."""
        return all(type(e).evaluate is Effect.evaluate for e in model.effects)

    def f_and_F(self, x, u, A, xdot) -> None:
        """A = F_nom(x, u), xdot = f_nom(x, u) (in place)."""
        nominal(x, u, *self._args, A, xdot, True)

    def lin_error_box(self, X, u, x0, A0) -> np.ndarray:
        """max over the rows of X of |f_nom(x) − f_nom(x0) − A0 (x − x0)| per state (a rounding
        floor makes an exactly linear drift give exactly 0)."""
        b = np.zeros(x0.shape[0])
        lin_error_box(np.ascontiguousarray(X, dtype=float), np.ascontiguousarray(u, dtype=float),
                      np.ascontiguousarray(x0, dtype=float), np.ascontiguousarray(A0, dtype=float),
                      *self._args, b)
        return b

    def residual(self, q, dq, ddq, th, dth, ddth, tau, out) -> None:
        """out = f of eq:loadsidewmotor (τ_h,act = 0) with the declared effects."""
        residual(q, dq, ddq, th, dth, ddth, tau, self.M, self.J, self.D_m, self.gravity, self.kappa,
                 *self.load, *self.motor, out)


@njit
def _side_sum(codes, joints, P, angle, vel, tau, d_ang, d_vel) -> None:
    """tau, d_ang, d_vel (n,) = Σ τ, ∂τ/∂angle, ∂τ/∂vel of one side's effects (zero acceleration)."""
    tau[:] = 0.0
    d_ang[:] = 0.0
    d_vel[:] = 0.0
    for i in range(codes.shape[0]):
        j = joints[i]
        t, pa, pv, _ = evaluate(codes[i], P[i], angle[j], vel[j], 0.0)
        tau[j] += t
        d_ang[j] += pa
        d_vel[j] += pv


@njit
def nominal(x, u, Minv, Jinv, D_m, K_s, D_s, gravity, kappa, half_band, lc, lj, lP, mc, mj, mP, sc, sj, sP,
            A, xdot, jacobian: bool) -> None:
    """xdot = f_nom(x, u) and, with ``jacobian``, A = F_nom(x, u) (module docstring)."""
    n = Minv.shape[0]
    th_m = x[:n]
    th_s = x[n:2 * n]
    dth_m = x[2 * n:3 * n]
    dth_s = x[3 * n:4 * n]
    tau_h = x[4 * n:5 * n]
    q = th_m + th_s
    dq = dth_m + dth_s
    # spring (eq:spring_torque): dead band g(θ_s), its slope, and the spring effects at θ_s
    g = np.empty(n)
    dg = np.empty(n)
    for j in range(n):
        if half_band[j] >= 0.0:
            g[j], dg[j] = deadband(th_s[j], half_band[j])
        else:
            g[j], dg[j] = th_s[j], 1.0
    se, dse, tmp = np.empty(n), np.empty(n), np.empty(n)
    _side_sum(sc, sj, sP, th_s, np.zeros(n), se, dse, tmp)
    tau_s = K_s @ g + D_s @ dth_s + se
    mo, dmo_a, dmo_v = np.empty(n), np.empty(n), np.empty(n)
    _side_sum(mc, mj, mP, th_m, dth_m, mo, dmo_a, dmo_v)
    lo, dlo_a, dlo_v = np.empty(n), np.empty(n), np.empty(n)
    _side_sum(lc, lj, lP, q, dq, lo, dlo_a, dlo_v)
    # eq:thetadd, eq:unknwn_load solved for q̈, eq:xsdd
    ddth_m = Jinv @ (kappa * u + tau_s - D_m @ dth_m - mo)
    ddq = Minv @ (tau_h - gravity * np.sin(q) - lo - tau_s)
    for j in range(n):
        xdot[j] = dth_m[j]
        xdot[n + j] = dth_s[j]
        xdot[2 * n + j] = ddth_m[j]
        xdot[3 * n + j] = ddq[j] - ddth_m[j]
        xdot[4 * n + j] = 0.0               # zero-order model of τ_h,act
    if not jacobian:
        return
    # ∂τ_s/∂θ_s
    dts = K_s * dg.reshape(1, n)
    for j in range(n):
        dts[j, j] += dse[j]
    dCq = np.diag(gravity * np.cos(q) + dlo_a)
    dLv = np.diag(dlo_v)
    A[:] = 0.0
    for j in range(n):
        A[j, 2 * n + j] = 1.0
        A[n + j, 3 * n + j] = 1.0
    am0 = Jinv @ -np.diag(dmo_a)
    am1 = Jinv @ dts
    am2 = Jinv @ (-D_m - np.diag(dmo_v))
    am3 = Jinv @ D_s
    aq0 = Minv @ -dCq
    aq1 = Minv @ (-dCq - dts)
    aq2 = Minv @ -dLv
    aq3 = Minv @ (-dLv - D_s)
    for i in range(n):
        for j in range(n):
            A[2 * n + i, j] = am0[i, j]
            A[2 * n + i, n + j] = am1[i, j]
            A[2 * n + i, 2 * n + j] = am2[i, j]
            A[2 * n + i, 3 * n + j] = am3[i, j]
            A[3 * n + i, j] = aq0[i, j] - am0[i, j]
            A[3 * n + i, n + j] = aq1[i, j] - am1[i, j]
            A[3 * n + i, 2 * n + j] = aq2[i, j] - am2[i, j]
            A[3 * n + i, 3 * n + j] = aq3[i, j] - am3[i, j]
            A[3 * n + i, 4 * n + j] = Minv[i, j]


@njit
def lin_error_boxes(X, u, x0, A0, Minv, Jinv, D_m, K_s, D_s, gravity, kappa, half_band, lc, lj, lP, mc, mj, mP,
                    sc, sj, sP, ell, col, slope, eff_group, eff_code, eff_p, b, b_smooth) -> None:
    """Over the rows x of X: b = max |ε(x)| with ε = f_nom(x) − f_nom(x0) − A0 (x − x0) (what
    :func:`lin_error_box` gives) and b_smooth = max |ε_smooth(x)|, the same for the model
    without the friction groups (the bound's friction candidate, AKFTheoremBound._friction_candidate):
    ε_smooth = ε − Σ_g col_g [τ_g(ℓ_gᵀx) − τ_g(ℓ_gᵀx0) − slope_g ℓ_gᵀ(x − x0)], τ_g the sum of the
    effects (eff_code, eff_p) with eff_group = g.  One f_nom evaluation per point for both."""
    d = x0.shape[0]
    ng = ell.shape[0]
    f0 = np.empty(d)
    fx = np.empty(d)
    Aw = np.empty((d, d))
    nominal(x0, u, Minv, Jinv, D_m, K_s, D_s, gravity, kappa, half_band, lc, lj, lP, mc, mj, mP, sc, sj, sP,
            Aw, f0, False)
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
        nominal(x, u, Minv, Jinv, D_m, K_s, D_s, gravity, kappa, half_band, lc, lj, lP, mc, mj, mP, sc, sj, sP,
                Aw, fx, False)
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
def lin_error_box(X, u, x0, A0, Minv, Jinv, D_m, K_s, D_s, gravity, kappa, half_band, lc, lj, lP, mc, mj, mP,
                  sc, sj, sP, b) -> None:
    """b = max over the rows x of X of |f_nom(x) − f_nom(x0) − A0 (x − x0)| (module docstring):
    :func:`lin_error_boxes` without friction groups."""
    d = x0.shape[0]
    none = np.zeros(0, dtype=np.int64)
    lin_error_boxes(X, u, x0, A0, Minv, Jinv, D_m, K_s, D_s, gravity, kappa, half_band, lc, lj, lP, mc, mj, mP,
                    sc, sj, sP, np.zeros((0, d)), np.zeros((0, d)), np.zeros(0), none, none, np.zeros((0, 1)), b,
                    np.zeros(d))


@njit
def residual(q, dq, ddq, th, dth, ddth, tau, M, J, D_m, gravity, kappa, lc, lj, lP, mc, mj, mP, out) -> None:
    """out = κ τ_m − (M q̈ + C(q) + Σ_load e + J θ̈_m + D_m θ̇_m + Σ_motor e): eq:loadsidewmotor with
    ass:passive_human (τ_h,act = 0)."""
    n = M.shape[0]
    lo, a1, v1 = np.empty(n), np.empty(n), np.empty(n)
    _side_sum(lc, lj, lP, q, dq, lo, a1, v1)
    mo, a2, v2 = np.empty(n), np.empty(n), np.empty(n)
    _side_sum(mc, mj, mP, th, dth, mo, a2, v2)
    r = kappa * tau - (M @ ddq + gravity * np.sin(q) + lo + J @ ddth + D_m @ dth + mo)
    for j in range(n):
        out[j] = r[j]


@warmer
def _warm() -> None:
    """Compile with the types the AKF passes (1 joint; shapes do not change the types)."""
    n, d = 1, 5
    e = np.zeros(0, dtype=np.int64)
    P = np.zeros((0, MAX_PARAMS))
    I = np.eye(n)
    v = np.zeros(n)
    tabs = (I, I, I, I, I, v, np.ones(n), np.full(n, -1.0), e, e, P, e, e, P, e, e, P)
    nominal(np.zeros(d), v, *tabs, np.zeros((d, d)), np.zeros(d), True)
    lin_error_box(np.zeros((2, d)), v, np.zeros(d), np.zeros((d, d)), *tabs, np.zeros(d))
    residual(v, v, v, v, v, v, v, I, I, I, v, np.ones(n), e, e, P, e, e, P, np.zeros(n))
