"""GP-enhanced augmented-state Kalman filter (GP-AKF, paper Alg. 2) with online learning.

The GP-AKF is the :class:`~sea_daemon.core.estimators.akf.AKF` with a learned load-side residual
``f(z)`` (eq:unknwn_load), one LoG-GP per joint (:class:`~sea_daemon.core.learning.ResidualGP`):

* prediction with the GP mean (eq:fwdynwtorqueresidual1), linearisation
  ``F = F_nom − I_μ M⁻¹ F_GP`` (eq:linearization), process noise
  ``Q = Σ_nom + I_μ M⁻¹ diag(σ²) M⁻ᵀ I_μᵀ`` (eq:gpakf_covariance, eq:GPvarfwd) — all in
  :meth:`AKF.step`, through its residual hook;
* online learning (Sec. IV-A, ass:passive_human): while :attr:`GPAKF.learning` is on, every
  sample also gives one training pair ``z = [q, q̇, q̈]`` → ``f(z) = τ_m − (τ_l(z) + J θ̈_m +
  D_m θ̇_m)`` (eq:loadsidewmotor with τ_h,act = 0) from the *same causal kinematics* the filter
  uses (the differentiator of :class:`AKF`), added to the GP with ``update`` (the LoG-GP runs
  its bounded hyperparameter slices inside ``update``, ``learning.hyperopt``).

The paper learns during the training phase (subject passive) and estimates with the model
frozen: :func:`learn_from_log` streams a training log through the filter with learning on
(:func:`~sea_daemon.core.estimators.factory.make_estimator` then turns learning off).
``reset`` (a new log) keeps the learned model.

Pure numerics: no I/O, no clock, no threads.
"""
from __future__ import annotations

import numpy as np

from sea_daemon.core.config import ModelConfig
from sea_daemon.errors import EstimatorFault
from sea_daemon.core.learning import ResidualGP
from sea_daemon.core.log import MeasuredLog
from sea_daemon.core.model import SEAModel
from sea_daemon.core.estimators import akf_core, gp_hook, gpakf_core
from sea_daemon.core.gp.loggp import LoGGP
from sea_daemon.core.gp.pack import GPPack
from sea_daemon.core.estimators.akf import AKF, DIVERGED
from sea_daemon.core.estimators.base import Estimate
from sea_daemon.core.estimators.health import InputBox, check_pd
from sea_daemon.core.estimators.validity import LEARNING

_I_STATUS, _I_KIN_HEAD, _I_HHEAD, _I_CAPPED, _I_PD, _I_CLIPPED, _I_OFF = (
    gpakf_core.I_STATUS, gpakf_core.I_KIN_HEAD, gpakf_core.I_HHEAD, gpakf_core.I_CAPPED, gpakf_core.I_PD,
    gpakf_core.I_CLIPPED, gpakf_core.I_OFF)
assert (gpakf_core.F_NIS, gpakf_core.F_PMAX) == (0, 1)
_OK = akf_core.OK


def _as_f64(a) -> np.ndarray:
    """``a`` itself when it is a float64 C-contiguous ndarray, else such a copy of it."""
    if type(a) is np.ndarray and a.dtype == np.float64 and a.flags.c_contiguous:
        return a
    return np.ascontiguousarray(a, dtype=float)


