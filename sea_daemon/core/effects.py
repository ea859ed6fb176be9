"""The effect vocabulary of docs/interfaces.md §2: small physical effects on top of the nominal SEA.

Each effect is a torque that the named side must overcome (it enters that side's dynamics
like friction does), or, for the structural ones, a change of how torque, deflection or
angle is formed.  The same objects serve the simulator (true plant), the estimator (declared
effects become part of the nominal model) and ``diagnose`` (candidate regressors).

Signals by side (joint side of the gear, SI):
    load   -- angle q,       velocity q̇,      acceleration q̈
    motor  -- angle θ_m,     velocity θ̇_m,    acceleration θ̈_m
    spring -- deflection θ_s = q − θ_m, rate θ̇_s

Every additive effect's formula — its torque and its partial derivatives — is written once, in
the compiled kernel :func:`evaluate` (one branch per type, parameters as a vector).  The Python
classes validate and name the parameters and call it: ``torque``/``partials``/``evaluate`` at
one sample (the model's sums and analytic Jacobians, :class:`~sea_daemon.core.model.SEAModel`),
``torque_array`` over a log (diagnose's regressors), and :func:`side_torque` from compiled code
(the simulated plant's RK4, :mod:`sea_daemon.core.sim.plant`).  Structural effects
(``spring_backlash``, ``torque_scale``, ``encoder_offset``, ``delay``) change how torque,
deflection or angle are formed; the model applies them (the dead band: :func:`deadband`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from typing import ClassVar, Mapping

import numpy as np

from sea_daemon.core.jit import njit, warmer
from sea_daemon.errors import ConfigError

#: every configured number lies within ±MAX_ABS: a larger one is a unit or typing error that would
#: only overflow later (no setting of the model needs more)
MAX_ABS = 1e9


def finite_number(v) -> bool:
    """Whether ``v`` converts to a finite float within ±:data:`MAX_ABS`."""
    try:
        return math.isfinite(float(v)) and abs(float(v)) <= MAX_ABS
    except (OverflowError, TypeError, ValueError):
        return False


#: velocity scale [rad/s] of the smoothed sign used for Coulomb/Stribeck friction
DEFAULT_SIGN_EPS = 0.01

#: codes of the additive effects in the compiled kernel :func:`evaluate` (0: structural, no torque)
STRUCTURAL, COULOMB, VISCOUS, STRIBECK, INERTIA, GRAVITY, HUMAN_VISCOELASTIC, COGGING, SPRING_CUBIC, \
    SPRING_SATURATION, TORQUE_OFFSET = range(11)
#: the longest parameter vector of an additive effect (:attr:`Effect.vector`)
MAX_PARAMS = 3


@njit
def softplus(x: float, w: float) -> tuple[float, float]:
    """w·log(1 + exp(x/w)) and its derivative, the logistic (linear above 30 w, 0 below −30 w)."""
    z = x / w
    if z > 30.0:
        return x, 1.0
    if z < -30.0:
        return 0.0, 0.0
    return w * math.log1p(math.exp(z)), 1.0 / (1.0 + math.exp(-z))


@njit
def evaluate(code: int, p, angle: float, vel: float, acc: float) -> tuple[float, float, float, float]:
    """(τ, ∂τ/∂angle, ∂τ/∂vel, ∂τ/∂acc) of one additive effect with parameter vector ``p``.

    The one definition of every effect's torque (the table of docs/interfaces.md §2): the
    model's sums and Jacobians, the simulated plant and diagnose's regressors all evaluate it.
    The friction sign is smoothed, sign(v) ≈ tanh(v/ε), ε the last entry of ``p``.
    """
    if code == COULOMB:                    # p = (F_c, ε): F_c sign(v)
        s = math.tanh(vel / p[1])
        return p[0] * s, 0.0, p[0] * ((1.0 - s * s) / p[1]), 0.0
    if code == VISCOUS:                    # p = (b,): b v
        return p[0] * vel, 0.0, p[0], 0.0
    if code == STRIBECK:                   # p = (F_s, v_s, ε): F_s exp(−(v/v_s)²) sign(v)
        e = math.exp(-((vel / p[1]) ** 2))
        s = math.tanh(vel / p[2])
        d = p[0] * e * ((1.0 - s * s) / p[2] - 2.0 * vel / p[1] ** 2 * s)
        return p[0] * e * s, 0.0, d, 0.0
    if code == INERTIA:                    # p = (dI,): dI v̇
        return p[0] * acc, 0.0, 0.0, p[0]
    if code == GRAVITY:                    # p = (a, φ): a sin(q + φ)
        return p[0] * math.sin(angle + p[1]), p[0] * math.cos(angle + p[1]), 0.0, 0.0
    if code == HUMAN_VISCOELASTIC:         # p = (k_h, q_h0, b_h): k_h (q − q_h0) + b_h q̇
        return p[0] * (angle - p[1]) + p[2] * vel, p[0], p[2], 0.0
    if code == COGGING:                    # p = (A, P, φ): A sin(P θ_m + φ)
        a = p[1] * angle + p[2]
        return p[0] * math.sin(a), p[0] * p[1] * math.cos(a), 0.0, 0.0
    if code == SPRING_CUBIC:               # p = (k3,): k3 θ_s³
        return p[0] * angle ** 3, 3.0 * p[0] * angle ** 2, 0.0, 0.0
    if code == SPRING_SATURATION:          # p = (θ_max, k_stop, w): k_stop (sp(θ_s − θ_max) − sp(−θ_s − θ_max))
        up, dup = softplus(angle - p[0], p[2])
        dn, ddn = softplus(-angle - p[0], p[2])
        return p[1] * (up - dn), p[1] * (dup + ddn), 0.0, 0.0
    if code == TORQUE_OFFSET:              # p = (τ₀,): the drive delivers τ₀ more, a torque of −τ₀ to overcome
        return -p[0], 0.0, 0.0, 0.0
    return 0.0, 0.0, 0.0, 0.0


@njit
def evaluate_many(code: int, p, angle, vel, acc, out) -> None:
    """``out[i]`` = τ of :func:`evaluate` at sample i (arrays of one joint's signals)."""
    for i in range(angle.shape[0]):
        out[i] = evaluate(code, p, angle[i], vel[i], acc[i])[0]


@njit
def side_torque(codes, P, angle: float, vel: float) -> float:
    """Σ τ of the effects (codes[i], P[i]) of one side at (angle, vel), zero acceleration."""
    tau = 0.0
    for i in range(codes.shape[0]):
        tau += evaluate(codes[i], P[i], angle, vel, 0.0)[0]
    return tau


@njit
def deadband(theta_s: float, half_width: float) -> tuple[float, float]:
    """The deflection a dead band of ±half_width passes on, θ_s − clip(θ_s, −h, h), and its slope."""
    if theta_s > half_width:
        return theta_s - half_width, 1.0
    if theta_s < -half_width:
        return theta_s + half_width, 1.0
    return 0.0, 0.0


@dataclass(frozen=True)
class Effect:
    """Base of every effect.  ``side`` and ``joint`` (0-based) locate it; params are fields."""

    side: str
    joint: int = 0

    type: ClassVar[str] = ""
    sides: ClassVar[tuple[str, ...]] = ()
    param_names: ClassVar[tuple[str, ...]] = ()
    #: additive torque effects take part in the dynamics sums; structural ones do not
    additive: ClassVar[bool] = True
    #: code of the formula in :func:`evaluate`
    code: ClassVar[int] = STRUCTURAL
    #: fields forming the parameter vector of :func:`evaluate`, in its order (default: param_names)
    vector_fields: ClassVar[tuple[str, ...]] = ()
    #: fields forming the parameter vector of :func:`evaluate`, in its order (default: param_names)

    @property
    def params(self) -> dict[str, float]:
        return {k: float(getattr(self, k)) for k in self.param_names}

    @cached_property
    def vector(self) -> np.ndarray:
        """The parameter vector ``p`` of :func:`evaluate` (length :data:`MAX_PARAMS`)."""
        v = np.zeros(MAX_PARAMS)
        for i, k in enumerate(self.vector_fields or self.param_names):
            v[i] = float(getattr(self, k))
        return v

    def to_dict(self, n_joints: int = 1) -> dict:
        d: dict = {"type": self.type, "side": self.side}
        if n_joints > 1:
            d["joint"] = self.joint + 1
        d.update(self.params)
        return d

    def evaluate(self, angle: float, vel: float, acc: float) -> tuple[float, float, float, float]:
        """(τ, ∂τ/∂angle, ∂τ/∂vel, ∂τ/∂acc) at one sample (:func:`evaluate`)."""
        return evaluate(self.code, self.vector, float(angle), float(vel), float(acc))

    def torque(self, angle: float, vel: float, acc: float) -> float:
        return self.evaluate(angle, vel, acc)[0]

    def partials(self, angle: float, vel: float, acc: float) -> tuple[float, float, float]:
        return self.evaluate(angle, vel, acc)[1:]

    def torque_array(self, angle, vel, acc) -> np.ndarray:
        """τ over arrays of samples (this effect's side and joint signals)."""
        a = np.ascontiguousarray(angle, dtype=float)
        out = np.empty(a.shape[0])
        evaluate_many(self.code, self.vector, a, np.ascontiguousarray(vel, dtype=float),
                      np.ascontiguousarray(acc, dtype=float), out)
        return out


@dataclass(frozen=True)
class Coulomb(Effect):
    F_c: float = 0.0
    eps: float = DEFAULT_SIGN_EPS
    type, sides, param_names, code, vector_fields = (
        "coulomb", ("load", "motor"), ("F_c",), COULOMB, ("F_c", "eps"))


@dataclass(frozen=True)
class Viscous(Effect):
    b: float = 0.0
    type, sides, param_names, code = "viscous", ("load", "motor"), ("b",), VISCOUS


@dataclass(frozen=True)
class Stribeck(Effect):
    F_s: float = 0.0
    v_s: float = 0.1
    eps: float = DEFAULT_SIGN_EPS
    type, sides, param_names, code, vector_fields = (
        "stribeck", ("load", "motor"), ("F_s", "v_s"), STRIBECK, ("F_s", "v_s", "eps"))


@dataclass(frozen=True)
class Inertia(Effect):
    dI: float = 0.0
    type, sides, param_names, code = "inertia", ("load", "motor"), ("dI",), INERTIA


@dataclass(frozen=True)
class Gravity(Effect):
    a: float = 0.0
    phi: float = 0.0
    type, sides, param_names, code = "gravity", ("load",), ("a", "phi"), GRAVITY


@dataclass(frozen=True)
class HumanViscoelastic(Effect):
    k_h: float = 0.0
    q_h0: float = 0.0
    b_h: float = 0.0
    type, sides, param_names, code = (
        "human_viscoelastic", ("load",), ("k_h", "q_h0", "b_h"), HUMAN_VISCOELASTIC)


@dataclass(frozen=True)
class Cogging(Effect):
    A: float = 0.0
    periods: float = 1.0
    phi: float = 0.0
    type, sides, param_names, code = "cogging", ("motor",), ("A", "periods", "phi"), COGGING


@dataclass(frozen=True)
class SpringCubic(Effect):
    """Spring torque gains k3·θ_s³ (additive on the spring, signal = deflection)."""

    k3: float = 0.0
    type, sides, param_names, code = "spring_cubic", ("spring",), ("k3",), SPRING_CUBIC


@dataclass(frozen=True)
class SpringSaturation(Effect):
    """(extension) Mechanical stop: beyond |θ_s| > theta_max the spring gains stiffness k_stop.

    The deflection therefore saturates while the transmitted torque keeps rising, so the
    spring-torque estimate K_s·θ_s saturates (paper Fig. 4).  Smoothed with a softplus of
    width ``smooth`` [rad] so the plant stays differentiable.
    """

    theta_max: float = 0.05
    k_stop: float = 2000.0
    smooth: float = 0.002
    type, sides, param_names, code, vector_fields = ("spring_saturation", ("spring",), ("theta_max", "k_stop"),
                                                     SPRING_SATURATION, ("theta_max", "k_stop", "smooth"))


@dataclass(frozen=True)
class TorqueOffset(Effect):
    """(extension) The drive delivers κ τ_m + ``tau_0`` [N m, joint side]: the offset of an
    analog command chain (a DAC or amplifier offset voltage, a current-sensor offset), the
    commanded-versus-delivered error that does not scale with the command.  As every additive
    effect it is a torque its side must overcome: −tau_0 (eq:motorside).
    """

    tau_0: float = 0.0
    type, sides, param_names, code = "torque_offset", ("motor",), ("tau_0",), TORQUE_OFFSET


# ---- structural effects: they change how torque/deflection/angle are formed ----------


@dataclass(frozen=True)
class SpringBacklash(Effect):
    """Spring deflection has a dead band of total ``width`` [rad] (±width/2)."""

    width: float = 0.0
    type, sides, param_names, additive = "spring_backlash", ("spring",), ("width",), False

    def deadband(self, theta_s: float) -> tuple[float, float]:
        """Effective deflection and its derivative w.r.t. θ_s (0 inside the band)."""
        return deadband(float(theta_s), 0.5 * self.width)

    def deadband_array(self, theta_s) -> np.ndarray:
        """The effective deflection over an array of samples: θ_s − clip(θ_s, −w/2, w/2)."""
        h = 0.5 * self.width
        return theta_s - np.clip(theta_s, -h, h)


@dataclass(frozen=True)
class TorqueScale(Effect):
    kappa: float = 1.0
    type, sides, param_names, additive = "torque_scale", ("motor",), ("kappa",), False


@dataclass(frozen=True)
class EncoderOffset(Effect):
    delta: float = 0.0
    type, sides, param_names, additive = "encoder_offset", ("load", "motor"), ("delta",), False


@dataclass(frozen=True)
class Delay(Effect):
    seconds: float = 0.0
    type, sides, param_names, additive = "delay", ("motor",), ("seconds",), False


EFFECT_TYPES: Mapping[str, type[Effect]] = {
    cls.type: cls
    for cls in (
        Coulomb, Viscous, Stribeck, Inertia, Gravity, HumanViscoelastic, SpringCubic,
        SpringBacklash, TorqueScale, EncoderOffset, Delay, Cogging, SpringSaturation, TorqueOffset,
    )
}

#: the range of every effect parameter: ``(type, parameter) -> (lo, hi, unit)``; ``lo`` excluded
#: where the parameter must be positive (:data:`_POSITIVE`).  Wide enough for any exoskeleton
#: joint, narrow enough that no value makes a command allocate or compute without bound (a
#: ``delay`` of d seconds keeps d·rate_hz past commands).  docs/interfaces.md §2 lists them.
PARAM_RANGES: Mapping[tuple[str, str], tuple[float, float, str]] = {
    ("coulomb", "F_c"): (0.0, 1e3, "N m"),
    ("viscous", "b"): (-1e3, 1e3, "N m s/rad"),
    ("stribeck", "F_s"): (0.0, 1e3, "N m"),
    ("stribeck", "v_s"): (0.0, 100.0, "rad/s"),
    ("inertia", "dI"): (-100.0, 100.0, "kg m²"),
    ("gravity", "a"): (-1e3, 1e3, "N m"),
    ("gravity", "phi"): (-100.0, 100.0, "rad"),
    ("human_viscoelastic", "k_h"): (-1e4, 1e4, "N m/rad"),
    ("human_viscoelastic", "q_h0"): (-100.0, 100.0, "rad"),
    ("human_viscoelastic", "b_h"): (-1e3, 1e3, "N m s/rad"),
    ("spring_cubic", "k3"): (-MAX_ABS, MAX_ABS, "N m/rad³"),
    ("spring_backlash", "width"): (0.0, 1.0, "rad"),
    ("torque_scale", "kappa"): (0.0, 10.0, ""),
    ("encoder_offset", "delta"): (-100.0, 100.0, "rad"),
    ("delay", "seconds"): (0.0, 1.0, "s"),
    ("cogging", "A"): (-1e3, 1e3, "N m"),
    ("cogging", "periods"): (0.0, 1e4, ""),
    ("cogging", "phi"): (-100.0, 100.0, "rad"),
    ("spring_saturation", "theta_max"): (0.0, 10.0, "rad"),
    ("spring_saturation", "k_stop"): (0.0, MAX_ABS, "N m/rad"),
    ("torque_offset", "tau_0"): (-1e3, 1e3, "N m"),
}
#: parameters that must be strictly positive (their range excludes its lower end)
_POSITIVE = {"v_s", "periods", "theta_max", "k_stop", "kappa"}


def param_range(typ: str, name: str) -> str:
    """The allowed range of an effect parameter as text, e.g. ``[0, 1] s`` or ``(0, 10]``."""
    lo, hi, unit = PARAM_RANGES[(typ, name)]
    return f"{'(' if name in _POSITIVE else '['}{lo:g}, {hi:g}]" + (f" {unit}" if unit else "")


def in_range(typ: str, name: str, v: float) -> bool:
    """Whether ``v`` lies in the range of parameter ``name`` of effect type ``typ``."""
    lo, hi, _ = PARAM_RANGES[(typ, name)]
    return (lo < v if name in _POSITIVE else lo <= v) and v <= hi


def effect_from_dict(d: Mapping, n_joints: int, source: str, where: str) -> Effect:
    """Build one effect from its YAML mapping, validating type, side, joint and params."""
    if not isinstance(d, Mapping):
        raise ConfigError(source, where, f"must be a mapping like {{type: coulomb, side: load, F_c: 0.3}}, got {d!r}")
    typ = d.get("type")
    if typ not in EFFECT_TYPES:
        raise ConfigError(source, f"{where}.type", f"unknown effect type {typ!r}; allowed: {', '.join(EFFECT_TYPES)}")
    cls = EFFECT_TYPES[typ]
    side = d.get("side", cls.sides[0] if len(cls.sides) == 1 else None)
    if side not in cls.sides:
        raise ConfigError(source, f"{where}.side", f"{side!r} is not a side for {typ}; allowed: {', '.join(cls.sides)}")
    joint = d.get("joint", 1)
    if not isinstance(joint, int) or isinstance(joint, bool) or not 1 <= joint <= n_joints:
        raise ConfigError(source, f"{where}.joint", f"{joint!r} is not a joint number; allowed: 1..{n_joints}")
    if n_joints > 1 and "joint" not in d:
        raise ConfigError(source, f"{where}.joint", f"missing; required when joints > 1 (allowed: 1..{n_joints})")
    allowed = {"type", "side", "joint", *cls.param_names}
    for k in d:
        if k not in allowed:
            raise ConfigError(source, f"{where}.{k}", f"unknown key for {typ}; allowed: {', '.join(sorted(allowed))}")
    kwargs = {}
    for p in cls.param_names:
        if p not in d:
            raise ConfigError(source, f"{where}.{p}", f"missing parameter of {typ} (needs {', '.join(cls.param_names)})")
        v = d[p]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not finite_number(v):
            raise ConfigError(source, f"{where}.{p}", f"must be a finite number within ±{MAX_ABS:g}, got {v!r}")
        v = float(v)
        if not in_range(typ, p, v):
            raise ConfigError(source, f"{where}.{p}", f"must be in {param_range(typ, p)}, got {v:g}")
        kwargs[p] = v
    return cls(side=side, joint=joint - 1, **kwargs)


def make_effect(type: str, side: str | None = None, joint: int = 0, **params: float) -> Effect:
    """Programmatic constructor (0-based joint): ``make_effect('coulomb', 'load', F_c=0.3)``."""
    cls = EFFECT_TYPES[type]
    return cls(side=side or cls.sides[0], joint=joint, **params)


@warmer
def _warm() -> None:
    p = np.zeros(MAX_PARAMS)
    for code in range(TORQUE_OFFSET + 1):
        evaluate(code, p + 1.0, 0.1, 0.2, 0.3)
    z = np.zeros(2)
    evaluate_many(COULOMB, p + 1.0, z, z, z, np.zeros(2))
    side_torque(np.zeros(1, dtype=np.int64), np.ones((1, MAX_PARAMS)), 0.1, 0.2)
    deadband(0.1, 0.05)
