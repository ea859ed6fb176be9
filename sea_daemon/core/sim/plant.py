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

A model with ``model.urdf`` (n coupled joints) integrates on the generic path, its load side
by the rigid body's forward dynamics (ABA, :meth:`SEAModel.accelerations`); a true plant that
differs from the nominal model in its links takes a scaled description
(:meth:`~sea_daemon.core.rigid.RigidBody.scaled`, :meth:`SEAParams.with_rigid`) and its
hidden effects per joint.

A URDF that declares its joints' ranges (``<limit lower upper>``) gives the arm end stops there:
a stiff spring with a damper beyond each limit, zero within it (:mod:`.endstops`).

For one joint the RK4 substeps are compiled (:func:`_rk4_1`, numba) around the one-joint
dynamics kernel :func:`sea_daemon.core.dynamics.accel_1`; numpy's per-call overhead would
dominate for n = 1.  ``tests/test_sim.py`` checks that it agrees with ``SEAModel.accelerations``.
"""
from __future__ import annotations

import bisect
import math

import numpy as np
from scipy.optimize import brentq, root

from sea_daemon.core.config import ModelConfig
from sea_daemon.core.dynamics import accel_1, example, motor_accel, side_torques, spring_torque
from sea_daemon.core.effects import Effect
from sea_daemon.core.hardware_config import joint_values
from sea_daemon.core.jit import njit, warmer
from sea_daemon.core.model import SEAModel
from sea_daemon.core.sim.endstops import end_stops, stop_rate, stop_torque, stop_torques
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
    seed : seed of the motor-torque noise (std ``cfg.hardware.torque_noise``, each joint's own).
    substep_hz : internal RK4 rate [Hz].
    sign_eps : friction-sign smoothing of the true plant [rad/s].
    torque_noise : override of ``cfg.hardware.torque_noise`` [N m]: a number (every joint) or one per joint.
    tau_h_act0 : active human torque present at rest before t = 0 (for the equilibrium).
    extra_load_torque : ``f(q, q̇) -> (n,)`` [N m], a load-side torque outside the effect
        vocabulary that the load must overcome (for tests and benchmarks: an effect no model
        can name).  Not part of the static equilibrium at q0; the plant then integrates on the
        generic path.
    extra_held : evaluate ``extra_load_torque`` once per :meth:`step`, at the state the step
        starts from, and hold it over the step like τ_h,act (zero-order hold; it then enters
        eq:unknwn_load as −f on the τ_h,act side, and the compiled one-joint path applies).
        The discrete-time model the estimator predicts with holds its residual over the
        sample the same way (eq:fwdynwtorqueresidual1).

    ``step(tau_m, dt, tau_h_act)`` advances by dt with the commanded torque held; the
    applied torque is clip(tau_m, ±torque_limit) + noise (then κ and the delay act).
    """

    def __init__(self, cfg: ModelConfig, q0=0.0, seed: int | None = None, *,
                 substep_hz: float = SUBSTEP_HZ, sign_eps: float = PLANT_SIGN_EPS,
                 torque_noise=None, tau_h_act0=0.0, extra_load_torque=None,
                 extra_held: bool = False):
        self.cfg = cfg
        self.model = SEAModel(cfg.model, sign_eps=sign_eps)
        m = self.model
        self.n = n = m.n
        self.h_max = 1.0 / float(substep_hz)
        self.sign_eps = float(sign_eps)
        # |τ_m| limit: a number for one joint, each joint's (n,) for n (hardware.torque_limit per joint)
        lims = cfg.hardware.torque_limits(n)
        self.torque_limit = float(lims[0]) if n == 1 else lims
        #: the joints' end stops where the URDF declares their range (:mod:`.endstops`), or None
        self._stops = end_stops(m, lims)
        self.noise_std = cfg.hardware.torque_noise if torque_noise is None else torque_noise
        self.rng = np.random.default_rng(seed)
        self.encoders = Encoders(cfg.hardware, m.offset_load, m.offset_motor, n=n)
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
        #: the held residual (evaluated per step) or the one evaluated in every RK4 stage
        self._extra_held = extra_load_torque if extra_held else None
        self.extra_load_torque = None if extra_held else extra_load_torque
        # the compiled substeps know the vocabulary's effects (codes of effects.evaluate); an
        # effect that evaluates itself (outside the vocabulary) takes the model's sums
        #: load effects that evaluate themselves: added at every RK4 stage in Python around
        #: the compiled accelerations (:meth:`_rk4_outside`)
        self._py_load = tuple(e for e in m.load_effects if type(e).evaluate is not Effect.evaluate)
        self._scalar = n == 1 and self.extra_load_torque is None and self._stops is None and \
            all(type(e).evaluate is Effect.evaluate for e in (*m.motor_effects, *m.spring_effects))
        if self._scalar:
            self._compile_scalar()
        #: a rigid body (URDF) without torques outside the compiled vocabulary: each RK4 stage is
        #: one compiled call (:func:`_rigid_stage`) and one Pinocchio ABA call (:meth:`_rk4_rigid`)
        self._rigid = m.rigid is not None and self.extra_load_torque is None and not m.outside_effects
        if self._rigid:
            self._compile_rigid()

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
                # a bracket grown symmetrically around the linear spring's deflection: the root
                # nearest to it (an identified spring effect may bend τ_s back far out, e.g. a
                # softening cubic, where a second, unphysical root lies)
                t0 = target[j] / K[j, j]
                d = 1e-3 + 0.1 * abs(t0)
                for _ in range(80):
                    lo_b, hi_b = t0 - d, t0 + d
                    if g(lo_b) <= 0 <= g(hi_b):
                        break
                    d *= 2
                else:
                    raise ValueError(f"no static equilibrium of the spring at q = {q[j]:g} rad")
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
        if self._extra_held is not None:
            # eq:unknwn_load: M q̈ + ... + f = τ_h,act, f held over the step
            f = np.asarray(self._extra_held(self.q, self.dq), dtype=float)
            tau_h_act = np.broadcast_to(np.asarray(tau_h_act, dtype=float), (self.n,)) - f
        if self._scalar and not self.model.delay[0]:
            self._step_scalar(tau_m, dt, tau_h_act)
            return
        if self._rigid and not self._delayed:
            self._step_rigid(tau_m, dt, tau_h_act)
            return
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
            rk4 = self._rk4_rigid if self._rigid else self._rk4
            for i in range(k):
                ts = t0 + i * h
                # input held over the substep (evaluated at its midpoint for the delay lookup)
                ui = self._delayed_input(ts + 0.5 * h)
                y = rk4(y, h, ui)
            self._y = y
        self.t = t0 + dt
        self._prune_history()

    def _step_scalar(self, tau_m, dt: float, tau_h_act) -> None:
        """:meth:`step` of one joint without an input delay (the device model's plant, once per
        SYNC): the same numbers with float arithmetic around the one compiled call."""
        if not dt > 0:
            raise ValueError(f"dt must be > 0, got {dt}")
        u = float(tau_m[0]) if np.ndim(tau_m) else float(tau_m)
        th = float(tau_h_act[0]) if np.ndim(tau_h_act) else float(tau_h_act)
        if not (math.isfinite(u) and math.isfinite(th)):
            raise ValueError(f"tau_m and tau_h_act must be finite, got {tau_m!r}, {tau_h_act!r}")
        lim = self.torque_limit
        u = -lim if u < -lim else (lim if u > lim else u)          # np.clip
        if self._noisy:
            u = u + float(self.rng.normal(0.0, self.noise_std, 1)[0])   # torque_noise
        ua = self._s_u
        ua[0] = u
        self._u_applied = ua.copy()
        self._tau_h = np.array([th])
        # no delay: the history is read only at its end (_delayed_input, _integrate_scalar)
        self._hist_t[-1] = self.t
        self._hist_u[-1] = self._u_applied
        k = max(1, int(math.ceil(dt / self.h_max - 1e-9)))
        y = self._s_y
        y[:] = self._y
        if self._py_load:
            self._rk4_outside(y, u, th, dt / k, k)
        else:
            _rk4_1(y, u, th, dt / k, k, self.model.kernel)
        self._y = y.copy()
        self.t = self.t + dt

    def _step_rigid(self, tau_m, dt: float, tau_h_act) -> None:
        """:meth:`step` of a rigid body without an input delay (the device model's plant of a
        URDF, once per SYNC): the same numbers into preallocated arrays, the history kept only at
        its end (as :meth:`_step_scalar`; no delay reads it elsewhere)."""
        if not dt > 0:
            raise ValueError(f"dt must be > 0, got {dt}")
        n, u, th = self.n, self._r_u, self._r_tau_h
        u[:] = tau_m
        th[:] = tau_h_act
        if not (np.isfinite(u).all() and np.isfinite(th).all()):
            raise ValueError(f"tau_m and tau_h_act must be finite, got {tau_m!r}, {tau_h_act!r}")
        np.clip(u, -self.torque_limit, self.torque_limit, out=u)
        if self._noisy:
            u += self.rng.normal(0.0, self.noise_std, n)          # torque_noise, each joint's std
        self._u_applied = u.copy()
        self._tau_h = th.copy()
        self._hist_t[-1] = self.t
        self._hist_u[-1] = self._u_applied
        k = max(1, int(math.ceil(dt / self.h_max - 1e-9)))
        h = dt / k
        y = self._y
        for _ in range(k):
            y = self._rk4_rigid(y, h, self._u_applied)
        self._y = y
        self.t = self.t + dt

    def _rk4_outside(self, y, u: float, tau_h: float, h: float, k: int) -> None:
        """:func:`_rk4_1` with the load effects outside the compiled vocabulary evaluated in
        Python at every stage: their torque f enters eq:unknwn_load on the τ_h,act side,
        M q̈ = (τ_h,act − f) − Σ_compiled − τ_s (what ``SEAModel.accelerations`` sums)."""
        p, eff = self.model.kernel, self._py_load

        def acc(q, th, dq, dth):
            f = 0.0
            for e in eff:
                f += e.evaluate(q, dq, 0.0)[0]
            return accel_1(p, q, th, dq, dth, u, tau_h - f)

        q, th, dq, dth = float(y[0]), float(y[1]), float(y[2]), float(y[3])
        h2 = 0.5 * h
        for _ in range(k):
            a1q, a1t = acc(q, th, dq, dth)
            v2q, v2t = dq + h2 * a1q, dth + h2 * a1t
            a2q, a2t = acc(q + h2 * dq, th + h2 * dth, v2q, v2t)
            v3q, v3t = dq + h2 * a2q, dth + h2 * a2t
            a3q, a3t = acc(q + h2 * v2q, th + h2 * v2t, v3q, v3t)
            v4q, v4t = dq + h * a3q, dth + h * a3t
            a4q, a4t = acc(q + h * v3q, th + h * v3t, v4q, v4t)
            q += h / 6.0 * (dq + 2.0 * v2q + 2.0 * v3q + v4q)
            th += h / 6.0 * (dth + 2.0 * v2t + 2.0 * v3t + v4t)
            dq += h / 6.0 * (a1q + 2.0 * a2q + 2.0 * a3q + a4q)
            dth += h / 6.0 * (a1t + 2.0 * a2t + 2.0 * a3t + a4t)
        y[0], y[1], y[2], y[3] = q, th, dq, dth

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
        # eq:thetadd and eq:unknwn_load, f_res the torque outside the vocabulary (if any)
        f_x = None if self.extra_load_torque is None else self.extra_load_torque(q, dq)
        if self._stops is not None:                 # the end stops: a torque the load overcomes
            f_s = np.zeros(n)
            if stop_torques(self._stops, q, dq, f_s):
                f_x = f_s if f_x is None else f_x + f_s
        ddth, ddq = self.model.accelerations(x, u, f_x)
        return np.concatenate([dq, dth, ddq, ddth])

    def _rk4(self, y: np.ndarray, h: float, u: np.ndarray) -> np.ndarray:
        k1 = self._deriv(y, u)
        k2 = self._deriv(y + 0.5 * h * k1, u)
        k3 = self._deriv(y + 0.5 * h * k2, u)
        k4 = self._deriv(y + h * k3, u)
        return y + h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)

    # rigid-body (URDF) path: the same equations, one compiled call and one ABA per stage
    def _compile_rigid(self) -> None:
        n = self.n
        self._r_k = np.zeros((4, 4 * n))              # the four stages' derivatives
        self._r_ys = np.zeros(4 * n)                  # the state a stage evaluates at
        self._r_q, self._r_dq, self._r_tau = np.zeros(n), np.zeros(n), np.zeros(n)
        self._r_u, self._r_tau_h, self._r_uh = np.zeros(n), np.zeros(n), np.zeros(n)
        self._delayed = bool(np.any(self.model.delay))
        # the end stops (no range: ±inf, never touched)
        self._r_stops = self._stops if self._stops is not None else \
            np.column_stack([np.full(n, -np.inf), np.full(n, np.inf), np.zeros(n), np.zeros(n)])
        # compiled (or loaded from numba's cache) now, at construction, not in the first step
        self._rk4_rigid(self._y.copy(), self.h_max, np.zeros(n))

    def _rk4_rigid(self, y: np.ndarray, h: float, u: np.ndarray) -> np.ndarray:
        """:meth:`_rk4` of a rigid body: per stage, :func:`_rigid_stage` gives q, q̇, the torque on
        the rigid body besides its bias and θ̈_m; Pinocchio's ABA gives q̈ (eq:unknwn_load)."""
        n, p, body = self.n, self.model.kernel, self.model.rigid
        model, data, aba = body.model, body.data, pinocchio_aba()
        K, ys, q, dq, tau = self._r_k, self._r_ys, self._r_q, self._r_dq, self._r_tau
        ua = self._r_uh
        ua[:] = u
        tau_h = self._tau_h
        for i, c in enumerate((0.0, 0.5 * h, 0.5 * h, h)):
            _rigid_stage(p, y, K[i - 1], c, ua, tau_h, ys, K[i], q, dq, tau, self._r_stops)
            K[i, 2 * n:3 * n] = aba(model, data, q, dq, tau)
        return _rk4_sum(y, h, K)

    # scalar (n = 1) path: the same equations compiled (:func:`_rk4_1`, dynamics.accel_1)
    def _compile_scalar(self) -> None:
        self._s_y = np.zeros(4)
        self._s_u = np.zeros(1)
        # compiled (or loaded from numba's cache) now, at construction, not in the first step
        _rk4_1(self._s_y.copy(), 0.0, 0.0, self.h_max, 0, self.model.kernel)

    def _deriv_scalar(self, q, th, dq, dth, u, tau_h) -> tuple[float, float]:
        """(q̈, θ̈_m) of the one joint (:func:`~sea_daemon.core.dynamics.accel_1`, the load effects
        outside the compiled vocabulary on the τ_h,act side as in :meth:`_rk4_outside`)."""
        f = sum(e.evaluate(q, dq, 0.0)[0] for e in self._py_load)
        return accel_1(self.model.kernel, q, th, dq, dth, u, tau_h - f)

    def _integrate_scalar(self, t0: float, h: float, k: int) -> None:
        y = self._s_y
        y[:] = self._y
        tau_h = float(self._tau_h[0])
        p = self.model.kernel
        if bool(self.model.delay[0]):
            for i in range(k):
                # input held over the substep, evaluated at its midpoint for the delay lookup
                u = float(self._delayed_input(t0 + i * h + 0.5 * h)[0])
                if self._py_load:
                    self._rk4_outside(y, u, tau_h, h, 1)
                else:
                    _rk4_1(y, u, tau_h, h, 1, p)
        elif self._py_load:
            self._rk4_outside(y, float(self._hist_u[-1][0]), tau_h, h, k)
        else:
            _rk4_1(y, float(self._hist_u[-1][0]), tau_h, h, k, p)
        self._y = y.copy()

    @property
    def noise_std(self):
        """Standard deviation of the motor-torque noise [N m]: a float for one joint, each
        joint's (n,) for n (``hardware.torque_noise`` per joint)."""
        return self._noise_std

    @noise_std.setter
    def noise_std(self, v) -> None:
        std = joint_values(v, self.n)
        self._noise_std = float(std[0]) if self.n == 1 else std
        self._noisy = bool(np.any(std > 0))

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
        lam = max(lam, math.sqrt(k_sp * mu), stop_rate(self._stops, m.Minv))
        if lam * self.h_max > 2.5:
            raise ValueError(f"substep {self.h_max:g} s too coarse for the plant's stiffest mode "
                             f"(|λ| ≈ {lam:.0f} 1/s); use substep_hz >= {lam / 2.5:.0f}")