class _ResidualHook:
    """The AKF's residual hook over a :class:`ResidualGP` with preallocated outputs.

    ``predict(z) -> (μ (n,), ∂μ/∂z (n, 3n), σ² (n,))`` (alg:torqueresidualAKF line 5,
    eq:moejac), calling each joint's LoG-GP directly (z is the filter's own array, already
    validated); the returned arrays are overwritten by the next call.
    """

    def __init__(self, gp: ResidualGP, margin: float = 0.1, noise_in_Q: bool = False):
        self.gp = gp
        # estimator.gp_noise_in_Q: σ² of the process noise = predictive variance σ² + σ_on²
        self.noise_in_Q = bool(noise_in_Q)
        n = gp.n
        self.mu = np.zeros(n)
        self.jac = np.zeros((n, 3 * n))
        self.var = np.zeros(n)
        # bounded GP inputs (health.InputBox): the box of the training inputs, from the data a
        # loaded model already holds, widened by ``margin`` of its width on each side
        self.box = InputBox.of_residual(gp, margin)
        # calls where some joint moved in a direction the GP has no data for
        # (ResidualGP.off_direction): mean and Jacobian 0 there, the physical model alone
        self.n_off_direction = 0
        self.off = False
        # False while the GP-AKF learns online from its own data (GPAKF.learning): what one way
        # taught it (a wrong mass, a stiffness) may hold the other way, and the pairs it gathers
        # moving that way cover it within DIRECTION_MIN_PAIRS; a frozen GP is gated
        self.gate = True
        self._off_direction = getattr(gp, "off_direction", None)     # a residual of one's own may lack it
        # the compiled path (freeze): LoG-GPs only
        self._loggp = all(type(g) is LoGGP for g in gp.gps)
        # the key the compiled path runs for (None: the Python path) and the pack's arrays
        # (GPPack.args() and σ_on² per leaf: gp_hook.hook_predict's arguments)
        self.key = self._pack_key = None
        self.pack_args = ()
        # the direction gate of the compiled path, made with the pack: each joint's gated
        # directions (down, up) as off_direction tells them, the speed beyond which they count,
        # and whether any direction is gated
        self.gated = np.zeros((n, 2), dtype=np.bool_)
        self.gate_speed = float(getattr(gp, "direction_speed", 0.0))
        self.gate_any = False

    def freeze(self, key) -> None:
        """``key``: None while the GP learns (the Python path), else a value that changes whenever
        the GP does (the GP-AKF's count of learned pairs): the prediction runs as one compiled
        call (:func:`gp_hook.hook_predict`) over a pack of the GPs made for that key."""
        if key is None or not self._loggp:
            self.key = None
            return
        if key != self._pack_key:
            pack = GPPack(self.gp.gps)
            self.pack_args = pack.args() + (pack.sn2,)
            self._pack_key = key
            self._gated_directions()
        self.key = key

    def _gated_directions(self) -> None:
        """:attr:`gated` from ``off_direction``: joint j alone moving down, then up, beyond the
        gate's speed (the compiled path's gate, :func:`gpakf_core.direction_gate`, equal to it)."""
        n = self.gp.n
        self.gated[:] = False
        if self._off_direction is not None:
            z = np.zeros(3 * n)
            for j in range(n):
                for way, v in ((0, -1.0), (1, 1.0)):
                    z[n + j] = v * (self.gate_speed + 1.0)
                    self.gated[j, way] = bool(self._off_direction(z))
                z[n + j] = 0.0
        self.gate_any = bool(self.gated.any())

    def predict(self, z):
        if self.key is not None:
            box = self.box
            if type(z) is not np.ndarray or z.dtype != np.float64 or not z.flags.c_contiguous:
                z = np.ascontiguousarray(z, dtype=float)
            any_clipped = gp_hook.hook_predict(z, box.clip_lo, box.clip_hi, box.clipped_z, box.clipped,
                                               self.noise_in_Q, self.mu, self.jac, self.var, *self.pack_args)
            box.any_clipped = any_clipped
            if any_clipped:
                box.n_clipped += 1
            return self._gate(z)
        # z clipped to the training box ± margin; the clipped coordinates get a zero Jacobian
        zc = self.box.clip(z)
        for i, g in enumerate(self.gp.gps):
            # eq:GPmean, eq:GPvariance, eq:moejac (merged over the leaves z reaches)
            # with gp_noise_in_Q the predictive variance of the residual torque at z: σ² + σ_on²
            # (docs/gpakf.md)
            # the Jacobian of the experts (Σ ω_i ∂μ_i/∂z, no routing ramp: docs/learning.md)
            self.mu[i], self.var[i] = g.predict_grad_into(zc, self.jac[i], self.noise_in_Q, False)
        if self.box.any_clipped:
            self.jac[:, self.box.clipped] = 0.0
        return self._gate(z)

    def _gate(self, z):
        """The direction gate: μ and ∂μ/∂z set to 0 where some joint moves at ``z`` in a
        direction the GP's training pairs did not cover (σ² kept: Q still has the GP's variance)."""
        off = self.off = self.gate and self._off_direction is not None and self._off_direction(z)
        if off:
            self.n_off_direction += 1
            self.mu[:] = 0.0
            self.jac[:] = 0.0
        return self.mu, self.jac, self.var


