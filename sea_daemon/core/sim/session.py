"""One simulated session of a plant: a reference tracked by PID (or the arm held still), a
subject that is passive or applies a torque, sampled like the hardware.

Used by the generalisation benchmark and the calibration tests: unlike :mod:`sea_daemon.runtime.sim_runner` (a
scenario file's two fixed phases) a session is built from parts —

* ``reference``: any object with ``reference(t) -> (q, q̇, q̈)`` (a
  :class:`~sea_daemon.core.excitation.MoveSequence`, :class:`SineReference`, ...),
  tracked by the PID of :mod:`sea_daemon.core.control` from rest at ``reference(0)``;
  or ``None`` with ``hold_q``: the Sec. V-C still-arm session — open loop
  τ_m = τ_comp + τ_des(t), τ_comp the true plant's holding torque, and the subject resists:
  τ_h,act = −τ_des (the arm stays at rest);
* ``human``: a function t -> τ_h,act (n,) (``None``: passive, τ_h,act = 0); in the still-arm
  session it is τ_des's negative, i.e. what the subject applies.

Per sample (period 1/rate_hz): read the encoders, compute τ_m, log (t, q, θ_m, τ_m, τ_h,act),
advance the plant with τ_m (+ noise) and τ_h,act held.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sea_daemon.core.config import ModelConfig
from sea_daemon.core.control import PID, PIDGains
from sea_daemon.core.log import MeasuredLog
from sea_daemon.core.sim.plant import Plant


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


def run_session(true_cfg: ModelConfig, duration_s: float, *, reference=None, hold_q: float | None = None,
                human=None, seed: int = 0, gains: PIDGains = SESSION_GAINS, substep_hz: float | None = None,
                sign_eps: float = 3e-3, torque_noise: float | None = None, t0: float = 0.0,
                extra_load_torque=None, extra_held: bool = False) -> MeasuredLog:
    """Simulate one session of the plant ``true_cfg`` (nominal model + hidden effects); see the
    module docstring (``extra_load_torque``, ``extra_held``: as :class:`~sea_daemon.core.sim.plant.Plant`).  Returns the measured log with the truth ``tau_h_act`` and, in ``extra``,
    ``q_true``, ``dq_true``, ``q_ref``."""
    rate = float(true_cfg.rate_hz)
    dt = 1.0 / rate
    N = int(round(duration_s * rate))
    sub = substep_hz if substep_hz is not None else max(1000.0, rate)
    if reference is None and hold_q is None:
        raise ValueError("run_session needs a reference or hold_q")
    q0 = reference.reference(0.0)[0] if reference is not None else float(hold_q)
    plant = Plant(true_cfg, q0=q0, seed=seed, substep_hz=sub, sign_eps=sign_eps, torque_noise=torque_noise,
                  extra_load_torque=extra_load_torque, extra_held=extra_held)
    limit = true_cfg.hardware.torque_limit
    pid = None
    if reference is not None:
        pid = PID(gains.kp, gains.ki, gains.kd, dt, limit, gains.velocity_filter_hz, derivative=gains.derivative)
        q_m, th_m = plant.measure()
        pid.reset(q_m if gains.derivative == "load" else th_m, plant.hold_torque)
    hold = plant.hold_torque.copy()
    cols = {k: np.empty(N) for k in ("t", "q", "theta_m", "tau_m", "tau_h_act", "q_true", "dq_true", "q_ref",
                                     "theta_m_true", "dtheta_m_true")}
    for k in range(N):
        t = k * dt
        q_m, th_m = plant.measure()
        tau_h = 0.0 if human is None else float(human(t))
        if pid is not None:
            q_ref, dq_ref, _ = reference.reference(t)
            u = pid.step(q_ref, q_m, dq_ref, th_m)
        else:
            q_ref = hold_q
            # Sec. V-C: τ_m = τ_comp + τ_des, the subject resists: τ_h,act = −τ_des
            u = np.clip(hold - tau_h, -limit, limit)
        cols["t"][k] = t0 + t
        cols["q"][k] = q_m[0]
        cols["theta_m"][k] = th_m[0]
        cols["tau_m"][k] = u[0]
        cols["tau_h_act"][k] = tau_h
        cols["q_true"][k] = plant.q[0]
        cols["dq_true"][k] = plant.dq[0]
        cols["q_ref"][k] = q_ref
        cols["theta_m_true"][k] = plant.theta_m[0]
        cols["dtheta_m_true"][k] = plant.dtheta_m[0]
        plant.step(u, dt, tau_h)
    base = ("t", "q", "theta_m", "tau_m", "tau_h_act")
    return MeasuredLog(t=cols["t"], q=cols["q"][:, None], theta_m=cols["theta_m"][:, None],
                       tau_m=cols["tau_m"][:, None], tau_h_act=cols["tau_h_act"][:, None],
                       extra={k: v for k, v in cols.items() if k not in base})
