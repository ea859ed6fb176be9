"""SEA dynamics for n joints (paper ``eq:sea``, ``eq:spring_torque``, ``eq:unknwn_load``).

Pure numerics: no I/O, no clock, no threads.  Everything on the joint side of the gear, SI.

Augmented state (Sec. IV-B):  x = [θ_m, θ_s, θ̇_m, θ̇_s, τ_h,act]  ∈ R^{5n},  u = τ_m ∈ R^n;
with ``estimator.tau_h_act_model: integrated`` also τ̇_h,act: x ∈ R^{6n} (:class:`StateLayout`).

Load side    M q̈ + C(q) + Σ_load e(q, q̇, q̈) + f(z) + τ_s = τ_h,act          eq:unknwn_load
Motor side   J θ̈_m + D_m θ̇_m + Σ_motor e(θ_m, θ̇_m, θ̈_m) − τ_s = κ τ_m      eq:motorside
Spring       τ_s = K_s g(θ_s) + D_s θ̇_s + Σ_spring e(θ_s),  θ_s = q − θ_m     eq:spring_torque

with C(q) = gravity ⊙ sin(q) and a constant M — or, with ``model.urdf``, M(q) and the bias
C(q, q̇) q̇ + g(q) in place of C(q), of the URDF's rigid body (:class:`~sea_daemon.core.rigid.RigidBody`,
Pinocchio; eq:loadside) — g the backlash dead band (identity when none is declared),
κ the declared torque scale (1 when none), and the declared effects of docs/interfaces.md §2.
Inertia effects are folded into M and J (they are linear in the acceleration).

The equations are written once, in the compiled kernels of :mod:`sea_daemon.core.dynamics`;
:class:`SEAModel` collects the declared parameters and effects into their
:class:`~sea_daemon.core.dynamics.Dynamics` (:attr:`SEAModel.dynamics`) and calls them.  Load
effects outside the vocabulary (an effect class with its own Python ``evaluate``) are summed
here and enter the kernels as a residual load torque f (eq:unknwn_load).
"""
from __future__ import annotations

import dataclasses

import numpy as np

from sea_daemon.core.config import TAU_MODELS, ModelConfig, SEAParams
from sea_daemon.core import dynamics
from sea_daemon.core.dynamics import make_dynamics
from sea_daemon.core.effects import Delay, Effect, EncoderOffset, Inertia, SpringBacklash, TorqueScale


