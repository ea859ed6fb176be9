"""The true plant: the SEA exoskeleton with a human forearm, as the estimator never sees it.

The true plant is :class:`~sea_daemon.core.model.SEAModel` built from a "true" model
configuration — the nominal ``exo_1dof`` model plus the effects the estimator is not told
about (arm inertia and gravity, human viscoelasticity, load friction with stiction, the
spring's mechanical stop, ...; docs/interfaces.md §2 vocabulary) — with no learned residual
(f_res = None) and the active human torque τ_h,act as an input:

    load   M q̈ + C(q) + Σ_load e + τ_s = τ_h,act                       eq:unknwn_load
    motor  J θ̈_m + D_m θ̇_m + Σ_motor e − τ_s = κ τ_m(t − d)            eq:motorside
    spring τ_s = K_s g(θ_s) + D_s θ̇_s + Σ_spring e                     eq:spring_torque

Every effect type is honoured: additive ones through SEAModel's sums, ``inertia`` folded
into M/J, ``torque_scale`` κ, ``spring_backlash`` g, ``delay`` d through an input history,
``encoder_offset`` in the encoders (:mod:`.sensors`).

Integration: classical RK4 on (q, θ_m, q̇, θ̇_m) at a fixed substep (default 1 kHz, i.e.
10 substeps per 10 ms sample) with the motor torque and τ_h,act held over each
``step`` call (zero-order hold).  The friction sign is smoothed with tanh(v/sign_eps)
(default 3e-3 rad/s): small enough to behave like stiction (the link sticks while
|torque| < F_c + F_s), large enough that RK4 stays stable at the substep; the
constructor checks the substep against the stiffest friction/spring slope.

For one joint a scalar (pure ``math``) evaluation of the same equations is used: numpy's
per-call overhead dominates for n = 1.  ``tests/test_sim.py`` checks that it agrees with
``SEAModel.accelerations``.
"""
from __future__ import annotations

import bisect
import math

import numpy as np
from scipy.optimize import brentq, root

from sea_daemon.core.config import ModelConfig
from sea_daemon.core.model import SEAModel
from sea_daemon.core.sim.sensors import Encoders, torque_noise

#: default friction-sign smoothing of the true plant [rad/s]
PLANT_SIGN_EPS = 3e-3
#: default internal integration rate [Hz]
SUBSTEP_HZ = 1000.0


