"""SEA dynamics for n joints (paper ``eq:sea``, ``eq:spring_torque``, ``eq:unknwn_load``).

Pure numerics: no I/O, no clock, no threads.  Everything on the joint side of the gear, SI.

Augmented state (Sec. IV-B):  x = [θ_m, θ_s, θ̇_m, θ̇_s, τ_h,act]  ∈ R^{5n},  u = τ_m ∈ R^n.

Load side    M q̈ + C(q) + Σ_load e(q, q̇, q̈) + f(z) + τ_s = τ_h,act          eq:unknwn_load
Motor side   J θ̈_m + D_m θ̇_m + Σ_motor e(θ_m, θ̇_m, θ̈_m) − τ_s = κ τ_m      eq:motorside
Spring       τ_s = K_s g(θ_s) + D_s θ̇_s + Σ_spring e(θ_s),  θ_s = q − θ_m     eq:spring_torque

with C(q) = gravity ⊙ sin(q), g the backlash dead band (identity when none is declared),
κ the declared torque scale (1 when none), and the declared effects of docs/interfaces.md §2.
Inertia effects are folded into M and J (they are linear in the acceleration).
"""
from __future__ import annotations

import dataclasses

import numpy as np

from sea_daemon.core.config import ModelConfig, SEAParams
from sea_daemon.core.effects import Delay, EncoderOffset, Inertia, SpringBacklash, TorqueScale


