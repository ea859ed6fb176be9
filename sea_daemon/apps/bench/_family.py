"""A family of random exoskeleton plants and the sessions the generalisation benchmark runs.

:func:`draw_plant` (seeded) draws one 1-DoF SEA elbow exoskeleton with a passive arm:

* the robot: nominal parameters M, J, D_m, K_s, D_s and the link's gravity each ±30 % around
  ``configs/exo_1dof.yaml``; the user's configuration declares this nominal robot only;
* hardware: encoder resolution 16–20 bit, gear 50–160, motor-torque noise 0.005–0.05 N m,
  100 Hz or 1 kHz;
* hidden effects from the vocabulary (the forearm's inertia and gravity, the elbow's
  viscoelasticity, load Coulomb/Stribeck/viscous friction; sometimes motor friction, a torque
  constant error, cogging, a stiffening spring) and, for most plants, effects OUTSIDE the
  vocabulary (:class:`PositionFriction`, :class:`GravityHarmonic`, :class:`TissueCubic`,
  :class:`PowerDamping`, :class:`AsymmetricFriction`) that ``diagnose`` cannot name;
* the declared working range and the human-torque band the calibration is told about.

:func:`sessions` lists the test sessions of a plant, unlike its calibration: slower and faster
moves, a wider range, other shapes, active subjects at several bandwidths (0.1–3 Hz) while
moving, and still-arm active sessions (Sec. V-C protocol).

:func:`degenerate_calibration` builds the calibration logs a user may record by mistake
(:data:`DEGENERATE`): the arm holding still, a short log, motion in one direction only, the
motor torque at its limit for part of the log, a log at another rate than the configuration's.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from sea_daemon.core.excitation import MoveSequence, WorkingRange, excitation, paper_moves
from sea_daemon.core.config import CalibrationConfig, HardwareConfig, ModelConfig
from sea_daemon.core.effects import Effect, make_effect
from sea_daemon.core.log import MeasuredLog
from sea_daemon.io.configfile import load_config, data_root
from sea_daemon.core.sim.session import BandLimitedTorque, SineReference, run_session

# --------------------------------------------------------------- effects outside the vocabulary


def smooth_sign(v: float, eps: float) -> float:
    """tanh(v/ε): the smoothed sign of the vocabulary's friction."""
    return math.tanh(v / eps)


def smooth_sign_deriv(v: float, eps: float) -> float:
    s = math.tanh(v / eps)
    return (1.0 - s * s) / eps


@dataclass(frozen=True)
class _Outside(Effect):
    """An effect outside the vocabulary (diagnose has no candidate for it): its torque and
    partials in Python (``evaluate`` overridden), so the plant and an oracle model evaluate it
    through :class:`~sea_daemon.core.model.SEAModel`'s sums (never through the compiled table)."""

    sides: ClassVar[tuple[str, ...]] = ("load",)

    def evaluate(self, angle, vel, acc):
        return (self.torque(angle, vel, acc), *self.partials(angle, vel, acc))



@dataclass(frozen=True)
class PositionFriction(_Outside):
    """Load friction whose level depends on the angle (a cuff strap rubbing): F(q) sign(q̇),
    F(q) = F0 (1 + r sin(2q + φ))."""

    F0: float = 0.0
    r: float = 0.5
    phi: float = 0.0
    eps: float = 0.01
    type: ClassVar[str] = "x_position_friction"
    param_names: ClassVar[tuple[str, ...]] = ("F0", "r", "phi")

    def torque(self, angle, vel, acc):
        return self.F0 * (1.0 + self.r * math.sin(2.0 * angle + self.phi)) * smooth_sign(vel, self.eps)

    def partials(self, angle, vel, acc):
        F = self.F0 * (1.0 + self.r * math.sin(2.0 * angle + self.phi))
        dF = self.F0 * self.r * 2.0 * math.cos(2.0 * angle + self.phi)
        return (dF * smooth_sign(vel, self.eps), F * smooth_sign_deriv(vel, self.eps), 0.0)


@dataclass(frozen=True)
class GravityHarmonic(_Outside):
    """A second harmonic of the gravity torque (cuff and strap geometry): a2 sin(2q + φ)."""

    a2: float = 0.0
    phi: float = 0.0
    type: ClassVar[str] = "x_gravity_harmonic"
    param_names: ClassVar[tuple[str, ...]] = ("a2", "phi")

    def torque(self, angle, vel, acc):
        return self.a2 * math.sin(2.0 * angle + self.phi)

    def partials(self, angle, vel, acc):
        return (2.0 * self.a2 * math.cos(2.0 * angle + self.phi), 0.0, 0.0)