class Plant:
    """Simulated exoskeleton joint(s), stepped in lock-step with a controller.

    Parameters
    ----------
    cfg : the *true* model configuration (nominal model + hidden effects).
    q0 : initial link angle(s) [rad]; the plant starts at rest in static equilibrium there,
        with the motor holding it (:attr:`hold_torque`).  Default 0.
    seed : seed of the motor-torque noise (std ``cfg.hardware.torque_noise``).
    substep_hz : internal RK4 rate [Hz].
    sign_eps : friction-sign smoothing of the true plant [rad/s].
    torque_noise : override of ``cfg.hardware.torque_noise`` [N m].
    tau_h_act0 : active human torque present at rest before t = 0 (for the equilibrium).

    ``step(tau_m, dt, tau_h_act)`` advances by dt with the commanded torque held; the
    applied torque is clip(tau_m, ±torque_limit) + noise (then κ and the delay act).
    """

    def __init__(self, cfg: ModelConfig, q0=0.0, seed: int | None = None, *,
                 substep_hz: float = SUBSTEP_HZ, sign_eps: float = PLANT_SIGN_EPS,
                 torque_noise: float | None = None, tau_h_act0=0.0):
        self.cfg = cfg
        self.model = SEAModel(cfg.model, sign_eps=sign_eps)
        m = self.model
        self.n = n = m.n
        self.h_max = 1.0 / float(substep_hz)
        self.sign_eps = float(sign_eps)
        self.torque_limit = float(cfg.hardware.torque_limit)
        self.noise_std = float(cfg.hardware.torque_noise if torque_noise is None else torque_noise)
        self.rng = np.random.default_rng(seed)
        self.encoders = Encoders(cfg.hardware, m.offset_load, m.offset_motor)
        self._check_substep()

        q0 = np.broadcast_to(np.asarray(q0, dtype=float), (n,)).copy()
        tau_h0 = np.broadcast_to(np.asarray(tau_h_act0, dtype=float), (n,)).copy()
        th_s0, tau_hold = self.static_equilibrium(q0, tau_h0)
        #: torque [N m] the motor applies to hold the plant at rest at q0 (before noise)
        self.hold_torque = tau_hold
        # y = [q, θ_m, q̇, θ̇_m]
        self._y = np.concatenate([q0, q0 - th_s0, np.zeros(n), np.zeros(n)])
        self.t = 0.0
        self._tau_h = tau_h0
        self._u_applied = tau_hold.copy()
        # input history for the delay effect: start times and applied torques
        self._hist_t: list[float] = [-math.inf]
        self._hist_u: list[np.ndarray] = [tau_hold.copy()]
        self._scalar = n == 1
        if self._scalar:
            self._compile_scalar()

    # ------------------------------------------------------------------ state

    @property
    def q(self) -> np.ndarray:
        return self._y[:self.n].copy()

    @property
    def theta_m(self) -> np.ndarray:
        return self._y[self.n:2 * self.n].copy()

    @property
    def dq(self) -> np.ndarray:
        return self._y[2 * self.n:3 * self.n].copy()

    @property
    def dtheta_m(self) -> np.ndarray:
        return self._y[3 * self.n:].copy()

    @property
    def state(self) -> np.ndarray:
        """Augmented state x = [θ_m, θ_s, θ̇_m, θ̇_s, τ_h,act] (5n) of the true plant (Sec. IV-B)."""
        n = self.n
        q, th, dq, dth = self._y[:n], self._y[n:2 * n], self._y[2 * n:3 * n], self._y[3 * n:]
        return np.concatenate([th, q - th, dth, dq - dth, self._tau_h])

    @property
    def tau_s(self) -> np.ndarray:
        """True spring torque τ_s (eq:spring_torque) with the plant's spring effects."""
        x = self.state
        n = self.n
        return self.model.spring_torque(x[n:2 * n], x[3 * n:4 * n])

    @property
    def applied_torque(self) -> np.ndarray:
        """Torque applied in the last step (after limit and noise, before κ and delay)."""
        return self._u_applied.copy()

    def accelerations(self) -> tuple[np.ndarray, np.ndarray]:
        """(q̈, θ̈_m) now, with the torque currently reaching the motor."""
        u = self._delayed_input(self.t)
        ddth, ddq = self.model.accelerations(self.state, u)
        return ddq, ddth

    def measure(self) -> tuple[np.ndarray, np.ndarray]:
        """Encoder readings (q, θ_m) on the joint side: quantised, with encoder offsets."""
        return self.encoders.read(self._y[:self.n], self._y[self.n:2 * self.n])

    def raw_counts(self) -> dict[str, np.ndarray]:
        """What the encoders put on the bus: single-turn counts and motor-shaft turns (:meth:`Encoders.raw`)."""
        return self.encoders.raw(self._y[:self.n], self._y[self.n:2 * self.n])

    # ------------------------------------------------------------------ statics

    def static_equilibrium(self, q: np.ndarray, tau_h_act=None) -> tuple[np.ndarray, np.ndarray]:
        """Deflection θ_s and motor torque τ_m holding the plant at rest at q.

        Load side at rest: τ_s(θ_s) = τ_h,act − C(q) − Σ_load e(q, 0)         (eq:unknwn_load)
        Motor side at rest: κ τ_m = Σ_motor e(θ_m, 0) − τ_s,  θ_m = q − θ_s    (eq:motorside)
        """
        m = self.model
        n = self.n
        q = np.asarray(q, dtype=float).reshape(n)
        tau_h = np.zeros(n) if tau_h_act is None else np.asarray(tau_h_act, dtype=float).reshape(n)
        z = np.zeros(n)
        lo, _, _ = m.load_effects_torque(q, z)
        target = tau_h - m.C(q) - lo
        K = m.K_s
        if np.allclose(K, np.diag(np.diag(K))) and not np.any(m.D_s - np.diag(np.diag(m.D_s))):
            th_s = np.zeros(n)
            for j in range(n):
                def g(ts, j=j):
                    v = np.zeros(n)
                    v[j] = ts
                    return m.spring_torque(v, z)[j] - target[j]
                lo_b, hi_b = -0.5, 0.5
                for _ in range(60):        # τ_s is non-decreasing and unbounded in θ_s
                    if g(lo_b) <= 0:
                        break
                    lo_b *= 2
                for _ in range(60):
                    if g(hi_b) >= 0:
                        break
                    hi_b *= 2
                th_s[j] = brentq(g, lo_b, hi_b, xtol=1e-14, rtol=1e-14)
        else:
            sol = root(lambda ts: m.spring_torque(ts, z) - target, np.linalg.solve(K, target), tol=1e-14)
            th_s = sol.x
        tau_s = m.spring_torque(th_s, z)
        mo, _, _ = m.motor_effects_torque(q - th_s, z)
        # eq:motorside at rest
        tau_m = (mo - tau_s) / m.kappa
        return th_s, tau_m

    # ------------------------------------------------------------------ stepping

    def step(self, tau_m, dt: float, tau_h_act=0.0) -> None:
        """Advance by dt [s] with the commanded motor torque and τ_h,act held (ZOH)."""
        if not dt > 0:
            raise ValueError(f"dt must be > 0, got {dt}")
        n = self.n
        u = np.broadcast_to(np.asarray(tau_m, dtype=float), (n,))
        if not (np.all(np.isfinite(u)) and np.all(np.isfinite(tau_h_act))):
            raise ValueError(f"tau_m and tau_h_act must be finite, got {tau_m!r}, {tau_h_act!r}")
        u = np.clip(u, -self.torque_limit, self.torque_limit)
        u = u + torque_noise(self.rng, self.noise_std, n)
        self._u_applied = u
        self._tau_h = np.broadcast_to(np.asarray(tau_h_act, dtype=float), (n,)).copy()
        self._hist_t.append(self.t)
        self._hist_u.append(u.copy())
        k = max(1, int(math.ceil(dt / self.h_max - 1e-9)))
        h = dt / k
        t0 = self.t
        if self._scalar:
            self._integrate_scalar(t0, h, k)
        else:
            y = self._y
            for i in range(k):
                ts = t0 + i * h
                # input held over the substep (evaluated at its midpoint for the delay lookup)
                ui = self._delayed_input(ts + 0.5 * h)
                y = self._rk4(y, h, ui)
            self._y = y
        self.t = t0 + dt
        self._prune_history()

    def _delayed_input(self, t: float) -> np.ndarray:
        """Applied torque reaching the motor at time t: u(t − delay) from the ZOH history."""
        d = self.model.delay
        if not np.any(d):
            return self._hist_u[-1]
        out = np.empty(self.n)
        for j in range(self.n):
            i = bisect.bisect_right(self._hist_t, t - d[j]) - 1
            out[j] = self._hist_u[max(i, 0)][j]
        return out

    def _prune_history(self) -> None:
        keep_from = self.t - float(np.max(self.model.delay)) - 1.0
        i = bisect.bisect_right(self._hist_t, keep_from) - 1
        if i > 0:
            del self._hist_t[:i]
            del self._hist_u[:i]

    # generic (any n) path: SEAModel.accelerations
    def _deriv(self, y: np.ndarray, u: np.ndarray) -> np.ndarray:
        n = self.n
        q, th, dq, dth = y[:n], y[n:2 * n], y[2 * n:3 * n], y[3 * n:]
        x = np.concatenate([th, q - th, dth, dq - dth, self._tau_h])
        # eq:thetadd and eq:unknwn_load with f_res = None
        ddth, ddq = self.model.accelerations(x, u)
        return np.concatenate([dq, dth, ddq, ddth])

    def _rk4(self, y: np.ndarray, h: float, u: np.ndarray) -> np.ndarray:
        k1 = self._deriv(y, u)
        k2 = self._deriv(y + 0.5 * h * k1, u)
        k3 = self._deriv(y + 0.5 * h * k2, u)
        k4 = self._deriv(y + h * k3, u)
        return y + h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)

    # scalar (n = 1) path: the same equations with math on floats
    def _compile_scalar(self) -> None:
        m = self.model
        self._s_M = float(m.M[0, 0])
        self._s_J = float(m.J[0, 0])
        self._s_Dm = float(m.D_m[0, 0])
        self._s_Ks = float(m.K_s[0, 0])
        self._s_Ds = float(m.D_s[0, 0])
        self._s_kappa = float(m.kappa[0])
        self._s_load = _compile_side(m.load_effects, gravity=float(m.gravity[0]))
        self._s_motor = _compile_side(m.motor_effects)
        self._s_spring = _compile_side(m.spring_effects)
        bl = m.backlash.get(0)
        self._s_backlash = bl.deadband if bl is not None else None

    def _deriv_scalar(self, q, th, dq, dth, u, tau_h):
        ths = q - th
        dths = dq - dth
        g = ths if self._s_backlash is None else self._s_backlash(ths)[0]
        # eq:spring_torque
        tau_s = self._s_Ks * g + self._s_Ds * dths + self._s_spring(ths, 0.0)
        # eq:thetadd
        ddth = (self._s_kappa * u + tau_s - self._s_Dm * dth - self._s_motor(th, dth)) / self._s_J
        # eq:unknwn_load solved for q̈ (f_res = None); C(q) is inside the compiled load sum
        ddq = (tau_h - self._s_load(q, dq) - tau_s) / self._s_M
        return ddq, ddth

    def _integrate_scalar(self, t0: float, h: float, k: int) -> None:
        q, th, dq, dth = (float(v) for v in self._y)
        tau_h = float(self._tau_h[0])
        f = self._deriv_scalar
        delayed = bool(self.model.delay[0])
        u = float(self._hist_u[-1][0])
        h2 = 0.5 * h
        for i in range(k):
            if delayed:
                u = float(self._delayed_input(t0 + i * h + h2)[0])
            a1q, a1t = f(q, th, dq, dth, u, tau_h)
            a2q, a2t = f(q + h2 * dq, th + h2 * dth, dq + h2 * a1q, dth + h2 * a1t, u, tau_h)
            v2q, v2t = dq + h2 * a1q, dth + h2 * a1t
            a3q, a3t = f(q + h2 * v2q, th + h2 * v2t, dq + h2 * a2q, dth + h2 * a2t, u, tau_h)
            v3q, v3t = dq + h2 * a2q, dth + h2 * a2t
            a4q, a4t = f(q + h * v3q, th + h * v3t, dq + h * a3q, dth + h * a3t, u, tau_h)
            v4q, v4t = dq + h * a3q, dth + h * a3t
            q += h / 6.0 * (dq + 2.0 * v2q + 2.0 * v3q + v4q)
            th += h / 6.0 * (dth + 2.0 * v2t + 2.0 * v3t + v4t)
            dq += h / 6.0 * (a1q + 2.0 * a2q + 2.0 * a3q + a4q)
            dth += h / 6.0 * (a1t + 2.0 * a2t + 2.0 * a3t + a4t)
        self._y = np.array([q, th, dq, dth])

    # ------------------------------------------------------------------ checks

    def _check_substep(self) -> None:
        """RK4 is stable for |λ h| ≲ 2.78: bound λ by the stiffest slope of friction and spring."""
        m = self.model
        lam = 0.0
        for side, inv in (("load", m.Minv), ("motor", m.Jinv)):
            eff = m.load_effects if side == "load" else m.motor_effects
            for e in eff:
                F = sum(float(getattr(e, p, 0.0)) for p in ("F_c", "F_s"))
                slope = F / self.sign_eps + float(getattr(e, "b", 0.0)) + float(getattr(e, "b_h", 0.0))
                lam = max(lam, slope * float(np.max(np.abs(np.diag(inv)))))
        k_sp = float(np.max(np.diag(m.K_s))) + sum(float(getattr(e, "k_stop", 0.0)) for e in m.spring_effects)
        mu = float(np.max(np.abs(np.diag(m.Minv))) + np.max(np.abs(np.diag(m.Jinv))))
        lam = max(lam, math.sqrt(k_sp * mu))
        if lam * self.h_max > 2.5:
            raise ValueError(f"substep {self.h_max:g} s too coarse for the plant's stiffest mode "
                             f"(|λ| ≈ {lam:.0f} 1/s); use substep_hz >= {lam / 2.5:.0f}")


