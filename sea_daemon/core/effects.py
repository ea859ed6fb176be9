"""The effect vocabulary of docs/interfaces.md §2: small physical effects on top of the nominal SEA.

Each effect is a torque that the named side must overcome (it enters that side's dynamics
like friction does), or, for the structural ones, a change of how torque, deflection or
angle is formed.  The same objects serve the simulator (true plant), the estimator (declared
effects become part of the nominal model) and ``diagnose`` (candidate regressors).

Signals by side (joint side of the gear, SI):
    load   -- angle q,       velocity q̇,      acceleration q̈
    motor  -- angle θ_m,     velocity θ̇_m,    acceleration θ̈_m
    spring -- deflection θ_s = q − θ_m, rate θ̇_s

Additive effects implement ``torque(angle, vel, acc)`` and ``partials(angle, vel, acc)`` ->
(∂τ/∂angle, ∂τ/∂vel, ∂τ/∂acc); these are used for the analytic Jacobians of the model.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar, Mapping

from sea_daemon.errors import ConfigError

#: velocity scale [rad/s] of the smoothed sign used for Coulomb/Stribeck friction
DEFAULT_SIGN_EPS = 0.01


def smooth_sign(v: float, eps: float) -> float:
    """sign(v) smoothed near zero: tanh(v/eps)."""
    return math.tanh(v / eps)


def smooth_sign_deriv(v: float, eps: float) -> float:
    """d/dv tanh(v/eps)."""
    t = math.tanh(v / eps)
    return (1.0 - t * t) / eps


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

    @property
    def params(self) -> dict[str, float]:
        return {k: float(getattr(self, k)) for k in self.param_names}

    def to_dict(self, n_joints: int = 1) -> dict:
        d: dict = {"type": self.type, "side": self.side}
        if n_joints > 1:
            d["joint"] = self.joint + 1
        d.update(self.params)
        return d

    # additive effects override these two
    def torque(self, angle: float, vel: float, acc: float) -> float:
        return 0.0

    def partials(self, angle: float, vel: float, acc: float) -> tuple[float, float, float]:
        return (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class Coulomb(Effect):
    F_c: float = 0.0
    eps: float = DEFAULT_SIGN_EPS
    type: ClassVar[str] = "coulomb"
    sides: ClassVar[tuple[str, ...]] = ("load", "motor")
    param_names: ClassVar[tuple[str, ...]] = ("F_c",)

    def torque(self, angle, vel, acc):
        return self.F_c * smooth_sign(vel, self.eps)

    def partials(self, angle, vel, acc):
        return (0.0, self.F_c * smooth_sign_deriv(vel, self.eps), 0.0)


@dataclass(frozen=True)
class Viscous(Effect):
    b: float = 0.0
    type: ClassVar[str] = "viscous"
    sides: ClassVar[tuple[str, ...]] = ("load", "motor")
    param_names: ClassVar[tuple[str, ...]] = ("b",)

    def torque(self, angle, vel, acc):
        return self.b * vel

    def partials(self, angle, vel, acc):
        return (0.0, self.b, 0.0)


@dataclass(frozen=True)
class Stribeck(Effect):
    F_s: float = 0.0
    v_s: float = 0.1
    eps: float = DEFAULT_SIGN_EPS
    type: ClassVar[str] = "stribeck"
    sides: ClassVar[tuple[str, ...]] = ("load", "motor")
    param_names: ClassVar[tuple[str, ...]] = ("F_s", "v_s")

    def torque(self, angle, vel, acc):
        return self.F_s * math.exp(-((vel / self.v_s) ** 2)) * smooth_sign(vel, self.eps)

    def partials(self, angle, vel, acc):
        e = math.exp(-((vel / self.v_s) ** 2))
        s = smooth_sign(vel, self.eps)
        d = self.F_s * e * (smooth_sign_deriv(vel, self.eps) - 2.0 * vel / self.v_s**2 * s)
        return (0.0, d, 0.0)


@dataclass(frozen=True)
class Inertia(Effect):
    dI: float = 0.0
    type: ClassVar[str] = "inertia"
    sides: ClassVar[tuple[str, ...]] = ("load", "motor")
    param_names: ClassVar[tuple[str, ...]] = ("dI",)

    def torque(self, angle, vel, acc):
        return self.dI * acc

    def partials(self, angle, vel, acc):
        return (0.0, 0.0, self.dI)


@dataclass(frozen=True)
class Gravity(Effect):
    a: float = 0.0
    phi: float = 0.0
    type: ClassVar[str] = "gravity"
    sides: ClassVar[tuple[str, ...]] = ("load",)
    param_names: ClassVar[tuple[str, ...]] = ("a", "phi")

    def torque(self, angle, vel, acc):
        return self.a * math.sin(angle + self.phi)

    def partials(self, angle, vel, acc):
        return (self.a * math.cos(angle + self.phi), 0.0, 0.0)


@dataclass(frozen=True)
class HumanViscoelastic(Effect):
    k_h: float = 0.0
    q_h0: float = 0.0
    b_h: float = 0.0
    type: ClassVar[str] = "human_viscoelastic"
    sides: ClassVar[tuple[str, ...]] = ("load",)
    param_names: ClassVar[tuple[str, ...]] = ("k_h", "q_h0", "b_h")

    def torque(self, angle, vel, acc):
        return self.k_h * (angle - self.q_h0) + self.b_h * vel

    def partials(self, angle, vel, acc):
        return (self.k_h, self.b_h, 0.0)


@dataclass(frozen=True)
class Cogging(Effect):
    A: float = 0.0
    periods: float = 1.0
    phi: float = 0.0
    type: ClassVar[str] = "cogging"
    sides: ClassVar[tuple[str, ...]] = ("motor",)
    param_names: ClassVar[tuple[str, ...]] = ("A", "periods", "phi")

    def torque(self, angle, vel, acc):
        return self.A * math.sin(self.periods * angle + self.phi)

    def partials(self, angle, vel, acc):
        return (self.A * self.periods * math.cos(self.periods * angle + self.phi), 0.0, 0.0)


@dataclass(frozen=True)
class SpringCubic(Effect):
    """Spring torque gains k3·θ_s³ (additive on the spring, signal = deflection)."""

    k3: float = 0.0
    type: ClassVar[str] = "spring_cubic"
    sides: ClassVar[tuple[str, ...]] = ("spring",)
    param_names: ClassVar[tuple[str, ...]] = ("k3",)

    def torque(self, angle, vel, acc):
        return self.k3 * angle**3

    def partials(self, angle, vel, acc):
        return (3.0 * self.k3 * angle**2, 0.0, 0.0)


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
    type: ClassVar[str] = "spring_saturation"
    sides: ClassVar[tuple[str, ...]] = ("spring",)
    param_names: ClassVar[tuple[str, ...]] = ("theta_max", "k_stop")

    def _sp(self, x: float) -> tuple[float, float]:
        # softplus(x) = smooth*log(1+exp(x/smooth)) and its derivative (logistic)
        z = x / self.smooth
        if z > 30:
            return x, 1.0
        if z < -30:
            return 0.0, 0.0
        return self.smooth * math.log1p(math.exp(z)), 1.0 / (1.0 + math.exp(-z))

    def torque(self, angle, vel, acc):
        up, _ = self._sp(angle - self.theta_max)
        dn, _ = self._sp(-angle - self.theta_max)
        return self.k_stop * (up - dn)

    def partials(self, angle, vel, acc):
        _, dup = self._sp(angle - self.theta_max)
        _, ddn = self._sp(-angle - self.theta_max)
        return (self.k_stop * (dup + ddn), 0.0, 0.0)


# ---- structural effects: they change how torque/deflection/angle are formed ----------


@dataclass(frozen=True)
class SpringBacklash(Effect):
    """Spring deflection has a dead band of total ``width`` [rad] (±width/2)."""

    width: float = 0.0
    type: ClassVar[str] = "spring_backlash"
    sides: ClassVar[tuple[str, ...]] = ("spring",)
    param_names: ClassVar[tuple[str, ...]] = ("width",)
    additive: ClassVar[bool] = False

    def deadband(self, theta_s: float) -> tuple[float, float]:
        """Effective deflection and its derivative w.r.t. θ_s (0 inside the band)."""
        h = 0.5 * self.width
        if theta_s > h:
            return theta_s - h, 1.0
        if theta_s < -h:
            return theta_s + h, 1.0
        return 0.0, 0.0


@dataclass(frozen=True)
class TorqueScale(Effect):
    kappa: float = 1.0
    type: ClassVar[str] = "torque_scale"
    sides: ClassVar[tuple[str, ...]] = ("motor",)
    param_names: ClassVar[tuple[str, ...]] = ("kappa",)
    additive: ClassVar[bool] = False


@dataclass(frozen=True)
class EncoderOffset(Effect):
    delta: float = 0.0
    type: ClassVar[str] = "encoder_offset"
    sides: ClassVar[tuple[str, ...]] = ("load", "motor")
    param_names: ClassVar[tuple[str, ...]] = ("delta",)
    additive: ClassVar[bool] = False


@dataclass(frozen=True)
class Delay(Effect):
    seconds: float = 0.0
    type: ClassVar[str] = "delay"
    sides: ClassVar[tuple[str, ...]] = ("motor",)
    param_names: ClassVar[tuple[str, ...]] = ("seconds",)
    additive: ClassVar[bool] = False


EFFECT_TYPES: Mapping[str, type[Effect]] = {
    cls.type: cls
    for cls in (
        Coulomb, Viscous, Stribeck, Inertia, Gravity, HumanViscoelastic, SpringCubic,
        SpringBacklash, TorqueScale, EncoderOffset, Delay, Cogging, SpringSaturation,
    )
}

#: parameters that must be strictly positive, per type (others may take any finite value)
_POSITIVE = {"v_s", "periods", "theta_max", "k_stop", "kappa"}
_NON_NEGATIVE = {"F_c", "F_s", "width", "seconds"}


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
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(float(v)):
            raise ConfigError(source, f"{where}.{p}", f"must be a finite number, got {v!r}")
        v = float(v)
        if p in _POSITIVE and v <= 0:
            raise ConfigError(source, f"{where}.{p}", f"must be > 0, got {v}")
        if p in _NON_NEGATIVE and v < 0:
            raise ConfigError(source, f"{where}.{p}", f"must be >= 0, got {v}")
        kwargs[p] = v
    return cls(side=side, joint=joint - 1, **kwargs)


def make_effect(type: str, side: str | None = None, joint: int = 0, **params: float) -> Effect:
    """Programmatic constructor (0-based joint): ``make_effect('coulomb', 'load', F_c=0.3)``."""
    cls = EFFECT_TYPES[type]
    return cls(side=side or cls.sides[0], joint=joint, **params)