@dataclass(frozen=True)
class TissueCubic(_Outside):
    """Soft tissue stiffening towards the ends of the elbow's range: k3 (q − q0)³."""

    k3: float = 0.0
    q0: float = 0.9
    type: ClassVar[str] = "x_tissue_cubic"
    param_names: ClassVar[tuple[str, ...]] = ("k3", "q0")

    def torque(self, angle, vel, acc):
        return self.k3 * (angle - self.q0) ** 3

    def partials(self, angle, vel, acc):
        return (3.0 * self.k3 * (angle - self.q0) ** 2, 0.0, 0.0)


@dataclass(frozen=True)
class PowerDamping(_Outside):
    """Damping growing faster than linearly with the speed: b2 |q̇|^1.5 sign(q̇) (smooth at 0)."""

    b2: float = 0.0
    type: ClassVar[str] = "x_power_damping"
    param_names: ClassVar[tuple[str, ...]] = ("b2",)

    def torque(self, angle, vel, acc):
        return self.b2 * vel * math.sqrt(abs(vel) + 1e-6)

    def partials(self, angle, vel, acc):
        a = math.sqrt(abs(vel) + 1e-6)
        return (0.0, self.b2 * (a + 0.5 * abs(vel) / a), 0.0)


@dataclass(frozen=True)
class AsymmetricFriction(_Outside):
    """Friction larger in one direction: d |tanh(q̇/ε)| on top of the symmetric part."""

    d: float = 0.0
    eps: float = 0.01
    type: ClassVar[str] = "x_asymmetric_friction"
    param_names: ClassVar[tuple[str, ...]] = ("d",)

    def torque(self, angle, vel, acc):
        return self.d * abs(smooth_sign(vel, self.eps))

    def partials(self, angle, vel, acc):
        s = 1.0 if vel >= 0 else -1.0
        return (0.0, self.d * s * smooth_sign_deriv(vel, self.eps), 0.0)


OUTSIDE = (PositionFriction, GravityHarmonic, TissueCubic, PowerDamping, AsymmetricFriction)

# --------------------------------------------------------------- plants


@dataclass
class PlantDraw:
    """One random plant: what the user declares and what the plant really is."""

    seed: int
    nominal: ModelConfig             # the user's configuration: nominal robot only
    true: ModelConfig                # the plant: nominal robot + hidden effects (oracle model)
    working_range: WorkingRange
    human_band_hz: tuple[float, float]
    human_rms: float
    torque_noise: float
    summary: dict


def _u(rng, lo, hi):
    return float(rng.uniform(lo, hi))


