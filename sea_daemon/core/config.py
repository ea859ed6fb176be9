"""Model configuration (docs/interfaces.md §2) as validated, frozen dataclasses.

The YAML has the contract's top level (``joints``, ``rate_hz``, ``model``) plus optional
sections this project adds (``estimator``, ``kinematics``, ``learning``, ``hardware``, ``assist``,
``calibration``, ``publish``).
Every section is a frozen dataclass; unknown keys, missing keys and values out of range
raise :class:`~sea_daemon.errors.ConfigError` naming the key and the allowed values.

To add an option, add a field with a default to the section's dataclass and, if it needs
a range check, a line in its ``_check``.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np

from sea_daemon.core import validate
from sea_daemon.core.effects import Effect, effect_from_dict
from sea_daemon.core.estimator_config import TAU_MODELS, EstimatorConfig
from sea_daemon.core.hardware_config import BusConfig, HardwareConfig, joint_values, per_joint
from sea_daemon.errors import ConfigError

#: the largest seed of a random generator a configuration may give (numpy's and Python's take any
#: integer; 32 bits are every seed anyone writes)
MAX_SEED = 2 ** 32 - 1

__all__ = ["SEAParams", "EstimatorConfig", "TAU_MODELS", "KinematicsConfig", "LearningConfig", "AssistConfig", "BusConfig",
           "HardwareConfig", "PublishConfig", "ModelConfig"]


@dataclass(frozen=True)
class SEAParams:
    """Nominal SEA model (``eq:sea``, ``eq:spring_torque``), joint side, SI units."""

    M: np.ndarray          # load-side inertia [kg m^2]            eq:loadside
    J: np.ndarray          # motor inertia through the gear        eq:motorside
    D_m: np.ndarray        # motor viscous damping [N m s/rad]     eq:motorside
    K_s: np.ndarray        # spring stiffness [N m/rad]            eq:spring_torque
    D_s: np.ndarray        # spring damping [N m s/rad]            eq:spring_torque
    gravity: np.ndarray    # m g l per joint: C(q) = gravity*sin(q) [N m]
    effects: tuple[Effect, ...] = ()
    # model.urdf: the robot description's path as the YAML gives it (relative to the YAML); its
    # rigid body (core.rigid.RigidBody) gives M(q) and C(q, q̇) q̇ + g(q) in place of M and
    # gravity (then M holds M(0) and gravity zeros)
    urdf: str | None = None
    rigid: Any = None

    KEYS = ["M", "J", "D_m", "K_s", "D_s", "gravity", "effects", "urdf"]
    REQUIRED = ["M", "J", "D_m", "K_s", "D_s"]

    @property
    def n(self) -> int:
        return self.M.shape[0]

    def with_effects(self, effects) -> "SEAParams":
        return dataclasses.replace(self, effects=tuple(effects))

    @classmethod
    def from_dict(cls, d: Mapping, n: int, source: str, urdf_text: str | None = None) -> "SEAParams":
        """``urdf_text``: the text of the file ``model.urdf`` names (the io layer reads it)."""
        has_urdf = isinstance(d, Mapping) and "urdf" in d
        validate.check_keys(source, "model.", d, cls.KEYS, cls.REQUIRED[1:] if has_urdf else cls.REQUIRED)
        eff = d.get("effects") or []
        if not isinstance(eff, list):
            raise ConfigError(source, "model.effects", f"must be a list of effect mappings, got {eff!r}")
        rigid = rigid_body(d, n, source, urdf_text) if has_urdf else None
        return cls(
            M=(rigid.mass_matrix(np.zeros(n)) if rigid is not None
               else validate.matrix(source, "model.M", d["M"], n, positive_definite=True)),
            J=validate.matrix(source, "model.J", d["J"], n, positive_definite=True),
            D_m=validate.matrix(source, "model.D_m", d["D_m"], n, non_negative=True),
            K_s=validate.matrix(source, "model.K_s", d["K_s"], n, positive_definite=True),
            D_s=validate.matrix(source, "model.D_s", d["D_s"], n, non_negative=True),
            gravity=validate.vector(source, "model.gravity", d.get("gravity", 0.0), n),
            effects=tuple(effect_from_dict(e, n, source, f"model.effects[{i}]") for i, e in enumerate(eff)),
            urdf=d["urdf"] if has_urdf else None, rigid=rigid,
        )

    def with_rigid(self, rigid) -> "SEAParams":
        """The same SEA part with another rigid body (e.g. a plant's, :meth:`RigidBody.scaled`)."""
        return dataclasses.replace(self, rigid=rigid, M=rigid.mass_matrix(np.zeros(self.n)))

    def to_dict(self) -> dict:
        def m(a):
            if self.n == 1:
                return float(a[0, 0])
            return a.tolist()
        out = {"urdf": self.urdf} if self.rigid is not None else {"M": m(self.M)}
        out.update({"J": m(self.J), "D_m": m(self.D_m), "K_s": m(self.K_s), "D_s": m(self.D_s)})
        if self.rigid is None:
            out["gravity"] = float(self.gravity[0]) if self.n == 1 else self.gravity.tolist()
        out["effects"] = [e.to_dict(self.n) for e in self.effects]
        return out


def rigid_body(d: Mapping, n: int, source: str, urdf_text: str | None):
    """The :class:`~sea_daemon.core.rigid.RigidBody` of ``model.urdf`` (its text read by the io
    layer); the URDF gives the load side's inertia and gravity, so ``M`` and ``gravity`` are refused
    beside it, and its movable joints must be the ``joints`` of the configuration."""
    # local import: Pinocchio takes 0.3 s to load; only a model with a URDF needs it
    from sea_daemon.core.rigid import RigidBody
    path = d["urdf"]
    if not isinstance(path, str) or not path.strip():
        raise ConfigError(source, "model.urdf", f"must be the path of a URDF file (relative to this file), got {path!r}")
    for key in ("M", "gravity"):
        if key in d:
            raise ConfigError(source, f"model.{key}",
                              "not allowed with model.urdf (the URDF gives the load side's inertia and gravity)")
    if urdf_text is None:
        raise ConfigError(source, "model.urdf", f"{path!r} was not read (load the configuration from its file)")
    rigid = RigidBody(urdf_text, source=f"{source}: {path}")
    if rigid.n != n:
        raise ConfigError(source, "model.urdf", f"{path!r} has {rigid.n} movable joint(s) "
                                                f"({', '.join(rigid.joint_names)}); joints is {n}")
    return rigid


@dataclass(frozen=True)
class KinematicsConfig:
    """Numerical differentiation of the encoder angles (Sec. V-A; sea_daemon.core.kinematics)."""

    window: int = 5          # moving-average length [samples] of the causal differentiator
    method: str = "savgol"   # "savgol": causal least-squares polynomial; "ma": differences + moving average (paper)
    degree: int = 2          # polynomial degree of "savgol" (2 <= degree < window)

    KEYS = ["window", "method", "degree"]
    METHODS = ("ma", "savgol")

    @classmethod
    def from_dict(cls, d: Mapping, n: int, source: str) -> "KinematicsConfig":
        validate.check_keys(source, "kinematics.", d, cls.KEYS, [])
        w = d.get("window", 5)
        if isinstance(w, bool) or not isinstance(w, int) or not 1 <= w <= 100:
            raise ConfigError(source, "kinematics.window", f"must be an integer in 1..100, got {w!r}")
        m = d.get("method", "savgol")
        if m not in cls.METHODS:
            raise ConfigError(source, "kinematics.method", f"must be one of {', '.join(cls.METHODS)}, got {m!r}")
        g = d.get("degree", 2)
        if isinstance(g, bool) or not isinstance(g, int) or not 2 <= g <= 5:
            raise ConfigError(source, "kinematics.degree", f"must be an integer in 2..5, got {g!r}")
        if m == "savgol" and g >= w:
            raise ConfigError(source, "kinematics.degree",
                              f"must be < kinematics.window ({w}) for method savgol, got {g}")
        return cls(window=w, method=m, degree=g)

    def to_dict(self) -> dict:
        return {"window": self.window, "method": self.method, "degree": self.degree}


@dataclass(frozen=True)
class LearningConfig:
    """LoG-GP online learning (Sec. IV-A, V-B)."""

    max_points: int = 100            # N̄: points per leaf
    max_leaves: int = 2000           # memory bound: leaves kept
    overlap: float = 0.01            # relative width of a split's overlap (flat cost to 1e6 points)
    lengthscales: tuple[float, ...] = (0.5, 1.0, 10.0)   # initial l_i for z = [q, q̇, q̈]
    sigma_f: float = 1.0             # initial signal std [N m]
    sigma_n: float = 0.05            # initial noise std σ_on [N m]
    hyperopt: bool = True            # online gradient-based hyperparameter adaptation
    seed: int = 0
    # c of the GP error bound's extrapolation term c·e(z) (LocalScale; docs/learning.md
    # "Novelty"); 0: off.  The GP's predictions do not change.
    extrapolation_scale: float = 0.7
    # every leaf's mean is evaluated at the input clipped into the box of its own data (its σ
    # at the input): no leaf extrapolates its mean (docs/learning.md "Novelty")
    clip_leaf_mean: bool = True
    # a full leaf splits the dimension of the widest spread in its length scales, not in raw
    # units (LoGGP split_in_lengthscales; the calibration's residual GP)
    split_in_lengthscales: bool = False

    KEYS = ["max_points", "max_leaves", "overlap", "lengthscales", "sigma_f", "sigma_n", "hyperopt", "seed",
            "extrapolation_scale", "clip_leaf_mean", "split_in_lengthscales"]
    #: integer settings' ranges: a leaf's factor holds N̄²/2 numbers and a split costs O(N̄³)
    INT_RANGES = {"max_points": (2, 1000), "max_leaves": (2, 100_000), "seed": (0, MAX_SEED)}

    @classmethod
    def from_dict(cls, d: Mapping, n: int, source: str) -> "LearningConfig":
        validate.check_keys(source, "learning.", d, cls.KEYS, [])
        out = {}
        for k in ("max_points", "max_leaves", "seed"):
            if k in d:
                v = d[k]
                lo, hi = cls.INT_RANGES[k]
                if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
                    raise ConfigError(source, f"learning.{k}", f"must be an integer in {lo}..{hi}, got {v!r}")
                out[k] = v
        if "overlap" in d:
            out["overlap"] = validate.num(source, "learning.overlap", d["overlap"], lo=0.0, hi=0.9)
        if "extrapolation_scale" in d:
            out["extrapolation_scale"] = validate.num(source, "learning.extrapolation_scale", d["extrapolation_scale"],
                                              lo=0.0, hi=10.0)
        # one length scale per input dimension of z = [q, q̇, q̈] (3n); three values are
        # taken as (l_q, l_q̇, l_q̈) for every joint
        ls = d.get("lengthscales", cls.lengthscales)
        if isinstance(ls, (list, tuple)) and len(ls) == 3 and n > 1:
            ls = list(np.repeat(np.asarray(ls, dtype=float), n)) if all(
                isinstance(v, (int, float)) and not isinstance(v, bool) for v in ls) else ls
        out["lengthscales"] = tuple(float(v) for v in validate.vector(source, "learning.lengthscales", ls, 3 * n, positive=True))
        for k in ("sigma_f", "sigma_n"):
            if k in d:
                out[k] = validate.num(source, f"learning.{k}", d[k], positive=True)
        for k in ("hyperopt", "clip_leaf_mean", "split_in_lengthscales"):
            if k in d:
                if not isinstance(d[k], bool):
                    raise ConfigError(source, f"learning.{k}", f"must be true or false, got {d[k]!r}")
                out[k] = d[k]
        return cls(**out)

    def to_dict(self) -> dict:
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in dataclasses.asdict(self).items()}