class SEAModel:
    """Nominal SEA model with declared effects: forward dynamics, Jacobian, inverse dynamics."""

    def __init__(self, params: SEAParams, sign_eps: float | None = None):
        self.params = params
        n = self.n = params.n
        eff = params.effects
        if sign_eps is not None:  # declared friction uses the estimator's smoothing
            eff = tuple(dataclasses.replace(e, eps=sign_eps) if hasattr(e, "eps") else e for e in eff)
        self.effects = eff
        M = np.array(params.M, dtype=float)
        J = np.array(params.J, dtype=float)
        for e in eff:
            if isinstance(e, Inertia):
                (M if e.side == "load" else J)[e.joint, e.joint] += e.dI
        self.M, self.J = M, J
        self.Minv = np.linalg.inv(M)
        self.Jinv = np.linalg.inv(J)
        self.D_m = np.array(params.D_m, dtype=float)
        self.K_s = np.array(params.K_s, dtype=float)
        self.D_s = np.array(params.D_s, dtype=float)
        self.gravity = np.array(params.gravity, dtype=float)
        add = [e for e in eff if e.additive and not isinstance(e, Inertia)]
        self.load_effects = [e for e in add if e.side == "load"]
        self.motor_effects = [e for e in add if e.side == "motor"]
        self.spring_effects = [e for e in add if e.side == "spring"]
        self.backlash = {e.joint: e for e in eff if isinstance(e, SpringBacklash)}
        self.kappa = np.ones(n)
        self.delay = np.zeros(n)
        self.offset_load = np.zeros(n)
        self.offset_motor = np.zeros(n)
        for e in eff:
            if isinstance(e, TorqueScale):
                self.kappa[e.joint] *= e.kappa
            elif isinstance(e, Delay):
                self.delay[e.joint] += e.seconds
            elif isinstance(e, EncoderOffset):
                (self.offset_load if e.side == "load" else self.offset_motor)[e.joint] += e.delta
        # I_μ: selects the θ̈_s rows (eq:unknown), 5n × n
        self.I_mu = np.zeros((5 * n, n))
        self.I_mu[3 * n:4 * n, :] = np.eye(n)

    @classmethod
    def from_config(cls, cfg: ModelConfig) -> "SEAModel":
        return cls(cfg.model, sign_eps=cfg.estimator.sign_eps)

    # ------------------------------------------------------------------ pieces

    def C(self, q: np.ndarray) -> np.ndarray:
        """Gravity term of the loaded link, C(q) = gravity ⊙ sin q."""
        return self.gravity * np.sin(q)

    def dC(self, q: np.ndarray) -> np.ndarray:
        return self.gravity * np.cos(q)

    @staticmethod
    def _sum(effects, n, angle, vel, acc):
        tau = np.zeros(n)
        d_ang = np.zeros(n)
        d_vel = np.zeros(n)
        for e in effects:
            j = e.joint
            t, pa, pv, _ = e.evaluate(angle[j], vel[j], acc[j])
            tau[j] += t
            d_ang[j] += pa
            d_vel[j] += pv
        return tau, d_ang, d_vel

    def _deflection(self, theta_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """g(θ_s) and g'(θ_s): the backlash dead band, identity without one."""
        if not self.backlash:
            return theta_s, np.ones(self.n)
        g = np.array(theta_s, dtype=float)
        dg = np.ones(self.n)
        for j, e in self.backlash.items():
            g[j], dg[j] = e.deadband(theta_s[j])
        return g, dg

    def spring_torque(self, theta_s: np.ndarray, dtheta_s: np.ndarray) -> np.ndarray:
        """τ_s (eq:spring_torque) with the declared spring effects."""
        g, _ = self._deflection(np.atleast_1d(theta_s))
        z = np.zeros(self.n)
        tau_e, _, _ = self._sum(self.spring_effects, self.n, np.atleast_1d(theta_s), z, z)
        return self.K_s @ g + self.D_s @ np.atleast_1d(dtheta_s) + tau_e

    def spring_torque_jac(self, theta_s: np.ndarray) -> np.ndarray:
        """∂τ_s/∂θ_s (n×n); ∂τ_s/∂θ̇_s is D_s."""
        _, dg = self._deflection(theta_s)
        z = np.zeros(self.n)
        _, d_e, _ = self._sum(self.spring_effects, self.n, theta_s, z, z)
        return self.K_s * dg[None, :] + np.diag(d_e)

    def load_effects_torque(self, q, dq):
        z = np.zeros(self.n)
        return self._sum(self.load_effects, self.n, q, dq, z)

    def motor_effects_torque(self, theta_m, dtheta_m):
        z = np.zeros(self.n)
        return self._sum(self.motor_effects, self.n, theta_m, dtheta_m, z)

    def applied_torque(self, tau_m: np.ndarray) -> np.ndarray:
        """Torque reaching the motor-side dynamics: κ τ_m (the delay is applied by the caller)."""
        return self.kappa * tau_m

    # ------------------------------------------------------------------ dynamics

    def split(self, x: np.ndarray):
        n = self.n
        return x[:n], x[n:2 * n], x[2 * n:3 * n], x[3 * n:4 * n], x[4 * n:5 * n]

    def accelerations(self, x: np.ndarray, u: np.ndarray, f_res: np.ndarray | None = None):
        """(θ̈_m, q̈) for state x, input τ_m = u and residual load torque f(z) (eq:thetadd, eq:xsdd)."""
        th_m, th_s, dth_m, dth_s, tau_h = self.split(x)
        q = th_m + th_s
        dq = dth_m + dth_s
        tau_s = self.spring_torque(th_s, dth_s)
        mo, _, _ = self.motor_effects_torque(th_m, dth_m)
        lo, _, _ = self.load_effects_torque(q, dq)
        # eq:thetadd
        ddth_m = self.Jinv @ (self.applied_torque(u) + tau_s - self.D_m @ dth_m - mo)
        # eq:unknwn_load solved for q̈
        rhs = tau_h - self.C(q) - lo - tau_s
        if f_res is not None:
            rhs = rhs - f_res
        ddq = self.Minv @ rhs
        return ddth_m, ddq

    def f_nom(self, x: np.ndarray, u: np.ndarray, f_res: np.ndarray | None = None) -> np.ndarray:
        """ẋ = f_nom(x, u) − I_μ M⁻¹ f(z) (eq:nonlindyn, eq:unknown)."""
        n = self.n
        ddth_m, ddq = self.accelerations(x, u, f_res)
        xd = np.empty(5 * n)
        xd[:n] = x[2 * n:3 * n]
        xd[n:2 * n] = x[3 * n:4 * n]
        xd[2 * n:3 * n] = ddth_m
        # eq:xsdd: θ̈_s = q̈ − θ̈_m
        xd[3 * n:4 * n] = ddq - ddth_m
        xd[4 * n:] = 0.0  # zero-order model of τ_h,act
        return xd

    def F_nom(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Analytic Jacobian ∂f_nom/∂x (5n×5n) (Park et al.; eq:linearization without the GP)."""
        n = self.n
        th_m, th_s, dth_m, dth_s, _ = self.split(x)
        q = th_m + th_s
        dq = dth_m + dth_s
        dts = self.spring_torque_jac(th_s)                  # ∂τ_s/∂θ_s
        _, dmo_a, dmo_v = self.motor_effects_torque(th_m, dth_m)
        _, dlo_a, dlo_v = self.load_effects_torque(q, dq)
        dCq = np.diag(self.dC(q) + dlo_a)                  # ∂(C + load effects)/∂q
        dLv = np.diag(dlo_v)
        Ji, Mi = self.Jinv, self.Minv
        # rows of θ̈_m (eq:thetadd)
        am = [Ji @ -np.diag(dmo_a), Ji @ dts, Ji @ (-self.D_m - np.diag(dmo_v)), Ji @ self.D_s, np.zeros((n, n))]
        # rows of q̈ (eq:unknwn_load)
        aq = [Mi @ -dCq, Mi @ (-dCq - dts), Mi @ -dLv, Mi @ (-dLv - self.D_s), Mi]
        A = np.zeros((5 * n, 5 * n))
        A[:n, 2 * n:3 * n] = np.eye(n)
        A[n:2 * n, 3 * n:4 * n] = np.eye(n)
        for b in range(5):
            A[2 * n:3 * n, b * n:(b + 1) * n] = am[b]
            # eq:xsdd: θ̈_s = q̈ − θ̈_m
            A[3 * n:4 * n, b * n:(b + 1) * n] = aq[b] - am[b]
        return A

    def B_nom(self) -> np.ndarray:
        """∂f_nom/∂u (5n×n)."""
        n = self.n
        B = np.zeros((5 * n, n))
        Jk = self.Jinv * self.kappa[None, :]
        B[2 * n:3 * n] = Jk
        B[3 * n:4 * n] = -Jk
        return B

    # ------------------------------------------------------------------ inverse dynamics

    def load_torque(self, q, dq, ddq) -> np.ndarray:
        """τ_l(z) = M q̈ + C(q) plus the declared load effects (eq:loadsidewmotor)."""
        lo, _, _ = self.load_effects_torque(q, dq)
        return self.M @ ddq + self.C(q) + lo

    def residual_from_kinematics(self, q, dq, ddq, th_m, dth_m, ddth_m, tau_m, tau_h_act=None) -> np.ndarray:
        """f(z) = τ_h,act + κτ_m − (τ_l(z) + J θ̈_m + D_m θ̇_m + motor effects)   (eq:loadsidewmotor).

        With the passive-human assumption (ass:passive_human) τ_h,act = 0.
        """
        mo, _, _ = self.motor_effects_torque(th_m, dth_m)
        f = self.applied_torque(tau_m) - (self.load_torque(q, dq, ddq) + self.J @ ddth_m + self.D_m @ dth_m + mo)
        if tau_h_act is not None:
            f = f + tau_h_act
        return f

    def correct_measurement(self, q_meas: np.ndarray, th_m_meas: np.ndarray):
        """Remove declared encoder offsets: the encoders read angle + δ (docs/interfaces.md §2)."""
        return q_meas - self.offset_load, th_m_meas - self.offset_motor