def draw_plant(seed: int, rate_hz: float | None = None) -> PlantDraw:
    """Draw plant ``seed`` (deterministic)."""
    rng = np.random.default_rng(10_000 + seed)
    base = load_config(data_root() / "configs" / "exo_1dof.yaml")
    if rate_hz is None:
        rate_hz = 1000.0 if seed % 3 == 2 else 100.0
    p = base.model
    sc = {k: _u(rng, 0.7, 1.3) for k in ("M", "J", "D_m", "K_s", "D_s", "gravity")}
    model = dataclasses.replace(p, M=p.M * sc["M"], J=p.J * sc["J"], D_m=p.D_m * sc["D_m"], K_s=p.K_s * sc["K_s"],
                                D_s=p.D_s * sc["D_s"], gravity=p.gravity * sc["gravity"], effects=())
    bits = int(rng.integers(16, 21))
    gear = float(rng.choice([50.0, 100.0, 160.0]))
    tn = float(math.exp(rng.uniform(math.log(0.005), math.log(0.05))))
    hw = dataclasses.replace(base.hardware, encoder_bits=bits, gear_ratio=gear, torque_noise=tn, torque_limit=25.0)
    nominal = dataclasses.replace(base, rate_hz=float(rate_hz), model=model, hardware=hw,
                                  source=f"<family plant {seed}>")
    eff: list[Effect] = [
        make_effect("inertia", "load", dI=_u(rng, 0.02, 0.08)),
        make_effect("gravity", "load", a=_u(rng, 1.0, 3.0), phi=_u(rng, -0.15, 0.15)),
        make_effect("human_viscoelastic", "load", k_h=_u(rng, 0.5, 3.0), q_h0=_u(rng, 0.8, 1.6), b_h=_u(rng, 0.1, 0.5)),
    ]
    if rng.random() < 0.9:
        eff.append(make_effect("coulomb", "load", F_c=_u(rng, 0.1, 0.6)))
    if rng.random() < 0.4:
        eff.append(make_effect("stribeck", "load", F_s=_u(rng, 0.05, 0.3), v_s=_u(rng, 0.03, 0.15)))
    if rng.random() < 0.5:
        eff.append(make_effect("viscous", "load", b=_u(rng, 0.01, 0.1)))
    if rng.random() < 0.3:
        eff.append(make_effect("coulomb", "motor", F_c=_u(rng, 0.02, 0.15)))
    if rng.random() < 0.3:
        eff.append(make_effect("viscous", "motor", b=_u(rng, -0.1, 0.2)))
    if rng.random() < 0.25:
        eff.append(make_effect("torque_scale", "motor", kappa=_u(rng, 0.92, 1.08)))
    if rng.random() < 0.15:
        eff.append(make_effect("cogging", "motor", A=_u(rng, 0.01, 0.04), periods=float(rng.integers(2, 7)),
                               phi=_u(rng, 0, 6.28)))
    if rng.random() < 0.15:
        ks = float(model.K_s[0, 0])
        eff.append(make_effect("spring_cubic", "spring", k3=_u(rng, 0.05, 0.2) * ks / 0.05**2))
    # outside the vocabulary: 0, 1 or 2 of them
    k_out = int(rng.choice([0, 1, 1, 2]))
    for cls in rng.permutation(len(OUTSIDE))[:k_out]:
        c = OUTSIDE[int(cls)]
        if c is PositionFriction:
            eff.append(PositionFriction(side="load", F0=_u(rng, 0.1, 0.3), r=_u(rng, 0.3, 0.8), phi=_u(rng, 0, 6.28)))
        elif c is GravityHarmonic:
            eff.append(GravityHarmonic(side="load", a2=_u(rng, 0.2, 0.6), phi=_u(rng, 0, 6.28)))
        elif c is TissueCubic:
            eff.append(TissueCubic(side="load", k3=_u(rng, 2.0, 8.0), q0=_u(rng, 0.7, 1.1)))
        elif c is PowerDamping:
            eff.append(PowerDamping(side="load", b2=_u(rng, 0.1, 0.4)))
        else:
            eff.append(AsymmetricFriction(side="load", d=_u(rng, 0.05, 0.2)))
    true = nominal.with_effects(tuple(eff))
    wr = WorkingRange(math.radians(_u(rng, 0.0, 20.0)), math.radians(_u(rng, 80.0, 110.0)),
                      v_max=_u(rng, 1.2, 2.0), a_max=_u(rng, 8.0, 15.0))
    band = (0.1, 3.0)
    summary = {"seed": seed, "rate_hz": rate_hz, "encoder_bits": bits, "gear": gear, "torque_noise": round(tn, 4),
               "scale": {k: round(v, 3) for k, v in sc.items()},
               "effects": [f"{e.type}({e.side})" for e in eff],
               "outside_vocabulary": [e.type for e in eff if isinstance(e, OUTSIDE)],
               "range_deg": [round(math.degrees(wr.q_min), 1), round(math.degrees(wr.q_max), 1)],
               "v_max": round(wr.v_max, 2)}
    return PlantDraw(seed, nominal, true, wr, band, 1.5, tn, summary)


# --------------------------------------------------------------- sessions


@dataclass(frozen=True)
class SessionSpec:
    """One test session: a reference (or the arm held still) and a human torque."""

    name: str
    duration_s: float
    reference: object | None
    hold_q: float | None
    human: object | None
    kind: str                       # passive | active | still


def noise_seeds(seed: int, n_sessions: int) -> dict:
    """The simulation noise seeds of plant ``seed``'s calibration log and of its ``n_sessions`` test
    sessions, in order (the one- and two-joint families' logs, and their cache keys)."""
    return {"calibration": 1000 + seed, "sessions": [2000 + 100 * seed + i for i in range(n_sessions)]}


def calibration_motion(pd: PlantDraw, duration_s: float = 60.0, seed: int = 0) -> MoveSequence:
    """The calibration excitation over the plant's declared working range."""
    return excitation(pd.working_range, duration_s, seed=seed)