def _compile_side(effects, gravity: float = 0.0):
    """Σ e.torque(angle, vel, 0) (+ gravity·sin(angle)) as one fast scalar function.

    The common types are folded into coefficients (same formulas as :mod:`sea_daemon.core.effects`):
    linear a0 + a1·angle + b·vel (viscous, human_viscoelastic), A sin + B cos (gravity:
    Σ a sin(angle + φ) = (Σ a cos φ) sin angle + (Σ a sin φ) cos angle), Coulomb and
    Stribeck friction, the spring stop; any other type is called as is.
    """
    from sea_daemon.core.effects import (
        Coulomb, Gravity, HumanViscoelastic, SpringSaturation, Stribeck, Viscous)
    c0 = c1 = b = 0.0
    A, B = gravity, 0.0
    coul: list[tuple[float, float]] = []
    strib: list[tuple[float, float, float]] = []
    stops: list[tuple[float, float, float]] = []
    other = []
    for e in effects:
        if isinstance(e, Viscous):
            b += e.b
        elif isinstance(e, HumanViscoelastic):
            c1 += e.k_h
            c0 -= e.k_h * e.q_h0
            b += e.b_h
        elif isinstance(e, Gravity):
            A += e.a * math.cos(e.phi)
            B += e.a * math.sin(e.phi)
        elif isinstance(e, Coulomb):
            coul.append((e.F_c, e.eps))
        elif isinstance(e, Stribeck):
            strib.append((e.F_s, 1.0 / e.v_s, e.eps))
        elif isinstance(e, SpringSaturation):
            stops.append((e.theta_max, e.k_stop, e.smooth))
        else:
            other.append(e.torque)
    tanh, exp, sin, cos, log1p = math.tanh, math.exp, math.sin, math.cos, math.log1p

    def softplus(x: float, w: float) -> float:
        z = x / w
        if z > 30.0:
            return x
        if z < -30.0:
            return 0.0
        return w * log1p(exp(z))

    def f(angle: float, vel: float) -> float:
        tau = c0 + c1 * angle + b * vel
        if A:
            tau += A * sin(angle)
        if B:
            tau += B * cos(angle)
        for F, eps in coul:
            tau += F * tanh(vel / eps)
        for F, ivs, eps in strib:
            r = vel * ivs
            tau += F * exp(-r * r) * tanh(vel / eps)
        for tm, k, w in stops:
            if angle > tm - 30.0 * w:
                tau += k * softplus(angle - tm, w)
            elif angle < 30.0 * w - tm:
                tau -= k * softplus(-angle - tm, w)
        for g in other:
            tau += g(angle, vel, 0.0)
        return tau

    if not (effects or gravity):
        return _zero
    return f


def _zero(angle: float, vel: float) -> float:
    return 0.0