@njit
def _rk4_1(y, u, tau_h, h, k, p) -> None:
    """k classical RK4 substeps of length h of y = [q, θ_m, q̇, θ̇_m] (one joint), u and τ_h,act
    held; p the packed :class:`~sea_daemon.core.dynamics.Dynamics` of the plant."""
    q, th, dq, dth = y[0], y[1], y[2], y[3]
    h2 = 0.5 * h
    for _ in range(k):
        a1q, a1t = accel_1(p, q, th, dq, dth, u, tau_h)
        v2q, v2t = dq + h2 * a1q, dth + h2 * a1t
        a2q, a2t = accel_1(p, q + h2 * dq, th + h2 * dth, v2q, v2t, u, tau_h)
        v3q, v3t = dq + h2 * a2q, dth + h2 * a2t
        a3q, a3t = accel_1(p, q + h2 * v2q, th + h2 * v2t, v3q, v3t, u, tau_h)
        v4q, v4t = dq + h * a3q, dth + h * a3t
        a4q, a4t = accel_1(p, q + h * v3q, th + h * v3t, v4q, v4t, u, tau_h)
        q += h / 6.0 * (dq + 2.0 * v2q + 2.0 * v3q + v4q)
        th += h / 6.0 * (dth + 2.0 * v2t + 2.0 * v3t + v4t)
        dq += h / 6.0 * (a1q + 2.0 * a2q + 2.0 * a3q + a4q)
        dth += h / 6.0 * (a1t + 2.0 * a2t + 2.0 * a3t + a4t)
    y[0], y[1], y[2], y[3] = q, th, dq, dth