def sessions(pd: PlantDraw, duration_s: float | None = None) -> list[SessionSpec]:
    """The test sessions of a plant (seeded by the plant's seed): none repeats the calibration."""
    rng = np.random.default_rng(20_000 + pd.seed)
    wr = pd.working_range
    T = duration_s if duration_s is not None else (20.0 if pd.nominal.rate_hz <= 200 else 12.0)
    lo, hi = wr.q_min, wr.q_max
    mid = 0.5 * (lo + hi)
    d = math.radians
    out = []
    # slow moves over the middle of the range (paper-like shape, 40 % of v_max or less)
    a, b = lo + 0.1 * wr.width, hi - 0.25 * wr.width
    move = max(1.875 * (b - a) / (0.3 * wr.v_max), 2.0)
    out.append(SessionSpec("slow", T, paper_moves(a, b, move, 100), None, None, "passive"))
    # fast moves: peak speed 1.1 × v_max (beyond the calibration's fastest)
    a, b = lo + 0.15 * wr.width, hi - 0.1 * wr.width
    move = max(1.875 * (b - a) / (1.1 * wr.v_max), math.sqrt(5.774 * (b - a) / (1.2 * wr.a_max)))
    out.append(SessionSpec("fast", T, paper_moves(a, b, move, 100), None, None, "passive"))
    # wider range: 12° beyond each end of the working range, moderate speed
    a, b = lo - d(12), hi + d(12)
    move = 1.875 * (b - a) / (0.6 * wr.v_max)
    out.append(SessionSpec("wide", T, paper_moves(a, b, move, 100), None, None, "passive"))
    # other shape: a sum of two sines over the range
    amp = 0.3 * wr.width
    f1 = 0.6 * wr.v_max / (2 * math.pi * amp)
    out.append(SessionSpec("sines", T, SineReference(mid, (amp, 0.25 * amp), (f1, 2.7 * f1),
                                                      (float(rng.uniform(0, 6.28)), float(rng.uniform(0, 6.28)))),
                           None, None, "passive"))
    # active while moving: slow sine motion + human torque 0.1–0.5 Hz and 0.5–3 Hz
    ref = SineReference(mid, (0.25 * wr.width,), (0.12,), (0.0,))
    out.append(SessionSpec("active_low", T, ref, None,
                           BandLimitedTorque(pd.human_rms, 0.1, 0.5, seed=pd.seed * 10 + 1), "active"))
    out.append(SessionSpec("active_high", T, ref, None,
                           BandLimitedTorque(0.7 * pd.human_rms, 0.5, 3.0, seed=pd.seed * 10 + 2), "active"))
    # still arm (Sec. V-C): the paper's cosine, and a band-limited torque 0.3–3 Hz
    q0 = lo + float(rng.uniform(0.1, 0.4)) * wr.width
    out.append(SessionSpec("still_cosine", T, None, q0,
                           lambda t: -(-2.0 * math.cos(2 * math.pi * 0.1 * t) + 2.0), "still"))
    out.append(SessionSpec("still_band", T, None, q0 + 0.3 * wr.width,
                           BandLimitedTorque(pd.human_rms, 0.3, 3.0, seed=pd.seed * 10 + 3), "still"))
    return out


def hardware_of(pd: PlantDraw) -> HardwareConfig:
    return pd.nominal.hardware


def user_config(pd: PlantDraw) -> ModelConfig:
    """The configuration the user gives ``sea-daemon fit``: the nominal robot, its declared
    working range and subject torque (the ``calibration`` section)."""
    wr = pd.working_range
    cal = CalibrationConfig(q_min_deg=math.degrees(wr.q_min), q_max_deg=math.degrees(wr.q_max), v_max=wr.v_max,
                            a_max=wr.a_max, human_band_hz=tuple(pd.human_band_hz), human_torque_rms=pd.human_rms)
    return dataclasses.replace(pd.nominal, calibration=cal)


# --------------------------------------------------------------- degenerate calibrations

#: the degenerate calibration logs, in the order the benchmark runs them
DEGENERATE = ("still", "short", "one_direction", "saturated", "wrong_rate")
#: the calibration the degenerate ones are compared with (chosen with ``--cases``): the calibration
#: excitation over the working range, as the README's flow records it
REFERENCE = "full"
#: lengths [s] of the still, short and one-direction logs
STILL_S, SHORT_S, ONE_DIRECTION_S = 6.0, 3.0, 10.0
#: the share of the saturated log's samples whose motor torque sits at the limit
SATURATED_SHARE = 0.15


@dataclass(frozen=True)
class DegenerateLog:
    """One degenerate calibration: the simulated log (with the truth in ``extra``), the
    configuration the user gives with it, and what it is, in one line."""

    case: str
    log: MeasuredLog
    config: ModelConfig
    what: str