class GPAKF(AKF):
    """AKF + per-joint LoG-GP residual, learning online while :attr:`learning` is True.

    ``cfg``: model configuration (nominal model, estimator noise, kinematics, learning
    options).  ``residual``: a :class:`ResidualGP` (default: a fresh one from ``cfg.learning``).
    ``learning``: learn from every sample (passive subject, ass:passive_human).
    ``tau_lag``: which motor torque a training target pairs with the sample's kinematics, in
    samples back (0: the torque commanded at the sample, as
    :func:`~sea_daemon.core.learning.training_pairs_from_log`).  ``bound``: as :class:`AKF`.
    """

    name = "gp-akf"

    @property
    def learning(self) -> bool:
        """Whether the GP learns online from the filter's own pairs (the direction gate of
        :class:`_ResidualHook` is off meanwhile)."""
        return self._learning

    @learning.setter
    def learning(self, on: bool) -> None:
        self._learning = bool(on)
        self.residual.gate = not self._learning

    def __init__(self, cfg: ModelConfig, dt: float | None = None, residual: ResidualGP | None = None,
                 learning: bool = True, model: SEAModel | None = None, tau_lag: int = 0, bound=None):
        self.gp = residual if residual is not None else ResidualGP.from_config(cfg)
        super().__init__(cfg, dt=dt, residual=_ResidualHook(self.gp, cfg.estimator.gp_input_margin,
                                                                  cfg.estimator.gp_noise_in_Q), model=model,
                         bound=bound)
        self.learning = bool(learning)
        self.tau_lag = int(tau_lag)
        n = self.n
        self.z_train = np.zeros(3 * n)       # last training input z = [q, q̇, q̈]
        self.f_train = np.zeros(n)           # last training target f (eq:loadsidewmotor)
        self.n_learned = 0
        self.since_reset = 0                 # samples since the last reset
        # one training pair per configuration step (estimator.Sigma_nom_dt, 10 ms): the LoG-GP
        # sees the data density it is configured for at any loop rate (every 10th sample at
        # 1 kHz; consecutive 1 ms pairs are nearly the same point, and ten times the pairs split
        # the leaves into small ones whose hyperparameters fit the noise: steep means)
        S_dt = float(cfg.estimator.Sigma_nom_dt)
        self.learn_every = max(1, int(round(S_dt / self.dt))) if S_dt > 0 else 1
        self._tau_hist = np.zeros((max(self.tau_lag, 0) + 1, n))
        # the frozen sample in compiled calls (gpakf_core) where they apply: no offsets, delay or
        # motor-torque noise, the hook of this class, and a model without declared effects (one
        # call) or a rigid body whose effects are all compiled (Pinocchio's ABA derivatives
        # between two calls)
        rigid = self.model.rigid is not None and not self.model.outside_effects
        self._fz_rigid = rigid and not self._affine
        self._fz_ok = ((self._affine or self._fz_rigid) and self._no_offsets and not self.has_delay
                       and type(self.residual) is _ResidualHook)
        self._fz_args = ()
        self._fz_iout = np.zeros(7, dtype=np.int64)
        self._fz_seen = [None, None, None]       # q, θ_m, τ_m arrays last checked (_frozen_update)
        self._fz_fout = np.zeros(2)
        # the rigid body's q, q̇ and load-side torque at x̂_{k−1} (gpakf_core.rigid_head), a zero residual
        self._fz_body = tuple(np.zeros(n) for _ in range(4))

    def reset(self, q=None, theta_m=None, tau_m=None, x0=None, P0=None) -> Estimate:
        """As :meth:`AKF.reset`; the learned model is kept."""
        self.since_reset = 0
        if tau_m is not None:
            self._tau_hist[:] = np.asarray(tau_m, dtype=float)
        return super().reset(q, theta_m, tau_m, x0, P0)

    def update(self, q, theta_m, tau_m, dt: float | None = None) -> Estimate:
        """One sample: the GP-AKF step (Alg. 2), then, while learning, one training pair."""
        was_ready = self._ready
        # frozen (learning off): the hook's compiled path over the GP as it is now
        freeze = getattr(self.residual, "freeze", None)       # a residual of one's own has none
        if freeze is not None:
            freeze(None if self.learning else self.n_learned)
        if (self._fz_ok and was_ready and not self._filling and (dt is None or dt == self.dt)
                and type(self.residual) is _ResidualHook and self.residual.key is not None and self.kin.primed):
            e = self._frozen_update(q, theta_m, tau_m)
        else:
            e = super().update(q, theta_m, tau_m, dt)
        if self.learning:
            # learning assumes a passive subject (τ_h,act = 0): τ̂_h,act holds the residual not
            # learned yet, no estimate of the subject's torque (the training phase publishes none)
            e.valid, e.invalid_reason = False, LEARNING
        if not was_ready:
            self._tau_hist[:] = np.asarray(tau_m, dtype=float)
            return e
        self.since_reset += 1
        if self.tau_lag:
            self._tau_hist[1:] = self._tau_hist[:-1]
            self._tau_hist[0] = tau_m
        if self.learning and self.since_reset >= self.kin.L and \
                (self.since_reset - self.kin.L) % self.learn_every == 0:
            self._learn(tau_m)
        return e

    def _frozen_update(self, q, theta_m, tau_m) -> Estimate:
        """:meth:`AKF.update` of a sample at the nominal period with the GP frozen, its numerics in
        compiled calls (:mod:`.gpakf_core`); the checks, the bound and the start-up gate as
        in :meth:`AKF.step` (the input history is pushed before the bound's step, which does not
        read it)."""
        res = self.residual
        a = self._fz_args
        dt = self.dt
        if not a or a[0] is not res.pack_args or a[3] is not self.bound or a[4] is not self._sigma_base(dt):
            a = self._fz_args = self._frozen_args(res)
        # float64 C-contiguous (n,) arrays as the loop's measurement is (others converted: the
        # compiled calls have one signature, made at construction); the loop hands the same
        # arrays every sample: those checked last time are not checked again
        seen = self._fz_seen
        if q is not seen[0]:
            q = seen[0] = _as_f64(q)
        if theta_m is not seen[1]:
            theta_m = seen[1] = _as_f64(theta_m)
        if tau_m is not seen[2]:
            tau_m = seen[2] = _as_f64(tau_m)
        iout, fout, kin = self._fz_iout, self._fz_fout, self.kin
        head = self._hhead
        iout[_I_KIN_HEAD] = kin.head
        iout[_I_HHEAD] = head
        gate = res.gate and res.gate_any
        if self._fz_rigid:
            self._rigid_sample(q, theta_m, dt, a, gate, head)
        else:
            gpakf_core.frozen_sample(q, theta_m, dt, *a[1], gate, res.gated, res.gate_speed)
        io = iout.tolist()                             # Python ints: one call, not one per value
        nis, pmax = fout.tolist()                      # F_NIS, F_PMAX
        kin.head = io[_I_KIN_HEAD]
        res.off = off = io[_I_OFF] != 0
        if off:
            res.n_off_direction += 1
        box = res.box
        box.any_clipped = clipped = io[_I_CLIPPED] != 0
        if clipped:
            box.n_clipped += 1
        status = io[_I_STATUS]
        if status != _OK:
            self._step_failed(status, nis)
        self.nis = nis
        if not pmax < DIVERGED:
            self._diverged(pmax)
        self.n_capped += io[_I_CAPPED]
        k = self.est.k + 1
        if io[_I_PD] != 0:
            check_pd(self.P, "P", k, full=False)       # raises CovarianceNotPD with the pivot
        self.health.nis.update(nis, k)
        self.est.k = k
        self._t += dt
        gpakf_core.frozen_finish(*a[2], tau_m, self._ht, self._hu, self._hcap, self._t, iout)
        self._hhead = int(iout[gpakf_core.I_HHEAD])
        return self._bound_and_gate(self.est, self._hu[head], dt)

    def _rigid_sample(self, q, theta_m, dt, a, gate: bool, head: int) -> None:
        """The frozen sample of a model with a rigid body: :func:`gpakf_core.rigid_head`, the
        body's forward dynamics and their derivatives at x̂_{k−1} (Pinocchio, as
        RigidTables.f_and_F), :func:`gpakf_core.rigid_body`, :func:`gpakf_core.sample_tail`."""
        first, body, tail = a[5]
        q_l, dq_l, tau_l, f0 = self._fz_body
        gpakf_core.rigid_head(q, theta_m, dt, *first)
        ddq, ddq_dq, ddq_dv, Minv = self.model.rigid.forward_derivatives(q_l, dq_l, tau_l)
        res = self.residual
        gpakf_core.rigid_body(*body[0], self._hu[head], body[1], ddq, ddq_dq, ddq_dv,
                              Minv, *body[2], gate, res.gated, res.gate_speed)
        gpakf_core.sample_tail(*tail)

    def _frozen_args(self, res: _ResidualHook) -> tuple:
        """The arrays of :func:`gpakf_core.frozen_sample` / ``frozen_finish`` and of the rigid
        body's calls (the same objects every sample; made again when the hook's pack changes)."""
        kin, box, e = self.kin, res.box, self.est
        self._sigma_base(self.dt)
        pack = res.pack_args[:-1]
        s_mode = (2 if self._tau_m_var > 0 else 1) if self._S_varies else 0
        step = (self._buf, self.d, self.m, self.n)
        head = (self._ang, kin.buf, kin.C, kin.out, self._ddq, self.z)
        noise = (s_mode, self._S_base, self.B_u, self._tau_m_var, self.Gamma_u)
        gp = (box.clip_lo, box.clip_hi, box.clipped_z, box.clipped, res.noise_in_Q, res.mu, res.jac, res.var, pack,
              res.pack_args[-1], self.bound is not None, self.record.x_prev, self.record.P_prev)
        iout, fout = self._fz_iout, self._fz_fout
        finish = (self.x, self.P, self._sqrt_s, e.x_hat, e.P, e.tau_h_act_hat, e.tau_h_act_sigma, e.tau_h_act_bound)
        if self._fz_rigid:
            q_l, dq_l, tau_l, f0 = self._fz_body
            kernel = self.model.kernel
            rigid = ((*step, *head, *noise, iout, kernel, f0, q_l, dq_l, tau_l), (step, kernel, (f0, self.z, *gp, iout)),
                     (*step, self.dt, float(self._gp_var_scale), res.mu, res.jac, res.var, self.P_max, DIVERGED,
                      iout, fout))
            return res.pack_args, (), finish, self.bound, self._S_base, rigid
        sample = (*step, *head, self._hu, *noise, self._A_lin, self._B_lin, self._MinvG, float(self._gp_var_scale),
                  *gp, self.P_max, DIVERGED, iout, fout)
        return res.pack_args, sample, finish, self.bound, self._S_base, None

    def training_pair(self, tau_m) -> tuple[np.ndarray, np.ndarray]:
        """(z, f) of the current sample from the causal kinematics (eq:loadsidewmotor)."""
        n = self.n
        ang, vel, acc = self.kin_angle, self.kin_vel, self.kin_acc     # [q, θ_m] each
        z = self.z_train
        z[:n] = ang[:n]
        z[n:2 * n] = vel[:n]
        z[2 * n:] = acc[:n]
        tau = self._tau_hist[self.tau_lag] if self.tau_lag else np.ascontiguousarray(tau_m, dtype=float)
        if self.has_delay:
            # a declared delay: the motor side felt τ_m(t − lag·dt − delay)
            tau = self._delayed_input(self._t - self.tau_lag * self.dt).copy()
        m = self.model
        if self._affine:
            # eq:loadsidewmotor with ass:passive_human (τ_h,act = 0), nominal model without
            # declared effects: f = τ_m − (M q̈ + g ⊙ sin q + J θ̈_m + D_m θ̇_m)
            akf_core.residual_affine(ang[:n], vel[:n], acc[:n], vel[n:], acc[n:], tau, m.M, m.gravity,
                                     m.J, m.D_m, self.f_train)
        elif self.tables is not None:
            # eq:loadsidewmotor with ass:passive_human (τ_h,act = 0), declared effects (compiled)
            self.tables.residual(ang[:n], vel[:n], acc[:n], ang[n:], vel[n:], acc[n:],
                                  np.ascontiguousarray(tau, dtype=float), self.f_train)
        else:
            # eq:loadsidewmotor with ass:passive_human (τ_h,act = 0), declared effects included
            self.f_train[:] = m.residual_from_kinematics(ang[:n], vel[:n], acc[:n], ang[n:], vel[n:], acc[n:], tau)
        return z, self.f_train

    def _learn(self, tau_m) -> None:
        z, f = self.training_pair(tau_m)
        self.residual.box.add(z)
        # one independent GP per joint (Sec. IV-A); the LoG-GP runs its bounded
        # hyperparameter slices inside update (learning.hyperopt)
        for i, g in enumerate(self.gp.gps):
            g.update(z, f[i])
        # the directions of motion learned: a direction with enough pairs becomes covered
        note = getattr(self.gp, "note_direction", None)
        if note is not None:
            note(z)
        self.n_learned += 1


def learn_from_log(est: GPAKF, log: MeasuredLog) -> GPAKF:
    """Stream a passive-subject log through ``est`` with learning on (the training phase).
    The bound component, if any, is not run meanwhile (its GP constants describe the trained
    model; it starts at the next reset)."""
    est.learning = True
    bound, est.bound = est.bound, None
    k = 0
    try:
        est.reset(log.q[0], log.theta_m[0], log.tau_m[0])
        for k in range(1, len(log)):
            est.update(log.q[k], log.theta_m[k], log.tau_m[k], log.t[k] - log.t[k - 1])
    except EstimatorFault as exc:
        raise EstimatorFault(f"{log.path} (training): sample {k} (t = {log.t[k]:.6g} s): {exc}",
                             fault=exc.fault) from None
    finally:
        est.bound = bound
    return est
