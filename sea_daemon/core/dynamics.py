"""The SEA dynamics kernels: the one place the equations of the SEA are written (compiled).

Joint side of the gear, SI; augmented state (Sec. IV-B) x = [θ_m, θ_s, θ̇_m, θ̇_s, τ_h,act] ∈ R^{5n},
q = θ_m + θ_s, input u = τ_m ∈ R^n:

    load side   M(q) q̈ + C(q, q̇) + Σ_load e + f(z) + τ_s = τ_h,act               eq:unknwn_load
    motor side  J θ̈_m + D_m θ̇_m + Σ_motor e − τ_s = κ τ_m                       eq:motorside
    spring      τ_s = K_s g(θ_s) + D_s θ̇_s + Σ_spring e(θ_s),  θ_s = q − θ_m     eq:spring_torque

Σ e are the declared additive effects of docs/interfaces.md §2 (their formulas in
:func:`sea_daemon.core.effects.evaluate`), g the backlash dead band (identity without one), κ
the torque scale, f(z) a residual load torque (the GP's, or a torque outside the effect
vocabulary; zero in the nominal model).  The load side's inertia and bias enter through
:func:`inertia` (M(q), M(q)⁻¹) and :func:`rigid_bias` (C(q, q̇) and its partials): a constant
M and the link's gravity C = gravity ⊙ sin q.  A model of n coupled joints from a URDF
(:class:`~sea_daemon.core.rigid.RigidBody`, Pinocchio, which numba cannot call) takes its
rigid body's part from Pinocchio and the SEA's from here: :func:`load_side_torque` gives the
torque on the body besides its own bias, the body's forward dynamics (ABA) and its derivatives
give q̈, ∂q̈/∂q (with −M⁻¹ (∂M/∂q) q̈), ∂q̈/∂q̇ and M⁻¹, and :func:`rigid_state` assembles f_nom
and F_nom from them (the same :func:`state_rates` and :func:`state_jacobian` as
:func:`f_nom` / :func:`F_nom`); :func:`load_torque_given` and :func:`residual_given` take the
body's inverse dynamics (RNEA).

The kernels take the parameters as one :class:`Dynamics` in its packed form
(:meth:`Dynamics.packed`, a plain tuple: numba types it at C speed; a NamedTuple argument costs
~5 µs per call) and unpack it by name.  Callers: :class:`~sea_daemon.core.model.SEAModel` (the
model's methods), :class:`~sea_daemon.core.model_core.ModelTables` (the filter with declared
effects) and :class:`~sea_daemon.core.model_core.RigidTables` (the filter with a URDF), the
simulator's true plant (:func:`accel_1`), diagnose's spring torque over a log
(:func:`spring_torque_many`).

Two forms keep their own floating-point order (they are what the filter and the simulator
have always computed, and their outputs are compared byte for byte): :func:`nominal_affine` /
:func:`residual_affine`, the nominal model without declared effects as an affine map plus the
gravity term (the AKF's fast path), and :func:`accel_1`, one joint in floats with the link's
gravity summed with the load effects and a division by M (the plant's RK4).
``tests/test_dynamics.py`` checks every kernel against hand-computed values, finite
differences and the general form.

Pure numerics: no I/O, no clock, no threads.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from sea_daemon.core.effects import MAX_PARAMS, deadband, evaluate, side_torque
from sea_daemon.core.jit import njit, warmer


class EffectTable(NamedTuple):
    """One side's additive effects as arrays: formula code (:func:`~sea_daemon.core.effects.evaluate`),
    0-based joint and parameter vector (:attr:`~sea_daemon.core.effects.Effect.vector`)."""

    code: np.ndarray      # (k,) int64
    joint: np.ndarray     # (k,) int64
    P: np.ndarray         # (k, MAX_PARAMS)


def effect_table(effects) -> EffectTable:
    """The :class:`EffectTable` of a sequence of additive vocabulary effects."""
    code = np.array([e.code for e in effects], dtype=np.int64).reshape(-1)
    joint = np.array([e.joint for e in effects], dtype=np.int64).reshape(-1)
    P = np.array([e.vector for e in effects], dtype=float).reshape(len(effects), MAX_PARAMS)
    return EffectTable(code, joint, P)


class Dynamics(NamedTuple):
    """The parameters of the dynamics kernels (n joints; inertia effects already folded in M, J)."""

    M: np.ndarray          # (n, n) load-side inertia [kg m²]                   eq:loadside
    Minv: np.ndarray       # (n, n) M⁻¹
    J: np.ndarray          # (n, n) motor inertia through the gear [kg m²]      eq:motorside
    Jinv: np.ndarray       # (n, n) J⁻¹
    D_m: np.ndarray        # (n, n) motor damping [N m s/rad]                   eq:motorside
    K_s: np.ndarray        # (n, n) spring stiffness [N m/rad]                  eq:spring_torque
    D_s: np.ndarray        # (n, n) spring damping [N m s/rad]                  eq:spring_torque
    gravity: np.ndarray    # (n,) m g l of the link: C(q) = gravity ⊙ sin q [N m]
    kappa: np.ndarray      # (n,) torque scale κ (1: none)
    half_band: np.ndarray  # (n,) backlash half-width [rad] (−1: no dead band)
    load: EffectTable
    motor: EffectTable
    spring: EffectTable

    def packed(self) -> tuple:
        """The plain-tuple form the kernels take (same order, the tables as plain tuples)."""
        return (self.M, self.Minv, self.J, self.Jinv, self.D_m, self.K_s, self.D_s, self.gravity, self.kappa,
                self.half_band, tuple(self.load), tuple(self.motor), tuple(self.spring))


def make_dynamics(M, J, D_m, K_s, D_s, gravity, kappa, half_band, load=(), motor=(), spring=()) -> Dynamics:
    """A :class:`Dynamics` from matrices, vectors and each side's additive vocabulary effects."""
    def mat(a):
        return np.ascontiguousarray(a, dtype=float)

    def vec(a):
        return np.array(a, dtype=float).reshape(-1)
    M, J = mat(M), mat(J)
    return Dynamics(M, mat(np.linalg.inv(M)), J, mat(np.linalg.inv(J)), mat(D_m), mat(K_s), mat(D_s), vec(gravity),
                    vec(kappa), vec(half_band), effect_table(load), effect_table(motor), effect_table(spring))


