"""One simulated session of a plant: a reference tracked by PID (or the arm held still), a
subject that is passive or applies a torque, sampled like the hardware.

Used by the generalisation and new-robot benchmarks and the calibration (its synthetic
sessions and tests): unlike :mod:`sea_daemon.runtime.sim_runner` (a scenario file's two fixed
phases through the daemon's loop) a session is built from parts —

* ``reference``: any object with ``reference(t) -> (q, q̇, q̈)`` (a
  :class:`~sea_daemon.core.excitation.MoveSequence`, :class:`SineReference`, ...),
  tracked from rest at ``reference(0)`` by :class:`~sea_daemon.core.control.ReferenceTracker`
  (the PID the scenario's controller runs too);
  or ``None`` with ``hold_q``: the Sec. V-C still-arm session — open loop
  τ_m = τ_comp + τ_des(t), τ_comp the true plant's holding torque, and the subject resists:
  τ_h,act = −τ_des (the arm stays at rest; :class:`~sea_daemon.core.control.StillArm`);
* ``human``: a function t -> τ_h,act (n,) (``None``: passive, τ_h,act = 0); in the still-arm
  session it is τ_des's negative, i.e. what the subject applies.  For n joints (a ``model.urdf``)
  the reference gives (n,) arrays (:class:`~sea_daemon.core.excitation.PerJoint`), ``hold_q``
  the n angles and ``human`` an (n,) torque.

Per sample k (period 1/rate_hz, t_k = k/rate_hz) the steps of every simulated run
(:mod:`sea_daemon.core.sim.sampling`): the plant stepped over [t_k−1, t_k] with τ_m (+ noise)
and τ_h,act of sample k−1 held, the encoders read, τ_m computed, τ_h,act(t_k), the row logged
(t, q, θ_m, τ_m, τ_h,act).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sea_daemon.core.config import ModelConfig
from sea_daemon.core.control import PIDGains, ReferenceTracker, StillArm
from sea_daemon.core.log import MeasuredLog
from sea_daemon.core.sim.plant import Plant
from sea_daemon.core.sim.sampling import SampledPlant, SampleRecorder


@dataclass(frozen=True)
class SineReference:
    """q_ref = c + Σ a_i sin(2π f_i t + φ_i) − Σ a_i sin φ_i (starts at c)."""

    center: float
    amps: tuple[float, ...]
    freqs: tuple[float, ...]
    phases: tuple[float, ...]

    def reference(self, t: float) -> tuple[float, float, float]:
        q, dq, ddq = self.center, 0.0, 0.0
        ramp = min(1.0, t / 1.0) if t > 0 else 0.0        # 1 s fade-in from rest
        for a, f, p in zip(self.amps, self.freqs, self.phases):
            w = 2.0 * math.pi * f
            q += ramp * a * (math.sin(w * t + p) - math.sin(p))
            dq += ramp * a * w * math.cos(w * t + p)
            ddq -= ramp * a * w * w * math.sin(w * t + p)
        return q, dq, ddq


@dataclass(frozen=True)
class BandLimitedTorque:
    """A smooth random torque: Σ_i c_i sin(2π f_i t + φ_i), f_i spread over [f_lo, f_hi] Hz,
    scaled to ``rms`` N m, plus ``offset``; faded in over ``fade_s``."""

    rms: float
    f_lo: float
    f_hi: float
    seed: int = 0
    components: int = 12
    offset: float = 0.0
    fade_s: float = 1.0

    def __post_init__(self):
        rng = np.random.default_rng(self.seed)
        f = np.exp(rng.uniform(math.log(self.f_lo), math.log(self.f_hi), self.components))
        c = rng.normal(size=self.components)
        c *= self.rms * math.sqrt(2.0) / max(float(np.linalg.norm(c)), 1e-12)
        object.__setattr__(self, "_f", f)
        object.__setattr__(self, "_c", c)
        object.__setattr__(self, "_p", rng.uniform(0, 2 * math.pi, self.components))

    def __call__(self, t: float) -> float:
        ramp = min(1.0, t / self.fade_s) if t > 0 else 0.0
        return self.offset * ramp + ramp * float(np.sum(self._c * np.sin(2 * math.pi * self._f * t + self._p)))

    @property
    def max_rate(self) -> float:
        """Upper bound of |dτ/dt| [N m/s] (without the fade-in)."""
        return float(np.sum(np.abs(self._c) * 2 * math.pi * self._f))


#: the gains a session's PID tracks its reference with unless given
SESSION_GAINS = PIDGains(40.0, 80.0, 2.0, velocity_filter_hz=30.0)


#: the extras of a session's log (joint 0; with n > 1 joints also per joint, ``q_true_1`` …)
SESSION_EXTRA = ("q_true", "dq_true", "q_ref", "theta_m_true", "dtheta_m_true")


def run_session(true_cfg: ModelConfig, duration_s: float, *, reference=None, hold_q: float | None = None,
                human=None, seed: int = 0, gains: PIDGains = SESSION_GAINS, substep_hz: float | None = None,
                sign_eps: float = 3e-3, torque_noise: float | tuple | None = None, t0: float = 0.0,
                extra_load_torque=None, extra_held: bool = False, hold: tuple[float, float] | None = None) -> MeasuredLog:
    """Simulate one session of the plant ``true_cfg`` (nominal model + hidden effects); see the
    module docstring (``extra_load_torque``, ``extra_held``: as :class:`~sea_daemon.core.sim.plant.Plant`).  Returns the measured log with the truth ``tau_h_act`` and, in ``extra``,
    ``q_true``, ``dq_true``, ``q_ref``, ``theta_m_true``, ``dtheta_m_true``.

    ``hold`` = (K [N m/rad], B [N m s/rad]), still-arm sessions only: the subject also holds the
    arm where it started, τ_h,act = −τ_des + K (q₀ − q) − B q̇ on the arm's state at the sample, as a
    person keeping a limb still does.  Without it the open loop has nothing that brings a drifting
    arm back (the spring's lag lets τ_des and the subject's torque part at a band's top), and a
    two-joint arm can drift into its end stops."""
    rate = float(true_cfg.rate_hz)
    dt = 1.0 / rate
    N = int(round(duration_s * rate))
    sub = substep_hz if substep_hz is not None else max(1000.0, rate)
    if reference is None and hold_q is None:
        raise ValueError("run_session needs a reference or hold_q")
    if hold is not None and reference is not None:
        raise ValueError("run_session: hold applies to a still-arm session (hold_q), not to a reference")
    # hold_q: one angle, or the n joints' angles (a ``model.urdf``)
    q0 = reference.reference(0.0)[0] if reference is not None else (
        float(hold_q) if np.ndim(hold_q) == 0 else np.asarray(hold_q, dtype=float))
    plant = Plant(true_cfg, q0=q0, seed=seed, substep_hz=sub, sign_eps=sign_eps, torque_noise=torque_noise,
                  extra_load_torque=extra_load_torque, extra_held=extra_held)
    limit = true_cfg.hardware.torque_limits(true_cfg.joints)      # each joint's
    if reference is not None:
        ctl = ReferenceTracker(gains, reference, dt, limit)
        ctl.start(*plant.measure(), plant.hold_torque)    # bumpless: the first command holds the arm
        n = plant.n

        def subject(t):             # τ_h,act: a number for one joint, (n,) for n
            if human is None:
                return 0.0
            return float(human(t)) if n == 1 else np.asarray(human(t), dtype=float).reshape(n)
    else:
        # Sec. V-C: τ_m = τ_comp + τ_des, the subject resists: τ_h,act = −τ_des (``human``)
        if human is None:
            des = (lambda t: -0.0)
        elif plant.n == 1:
            des = (lambda t: -float(human(t)))
        else:                         # n joints: τ_des (n,), the subject's torque on every joint
            des = (lambda t: -np.asarray(human(t), dtype=float).reshape(plant.n))
        ctl = StillArm(plant.hold_torque.copy(), des, limit, float(q0) if plant.n == 1 else np.ravel(q0).copy())
        subject = ctl.subject if hold is None else _holding(ctl.subject, plant, ctl.q_ref, hold)
    return _sample(SampledPlant(plant, dt), ctl, subject, N, t0)


def _holding(resist, plant: Plant, q_hold, hold: tuple[float, float]):
    """The still-arm subject that resists τ_des (``resist``) and holds the arm at ``q_hold`` with
    stiffness and damping ``hold`` = (K, B) on the plant's state (:func:`run_session`)."""
    K, B = (float(v) for v in hold)
    if not (K >= 0.0 and B >= 0.0 and np.isfinite(K) and np.isfinite(B)):
        raise ValueError(f"run_session: hold = (K, B) must be finite and >= 0, got {hold!r}")

    def subject(t):
        return resist(t) + K * (q_hold - plant.q) - B * plant.dq
    return subject


def _sample(sp: SampledPlant, ctl, subject, rows: int, t0: float) -> MeasuredLog:
    """The session's samples (:mod:`sea_daemon.core.sim.sampling`): per sample k the plant
    stepped and read, the command, the subject's torque, the row; then the read that steps the
    last row's interval."""
    rec = SampleRecorder(rows, sp.n, SESSION_EXTRA)
    u, tau_h = None, 0.0
    for k in range(rows + 1):
        q_m, th_m = sp.read(u, tau_h)
        rec.acted(sp)
        if k == rows:
            break
        u = ctl.update(sp.t, q_m, th_m)
        tau_h = subject(sp.t)
        rec.sample(k, t0 + sp.t, q_m, th_m, u, sp, ctl)
    return rec.log(slice(0, rows))
