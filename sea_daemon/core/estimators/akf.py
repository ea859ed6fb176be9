"""Augmented-state extended Kalman filter (AKF) of Park et al., with the GP-AKF hook.

State (Sec. IV-B)  x = [θ_m, θ_s, θ̇_m, θ̇_s, τ_h,act] ∈ R^{5n} (integrated walk: τ̇_h,act too, 6n), input u = τ_m,
measurement        y = [θ_m, θ_s, θ̇_m, θ̇_s] = H x + v,  H = [I_4n 0]   (eq:nonlinkOsys)

from the two encoders: θ_s = q − θ_m, velocities from the causal differentiator of
:mod:`sea_daemon.core.kinematics`, declared encoder offsets removed first
(:meth:`SEAModel.correct_measurement`).

Prediction (Alg. 1 lines 3-5; with a residual, Alg. 2 lines 4-10)
    ẋ = f_nom(x, u) − I_μ M⁻¹ μ(ẑ)                          eq:fwdynwtorqueresidual1
    A = F_nom(x̂, u) − I_μ M⁻¹ F_GP                           eq:linearization
    discretised by local linearisation over the step (one matrix exponential,
    :func:`sea_daemon.core.linalg.zoh` of [[A, f, I_μ M⁻¹], [0, 0, 0]]·dt): exact zero-order
    hold for a linear plant, so on a linear plant this filter equals the textbook discrete KF
    step for step.
    Q_k = Σ_nom + Γ_μ diag(σ²) Γ_μᵀ                          eq:gpakf_covariance, eq:GPvarfwd
Update (Alg. 1 lines 6-8), with the covariance in Joseph form (symmetrised).

Declared model effects all act through :class:`SEAModel` (friction, gravity, human
viscoelasticity, spring non-linearities, torque scale, inertia); encoder offsets through
``correct_measurement``; a declared ``delay`` by applying τ_m(t − delay) from a short
input history.  An "oracle" AKF is this class built from the true plant's configuration.

The numerics of a step are compiled (:mod:`~sea_daemon.core.estimators.akf_core`, numba; compiled
or loaded from numba's cache at construction).  Pure numerics: no I/O, no clock, no
threads.  Per-step quantities are kept as attributes (as filterpy's): ``A_k``
(continuous Jacobian), ``F_k`` (discrete transition), ``Gamma_mu`` (discrete map of a torque
error held over the step to the state), ``Q_k``, ``xdot_k``, ``x_prior``, ``P_prior``,
``S_k``, ``K_k``, ``innovation``, ``nis``, ``y``, ``P`` (posterior); and the causal
kinematics of the sample (``kin_angle``, ``kin_vel``, ``kin_acc``, each
[q, θ_m]).  What the Theorem-1 bound needs of a step is its :attr:`record`
(:class:`~sea_daemon.core.estimators.record.StepRecord`, views of these attributes and x̂_{k−1},
P_{k−1}, u, dt), handed to the bound at the end of every reset and step (:meth:`AKF.finish_step`)
or to a consumer attached in its place (:meth:`AKF.attach`).  The differentiator assumes the nominal period ``dt``; the prediction uses each
step's own dt.
"""
from __future__ import annotations

import math
from typing import Callable

import numpy as np

from sea_daemon.core.jit import warm_up
from sea_daemon.core.config import ModelConfig
from sea_daemon.core.kinematics import CausalDifferentiator
from sea_daemon.core.model import SEAModel, StateLayout
from sea_daemon.core.model_core import ModelTables, RigidTables
from sea_daemon.core.estimators import akf_core
from sea_daemon.core.bounds.ellipsoid import chi2_quantile
from sea_daemon.core.estimators.base import Bound, Estimate, Residual
from sea_daemon.core.estimators.gate import StartupGate
from sea_daemon.core.estimators.validity import STARTUP, BoundValidity
from sea_daemon.core.estimators.record import RESET, STEP, BoundConsumer, StepRecord
from sea_daemon.core.estimators.health import CovarianceDiverged, CovarianceNotPD, EstimatorHealth, EstimatorNonFinite
from sea_daemon.errors import EstimatorFault


#: the longest step :meth:`AKF.update` bridges, in periods
MAX_GAP = 10.0


class SampleGap(EstimatorFault):
    """A step much longer than the period (a gap in a log); raised before the filter moves."""