# ------------------------------------------------------------------ pieces


@njit
def side_sum(tab, angle, vel, tau, d_ang, d_vel) -> None:
    """tau, d_ang, d_vel (n,) = Σ τ, ∂τ/∂angle, ∂τ/∂vel of one side's effects (zero acceleration)."""
    code, joint, P = tab
    tau[:] = 0.0
    d_ang[:] = 0.0
    d_vel[:] = 0.0
    for i in range(code.shape[0]):
        j = joint[i]
        t, pa, pv, _ = evaluate(code[i], P[i], angle[j], vel[j], 0.0)
        tau[j] += t
        d_ang[j] += pa
        d_vel[j] += pv


@njit
def side_torques(tab, angle, vel):
    """(Σ τ, Σ ∂τ/∂angle, Σ ∂τ/∂vel) of one side's effects, each (n,) (:func:`side_sum`)."""
    n = angle.shape[0]
    tau, d_ang, d_vel = np.empty(n), np.empty(n), np.empty(n)
    side_sum(tab, angle, vel, tau, d_ang, d_vel)
    return tau, d_ang, d_vel


@njit
def inertia(p, q):
    """(M(q), M(q)⁻¹) of the load side (eq:loadside); constant for the one-joint link."""
    M, Minv, J, Jinv, D_m, K_s, D_s, gravity, kappa, half_band, load, motor, spring = p
    return M, Minv