def pinocchio_aba():
    """Pinocchio's ``aba(model, data, q, dq, tau)`` (imported where a rigid body exists)."""
    import pinocchio  # local import: only a plant with a URDF needs it
    return pinocchio.aba


@njit
def _rigid_stage(p, y, k_prev, c, u, tau_h, ys, k, q, dq, tau, stops) -> None:
    """One RK4 stage of a rigid body's plant, y = [q, θ_m, q̇, θ̇_m] (4n): ys = y + c k_prev; k gets
    [q̇, θ̇_m, ·, θ̈_m] at ys (q̈ left to the rigid body's ABA); q, dq, tau the ABA's inputs, tau =
    τ_h,act − Σ_load e − τ_s − f_stop (eq:unknwn_load, eq:thetadd, eq:spring_torque; ``stops`` the
    end stops of :mod:`.endstops`, f_stop = 0 within the joints' ranges)."""
    n = q.shape[0]
    for i in range(4 * n):
        ys[i] = y[i] + c * k_prev[i] if c != 0.0 else y[i]
    th_m, dth_m = ys[n:2 * n], ys[3 * n:]
    for j in range(n):
        q[j] = ys[j]
        dq[j] = ys[2 * n + j]
    tau_s = spring_torque(p, q - th_m, dq - dth_m)
    lo, _, _ = side_torques(p[10], q, dq)
    ddth = motor_accel(p, th_m, dth_m, u, tau_s)
    for j in range(n):
        tau[j] = tau_h[j] - lo[j] - tau_s[j]
        f = stop_torque(stops, j, q[j], dq[j])
        if f != 0.0:
            tau[j] -= f
        k[j] = dq[j]
        k[n + j] = dth_m[j]
        k[3 * n + j] = ddth[j]


@njit
def _rk4_sum(y, h, K):
    """y + h/6 (k1 + 2 k2 + 2 k3 + k4), a new array."""
    return y + h / 6.0 * (K[0] + 2.0 * K[1] + 2.0 * K[2] + K[3])


@warmer
def _warm() -> None:
    _rk4_1(np.zeros(4), 0.0, 0.0, 1e-3, 1, example(1).packed())