#: caps of bounded P (standard deviations): angles [rad], velocities [rad/s], τ_h,act [× hardware.torque_limit], τ̇_h,act [× that /s]
P_CAP_ANGLE, P_CAP_VEL, P_CAP_TORQUE, P_CAP_TORQUE_RATE = 1.0, 50.0, 10.0, 1000.0
#: a predicted variance beyond this many times its cap is divergence (the typed fault)
DIVERGED = 1e12
#: [s] the GP-AKF's residual error enters Q as held over this long (at least one step; eq:GPvarfwd)
GP_HOLD_S = 0.01


class AKF:
    """Augmented-state EKF (Alg. 1); with ``residual`` the GP-AKF (Alg. 2).

    ``cfg``: model configuration (nominal model + declared effects, R, Σ_nom, P0, δ,
    kinematics).  ``dt``: nominal sample period (default ``1/cfg.rate_hz``).
    ``residual``: optional :class:`~sea_daemon.core.estimators.base.Residual` (learned f(z)).
    ``bound``: optional ``bound(akf) -> Bound | None``, called once at the end of construction;
    the :class:`~sea_daemon.core.estimators.base.Bound` it returns (:attr:`bound`) fills
    ``tau_h_act_bound`` at the end of every reset and filter step from the step's :attr:`record`
    (e.g. :func:`sea_daemon.core.bounds.akf_bound.theorem_bound`, the Theorem-1 ρ_k); then the
    start-up gate (:attr:`gate`, a :class:`StartupGate`) sets ``valid``.  A
    :class:`~sea_daemon.core.estimators.record.BoundConsumer` attached with :meth:`attach`
    takes the records instead (the daemon's bound worker).

    Without a bound ``tau_h_act_bound`` is the KF's own ellipsoidal bound sqrt(s·P_ττ) with s
    the χ² quantile for 5n degrees of freedom at 1 − δ (eq:gaussianellipsoid): the confidence
    set C_k of Theorem 1 with a point set of means (X̂_k = 0), projected on each τ_h,act
    component.
    """

    name = "akf"

    def __init__(self, cfg: ModelConfig, dt: float | None = None, residual: Residual | None = None,
                 model: SEAModel | None = None, bound: Callable[["AKF"], Bound | None] | None = None):
        self.cfg = cfg
        self.model = model if model is not None else SEAModel.from_config(cfg)
        n = self.n = self.model.n
        est = cfg.estimator
        self.layout = StateLayout.of(n, est.tau_h_act_model)    # where τ_h,act (and τ̇_h,act) lie in x
        d = self.d = self.layout.d
        m = self.m = self.layout.m
        self.dt = float(dt) if dt else cfg.dt
        self._init_step_arrays()
        self.R[:] = est.R
        self._init_process_noise(est)
        self._init_filter(est, residual)
        self._init_input_history()
        self._init_nominal()
        # the compiled step (akf_core) is compiled or loaded from numba's cache now, not in
        # the first loop cycle
        warm_up()
        # the start-up gate (Estimate.valid, :class:`StartupGate`)
        t_max = est.tau_h_act_max if est.tau_h_act_max is not None else cfg.hardware.torque_limit_max
        self.tau_h_act_max = float(t_max)
        self.gate = StartupGate(n, self.H, self.s, self.tau_h_act_max)
        # after the gate, whether ρ_k is a real estimate (validity.BoundValidity)
        self.validity = BoundValidity(n, self.H, self.s, self.P_max, False,
                                      self.tau_h_act_max if est.bound_limit is None else est.bound_limit)
        # what each step hands its bound (record.StepRecord): views of this filter's arrays, and
        # x̂_{k−1}, P_{k−1} kept for it before each step
        self.record = StepRecord(STEP, 0, self.dt, False, 0, np.zeros(n), np.zeros(d), np.zeros((d, d)), self.z,
                                 self.A_k, self.F_k, self.Gamma_mu, self.K_k, self.P, self.mu, self.dmu_dz,
                                 self.gate.b0, self.Sigma_nom, self.innovation, self.S_k)
        # the bound component, and what takes the records in its place (:meth:`attach`)
        self.consumer: BoundConsumer | None = None
        self.bound: Bound | None = None
        if bound is not None:
            self.bound = bound(self)

    def _init_step_arrays(self) -> None:
        """The arrays of the compiled step (akf_core.STEP_FIELDS): views of one flat buffer; the
        step takes the buffer, the AKF reads and writes them by name."""
        d, m, n = self.d, self.m, self.n
        self._buf = np.zeros(akf_core.buffer_size(d, m, n))
        (self.A_k, self.xdot_k, self.mu, self.dmu_dz, self.dz_dx, self.sigma2, self.G_mu, self.Sigma_nom, self.R,
         self.y, self.x, self.P, self.F_k, self.Gamma_mu, self.Q_k, self.x_prior, self.P_prior, self.S_k, self.K_k,
         self.innovation, self._aug, self._E, self._Bx, self._L, self._rhs, self._IKH, self._work,
         self._KR) = akf_core.views(self._buf, d, m, n)

    def _init_process_noise(self, est) -> None:
        """Σ_nom as configured, its per-step form (:meth:`fill_sigma_nom`) and the GP variance's scale."""
        # Σ_nom as configured; ``Sigma_nom`` is the per-step value the next step uses
        # (:meth:`fill_sigma_nom`, equal to the configured one unless Sigma_nom_dt / tau_m_noise)
        self.Sigma_nom_cfg = np.array(est.Sigma_nom, dtype=float)
        self.Sigma_nom[:] = self.Sigma_nom_cfg
        self._S_dt = float(est.Sigma_nom_dt)
        self._tau_m_var = float(est.tau_m_noise) ** 2
        self._S_varies = self._S_dt > 0 or self._tau_m_var > 0
        # GP-AKF: the residual's predictive variance enters Q as a torque error held over the
        # step (eq:GPvarfwd), a smooth function of z correlated over far more than one cycle: held
        # over GP_HOLD_S (σ²·T/dt per step of dt < T; ×10 at 1 kHz), not one cycle, else the 1 kHz
        # filter believes the GP ten times better per second and the set of means runs away at
        # standstills (docs/bounds.md §8).
        self._gp_var_scale = max(1.0, GP_HOLD_S / self.dt)
        self._S_base_dt = -1.0                        # step length of the cached Σ_nom·dt/T
        self._S_base = self.Sigma_nom_cfg

    def _init_filter(self, est, residual) -> None:
        """P₀, δ and s, H, the residual, the differentiator, ∂z/∂x and the other per-step quantities."""
        n, d, m = self.n, self.d, self.m
        # estimator.init_after_kinematics: samples left until the differentiator is full
        self._init_kin = bool(est.init_after_kinematics)
        self._filling = 0
        self.P0 = np.array(est.P0, dtype=float)
        self._P_init = self.P0
        self.delta = est.delta
        # eq:gaussianellipsoid: χ² quantile, dof = 5n, level 1 − δ
        self.s = chi2_quantile(1.0 - self.delta, d)
        self._sqrt_s = math.sqrt(self.s)
        self.H = np.hstack([np.eye(m), np.zeros((m, d - m))])
        self.residual = residual
        # I_μ M⁻¹ (d × n): how a load-side torque enters ẋ (eq:unknown)
        self.G_mu[:] = self.layout.pad(self.model.I_mu) @ self.model.Minv
        kin = self.cfg.kinematics
        self.kin = CausalDifferentiator(self.dt, kin.window, 2 * n, kin.method, kin.degree)
        # ∂z/∂x for z = [q, q̇, q̈]: q = θ_m + θ_s, q̇ = θ̇_m + θ̇_s; q̈ comes from the
        # differentiator (a measurement, not a state function), so ∂q̈/∂x = 0.
        I = np.eye(n)
        self.dz_dx[:n, :n] = I
        self.dz_dx[:n, n:2 * n] = I
        self.dz_dx[n:2 * n, 2 * n:3 * n] = I
        self.dz_dx[n:2 * n, 3 * n:4 * n] = I
        # --- other per-step quantities
        self.F_k[:] = np.eye(d)
        self.Q_k[:] = self.Sigma_nom
        self.B_u = self.layout.pad(self.model.B_nom())    # ∂f_nom/∂u (d × n)
        self.Gamma_u, self.nis = np.zeros((d, n)), 0.0     # ZOH map of a held motor-torque error; NIS
        self.z = np.zeros(3 * n)          # ẑ_{k−1} given to the residual
        self._bound0 = np.zeros(n)        # the bound published at reset (and while the kinematics fill)
        self.u_applied = np.zeros(n)
        self._ang = np.zeros(2 * n)
        self._ddq = np.zeros(n)
        self.est = Estimate.zeros(n, d)
        # bounded P: caps of the variances of [θ_m, θ_s, θ̇_m, θ̇_s, τ_h,act(, τ̇_h,act)] (akf_core.cap_covariance)
        lim = self.cfg.hardware.torque_limit_max
        self.P_max = np.repeat([P_CAP_ANGLE ** 2, P_CAP_ANGLE ** 2, P_CAP_VEL ** 2, P_CAP_VEL ** 2,
                                (P_CAP_TORQUE * lim) ** 2, (P_CAP_TORQUE_RATE * lim) ** 2][:d // n], n)
        self.n_capped = 0
        # estimator hygiene (docs/safety.md): windowed NIS against its chi2 band, Cholesky of P
        self.health = EstimatorHealth(m, est.nis_window, est.nis_alpha, est.nis_scale)

    def _init_input_history(self) -> None:
        """The input history for the declared delay (τ_m(t − delay), linear interpolation of the
        sample sequence = the exact interval average of a zero-order-hold input)."""
        n = self.n
        self.delay = np.array(self.model.delay, dtype=float)
        self.has_delay = bool(np.any(self.delay > 0))
        cap = int(math.ceil(float(self.delay.max(initial=0.0)) / self.dt)) + 4
        self._hcap = cap
        self._ht = np.zeros(2 * cap)
        self._hu = np.zeros((2 * cap, n))
        self._hhead = cap - 1
        self._t = 0.0
        self._ready = False

    def _init_nominal(self) -> None:
        """F_nom / f_nom: constant blocks of the plain model, else the tables of one with declared
        effects or a rigid body of n coupled joints (a URDF: M(q), C(q, q̇) by Pinocchio, G_μ per step)."""
        n, d = self.n, self.d
        # the plain nominal model (no declared effects): f_nom is affine in x but for C(q) = g ⊙ sin q,
        # so the constant blocks of F_nom and f_nom are built once here (= SEAModel.F_nom / f_nom)
        self._affine = not self.model.effects and self.model.rigid is None
        self._no_offsets = not (np.any(self.model.offset_load) or np.any(self.model.offset_motor))
        # declared effects: F_nom / f_nom compiled (model_core, through effects.evaluate; equal to
        # SEAModel.F_nom / f_nom); None where the model is affine or outside the compiled vocabulary
        self.tables = None
        if self.model.rigid is not None:
            self.tables = RigidTables(self.model, self.G_mu)
        elif not self._affine and ModelTables.supports(self.model):
            self.tables = ModelTables(self.model)
        if self._affine:
            m_ = self.model
            # F_nom at q = 0 contains −M⁻¹ diag(g cos 0) in the θ̈_s rows; add it back
            A_lin = m_.F_nom(np.zeros(d), np.zeros(n))          # (d, d): with the integrated walk's τ̇ rows
            self._MinvG = m_.Minv * m_.gravity[None, :]           # M⁻¹ diag(g)
            A_lin[3 * n:4 * n, :n] += self._MinvG
            A_lin[3 * n:4 * n, n:2 * n] += self._MinvG
            self._A_lin = A_lin
            self._B_lin = self.B_u

    @property
    def ready(self) -> bool:
        """Whether the filter was initialised from a sample (the next ``update`` steps it)."""
        return self._ready

    @property
    def converged(self) -> bool:
        """The start-up gate has opened since the last start (:class:`StartupGate`)."""
        return self.gate.converged

    @property
    def converged_at(self) -> int:
        """The step count k at which the start-up gate opened (−1: not yet)."""
        return self.gate.converged_at

    @property
    def gate_starts(self) -> int:
        """How often the start-up gate started."""
        return self.gate.starts

    # ------------------------------------------------------------------ the bound's seam

    def attach(self, consumer: BoundConsumer) -> None:
        """Hand every reset's and step's :class:`StepRecord` to ``consumer`` in place of the
        in-step bound and start-up gate (the consumer fills ρ and ``valid``; e.g. the daemon's
        bound worker, which runs :meth:`finish_step` on a copy of this filter)."""
        self.consumer = consumer

    def detach(self) -> BoundConsumer | None:
        """The consumer attached (or None), detached: the bound runs in the step again."""
        c, self.consumer = self.consumer, None
        return c

    def finish_step(self, e: Estimate, record: StepRecord) -> bool:
        """The end of a reset or filter step on its record: the bound's reset or step (ρ_k into
        ``e.tau_h_act_bound``), then, for a step, the start-up gate; returns whether the estimate
        is valid.  What :meth:`step` does, and what a consumer runs on its copy of the filter."""
        b = self.bound
        gate = self.gate
        e.invalid_reason = STARTUP
        if record.kind == RESET:
            gate.stop()
            self.validity.stop()
            if b is not None:
                b.reset(e, record)
            return False
        if b is not None:
            b.step(e, record)
        gate.follow(record.gate_starts, record.gate_box)
        if not gate.check(record.K_k, record.F_k, e.tau_h_act_bound, e.k):
            return False
        return self.validity.judge(e, record, self.residual is not None, b)

    # ------------------------------------------------------------------ measurement

    def measure(self, q, theta_m) -> np.ndarray:
        """y = [θ_m, θ_s, θ̇_m, θ̇_s] from raw encoder angles (updates the differentiator)."""
        n = self.n
        if self._no_offsets:                # no declared encoder offsets: the angles as read
            self._ang[:n] = q
            self._ang[n:] = theta_m
        else:
            qc, thc = self.model.correct_measurement(np.asarray(q, dtype=float), np.asarray(theta_m, dtype=float))
            self._ang[:n] = qc
            self._ang[n:] = thc
        ang, vel, acc = self.kin.update(self._ang)
        y = self.y
        y[:n] = ang[n:]
        # θ_s = q − θ_m (eq:spring_torque)
        np.subtract(ang[:n], ang[n:], out=y[n:2 * n])
        y[2 * n:3 * n] = vel[n:]
        np.subtract(vel[:n], vel[n:], out=y[3 * n:])
        self._ddq[:] = acc[:n]
        # the causal kinematics of this sample, [q, θ_m] each (views, overwritten next sample):
        # what a learner needs for training pairs (eq:loadsidewmotor) with the same filter
        self.kin_angle, self.kin_vel, self.kin_acc = ang, vel, acc
        return y

    def _push_input(self, tau_m) -> None:
        h = self._hhead + 1
        if h >= self._hcap:
            h = 0
        self._hhead = h
        self._ht[h] = self._ht[h + self._hcap] = self._t
        self._hu[h] = self._hu[h + self._hcap] = tau_m

    def _delayed_input(self, t_query: float) -> np.ndarray:
        """τ_m(t_query − delay) per joint from the history (clamped at its ends)."""
        h = self._hhead + 1
        ts = self._ht[h:h + self._hcap]
        us = self._hu[h:h + self._hcap]
        for j in range(self.n):
            self.u_applied[j] = np.interp(t_query - self.delay[j], ts, us[:, j])
        return self.u_applied

    # ------------------------------------------------------------------ API

    def reset(self, q=None, theta_m=None, tau_m=None, x0=None, P0=None) -> Estimate:
        """Initialise from the first sample: x̂₀ measured (velocities 0, τ_h,act = 0),
        P₀ from the configuration (Sec. V-B: the measurement noise R, plus P0_tau).  With
        ``estimator.init_after_kinematics`` the filter starts once the differentiator is full,
        with the measured velocities (:meth:`_fill_kinematics`).

        Without a sample (``reset()``) the next :meth:`update` initialises instead.
        """
        n = self.n
        self.health.reset()
        if q is None or theta_m is None:
            self._ready = False
            self.est.k = 0
            self._hand_reset(self.est)
            return self.est
        self.kin.forget()
        tau_m = np.zeros(n) if tau_m is None else np.asarray(tau_m, dtype=float)
        y = self.measure(q, theta_m)
        self._check_finite(y, tau_m)
        if x0 is None:
            self.x[:] = 0.0
            self.x[:2 * n] = y[:2 * n]
        else:
            self.x[:] = x0
        self.P[:] = self.P0 if P0 is None else P0
        # init_after_kinematics: the velocities of y are valid once the differentiator holds a
        # full window; until then hold x̂ at the measured angles and P at P₀ (see _fill_kinematics)
        self._P_init = self.P0 if P0 is None else np.array(P0, dtype=float)
        self._filling = self.kin.L - 1 if (self._init_kin and x0 is None) else 0
        self._t = 0.0
        # history primed with τ_m held before the first sample (times strictly increasing)
        self._hhead = self._hcap - 1
        past = -self.dt * np.arange(self._hcap - 1, -1, -1, dtype=float)
        self._ht[:self._hcap] = past
        self._ht[self._hcap:] = past
        self._hu[:] = tau_m
        self.u_applied[:] = tau_m
        self._ready = True
        self.est.k = 0
        self.gate.stop()
        if not self._filling:
            self.gate.start(self.P)
        e = self._fill_estimate()
        e.valid, e.invalid_reason = False, STARTUP     # the first sample: no estimate of τ_h,act yet
        self._hand_reset(e)
        # while the differentiator fills, x̂ holds the angles and P = P₀: the bound of the reset holds
        self._bound0[:] = e.tau_h_act_bound
        return e

    def update(self, q, theta_m, tau_m, dt: float | None = None) -> Estimate:
        """One sample: predict over dt with τ_m of the previous sample, update with y_k."""
        if not self._ready:
            return self.reset(q, theta_m, tau_m)
        dt = self.dt if dt is None else float(dt)
        if not 0.0 < dt <= MAX_GAP * self.dt:
            # the differentiator and the prediction's linearisation hold over a few periods, not a
            # gap: a log with one is two logs
            raise SampleGap(f"AKF step {self.est.k + 1}: step of {dt:.6g} s, allowed 0 < dt <= {MAX_GAP:g} x "
                            f"the period {self.dt:.6g} s (a gap in the log: split it there)")
        if self._filling:
            return self._fill_kinematics(q, theta_m, tau_m, dt)
        n = self.n
        # ẑ_{k−1} = [q̂, q̂̇, q̈] at the previous posterior (Alg. 2 line 5)
        x = self.x
        np.add(x[:n], x[n:2 * n], out=self.z[:n])
        np.add(x[2 * n:3 * n], x[3 * n:4 * n], out=self.z[n:2 * n])
        self.z[2 * n:] = self._ddq
        if self.has_delay:
            u = self._delayed_input(self._t)
        else:
            u = self._hu[self._hhead]
        y = self.measure(q, theta_m)
        if self._S_varies:
            self.fill_sigma_nom(dt)
        self.step(y, u, dt)
        self._t += dt
        self._push_input(np.asarray(tau_m, dtype=float))
        return self.est

    def _fill_kinematics(self, q, theta_m, tau_m, dt: float) -> Estimate:
        """A sample while the differentiator fills after :meth:`reset` (``init_after_kinematics``).

        Sec. V-B: "the initial state x̂₀ is measured and P₀ is set to R" — but the velocities of y
        come from the causal differentiator, which needs a full window (``kin.L`` samples) before
        they are valid; started at once, a joint that is already moving (velocity 0 in x̂₀ with
        P₀ = R) puts a spurious torque into τ̂_h,act.  So x̂ holds the measured angles, τ̂_h,act = 0
        and P = P₀ until the window is full; at that sample x̂₀ = [y, 0] (angles and velocities
        measured) and the filter runs from the next one.
        """
        n = self.n
        y = self.measure(q, theta_m)
        self._check_finite(y, tau_m)
        self._filling -= 1
        x = self.x
        x[:] = 0.0
        x[:2 * n] = y[:2 * n]
        self.P[:] = self._P_init
        if not self._filling:
            x[:4 * n] = y
            self.gate.start(self.P)
        self._t += dt
        self._push_input(np.asarray(tau_m, dtype=float))
        self.est.k += 1
        e = self._fill_estimate()
        e.tau_h_act_bound[:] = self._bound0
        e.valid, e.invalid_reason = False, STARTUP     # the differentiator is still filling
        return e

    def _check_finite(self, y, tau_m) -> None:
        """The typed fault for a non-finite sample outside the compiled step (which checks its own)."""
        if not (np.isfinite(y).all() and np.isfinite(tau_m).all()):
            raise EstimatorNonFinite(f"AKF step {self.est.k + 1}: non-finite measurement or motor torque "
                                     f"(y = {np.asarray(y).tolist()}, tau_m = {np.asarray(tau_m).tolist()})")

    def fill_sigma_nom(self, dt: float) -> np.ndarray:
        """Σ_nom,k for the next step of length ``dt`` into :attr:`Sigma_nom` (which :meth:`step` uses).

        * ``estimator.Sigma_nom_dt`` = T > 0: the configured Σ_nom holds per step of T seconds,
          i.e. white-noise intensities Σ_nom/T, so a step of dt gets Σ_nom·dt/T (the same
          filter at 100 Hz and 1 kHz; Van Loan, IEEE TAC 1978, to first order in dt).
        * ``estimator.tau_m_noise`` = σ_u > 0: the motor torque applied differs from the
          commanded one by an error of std σ_u held over the step (current ripple, torque
          constant); it enters like the input, ẋ = f_nom + B (u + w) (eq:nonlindyn), so it adds
          Γ_u σ_u² Γ_uᵀ with Γ_u = ∫₀^dt e^{As} ds B (Franklin, Powell & Workman §4.3.3): one
          rank-n term that moves θ̇_m and θ̇_s in opposite directions (q̈ does not see τ_m).
          Γ_u from Van Loan's block exponential with A the last step's Jacobian ``A_k``
          (:func:`sea_daemon.core.linalg.zoh`, one (5n+n)² expm).
        """
        S = self.Sigma_nom
        self._sigma_base(dt)
        if self._tau_m_var > 0:
            # Γ_u = ∫₀^dt e^{As} ds B (Van Loan), S = Σ_nom·dt/T + Γ_u σ_u² Γ_uᵀ
            # (compiled: akf_core.input_noise)
            akf_core.input_noise(self.A_k, self.B_u, float(dt), self._tau_m_var, self._S_base,
                                 self.Gamma_u, S)
        else:
            S[:] = self._S_base
        return S

    def _sigma_base(self, dt: float) -> np.ndarray:
        """Σ_nom·dt/T (``estimator.Sigma_nom_dt`` = T; the configured Σ_nom without), cached per step length."""
        if dt != self._S_base_dt:
            self._S_base_dt = dt
            self._S_base = self.Sigma_nom_cfg * (dt / self._S_dt) if self._S_dt > 0 else self.Sigma_nom_cfg
        return self._S_base

    def _nominal_affine(self, x: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(F_nom(x, u), f_nom(x, u)) for a model without declared effects, from cached blocks,
        written into ``A_k`` and ``xdot_k`` (:func:`akf_core.nominal_affine`; equal to
        SEAModel.F_nom / f_nom)."""
        akf_core.nominal_affine(x, u, self._A_lin, self._B_lin, self._MinvG, self.A_k, self.xdot_k)
        return self.A_k, self.xdot_k

    def step(self, y: np.ndarray, u: np.ndarray, dt: float) -> Estimate:
        """The filter proper: predict with input u over dt, then update with y (4n,).

        With a residual, μ, ∂μ/∂z, σ² are evaluated at ``self.z`` (set by :meth:`update`).
        Raises :class:`EstimatorFault` if the state or covariance is not finite, or the
        innovation covariance is not positive definite.

        The numerics are :func:`akf_core.filter_step` (compiled); ``self.Sigma_nom`` is read
        every step (the nominal process noise of this step).
        """
        if y is not self.y:              # the step reads y from its buffer (update measures into it)
            self.y[:] = y
        x = self.x
        if self._affine:
            self._nominal_affine(x, np.asarray(u, dtype=float))
        elif self.tables is not None:
            # Alg. 1 line 3 / eq:nonlindyn, eq:linearization with the declared effects (compiled)
            self.tables.f_and_F(x, np.asarray(u, dtype=float), self.A_k, self.xdot_k)
        else:
            # Alg. 1 line 3 / eq:linearization: continuous Jacobian of f_nom at (x̂_{k−1}, u_{k−1})
            self.A_k[:] = self.model.F_nom(x, u)
            # eq:nonlindyn
            self.xdot_k[:] = self.model.f_nom(x, u)
        if self.bound is not None:
            # x̂_{k−1}, P_{k−1} for the bound (StepRecord)
            self.record.x_prev[:] = x
            self.record.P_prev[:] = self.P
        use_gp = self.residual is not None
        dmu = self.dmu_dz
        if use_gp:
            # Alg. 2 lines 4-6: μ, σ² = GP.PREDICT(ẑ_{k−1})
            mu, dmu_dz, var = self.residual.predict(self.z)
            self.mu[:] = mu
            if self._gp_var_scale != 1.0:
                np.multiply(var, self._gp_var_scale, out=self.sigma2)
            else:
                self.sigma2[:] = var
            dmu[:] = dmu_dz
        # Alg. 2 lines 7-11 / Alg. 1 lines 3-8 (akf_core.filter_step: A_k and xdot_k get the
        # GP terms of eq:fwdynwtorqueresidual1 / eq:linearization; x̂⁻, P⁻, S, K, ν, x̂, P)
        status, nis = akf_core.filter_step(self._buf, self.d, self.m, self.n, use_gp, float(dt))
        if status != akf_core.OK:
            self._step_failed(status, nis)
        self.nis = nis
        # bounded P (akf_core.cap_covariance): no variance beyond its physical cap; a prior far
        # beyond the caps means the linearised model expands the covariance without bound: a
        # typed fault with the step and the reason, never an overflow later
        pmax = float(np.max(np.diag(self.P_prior) / self.P_max))
        if not pmax < DIVERGED:
            self._diverged(pmax)
        self.n_capped += akf_core.cap_covariance(self.P, self.P_max)
        # P symmetric positive definite, windowed NIS inside its divergence bound (health.py)
        self.health.check(nis, self.P, self.est.k + 1)
        self.est.k += 1
        return self._bound_and_gate(self._fill_estimate(), u, dt)

    def _bound_and_gate(self, e: Estimate, u: np.ndarray, dt: float) -> Estimate:
        """The end of a filter step (this one and the GP-AKF's compiled one): step k's
        :class:`StepRecord` (x̂_{k−1}, P_{k−1} and the input ``u`` held over ``dt``) to the
        consumer attached, else :meth:`finish_step` here (the bound's step, the start-up gate)."""
        r = self.record
        r.kind, r.k, r.dt, r.ready, r.gate_starts = STEP, e.k, dt, self._ready, self.gate.starts
        r.u[:] = u
        c = self.consumer
        if c is not None:                  # computed elsewhere: ρ and the gate come with it
            c.take(e, r)
            return e
        e.valid = self.finish_step(e, r)
        return e

    def _hand_reset(self, e: Estimate) -> None:
        """The end of a reset: its record (kind RESET; ``P`` is P₀) to the consumer or the bound."""
        r = self.record
        r.kind, r.k, r.ready, r.gate_starts = RESET, e.k, self._ready, self.gate.starts
        c = self.consumer
        if c is not None:
            c.take(e, r)
        elif self.bound is not None:
            self.bound.reset(e, r)

    def _step_failed(self, status: int, nis: float) -> None:
        """Raise the typed fault of a filter step that returned ``status`` (not OK)."""
        k = self.est.k + 1
        if status == akf_core.PRIOR_NONFINITE:
            raise EstimatorNonFinite(f"AKF step {k}: prediction became non-finite "
                                     f"(non-finite state, measurement or covariance)")
        if status == akf_core.S_NOT_PD:
            raise CovarianceNotPD(f"AKF step {k}: innovation covariance S is not positive definite "
                                  f"(min diag {np.min(np.diag(self.S_k)):.3g}); check R, Sigma_nom, P0")
        self.nis = nis
        raise EstimatorNonFinite(f"AKF step {k}: state or covariance became non-finite "
                                 f"(non-finite measurement or diverging model/noise settings)")

    def _diverged(self, pmax: float) -> None:
        """Raise CovarianceDiverged: the predicted covariance is ``pmax`` times its cap."""
        raise CovarianceDiverged(f"AKF step {self.est.k + 1}: the predicted covariance is {pmax:.3g} x its "
                                 f"physical cap (the linearised model diverges: check the model, R, "
                                 f"Sigma_nom, or a log that does not fit the model)")

    def _fill_estimate(self) -> Estimate:
        e = self.est
        # x̂, P, τ̂_h,act, its σ and eq:gaussianellipsoid projected on τ_h,act: ρ = sqrt(s P_ττ)
        akf_core.fill_estimate(self.x, self.P, self._sqrt_s, e.x_hat, e.P, e.tau_h_act_hat,
                               e.tau_h_act_sigma, e.tau_h_act_bound)
        return e