@njit
def rigid_bias(p, q, dq):
    """C(q, q̇) of the load side (eq:loadside): the link's gravity, gravity ⊙ sin q."""
    M, Minv, J, Jinv, D_m, K_s, D_s, gravity, kappa, half_band, load, motor, spring = p
    return gravity * np.sin(q)


@njit
def rigid_bias_jac(p, q, dq):
    """(∂C/∂q, ∂C/∂q̇), each (n, n), of :func:`rigid_bias`."""
    M, Minv, J, Jinv, D_m, K_s, D_s, gravity, kappa, half_band, load, motor, spring = p
    n = q.shape[0]
    return np.diag(gravity * np.cos(q)), np.zeros((n, n))


@njit
def deflection(p, th_s):
    """(g(θ_s), g'(θ_s)), each (n,): the backlash dead band, identity where none is declared."""
    M, Minv, J, Jinv, D_m, K_s, D_s, gravity, kappa, half_band, load, motor, spring = p
    n = th_s.shape[0]
    g = np.empty(n)
    dg = np.empty(n)
    for j in range(n):
        if half_band[j] >= 0.0:
            g[j], dg[j] = deadband(th_s[j], half_band[j])
        else:
            g[j], dg[j] = th_s[j], 1.0
    return g, dg


# ------------------------------------------------------------------ spring


@njit
def spring_torque(p, th_s, dth_s):
    """τ_s (n,) with the declared spring effects."""
    M, Minv, J, Jinv, D_m, K_s, D_s, gravity, kappa, half_band, load, motor, spring = p
    g, dg = deflection(p, th_s)
    se, dse, _ = side_torques(spring, th_s, np.zeros(th_s.shape[0]))
    # eq:spring_torque: τ_s = K_s g(θ_s) + D_s θ̇_s + Σ_spring e(θ_s)
    return K_s @ g + D_s @ dth_s + se


@njit
def spring_torque_jac(p, th_s):
    """∂τ_s/∂θ_s (n, n) (∂τ_s/∂θ̇_s is D_s)."""
    M, Minv, J, Jinv, D_m, K_s, D_s, gravity, kappa, half_band, load, motor, spring = p
    n = th_s.shape[0]
    g, dg = deflection(p, th_s)
    se, dse, _ = side_torques(spring, th_s, np.zeros(n))
    # eq:spring_torque: ∂τ_s/∂θ_s = K_s diag(g') + diag(∂Σ_spring e/∂θ_s)
    dts = K_s * dg.reshape(1, n)
    for j in range(n):
        dts[j, j] += dse[j]
    return dts


@njit
def spring_torque_many(p, th_s, dth_s, out) -> None:
    """out[k] = τ_s at sample k of (N, n) arrays θ_s, θ̇_s (:func:`spring_torque` over a log)."""
    for k in range(th_s.shape[0]):
        out[k] = spring_torque(p, th_s[k], dth_s[k])


# ------------------------------------------------------------------ motor side


@njit
def motor_accel(p, th_m, dth_m, u, tau_s):
    """θ̈_m (n,) for the motor torque u = τ_m and spring torque τ_s."""
    M, Minv, J, Jinv, D_m, K_s, D_s, gravity, kappa, half_band, load, motor, spring = p
    mo, _, _ = side_torques(motor, th_m, dth_m)
    # eq:thetadd (eq:motorside solved for θ̈_m): θ̈_m = J⁻¹ (κ τ_m + τ_s − D_m θ̇_m − Σ_motor e)
    return Jinv @ (kappa * u + tau_s - D_m @ dth_m - mo)


@njit
def motor_accel_jac(p, th_m, dth_m, dts):
    """∂θ̈_m/∂(θ_m, θ_s, θ̇_m, θ̇_s), four (n, n) blocks (∂/∂τ_h,act = 0); dts = ∂τ_s/∂θ_s."""
    M, Minv, J, Jinv, D_m, K_s, D_s, gravity, kappa, half_band, load, motor, spring = p
    _, dmo_a, dmo_v = side_torques(motor, th_m, dth_m)
    # eq:thetadd differentiated
    am0 = Jinv @ -np.diag(dmo_a)
    am1 = Jinv @ dts
    am2 = Jinv @ (-D_m - np.diag(dmo_v))
    am3 = Jinv @ D_s
    return am0, am1, am2, am3