@dataclass(frozen=True)
class AssistConfig:
    """Assist-as-needed (``assist``; docs/assist.md): motor torque from the estimate, gated by its bound.

    Per joint, with τ̄̂ and ρ̄ the estimate τ̂_h,act and its bound ρ_k averaged over ``smoothing_s``:

        τ_cert   = sign(τ̄̂) · max(|τ̄̂| − ρ̄ − deadband, 0)    the part of the effort the bound certifies
        τ_target = clip(gain · τ_cert, ±max_torque)          (0 while ρ̄ > rho_max)
        τ_assist → τ_target at most max_rate; 0 at once while the estimate is not valid

    and the motor torque is the compensation (the nominal model's static load torque at the
    measured angle, ``compensation: nominal``) plus τ_assist.  Off unless ``enabled: true``.
    ``gain``, ``deadband``, ``rho_max``, ``max_torque`` and ``max_rate`` are one number for every
    joint or a tuple of one per joint (``assist.rho_max: [1.5, 0.8]``; :meth:`per_joint`).
    """

    enabled: bool = False          # off unless asked
    gain: float | tuple = 2.0  # α: assistance per N m of certified active torque [-]
    deadband: float | tuple = 0.05  # [N m] taken off |τ̂| together with ρ_k
    rho_max: float | tuple = 1.5  # [N m] no assistance while the averaged ρ_k is above this
    max_torque: float | tuple = 3.0  # [N m] |τ_assist| limit
    max_rate: float | tuple = 10.0  # [N m/s] |dτ_assist/dt| limit (an invalid estimate or a fault: 0 at once)
    smoothing_s: float = 0.6       # [s] time constant over which τ̂ and ρ are averaged before the gate (0: none)
    innovation_max: float = 1.0e4  # a step whose normalised innovation νᵀS⁻¹ν exceeds this is a fault
    compensation: str = "nominal"  # nominal: + the nominal model's static load torque; none: τ_assist alone
    dry_run: bool = False          # τ_assist computed, logged and published, not commanded

    KEYS = ["enabled", "gain", "deadband", "rho_max", "max_torque", "max_rate", "smoothing_s", "innovation_max",
            "compensation", "dry_run"]
    COMPENSATIONS = ("nominal", "none")

    @classmethod
    def from_dict(cls, d: Mapping, n: int, source: str, torque_limit: float) -> "AssistConfig":
        validate.check_keys(source, "assist.", d, cls.KEYS, [])
        k = "assist."
        enabled = d.get("enabled", False)
        if not isinstance(enabled, bool):
            raise ConfigError(source, k + "enabled", f"must be true or false, got {enabled!r}")
        dry_run = d.get("dry_run", False)
        if not isinstance(dry_run, bool):
            raise ConfigError(source, k + "dry_run", f"must be true or false, got {dry_run!r}")
        comp = d.get("compensation", "nominal")
        if comp not in cls.COMPENSATIONS:
            raise ConfigError(source, k + "compensation",
                              f"must be one of {', '.join(cls.COMPENSATIONS)}, got {comp!r}")
        limits = np.broadcast_to(np.asarray(torque_limit, dtype=float), (n,))
        default_max = [min(cls.max_torque, float(x)) for x in limits]
        default_max = default_max[0] if len(set(default_max)) == 1 else default_max
        max_torque = per_joint(source, k + "max_torque", d.get("max_torque", default_max), n, positive=True)
        for j, (m, lim) in enumerate(zip(np.broadcast_to(max_torque, (n,)), limits)):
            if m > lim:
                joint = f" (joint {j + 1})" if n > 1 else ""
                raise ConfigError(source, k + "max_torque",
                                  f"must be in (0, hardware.torque_limit = {lim:g}] N m{joint}, got {m:g}")
        return cls(
            enabled=enabled,
            gain=per_joint(source, k + "gain", d.get("gain", cls.gain), n, lo=0.0, hi=10.0),
            deadband=per_joint(source, k + "deadband", d.get("deadband", cls.deadband), n, lo=0.0, hi=100.0),
            rho_max=per_joint(source, k + "rho_max", d.get("rho_max", cls.rho_max), n, positive=True),
            max_torque=max_torque,
            max_rate=per_joint(source, k + "max_rate", d.get("max_rate", cls.max_rate), n, positive=True),
            smoothing_s=validate.num(source, k + "smoothing_s", d.get("smoothing_s", cls.smoothing_s), lo=0.0, hi=10.0),
            innovation_max=validate.num(source, k + "innovation_max", d.get("innovation_max", cls.innovation_max),
                                        positive=True),
            compensation=comp, dry_run=dry_run)

    def per_joint(self, name: str, n: int) -> np.ndarray:
        """Setting ``name`` as an array of ``n`` values, one per joint."""
        return joint_values(getattr(self, name), n)

    def to_dict(self) -> dict:
        return {key: list(v) if isinstance(v, tuple) else v for key, v in ((key, getattr(self, key)) for key in self.KEYS)}