def one_direction_motion(wr: WorkingRange, duration_s: float) -> MoveSequence:
    """Minimum-jerk moves from q_min to q_max in four steps of a quarter of the range each, at
    different speeds, with dwells between them: the arm never goes back."""
    weights = (1.0, 0.5, 1.6, 0.8)
    dwell = 0.1 * duration_s / len(weights)
    moving = duration_s - dwell * len(weights)
    step = wr.width / len(weights)
    targets = tuple(wr.q_min + step * (i + 1) for i in range(len(weights)))
    durations = tuple(moving * w / sum(weights) for w in weights)
    return MoveSequence(wr.q_min, targets, durations, (dwell,) * len(weights))


def other_rate(rate_hz: float) -> float:
    """The rate a wrong-rate log is recorded at: 1 kHz for a 100 Hz configuration, else 100 Hz."""
    return 1000.0 if rate_hz <= 200.0 else 100.0


def degenerate_calibration(pd: PlantDraw, case: str, cal_s: float = 60.0) -> DegenerateLog:
    """The degenerate calibration log ``case`` (one of :data:`DEGENERATE`) of plant ``pd``,
    passive (τ_h,act = 0), seeded by the plant's seed:

    * ``still``: the arm held still at mid-range by the PID for :data:`STILL_S` s;
    * ``short``: the calibration excitation for :data:`SHORT_S` s;
    * ``one_direction``: :func:`one_direction_motion` over :data:`ONE_DIRECTION_S` s;
    * ``saturated``: the calibration excitation for ``cal_s`` s, its logged motor torque at
      ±L for :data:`SATURATED_SHARE` of the samples (the drive reporting its limit while the
      plant received more), the configuration's ``hardware.torque_limit`` L;
    * ``wrong_rate``: the calibration excitation for ``cal_s`` s recorded at
      :func:`other_rate` while the configuration keeps its own rate;
    * ``full`` (:data:`REFERENCE`, not degenerate): the calibration excitation for ``cal_s`` s."""
    cfg = user_config(pd)
    wr = pd.working_range
    seed = 5000 + pd.seed
    if case == "still":
        mid = 0.5 * (wr.q_min + wr.q_max)
        log = run_session(pd.true, STILL_S, reference=SineReference(mid, (), (), ()), seed=seed)
        return DegenerateLog(case, log, cfg, f"the arm held still at {math.degrees(mid):.0f} deg for {STILL_S:g} s")
    if case == REFERENCE:
        log = run_session(pd.true, cal_s, reference=calibration_motion(pd, cal_s, seed=pd.seed), seed=seed)
        return DegenerateLog(case, log, cfg, f"the calibration excitation for {cal_s:g} s (not degenerate)")
    if case == "short":
        log = run_session(pd.true, SHORT_S, reference=calibration_motion(pd, SHORT_S, seed=pd.seed), seed=seed)
        return DegenerateLog(case, log, cfg, f"the calibration excitation for {SHORT_S:g} s")
    if case == "one_direction":
        log = run_session(pd.true, ONE_DIRECTION_S, reference=one_direction_motion(wr, ONE_DIRECTION_S), seed=seed)
        return DegenerateLog(case, log, cfg, f"{math.degrees(wr.q_min):.0f} to {math.degrees(wr.q_max):.0f} deg in "
                                             f"four moves, never back, {ONE_DIRECTION_S:g} s")
    if case == "saturated":
        log = run_session(pd.true, cal_s, reference=calibration_motion(pd, cal_s, seed=pd.seed), seed=seed)
        lim = float(np.quantile(np.abs(log.tau_m), 1.0 - SATURATED_SHARE))
        log = dataclasses.replace(log, tau_m=np.clip(log.tau_m, -lim, lim))
        cfg = dataclasses.replace(cfg, hardware=dataclasses.replace(cfg.hardware, torque_limit=lim))
        return DegenerateLog(case, log, cfg, f"the calibration excitation for {cal_s:g} s, the motor torque at its "
                                             f"limit {lim:.3g} N m for {100 * SATURATED_SHARE:g} % of the samples")
    if case == "wrong_rate":
        rate = other_rate(cfg.rate_hz)
        log = run_session(dataclasses.replace(pd.true, rate_hz=rate), cal_s,
                          reference=calibration_motion(pd, cal_s, seed=pd.seed), seed=seed)
        return DegenerateLog(case, log, cfg, f"the calibration excitation for {cal_s:g} s recorded at {rate:g} Hz, "
                                             f"the configuration at {cfg.rate_hz:g} Hz")
    raise ValueError(f"degenerate_calibration: unknown case {case!r}; one of {', '.join(DEGENERATE + (REFERENCE,))}")