# ------------------------------------------------------------------ load side


@njit
def load_accel(p, q, dq, tau_h, tau_s, f):
    """q̈ (n,) for τ_h,act, τ_s and a residual load torque f (zeros: the nominal model)."""
    M, Minv = inertia(p, q)
    _, _, _, _, _, _, _, _, _, _, load, _, _ = p
    lo, _, _ = side_torques(load, q, dq)
    # eq:unknwn_load solved for q̈: q̈ = M⁻¹ (τ_h,act − C(q, q̇) − Σ_load e − τ_s − f(z))
    return Minv @ (tau_h - rigid_bias(p, q, dq) - lo - tau_s - f)


@njit
def load_accel_jac(p, q, dq, dts, f_q, f_v):
    """∂q̈/∂(θ_m, θ_s, θ̇_m, θ̇_s, τ_h,act), five (n, n) blocks; dts = ∂τ_s/∂θ_s, f_q and f_v
    (n,) the partials of the residual load torque f by q and q̇ (zeros: nominal model)."""
    M, Minv = inertia(p, q)
    _, _, _, _, _, _, D_s, _, _, _, load, _, _ = p
    _, dlo_a, dlo_v = side_torques(load, q, dq)
    Cq, Cv = rigid_bias_jac(p, q, dq)
    # ∂(C + Σ_load e + f)/∂q and /∂q̇ (q = θ_m + θ_s, q̇ = θ̇_m + θ̇_s)
    dCq = Cq + np.diag(dlo_a + f_q)
    dLv = Cv + np.diag(dlo_v + f_v)
    # eq:unknwn_load differentiated (constant M)
    aq0 = Minv @ -dCq
    aq1 = Minv @ (-dCq - dts)
    aq2 = Minv @ -dLv
    aq3 = Minv @ (-dLv - D_s)
    return aq0, aq1, aq2, aq3, Minv


@njit
def load_torque(p, q, dq, ddq):
    """τ_l(z) = M q̈ + C(q, q̇) plus the declared load effects (eq:loadsidewmotor)."""
    M, Minv = inertia(p, q)
    return load_torque_given(p, q, dq, M @ ddq + rigid_bias(p, q, dq))


@njit
def load_torque_given(p, q, dq, tau_rigid):
    """τ_l(z) = τ_rigid plus the declared load effects, τ_rigid = M(q) q̈ + C(q, q̇) the rigid
    body's inverse dynamics (eq:loadsidewmotor; a rigid body from a URDF gives it by RNEA)."""
    _, _, _, _, _, _, _, _, _, _, load, _, _ = p
    lo, _, _ = side_torques(load, q, dq)
    return tau_rigid + lo


@njit
def load_side_torque(p, x, f):
    """τ_h,act − Σ_load e − τ_s − f (n,) at the state x: the torque on the rigid body besides its own
    bias, so that q̈ = M(q)⁻¹ (τ − C(q, q̇)) (eq:unknwn_load; a URDF's forward dynamics takes it)."""
    n = f.shape[0]
    _, _, _, _, _, _, _, _, _, _, load, _, _ = p
    q = x[:n] + x[n:2 * n]
    dq = x[2 * n:3 * n] + x[3 * n:4 * n]
    tau_s = spring_torque(p, x[n:2 * n], x[3 * n:4 * n])
    lo, _, _ = side_torques(load, q, dq)
    return x[4 * n:5 * n] - lo - tau_s - f


# ------------------------------------------------------------------ state space