@dataclass(frozen=True)
class CalibrationConfig:
    """What the user declares for the calibration (``calibration``; docs/calibration.md): the
    joint's working range the excitation covers, and the band and size of the subject's active
    torque (the τ_h,act random walk is chosen for it: for the estimate, or with ``walk_for: bound`` for
    the Theorem-1 bound as well).  Absent: the working range is the
    calibration log's own, the human torque 0.1–1 Hz at 1.5 N m RMS."""

    q_min_deg: float | None = None       # working range [deg]
    q_max_deg: float | None = None
    v_max: float = 1.5                   # fastest speed of the excitation [rad/s]
    a_max: float = 12.0                  # largest acceleration of the excitation [rad/s²]
    duration_s: float = 60.0             # length of the excitation [s]
    human_band_hz: tuple[float, float] = (0.1, 1.0)   # band of τ_h,act [Hz]
    human_torque_rms: float = 1.5        # RMS of τ_h,act [N m]
    seed: int = 0                        # of the excitation's random moves
    walk_for: str = "estimate"           # the τ_h,act walk chosen for: estimate | bound

    KEYS = ["q_min_deg", "q_max_deg", "v_max", "a_max", "duration_s", "human_band_hz", "human_torque_rms", "seed",
            "walk_for"]
    #: what the calibration may choose the τ_h,act walk for (docs/calibration.md step 5)
    WALK_FOR = ("estimate", "bound")
    #: the largest speed [rad/s], acceleration [rad/s²], duration [s] and RMS torque [N m]: the
    #: calibration's moves are planned sample by sample over ``duration_s``
    MAX = {"v_max": 100.0, "a_max": 1e4, "duration_s": 3600.0, "human_torque_rms": 1e3}

    @classmethod
    def from_dict(cls, d: Mapping, n: int, source: str) -> "CalibrationConfig":
        validate.check_keys(source, "calibration.", d, cls.KEYS, [])
        k = "calibration."
        out: dict = {}
        for key in ("q_min_deg", "q_max_deg"):
            if isinstance(d.get(key), (list, tuple)):
                raise ConfigError(source, k + key, f"must be one angle in -360..360 deg for every joint, got {d[key]!r} "
                                                   "(one range per joint: leave it out and give each joint's URDF "
                                                   "<limit lower upper>)")
            if d.get(key) is not None:
                out[key] = validate.num(source, k + key, d[key], lo=-360.0, hi=360.0)
        for key in ("v_max", "a_max", "duration_s", "human_torque_rms"):
            if key in d:
                out[key] = validate.num(source, k + key, d[key], positive=True)
                if out[key] > cls.MAX[key]:
                    raise ConfigError(source, k + key, f"must be in (0, {cls.MAX[key]:g}], got {out[key]:g}")
        if "human_band_hz" in d:
            b = validate.vector(source, k + "human_band_hz", d["human_band_hz"], 2, positive=True)
            if not b[0] < b[1]:
                raise ConfigError(source, k + "human_band_hz", f"must be [low, high] with low < high, got {list(b)}")
            out["human_band_hz"] = (float(b[0]), float(b[1]))
        if "seed" in d:
            v = d["seed"]
            if isinstance(v, bool) or not isinstance(v, int) or not 0 <= v <= MAX_SEED:
                raise ConfigError(source, k + "seed", f"must be an integer in 0..{MAX_SEED}, got {v!r}")
            out["seed"] = v
        if "walk_for" in d:
            if d["walk_for"] not in cls.WALK_FOR:
                raise ConfigError(source, k + "walk_for", f"must be one of {', '.join(cls.WALK_FOR)}, got {d['walk_for']!r}")
            out["walk_for"] = d["walk_for"]
        if out.get("q_min_deg") is not None and out.get("q_max_deg") is not None \
                and not out["q_min_deg"] < out["q_max_deg"]:
            raise ConfigError(source, k + "q_max_deg", "must be > q_min_deg")
        return cls(**out)

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d["human_band_hz"] = list(self.human_band_hz)
        return d