@dataclasses.dataclass(frozen=True)
class StateLayout:
    """Where each part of the filter's state lies: x = [θ_m, θ_s, θ̇_m, θ̇_s, τ_h,act] (5n, the
    random walk) or [θ_m, θ_s, θ̇_m, θ̇_s, τ_h,act, τ̇_h,act] (6n, ``integrated``); the measured
    part y = x[:4n] in both."""

    n: int
    integrated: bool = False

    @classmethod
    def of(cls, n: int, tau_model: str = "walk") -> "StateLayout":
        if tau_model not in TAU_MODELS:
            raise ValueError(f"tau_h_act_model must be one of {', '.join(TAU_MODELS)}, got {tau_model!r}")
        return cls(int(n), tau_model == "integrated")

    @property
    def d(self) -> int:
        """The state's dimension: 5n or 6n."""
        return (6 if self.integrated else 5) * self.n

    @property
    def m(self) -> int:
        """The measurement's dimension, 4n (y = [θ_m, θ_s, θ̇_m, θ̇_s])."""
        return 4 * self.n

    @property
    def tau(self) -> slice:
        """τ_h,act in x."""
        return slice(4 * self.n, 5 * self.n)

    @property
    def dtau(self) -> slice | None:
        """τ̇_h,act in x (None: the random walk has none)."""
        return slice(5 * self.n, 6 * self.n) if self.integrated else None

    @property
    def tau_idx(self) -> np.ndarray:
        """The indices of τ_h,act in x."""
        return np.arange(4 * self.n, 5 * self.n)

    @property
    def rate_idx(self) -> np.ndarray:
        """The indices of the state the bound's declared deterministic input drives: τ_h,act for the
        random walk (|τ̇_h,act| ≤ r), τ̇_h,act for the integrated one (|τ̈_h,act| ≤ a)."""
        return np.arange(5 * self.n, 6 * self.n) if self.integrated else self.tau_idx

    def embed(self, A5: np.ndarray) -> np.ndarray:
        """A (5n, 5n) matrix as (d, d): the integrated walk's dτ_h,act/dt = τ̇_h,act added."""
        if not self.integrated:
            return A5
        n = self.n
        A = np.zeros((self.d, self.d))
        A[:5 * n, :5 * n] = A5
        A[4 * n:5 * n, 5 * n:] = np.eye(n)
        return A

    def pad(self, B5: np.ndarray) -> np.ndarray:
        """A (5n, k) matrix as (d, k): zero τ̇_h,act rows."""
        if not self.integrated:
            return B5
        return np.vstack([B5, np.zeros((self.n, B5.shape[1]))])


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
        #: the rigid body of ``model.urdf`` (:class:`~sea_daemon.core.rigid.RigidBody`; its own copy,
        #: declared load inertia added as armature) or None: then M and C(q) = gravity ⊙ sin q
        self.rigid = None
        if params.rigid is not None:
            dI = np.zeros(n)
            for e in eff:
                if isinstance(e, Inertia) and e.side == "load":
                    dI[e.joint] += e.dI
            self.rigid = params.rigid.with_armature(dI)
        # with a rigid body, M and M⁻¹ are M(q) at the state last given to :meth:`at` (M(0) at first)
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
        #: load effects outside the vocabulary (their own Python ``evaluate``): the kernels take
        #: their torque as a residual load torque f (eq:unknwn_load)
        self.outside_effects = tuple(e for e in self.load_effects if not _in_vocabulary(e))
        if any(not _in_vocabulary(e) for e in (*self.motor_effects, *self.spring_effects)):
            raise ValueError("effects outside the vocabulary (a Python evaluate) act on the load side only")
        half_band = np.full(n, -1.0)          # backlash half-width per joint (−1: none)
        for j, e in self.backlash.items():
            half_band[j] = 0.5 * e.width
        #: the parameters of the dynamics kernels (:mod:`sea_daemon.core.dynamics`)
        self.dynamics = make_dynamics(M, J, self.D_m, self.K_s, self.D_s, self.gravity, self.kappa, half_band,
                                      [e for e in self.load_effects if _in_vocabulary(e)], self.motor_effects,
                                      self.spring_effects)
        #: the same in the packed form the kernels take (:meth:`Dynamics.packed`)
        self.kernel = self.dynamics.packed()
        # I_μ: selects the θ̈_s rows (eq:unknown), 5n × n
        self.I_mu = np.zeros((5 * n, n))
        self.I_mu[3 * n:4 * n, :] = np.eye(n)

    @classmethod
    def from_config(cls, cfg: ModelConfig) -> "SEAModel":
        return cls(cfg.model, sign_eps=cfg.estimator.sign_eps)

    # ------------------------------------------------------------------ pieces

    def C(self, q: np.ndarray) -> np.ndarray:
        """Gravity term of the loaded link, C(q) = gravity ⊙ sin q (a rigid body's g(q), q one
        configuration)."""
        if self.rigid is not None:
            return self.rigid.gravity(q)
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

    def outside_torque(self, q, dq):
        """(f, ∂f/∂q, ∂f/∂q̇) of the load effects outside the vocabulary (Python ``evaluate``):
        the kernels take them as a residual load torque f (eq:unknwn_load)."""
        z = np.zeros(self.n)
        return self._sum(self.outside_effects, self.n, q, dq, z)

    def spring_torque(self, theta_s: np.ndarray, dtheta_s: np.ndarray) -> np.ndarray:
        """τ_s (eq:spring_torque) with the declared spring effects (:func:`dynamics.spring_torque`)."""
        return dynamics.spring_torque(self.kernel, _vec(theta_s), _vec(dtheta_s))

    def spring_torque_jac(self, theta_s: np.ndarray) -> np.ndarray:
        """∂τ_s/∂θ_s (n×n); ∂τ_s/∂θ̇_s is D_s."""
        return dynamics.spring_torque_jac(self.kernel, _vec(theta_s))

    def load_effects_torque(self, q, dq):
        """(Σ τ, ∂/∂q, ∂/∂q̇) of the declared load effects, the ones outside the vocabulary last."""
        q, dq = _vec(q), _vec(dq)
        t = dynamics.side_torques(self.kernel[10], q, dq)
        if not self.outside_effects:
            return t
        return tuple(a + b for a, b in zip(t, self.outside_torque(q, dq)))

    def motor_effects_torque(self, theta_m, dtheta_m):
        """(Σ τ, ∂/∂θ_m, ∂/∂θ̇_m) of the declared motor effects."""
        return dynamics.side_torques(self.kernel[11], _vec(theta_m), _vec(dtheta_m))

    def applied_torque(self, tau_m: np.ndarray) -> np.ndarray:
        """Torque reaching the motor-side dynamics: κ τ_m (the delay is applied by the caller)."""
        return self.kappa * tau_m

    # ------------------------------------------------------------------ dynamics

    def split(self, x: np.ndarray):
        n = self.n
        return x[:n], x[n:2 * n], x[2 * n:3 * n], x[3 * n:4 * n], x[4 * n:5 * n]

    def _f(self, q, dq, f_res) -> np.ndarray:
        """The residual load torque the kernels take: f_res plus the effects outside the vocabulary."""
        f = np.zeros(self.n) if f_res is None else _vec(f_res)
        if self.outside_effects:
            f = f + self.outside_torque(q, dq)[0]
        return f

    def accelerations(self, x: np.ndarray, u: np.ndarray, f_res: np.ndarray | None = None):
        """(θ̈_m, q̈) for state x, input τ_m = u and residual load torque f(z) (eq:thetadd, eq:xsdd)."""
        x = _vec(x)
        th_m, th_s, dth_m, dth_s, tau_h = self.split(x)
        q = th_m + th_s
        dq = dth_m + dth_s
        p = self.kernel
        tau_s = dynamics.spring_torque(p, th_s, dth_s)
        ddth_m = dynamics.motor_accel(p, th_m, dth_m, _vec(u), tau_s)
        if self.rigid is not None:
            # eq:unknwn_load by the rigid body's forward dynamics (ABA)
            ddq = self.rigid.forward(q, dq, dynamics.load_side_torque(p, x, self._f(q, dq, f_res)))
        else:
            ddq = dynamics.load_accel(p, q, dq, tau_h, tau_s, self._f(q, dq, f_res))
        return ddth_m, ddq

    def f_nom(self, x: np.ndarray, u: np.ndarray, f_res: np.ndarray | None = None) -> np.ndarray:
        """ẋ = f_nom(x, u) − I_μ M⁻¹ f(z) (eq:nonlindyn, eq:unknown; :func:`dynamics.f_nom`)."""
        x = _vec(x)
        n = self.n
        xd = np.empty(x.shape[0])          # 5n, or 6n with the integrated walk of τ_h,act (StateLayout)
        f = self._f(x[:n] + x[n:2 * n], x[2 * n:3 * n] + x[3 * n:4 * n], f_res)
        if self.rigid is not None:
            self.rigid_f_and_F(x, _vec(u), f, None, None, None, xd)
            return xd
        dynamics.f_nom(self.kernel, x, _vec(u), f, xd)
        return xd

    def F_nom(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Analytic Jacobian ∂f_nom/∂x (5n×5n; 6n×6n for a state x of 6n, StateLayout) (Park et al.;
        eq:linearization without the GP)."""
        x = _vec(x)
        n = self.n
        A = np.empty((x.shape[0], x.shape[0]))
        if self.outside_effects:
            f, f_q, f_v = self.outside_torque(x[:n] + x[n:2 * n], x[2 * n:3 * n] + x[3 * n:4 * n])
        else:
            f = f_q = f_v = np.zeros(n)
        if self.rigid is not None:
            self.rigid_f_and_F(x, _vec(u), f, f_q, f_v, A, np.empty(x.shape[0]))
            return A
        dynamics.F_nom(self.kernel, x, _vec(u), f_q, f_v, A)
        return A

    def at(self, x) -> None:
        """M and M⁻¹ (:attr:`M`, :attr:`Minv`, in place) at the state x (5n,): a rigid body's M(q),
        q = θ_m + θ_s; a constant M stays as it is."""
        if self.rigid is not None:
            n = self.n
            self.M[:] = self.rigid.mass_matrix(np.asarray(x[:n], dtype=float) + x[n:2 * n])
            self.Minv[:] = np.linalg.inv(self.M)

    def rigid_f_and_F(self, x, u, f, f_q, f_v, A, xdot) -> np.ndarray:
        """xdot = f_nom(x, u) − I_μ M⁻¹(q) f and, with ``A`` (f_q, f_v the partials of f), A = F_nom
        of the model with a rigid body (:func:`dynamics.rigid_state` around one ABA or ABA-derivatives
        call, eq:unknwn_load); returns M(q)⁻¹ (n, n)."""
        n = self.n
        p = self.kernel
        q = x[:n] + x[n:2 * n]
        dq = x[2 * n:3 * n] + x[3 * n:4 * n]
        tau = dynamics.load_side_torque(p, x, f)
        if A is None:
            ddq = self.rigid.forward(q, dq, tau)
            dynamics.rigid_state(p, x, u, ddq, _NONE, _NONE, _NONE, f, f, _NONE, xdot, False)
            return _NONE
        ddq, ddq_dq, ddq_dv, Minv = self.rigid.forward_derivatives(q, dq, tau)
        dynamics.rigid_state(p, x, u, ddq, ddq_dq, ddq_dv, Minv, f_q, f_v, A, xdot, True)
        return Minv

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
        """τ_l(z) = M q̈ + C(q) plus the declared load effects (eq:loadsidewmotor); a rigid body's
        M(q) q̈ + C(q, q̇) q̇ + g(q) by RNEA."""
        q, dq = _vec(q), _vec(dq)
        if self.rigid is not None:
            t = dynamics.load_torque_given(self.kernel, q, dq, self.rigid.inverse(q, dq, ddq))
        else:
            t = dynamics.load_torque(self.kernel, q, dq, _vec(ddq))
        return t + self.outside_torque(q, dq)[0] if self.outside_effects else t

    def residual_from_kinematics(self, q, dq, ddq, th_m, dth_m, ddth_m, tau_m, tau_h_act=None) -> np.ndarray:
        """f(z) = τ_h,act + κτ_m − (τ_l(z) + J θ̈_m + D_m θ̇_m + motor effects)   (eq:loadsidewmotor).

        With the passive-human assumption (ass:passive_human) τ_h,act = 0.
        """
        q, dq = _vec(q), _vec(dq)
        f = np.empty(self.n)
        if self.rigid is not None:
            dynamics.residual_given(self.kernel, q, dq, self.rigid.inverse(q, dq, ddq), _vec(th_m), _vec(dth_m),
                                    _vec(ddth_m), _vec(tau_m), f)
        else:
            dynamics.residual(self.kernel, q, dq, _vec(ddq), _vec(th_m), _vec(dth_m), _vec(ddth_m), _vec(tau_m), f)
        if self.outside_effects:
            f = f - self.outside_torque(q, dq)[0]
        if tau_h_act is not None:
            f = f + tau_h_act
        return f

    def correct_measurement(self, q_meas: np.ndarray, th_m_meas: np.ndarray):
        """Remove declared encoder offsets: the encoders read angle + δ (docs/interfaces.md §2)."""
        return q_meas - self.offset_load, th_m_meas - self.offset_motor


#: a placeholder (0, 0) array for the arguments :func:`dynamics.rigid_state` does not read
_NONE = np.zeros((0, 0))


def _vec(a) -> np.ndarray:
    """A 1-d contiguous float array (what the kernels take)."""
    return np.ascontiguousarray(np.atleast_1d(a), dtype=float)


def _in_vocabulary(e) -> bool:
    """The effect's formula is in the compiled :func:`~sea_daemon.core.effects.evaluate`."""
    return type(e).evaluate is Effect.evaluate