@njit
def f_nom(p, x, u, f, xdot) -> None:
    """xdot = f_nom(x, u) − I_μ M⁻¹ f (eq:nonlindyn, eq:unknown); f (n,) the residual load torque."""
    n = u.shape[0]
    th_m = x[:n]
    th_s = x[n:2 * n]
    dth_m = x[2 * n:3 * n]
    dth_s = x[3 * n:4 * n]
    tau_h = x[4 * n:5 * n]
    q = th_m + th_s
    dq = dth_m + dth_s
    tau_s = spring_torque(p, th_s, dth_s)
    ddth_m = motor_accel(p, th_m, dth_m, u, tau_s)
    ddq = load_accel(p, q, dq, tau_h, tau_s, f)
    state_rates(n, dth_m, dth_s, ddth_m, ddq, xdot)
    torque_rate_rows(n, x, xdot)


@njit
def load_side_torques(p, X, out) -> None:
    """out[k] = :func:`load_side_torque` at the row k of X (f = 0): the rigid body's torques at many states."""
    f = np.zeros(out.shape[1])
    for k in range(X.shape[0]):
        out[k] = load_side_torque(p, X[k], f)


@njit
def rigid_lin_error_box(p, X, u, A0, DDQ, b) -> None:
    """b = max over the rows x of X[1:] of |f_nom(x) − f_nom(x0) − A0 (x − x0)| per state, x0 = X[0],
    for a model with a rigid body whose q̈ at the rows are DDQ (:func:`rigid_state`; the rounding
    floor of :func:`~sea_daemon.core.model_core.lin_error_boxes`: an exactly linear drift gives 0)."""
    d = X.shape[1]
    none = np.zeros((0, 0))
    f0 = np.empty(d)
    fx = np.empty(d)
    v = np.zeros(0)
    rigid_state(p, X[0], u, DDQ[0], none, none, none, v, v, none, f0, False)
    for r in range(1, X.shape[0]):
        rigid_state(p, X[r], u, DDQ[r], none, none, none, v, v, none, fx, False)
        for i in range(d):
            lin = 0.0
            for k in range(d):
                lin += A0[i, k] * (X[r, k] - X[0, k])
            e = abs(fx[i] - f0[i] - lin)
            if e <= 1e-12 * (abs(fx[i]) + abs(f0[i]) + abs(lin)):
                e = 0.0
            if e > b[i]:
                b[i] = e


@njit
def state_rates(n, dth_m, dth_s, ddth_m, ddq, xdot) -> None:
    """xdot = [θ̇_m, θ̇_s, θ̈_m, q̈ − θ̈_m, 0] (eq:xsdd; a zero-order model of τ_h,act)."""
    for j in range(n):
        xdot[j] = dth_m[j]
        xdot[n + j] = dth_s[j]
        xdot[2 * n + j] = ddth_m[j]
        # eq:xsdd: θ̈_s = q̈ − θ̈_m
        xdot[3 * n + j] = ddq[j] - ddth_m[j]
        xdot[4 * n + j] = 0.0               # zero-order model of τ_h,act


@njit
def torque_rate_rows(n, x, xdot) -> None:
    """The integrated random walk of τ_h,act (a state of 6n, ``estimator.tau_h_act_model:
    integrated``): dτ_h,act/dt = τ̇_h,act, dτ̇_h,act/dt = 0 (the τ̇ rows after the 5n of
    :func:`state_rates`); nothing for the random walk's 5n."""
    for j in range(xdot.shape[0] - 5 * n):
        xdot[4 * n + j] = x[5 * n + j]
        xdot[5 * n + j] = 0.0