@dataclass(frozen=True)
class PublishConfig:
    """Where else ``sea-daemon run`` sends the estimate (``publish``; docs/interfaces.md §7): a Lab
    Streaming Layer outlet named ``lsl_name`` (``lsl``; the daemon waits up to ``lsl_wait_s`` for
    an inlet before its loop starts) and an MCAP recording beside the CSV log (``mcap``).  Both
    off unless asked (here or by ``run --lsl`` / ``--mcap``)."""

    lsl: bool = False
    lsl_name: str = "sea-daemon"
    lsl_wait_s: float = 0.0
    mcap: bool = False

    KEYS = ["lsl", "lsl_name", "lsl_wait_s", "mcap"]

    @classmethod
    def from_dict(cls, d: Mapping, n: int, source: str) -> "PublishConfig":
        validate.check_keys(source, "publish.", d, cls.KEYS, [])
        out: dict = {}
        for key in ("lsl", "mcap"):
            if key in d:
                if not isinstance(d[key], bool):
                    raise ConfigError(source, "publish." + key, f"must be true or false, got {d[key]!r}")
                out[key] = d[key]
        if "lsl_name" in d:
            name = d["lsl_name"]
            if not isinstance(name, str) or not 1 <= len(name) <= 64 or not name.isprintable():
                raise ConfigError(source, "publish.lsl_name", f"must be 1 to 64 printable characters, got {name!r}")
            out["lsl_name"] = name
        if "lsl_wait_s" in d:
            out["lsl_wait_s"] = validate.num(source, "publish.lsl_wait_s", d["lsl_wait_s"], lo=0.0, hi=3600.0)
        return cls(**out)

    def to_dict(self) -> dict:
        return {key: getattr(self, key) for key in self.KEYS}