@njit
def F_nom(p, x, u, f_q, f_v, A) -> None:
    """A = ∂f_nom/∂x (5n × 5n) (eq:linearization without the GP); f_q, f_v as :func:`load_accel_jac`."""
    n = u.shape[0]
    th_m = x[:n]
    th_s = x[n:2 * n]
    dth_m = x[2 * n:3 * n]
    dth_s = x[3 * n:4 * n]
    q = th_m + th_s
    dq = dth_m + dth_s
    dts = spring_torque_jac(p, th_s)
    am0, am1, am2, am3 = motor_accel_jac(p, th_m, dth_m, dts)
    aq0, aq1, aq2, aq3, aq4 = load_accel_jac(p, q, dq, dts, f_q, f_v)
    state_jacobian(n, am0, am1, am2, am3, aq0, aq1, aq2, aq3, aq4, A)


@njit
def state_jacobian(n, am0, am1, am2, am3, aq0, aq1, aq2, aq3, aq4, A) -> None:
    """A = ∂f_nom/∂x from the (n, n) blocks ∂θ̈_m/∂(θ_m, θ_s, θ̇_m, θ̇_s) and ∂q̈/∂(θ_m, θ_s, θ̇_m,
    θ̇_s, τ_h,act) (eq:xsdd: the θ̈_s rows are their difference)."""
    A[:] = 0.0
    for j in range(n):
        A[j, 2 * n + j] = 1.0
        A[n + j, 3 * n + j] = 1.0
    for j in range(A.shape[0] - 5 * n):     # the integrated random walk: dτ_h,act/dt = τ̇_h,act (torque_rate_rows)
        A[4 * n + j, 5 * n + j] = 1.0
    for i in range(n):
        for j in range(n):
            A[2 * n + i, j] = am0[i, j]
            A[2 * n + i, n + j] = am1[i, j]
            A[2 * n + i, 2 * n + j] = am2[i, j]
            A[2 * n + i, 3 * n + j] = am3[i, j]
            # eq:xsdd: ∂θ̈_s = ∂q̈ − ∂θ̈_m
            A[3 * n + i, j] = aq0[i, j] - am0[i, j]
            A[3 * n + i, n + j] = aq1[i, j] - am1[i, j]
            A[3 * n + i, 2 * n + j] = aq2[i, j] - am2[i, j]
            A[3 * n + i, 3 * n + j] = aq3[i, j] - am3[i, j]
            A[3 * n + i, 4 * n + j] = aq4[i, j]


@njit
def rigid_state(p, x, u, ddq, ddq_dq, ddq_dv, Minv, f_q, f_v, A, xdot, jacobian: bool) -> None:
    """xdot = f_nom(x, u) and, with ``jacobian``, A = F_nom(x, u) of a model whose load side is a
    rigid body of n coupled joints (a URDF): its forward dynamics q̈ = M(q)⁻¹ (τ − C(q, q̇)) at
    τ = :func:`load_side_torque` comes in with ∂q̈/∂q, ∂q̈/∂q̇ at fixed τ and M(q)⁻¹ = ∂q̈/∂τ
    (:meth:`~sea_daemon.core.rigid.RigidBody.forward_derivatives`); the chain rule through τ
    (Σ_load e, τ_s, the residual f with partials f_q, f_v) is added here (eq:unknwn_load,
    eq:linearization; the −M⁻¹ (∂M/∂q) q̈ term of a configuration-dependent M is in ∂q̈/∂q)."""
    n = u.shape[0]
    M, Minv0, J, Jinv, D_m, K_s, D_s, gravity, kappa, half_band, load, motor, spring = p
    th_m = x[:n]
    th_s = x[n:2 * n]
    dth_m = x[2 * n:3 * n]
    dth_s = x[3 * n:4 * n]
    tau_s = spring_torque(p, th_s, dth_s)
    ddth_m = motor_accel(p, th_m, dth_m, u, tau_s)
    state_rates(n, dth_m, dth_s, ddth_m, ddq, xdot)
    torque_rate_rows(n, x, xdot)
    if not jacobian:
        return
    dts = spring_torque_jac(p, th_s)
    am0, am1, am2, am3 = motor_accel_jac(p, th_m, dth_m, dts)
    _, dlo_a, dlo_v = side_torques(load, th_m + th_s, dth_m + dth_s)
    # q̈ = ABA(q, q̇, τ), τ = τ_h,act − Σ_load e(q, q̇) − τ_s(θ_s, θ̇_s) − f: ∂q̈/∂x = ∂q̈/∂q ∂q/∂x
    # + ∂q̈/∂q̇ ∂q̇/∂x + M⁻¹ ∂τ/∂x (q = θ_m + θ_s, q̇ = θ̇_m + θ̇_s)
    Lq = ddq_dq - Minv @ np.diag(dlo_a + f_q)
    Lv = ddq_dv - Minv @ np.diag(dlo_v + f_v)
    state_jacobian(n, am0, am1, am2, am3, Lq, Lq - Minv @ dts, Lv, Lv - Minv @ D_s, Minv, A)


@njit
def nominal(p, x, u, A, xdot, jacobian: bool) -> None:
    """xdot = f_nom(x, u) and, with ``jacobian``, A = F_nom(x, u) of the nominal model (f = 0)."""
    z = np.zeros(u.shape[0])
    f_nom(p, x, u, z, xdot)
    if jacobian:
        F_nom(p, x, u, z, z, A)


@njit
def residual(p, q, dq, ddq, th, dth, ddth, tau, out) -> None:
    """out = f(z) of eq:loadsidewmotor with ass:passive_human (τ_h,act = 0)."""
    M, Minv = inertia(p, q)
    residual_given(p, q, dq, M @ ddq + rigid_bias(p, q, dq), th, dth, ddth, tau, out)


@njit
def residual_given(p, q, dq, tau_rigid, th, dth, ddth, tau, out) -> None:
    """:func:`residual` with the rigid body's inverse dynamics τ_rigid = M(q) q̈ + C(q, q̇) given."""
    M, Minv, J, Jinv, D_m, K_s, D_s, gravity, kappa, half_band, load, motor, spring = p
    mo, _, _ = side_torques(motor, th, dth)
    # eq:loadsidewmotor: f = κ τ_m − (τ_l(z) + J θ̈_m + D_m θ̇_m + Σ_motor e),  τ_l = M q̈ + C + Σ_load e
    r = kappa * tau - (load_torque_given(p, q, dq, tau_rigid) + J @ ddth + D_m @ dth + mo)
    for j in range(q.shape[0]):
        out[j] = r[j]


# ------------------------------------------------------------------ specialised forms


@njit
def accel_1(p, q, th, dq, dth, u, tau_h):
    """(q̈, θ̈_m) of one joint in floats (the simulator's RK4; f = 0): the link's gravity is
    summed first with the load effects, and q̈ divides by M."""
    M, Minv, J, Jinv, D_m, K_s, D_s, gravity, kappa, half_band, load, motor, spring = p
    ths = q - th
    dths = dq - dth
    hb = half_band[0]
    g = ths if hb <= 0.0 else deadband(ths, hb)[0]
    # eq:spring_torque
    tau_s = K_s[0, 0] * g + D_s[0, 0] * dths + side_torque(spring[0], spring[2], ths, 0.0)
    # eq:thetadd
    ddth = (kappa[0] * u + tau_s - D_m[0, 0] * dth - side_torque(motor[0], motor[2], th, dth)) / J[0, 0]
    # eq:unknwn_load solved for q̈: C(q) = gravity sin q, then the load effects
    lo = 0.0
    if gravity[0] != 0.0:
        lo += gravity[0] * math.sin(q)
    code, _, P = load
    for i in range(code.shape[0]):
        lo += evaluate(code[i], P[i], q, dq, 0.0)[0]
    ddq = (tau_h - lo - tau_s) / M[0, 0]
    return ddq, ddth