@dataclass(frozen=True)
class ModelConfig:
    """The whole YAML of docs/interfaces.md §2 (plus the optional sections)."""

    joints: int
    rate_hz: float
    model: SEAParams
    estimator: EstimatorConfig
    kinematics: KinematicsConfig = field(default_factory=KinematicsConfig)
    learning: LearningConfig = field(default_factory=LearningConfig)
    hardware: HardwareConfig = field(default_factory=HardwareConfig)
    source: str = "<memory>"
    assist: AssistConfig = field(default_factory=AssistConfig)
    calibration: CalibrationConfig = field(default_factory=CalibrationConfig)
    publish: PublishConfig = field(default_factory=PublishConfig)

    TOP_KEYS = ["joints", "rate_hz", "model", "estimator", "kinematics", "learning", "hardware", "assist",
                "calibration", "publish"]

    @property
    def dt(self) -> float:
        return 1.0 / self.rate_hz

    @classmethod
    def from_dict(cls, d: Any, source: str = "<memory>", urdf_text: str | None = None) -> "ModelConfig":
        """``urdf_text``: the text of the file ``model.urdf`` names, if it names one (the io layer
        reads it: :func:`sea_daemon.io.configfile.load_config`)."""
        validate.check_keys(source, "", d, cls.TOP_KEYS, ["joints", "rate_hz", "model"])
        n = d["joints"]
        if isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= 16:
            raise ConfigError(source, "joints", f"must be an integer in 1..16, got {n!r}")
        rate = validate.num(source, "rate_hz", d["rate_hz"], lo=1.0, hi=100000.0)
        hardware = HardwareConfig.from_dict(d.get("hardware") or {}, n, source)
        return cls(
            joints=n, rate_hz=rate,
            model=SEAParams.from_dict(d["model"], n, source, urdf_text),
            estimator=EstimatorConfig.from_dict(d.get("estimator") or {}, n, source),
            kinematics=KinematicsConfig.from_dict(d.get("kinematics") or {}, n, source),
            learning=LearningConfig.from_dict(d.get("learning") or {}, n, source),
            hardware=hardware,
            source=source,
            # each joint's assistance within its own joint's torque limit
            assist=AssistConfig.from_dict(d.get("assist") or {}, n, source, hardware.torque_limits(n)),
            calibration=CalibrationConfig.from_dict(d.get("calibration") or {}, n, source),
            publish=PublishConfig.from_dict(d.get("publish") or {}, n, source),
        )

    def to_dict(self) -> dict:
        return {
            "joints": self.joints, "rate_hz": self.rate_hz, "model": self.model.to_dict(),
            "estimator": self.estimator.to_dict(), "kinematics": self.kinematics.to_dict(),
            "learning": self.learning.to_dict(), "hardware": self.hardware.to_dict(),
            "assist": self.assist.to_dict(), "calibration": self.calibration.to_dict(),
            "publish": self.publish.to_dict(),
        }

    def with_effects(self, effects) -> "ModelConfig":
        return dataclasses.replace(self, model=self.model.with_effects(effects))