@njit
def nominal_affine(x, u, A_lin, B_lin, MinvG, A, xdot):
    """A = F_nom(x, u), xdot = f_nom(x, u) of the nominal model without declared effects.

    f_nom(x, u) = A_lin x + B u − I_μ M⁻¹ g ⊙ sin q,  F_nom = A_lin − I_μ M⁻¹ diag(g cos q) ∂q/∂x,
    q = θ_m + θ_s (eq:nonlindyn with C(q) = g ⊙ sin q); A_lin, B_lin the constant blocks of
    :func:`F_nom`, MinvG = M⁻¹ diag(g).
    """
    n = u.shape[0]
    d = x.shape[0]
    A[:, :] = A_lin
    # eq:nonlindyn, affine part
    for i in range(d):
        s = 0.0
        for j in range(d):
            s += A_lin[i, j] * x[j]
        for j in range(n):
            s += B_lin[i, j] * u[j]
        xdot[i] = s
    for j in range(n):
        q = x[j] + x[n + j]
        c = math.cos(q)
        sn = math.sin(q)
        for i in range(n):
            # ∂(−M⁻¹ C(q))/∂θ_m = ∂/∂θ_s = −M⁻¹ diag(g cos q)   (θ̈_s rows, eq:xsdd)
            A[3 * n + i, j] -= MinvG[i, j] * c
            A[3 * n + i, n + j] -= MinvG[i, j] * c
            # −M⁻¹ C(q) in the θ̈_s rows (eq:xsdd)
            xdot[3 * n + i] -= MinvG[i, j] * sn


@njit
def residual_affine(q, dq, ddq, dth, ddth, tau, M, gravity, J, D_m, f):
    """f = τ_m − (M q̈ + g ⊙ sin q + J θ̈_m + D_m θ̇_m): eq:loadsidewmotor with ass:passive_human
    (τ_h,act = 0) for the nominal model without declared effects (training target)."""
    n = f.shape[0]
    for i in range(n):
        s = tau[i] - gravity[i] * math.sin(q[i])
        for j in range(n):
            s -= M[i, j] * ddq[j] + J[i, j] * ddth[j] + D_m[i, j] * dth[j]
        f[i] = s


def example(n: int = 1) -> Dynamics:
    """A small :class:`Dynamics` of n joints without effects (unit matrices), for compiling."""
    I = np.eye(n)
    v = np.zeros(n)
    return make_dynamics(I, I, I, I, I, v, np.ones(n), np.full(n, -1.0))


@warmer
def _warm() -> None:
    """Compile with the types the model, the filter and the plant pass (1 joint)."""
    n, d = 1, 5
    p = example(n).packed()
    v = np.zeros(n)
    A, xdot = np.zeros((d, d)), np.zeros(d)
    nominal(p, np.zeros(d), v, A, xdot, True)
    f_nom(p, np.zeros(d), v, v, xdot)
    F_nom(p, np.zeros(d), v, v, v, A)
    residual(p, v, v, v, v, v, v, v, np.zeros(n))
    residual_given(p, v, v, v, v, v, v, v, np.zeros(n))
    load_side_torque(p, np.zeros(d), v)
    load_side_torques(p, np.zeros((2, d)), np.zeros((2, n)))
    rigid_lin_error_box(p, np.zeros((2, d)), v, np.zeros((d, d)), np.zeros((2, n)), np.zeros(d))
    rigid_state(p, np.zeros(d), v, v, np.eye(n), np.eye(n), np.eye(n), v, v, A, xdot, True)
    load_torque(p, v, v, v)
    load_torque_given(p, v, v, v)
    load_accel(p, v, v, v, v, v)
    motor_accel(p, v, v, v, v)
    spring_torque(p, v, v)
    spring_torque_jac(p, v)
    spring_torque_many(p, np.zeros((2, n)), np.zeros((2, n)), np.zeros((2, n)))
    side_torques(p[10], v, v)
    accel_1(p, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    nominal_affine(np.zeros(d), v, np.zeros((d, d)), np.zeros((d, n)), np.zeros((n, n)), A, xdot)
    residual_affine(v, v, v, v, v, v, np.eye(n), v, np.eye(n), np.eye(n), np.zeros(n))
