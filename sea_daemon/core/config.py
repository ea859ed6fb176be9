"""Model configuration (docs/interfaces.md §2) as validated, frozen dataclasses.

The YAML has the contract's top level (``joints``, ``rate_hz``, ``model``) plus optional
sections this project adds (``estimator``, ``kinematics``, ``learning``, ``hardware``).
Every section is a frozen dataclass; unknown keys, missing keys and values out of range
raise :class:`~sea_daemon.errors.ConfigError` naming the key and the allowed values.

To add an option, add a field with a default to the section's dataclass and, if it needs
a range check, a line in its ``_check``.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np

from sea_daemon.core.effects import MAX_ABS, Effect, effect_from_dict, finite_number as _finite
from sea_daemon.errors import ConfigError


# ---------------------------------------------------------------------------- helpers

def _num(source: str, key: str, v: Any, *, positive=False, non_negative=False,
         lo: float | None = None, hi: float | None = None) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not _finite(v):
        raise ConfigError(source, key, f"must be a finite number within ±{MAX_ABS:g}, got {v!r}")
    v = float(v)
    if positive and v <= 0:
        raise ConfigError(source, key, f"must be > 0, got {v}")
    if non_negative and v < 0:
        raise ConfigError(source, key, f"must be >= 0, got {v}")
    if lo is not None and v < lo or hi is not None and v > hi:
        raise ConfigError(source, key, f"must be in [{lo}, {hi}], got {v}")
    return v


def _numbers(v: Any) -> np.ndarray:
    """``v`` (a number or nested lists of numbers) as a float array; ValueError for anything else
    (strings, which numpy would parse with Python's lenient float(), booleans, ragged lists)."""
    a = np.asarray(v)
    if a.dtype.kind not in "iuf":
        raise ValueError(f"not numbers: {a.dtype}")
    return a.astype(float)


def _matrix(source: str, key: str, v: Any, n: int, *, positive_definite=False,
            non_negative=False) -> np.ndarray:
    """scalar -> s·I (n=1 or diagonal), list of n -> diag, n×n nested list -> matrix."""
    try:
        a = _numbers(v)
    except (TypeError, ValueError, OverflowError):
        raise ConfigError(source, key, f"must be a number, a list of {n} or an {n}x{n} matrix, got {v!r}") from None
    if a.ndim == 0:
        a = np.eye(n) * float(a)
    elif a.ndim == 1 and a.shape[0] == n:
        a = np.diag(a)
    elif not (a.ndim == 2 and a.shape == (n, n)):
        raise ConfigError(source, key, f"must be a number, a list of {n} or an {n}x{n} matrix, got shape {a.shape}")
    if not np.all(np.isfinite(a)) or np.any(np.abs(a) > MAX_ABS):
        raise ConfigError(source, key, f"must be finite, within ±{MAX_ABS:g}, got {v!r}")
    if positive_definite:
        if not np.allclose(a, a.T) or np.any(np.linalg.eigvalsh(0.5 * (a + a.T)) <= 0):
            raise ConfigError(source, key, f"must be positive (symmetric positive definite), got {v!r}")
    if non_negative:
        if not np.allclose(a, a.T) or np.any(np.linalg.eigvalsh(0.5 * (a + a.T)) < -1e-12):
            raise ConfigError(source, key, f"must be >= 0 (symmetric positive semi-definite), got {v!r}")
    a.setflags(write=False)
    return a


def _vector(source: str, key: str, v: Any, n: int, *, non_negative=False, positive=False) -> np.ndarray:
    """scalar -> repeated, list of n -> vector."""
    try:
        a = _numbers(v)
    except (TypeError, ValueError, OverflowError):
        raise ConfigError(source, key, f"must be a number or a list of {n} numbers, got {v!r}") from None
    if a.ndim == 0:
        a = np.full(n, float(a))
    if a.ndim != 1 or a.shape[0] != n:
        raise ConfigError(source, key, f"must be a number or a list of {n} numbers, got {v!r}")
    if not np.all(np.isfinite(a)) or np.any(np.abs(a) > MAX_ABS):
        raise ConfigError(source, key, f"must be finite, within ±{MAX_ABS:g}, got {v!r}")
    if positive and np.any(a <= 0):
        raise ConfigError(source, key, f"every entry must be > 0, got {v!r}")
    if non_negative and np.any(a < 0):
        raise ConfigError(source, key, f"every entry must be >= 0, got {v!r}")
    a.setflags(write=False)
    return a


def _diag_or_matrix(source: str, key: str, v: Any, n: int, positive_definite: bool = False) -> np.ndarray:
    """Covariances: list of n -> diag, n×n -> matrix; must be symmetric PSD (``positive_definite``:
    PD, every variance > 0)."""
    try:
        a = _numbers(v) if not isinstance(v, (str, bytes, Mapping)) else None
    except (TypeError, ValueError, OverflowError):      # ragged lists, strings inside
        a = None
    if a is None or a.ndim not in (1, 2):
        raise ConfigError(source, key, f"must be a list of {n} variances or an {n}x{n} matrix, got {v!r}")
    kind = {"positive_definite": True} if positive_definite else {"non_negative": True}
    if a.ndim == 1:
        return _matrix(source, key, a if a.shape[0] == n else v, n, **kind)
    return _matrix(source, key, a, n, **kind)


def _check_keys(source: str, prefix: str, d: Mapping, allowed: list[str], required: list[str]) -> None:
    if not isinstance(d, Mapping):
        raise ConfigError(source, prefix or "<top level>", f"must be a mapping, got {type(d).__name__}")
    for k in d:
        if k not in allowed:
            raise ConfigError(source, f"{prefix}{k}", f"unknown key; allowed: {', '.join(allowed)}")
    for k in required:
        if k not in d:
            raise ConfigError(source, f"{prefix}{k}", f"missing required key (required: {', '.join(required)})")


# ---------------------------------------------------------------------------- sections

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

    KEYS = ["M", "J", "D_m", "K_s", "D_s", "gravity", "effects"]
    REQUIRED = ["M", "J", "D_m", "K_s", "D_s"]

    @property
    def n(self) -> int:
        return self.M.shape[0]

    def with_effects(self, effects) -> "SEAParams":
        return dataclasses.replace(self, effects=tuple(effects))

    @classmethod
    def from_dict(cls, d: Mapping, n: int, source: str) -> "SEAParams":
        _check_keys(source, "model.", d, cls.KEYS, cls.REQUIRED)
        eff = d.get("effects") or []
        if not isinstance(eff, list):
            raise ConfigError(source, "model.effects", f"must be a list of effect mappings, got {eff!r}")
        return cls(
            M=_matrix(source, "model.M", d["M"], n, positive_definite=True),
            J=_matrix(source, "model.J", d["J"], n, positive_definite=True),
            D_m=_matrix(source, "model.D_m", d["D_m"], n, non_negative=True),
            K_s=_matrix(source, "model.K_s", d["K_s"], n, positive_definite=True),
            D_s=_matrix(source, "model.D_s", d["D_s"], n, non_negative=True),
            gravity=_vector(source, "model.gravity", d.get("gravity", 0.0), n),
            effects=tuple(effect_from_dict(e, n, source, f"model.effects[{i}]") for i, e in enumerate(eff)),
        )

    def to_dict(self) -> dict:
        def m(a):
            if self.n == 1:
                return float(a[0, 0])
            return a.tolist()
        return {
            "M": m(self.M), "J": m(self.J), "D_m": m(self.D_m), "K_s": m(self.K_s), "D_s": m(self.D_s),
            "gravity": float(self.gravity[0]) if self.n == 1 else self.gravity.tolist(),
            "effects": [e.to_dict(self.n) for e in self.effects],
        }


@dataclass(frozen=True)
class EstimatorConfig:
    """AKF / GP-AKF settings (Alg. 1, Alg. 2; Sec. V-B)."""

    R: np.ndarray                  # measurement noise, y = [θ_m, θ_s, θ̇_m, θ̇_s]   (4n×4n)
    Sigma_nom: np.ndarray          # nominal process noise per step, x order     (5n×5n)
    P0: np.ndarray                 # initial covariance                          (5n×5n)
    delta: float = 0.05            # probability level of the bounds (eq:bounds)
    sign_eps: float = 0.01         # [rad/s] smoothing of sign() in declared friction
    # estimator health (sea_daemon.core.estimators.health, docs/safety.md)
    nis_window: int = 100          # steps of the windowed mean NIS
    nis_alpha: float = 1e-3        # two-sided level of its chi2 band
    nis_scale: float = 10.0        # divergence: windowed mean > nis_scale x the band's upper edge
    pd_check_every: int = 1        # Cholesky of P every k steps (0: never)
    gp_input_margin: float = 0.1   # GP inputs clipped to the training box +- this fraction of its width
    # GP error bound of the Theorem-1 bound (docs/bounds.md §2): "lederer" (LUH19, eq:gpmeanbounds)
    # or a number beta > 0 (|f - mu| <= beta sqrt(sigma^2 + sigma_n^2), e.g. a split-conformal beta)
    gp_beta: str | float = "lederer"
    # per-step process noise (docs/estimators.md, "Process noise"); the defaults keep Σ_nom as given
    Sigma_nom_dt: float = 0.0      # [s] step Σ_nom is given for; > 0: Σ_nom,k = Σ_nom·dt/Sigma_nom_dt
    tau_m_noise: float = 0.0       # [N m] std of the motor-torque error held over a step: + Γ_u σ² Γ_uᵀ
    gp_noise_in_Q: bool = False    # GP-AKF: Q with the residual's predictive variance σ² + σ_on²
    init_after_kinematics: bool = False   # start when the differentiator is full: x̂₀ = y (velocities measured)
    # Theorem-1 bound (docs/bounds.md §6): declared bound on how fast the active human torque
    # changes beyond the random walk of Σ_nom, |dτ_h,act/dt| <= tau_h_act_rate [N m/s]; it enters
    # the set of means as a bounded input (0: the paper's pure random walk)
    tau_h_act_rate: float = 0.0

    KEYS = ["R", "Sigma_nom", "P0", "P0_tau", "delta", "sign_eps", "nis_window", "nis_alpha", "nis_scale",
            "pd_check_every", "gp_input_margin", "Sigma_nom_dt", "tau_m_noise", "gp_noise_in_Q", "init_after_kinematics", "gp_beta",
            "tau_h_act_rate"]

    @classmethod
    def default(cls, n: int) -> "EstimatorConfig":
        return cls.from_dict({}, n, "<default>")

    @classmethod
    def from_dict(cls, d: Mapping, n: int, source: str) -> "EstimatorConfig":
        _check_keys(source, "estimator.", d, cls.KEYS, [])
        # Sec. V-B: R identified by ALS, Sigma_nom hand-set, P0 = R (plus τ_h,act)
        # every measurement has noise: R positive definite (eq:nonlinkOsys)
        R = _diag_or_matrix(source, "estimator.R", d.get("R", np.repeat([0.0461, 3.6e-6, 0.1288, 1.01e-5], n)),
                            4 * n, positive_definite=True)
        S = _diag_or_matrix(source, "estimator.Sigma_nom",
                            d.get("Sigma_nom", np.repeat([1e-1, 1e3, 1e2, 1e-9, 1e-2], n)), 5 * n)
        P0_tau = _num(source, "estimator.P0_tau", d.get("P0_tau", 1.0), positive=True)
        if "P0" in d:
            P0 = _diag_or_matrix(source, "estimator.P0", d["P0"], 5 * n)
        else:
            P0 = np.zeros((5 * n, 5 * n))
            P0[: 4 * n, : 4 * n] = R
            P0[4 * n:, 4 * n:] = np.eye(n) * P0_tau
            P0.setflags(write=False)
        delta = _num(source, "estimator.delta", d.get("delta", 0.05))
        if not 0 < delta < 1:
            raise ConfigError(source, "estimator.delta", f"must be in (0, 1), got {delta}")
        def _int(key, default, lo, hi):
            v = d.get(key, default)
            if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
                raise ConfigError(source, f"estimator.{key}", f"must be an integer in {lo}..{hi}, got {v!r}")
            return v
        nis_alpha = _num(source, "estimator.nis_alpha", d.get("nis_alpha", 1e-3))
        if not 0 < nis_alpha < 1:
            raise ConfigError(source, "estimator.nis_alpha", f"must be in (0, 1), got {nis_alpha}")
        nis_scale = _num(source, "estimator.nis_scale", d.get("nis_scale", 10.0))
        if not nis_scale >= 1:
            raise ConfigError(source, "estimator.nis_scale", f"must be >= 1, got {nis_scale}")
        def _nonneg(key, default, unit=""):
            v = _num(source, f"estimator.{key}", d.get(key, default))
            if not v >= 0:
                raise ConfigError(source, f"estimator.{key}", f"must be >= 0{unit}, got {v}")
            return v
        margin = _nonneg("gp_input_margin", 0.1)
        gp_beta = d.get("gp_beta", "lederer")
        if gp_beta != "lederer":
            if isinstance(gp_beta, bool) or not isinstance(gp_beta, (int, float)) or not (
                    np.isfinite(gp_beta) and gp_beta > 0):
                raise ConfigError(source, "estimator.gp_beta", f"must be 'lederer' or a number > 0, got {gp_beta!r}")
            gp_beta = float(gp_beta)
        S_dt = _nonneg("Sigma_nom_dt", 0.0, " [s] (0: Sigma_nom per step)")
        tau_m_noise = _nonneg("tau_m_noise", 0.0, " [N m]")
        rate = _nonneg("tau_h_act_rate", 0.0, " [N m/s]")
        def _bool(key):
            v = d.get(key, False)
            if not isinstance(v, bool):
                raise ConfigError(source, f"estimator.{key}", f"must be true or false, got {v!r}")
            return v
        gp_noise, init_kin = _bool("gp_noise_in_Q"), _bool("init_after_kinematics")
        return cls(R=R, Sigma_nom=S, P0=P0, delta=delta,
                   sign_eps=_num(source, "estimator.sign_eps", d.get("sign_eps", 0.01), positive=True),
                   nis_window=_int("nis_window", 100, 1, 100000), nis_alpha=nis_alpha, nis_scale=nis_scale,
                   pd_check_every=_int("pd_check_every", 1, 0, 1000000), gp_input_margin=margin,
                   gp_beta=gp_beta,
                   Sigma_nom_dt=S_dt, tau_m_noise=tau_m_noise, gp_noise_in_Q=gp_noise,
                   init_after_kinematics=init_kin, tau_h_act_rate=rate)

    def to_dict(self) -> dict:
        def dg(a):
            return np.diag(a).tolist() if np.allclose(a, np.diag(np.diag(a))) else a.tolist()
        return {"R": dg(self.R), "Sigma_nom": dg(self.Sigma_nom), "P0": dg(self.P0),
                "delta": self.delta, "sign_eps": self.sign_eps, "nis_window": self.nis_window,
                "nis_alpha": self.nis_alpha, "nis_scale": self.nis_scale, "pd_check_every": self.pd_check_every,
                "gp_input_margin": self.gp_input_margin, "gp_beta": self.gp_beta,
                "Sigma_nom_dt": self.Sigma_nom_dt,
                "tau_m_noise": self.tau_m_noise, "gp_noise_in_Q": self.gp_noise_in_Q,
                "init_after_kinematics": self.init_after_kinematics, "tau_h_act_rate": self.tau_h_act_rate}


@dataclass(frozen=True)
class KinematicsConfig:
    """Numerical differentiation of the encoder angles (Sec. V-A; sea_daemon.core.kinematics)."""

    window: int = 5          # moving-average length [samples] of the causal differentiator
    method: str = "ma"       # "ma": differences + moving average (paper); "savgol": causal LS polynomial
    degree: int = 2          # polynomial degree of "savgol" (2 <= degree < window)

    KEYS = ["window", "method", "degree"]
    METHODS = ("ma", "savgol")

    @classmethod
    def from_dict(cls, d: Mapping, n: int, source: str) -> "KinematicsConfig":
        _check_keys(source, "kinematics.", d, cls.KEYS, [])
        w = d.get("window", 5)
        if isinstance(w, bool) or not isinstance(w, int) or not 1 <= w <= 100:
            raise ConfigError(source, "kinematics.window", f"must be an integer in 1..100, got {w!r}")
        m = d.get("method", "ma")
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
    extrapolation_scale: float = 0.0
    # every leaf's mean is evaluated at the input clipped into the box of its own data (its σ
    # at the input): no leaf extrapolates its mean (docs/learning.md "Novelty")
    clip_leaf_mean: bool = False

    KEYS = ["max_points", "max_leaves", "overlap", "lengthscales", "sigma_f", "sigma_n", "hyperopt", "seed",
            "extrapolation_scale", "clip_leaf_mean"]

    @classmethod
    def from_dict(cls, d: Mapping, n: int, source: str) -> "LearningConfig":
        _check_keys(source, "learning.", d, cls.KEYS, [])
        out = {}
        for k in ("max_points", "max_leaves", "seed"):
            if k in d:
                v = d[k]
                lo = 0 if k == "seed" else 2
                if isinstance(v, bool) or not isinstance(v, int) or v < lo:
                    raise ConfigError(source, f"learning.{k}", f"must be an integer >= {lo}, got {v!r}")
                out[k] = v
        if "overlap" in d:
            out["overlap"] = _num(source, "learning.overlap", d["overlap"], lo=0.0, hi=0.9)
        if "extrapolation_scale" in d:
            out["extrapolation_scale"] = _num(source, "learning.extrapolation_scale", d["extrapolation_scale"],
                                              lo=0.0, hi=10.0)
        # one length scale per input dimension of z = [q, q̇, q̈] (3n); three values are
        # taken as (l_q, l_q̇, l_q̈) for every joint
        ls = d.get("lengthscales", cls.lengthscales)
        if isinstance(ls, (list, tuple)) and len(ls) == 3 and n > 1:
            ls = list(np.repeat(np.asarray(ls, dtype=float), n)) if all(
                isinstance(v, (int, float)) and not isinstance(v, bool) for v in ls) else ls
        out["lengthscales"] = tuple(float(v) for v in _vector(source, "learning.lengthscales", ls, 3 * n, positive=True))
        for k in ("sigma_f", "sigma_n"):
            if k in d:
                out[k] = _num(source, f"learning.{k}", d[k], positive=True)
        for k in ("hyperopt", "clip_leaf_mean"):
            if k in d:
                if not isinstance(d[k], bool):
                    raise ConfigError(source, f"learning.{k}", f"must be true or false, got {d[k]!r}")
                out[k] = d[k]
        return cls(**out)

    def to_dict(self) -> dict:
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in dataclasses.asdict(self).items()}


def _node_ids(source: str, key: str, v: Any, n: int) -> tuple[int, ...]:
    """CANopen node id(s): an integer (one joint) or a list of n integers, each 1..127."""
    vals = [v] if not isinstance(v, (list, tuple)) else list(v)
    if len(vals) != n or any(isinstance(x, bool) or not isinstance(x, int) or not 1 <= x <= 127 for x in vals):
        raise ConfigError(source, key, f"must be {'an integer' if n == 1 else f'a list of {n} integers'} "
                                       f"in 1..127 (CANopen node id), got {v!r}")
    return tuple(vals)


@dataclass(frozen=True)
class BusConfig:
    """The CAN bus and the CANopen devices on it (``drivers``; issue 5).

    Angles and speeds are joint side [rad, rad/s]; ``rated_torque`` is the drive's 0x6076 on the
    MOTOR side in mN m, so one per mille of 0x6071/0x6077 is ``rated_torque/1e6 * gear_ratio`` N m
    on the joint side.
    """

    interface: str = "virtual"            # virtual | socketcan | remote
    channel: str = "sea-daemon"           # virtual: any name; socketcan: can0/vcan0; remote: ws://host:port/
    bitrate: int = 1000000                # [bit/s]
    drive_node: tuple[int, ...] = (1,)    # CiA 402 drive node id per joint
    encoder_node: tuple[int, ...] = (2,)  # CiA 406 load encoder node id per joint
    heartbeat_ms: int = 50                # producer heartbeat time written to 0x1017 of every node
    heartbeat_timeout_ms: int = 200       # consumer: a node is lost after this long without heartbeat
    pdo_timeout_ms: float = 8.0           # wait for a cycle's TPDOs after SYNC [ms]
    max_missed_cycles: int = 0            # consecutive cycles with missing TPDOs tolerated (0: first raises)
    rated_torque: float = 100.0           # expected 0x6076, motor side [mN m]
    q_offset: tuple[float, ...] = (0.0,)        # load encoder zero: q = angle(counts) - q_offset [rad]
    theta_m_offset: tuple[float, ...] = (0.0,)  # motor encoder zero, joint side [rad]
    max_joint_speed: float = 20.0         # encoder jump: |dq| > max_joint_speed*dt + 2 quanta [rad/s]
    stuck_cycles: int = 20                # encoder stuck: same count this many cycles ...
    stuck_motion: float = 0.05            # ... while the other encoder of the joint moved this far [rad]
    sync_rpdo: bool = False               # false: the drive actuates the torque RPDO on reception (type 255);
    #                                       true: at the next SYNC (type 1, one cycle more delay)
    sdo_timeout_ms: int = 300             # start-up: wait this long for each SDO answer (one retry)
    master_node: int = 127                # the daemon's own node id: its heartbeat, watched by the drives
    #                                       (0x1016, heartbeat_timeout_ms; reaction 0x6007 = quick stop)

    KEYS = ["interface", "channel", "bitrate", "drive_node", "encoder_node", "heartbeat_ms",
            "heartbeat_timeout_ms", "pdo_timeout_ms", "max_missed_cycles", "rated_torque", "q_offset",
            "theta_m_offset", "max_joint_speed", "stuck_cycles", "stuck_motion", "sync_rpdo", "sdo_timeout_ms",
            "master_node"]
    INTERFACES = ("virtual", "socketcan", "remote")

    @classmethod
    def default(cls, n: int) -> "BusConfig":
        return cls.from_dict({}, n, "<default>")

    @classmethod
    def from_dict(cls, d: Mapping, n: int, source: str) -> "BusConfig":
        _check_keys(source, "hardware.bus.", d, cls.KEYS, [])
        k = "hardware.bus."
        iface = d.get("interface", "virtual")
        if iface not in cls.INTERFACES:
            raise ConfigError(source, k + "interface", f"must be one of {', '.join(cls.INTERFACES)}, got {iface!r}")
        channel = d.get("channel", "sea-daemon")
        if not isinstance(channel, str) or not channel:
            raise ConfigError(source, k + "channel", f"must be a non-empty string, got {channel!r}")
        if iface == "remote" and not channel.startswith(("ws://", "wss://")):
            raise ConfigError(source, k + "channel", f"remote bus needs ws://HOST:PORT/, got {channel!r}")
        ints = {}
        for key, lo, hi, default in (("bitrate", 10000, 1000000, 1000000), ("heartbeat_ms", 1, 65535, 50),
                                     ("heartbeat_timeout_ms", 1, 600000, 200), ("max_missed_cycles", 0, 1000, 0),
                                     ("stuck_cycles", 2, 100000, 20), ("sdo_timeout_ms", 10, 60000, 300),
                                     ("master_node", 1, 127, 127)):
            v = d.get(key, default)
            if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
                raise ConfigError(source, k + key, f"must be an integer in {lo}..{hi}, got {v!r}")
            ints[key] = v
        if ints["heartbeat_timeout_ms"] <= ints["heartbeat_ms"]:
            raise ConfigError(source, k + "heartbeat_timeout_ms",
                              f"must be > heartbeat_ms ({ints['heartbeat_ms']}), got {ints['heartbeat_timeout_ms']}")
        # default: joint i has drive 2i+1 and load encoder 2i+2
        drive = _node_ids(source, k + "drive_node", d.get("drive_node", [2 * i + 1 for i in range(n)]), n)
        enc = _node_ids(source, k + "encoder_node", d.get("encoder_node", [2 * i + 2 for i in range(n)]), n)
        if len(set(drive) | set(enc) | {ints["master_node"]}) != 2 * n + 1:
            raise ConfigError(source, k + "encoder_node", f"node ids must all differ, got drives {list(drive)}, "
                                                          f"encoders {list(enc)}, master {ints['master_node']}")
        sync_rpdo = d.get("sync_rpdo", False)
        if not isinstance(sync_rpdo, bool):
            raise ConfigError(source, k + "sync_rpdo", f"must be true or false, got {sync_rpdo!r}")
        return cls(
            interface=iface, channel=channel, drive_node=drive, encoder_node=enc, **ints, sync_rpdo=sync_rpdo,
            pdo_timeout_ms=_num(source, k + "pdo_timeout_ms", d.get("pdo_timeout_ms", 8.0), lo=0.1, hi=10000.0),
            rated_torque=_num(source, k + "rated_torque", d.get("rated_torque", 100.0), positive=True),
            q_offset=tuple(float(x) for x in _vector(source, k + "q_offset", d.get("q_offset", 0.0), n)),
            theta_m_offset=tuple(float(x) for x in _vector(source, k + "theta_m_offset", d.get("theta_m_offset", 0.0), n)),
            max_joint_speed=_num(source, k + "max_joint_speed", d.get("max_joint_speed", 20.0), positive=True),
            stuck_motion=_num(source, k + "stuck_motion", d.get("stuck_motion", 0.05), positive=True),
        )

    def to_dict(self) -> dict:
        out = dataclasses.asdict(self)
        for key in ("drive_node", "encoder_node", "q_offset", "theta_m_offset"):
            v = list(out[key])
            out[key] = v[0] if len(v) == 1 else v
        return out


@dataclass(frozen=True)
class HardwareConfig:
    """The exoskeleton's sensors and actuator (Sec. V-A) and the CAN bus."""

    gear_ratio: float = 100.0        # motor turns per joint turn
    encoder_bits: int = 19           # both absolute encoders
    torque_limit: float = 10.0       # |τ_m| limit, joint side [N m]
    torque_noise: float = 0.02       # std of motor-torque noise, joint side [N m] (simulator)
    bus: BusConfig = field(default_factory=BusConfig)   # CAN bus and CANopen devices (drivers)

    KEYS = ["gear_ratio", "encoder_bits", "torque_limit", "torque_noise", "bus"]

    @classmethod
    def from_dict(cls, d: Mapping, n: int, source: str) -> "HardwareConfig":
        _check_keys(source, "hardware.", d, cls.KEYS, [])
        out = {}
        if "gear_ratio" in d:
            out["gear_ratio"] = _num(source, "hardware.gear_ratio", d["gear_ratio"], positive=True)
        if "encoder_bits" in d:
            b = d["encoder_bits"]
            if isinstance(b, bool) or not isinstance(b, int) or not 8 <= b <= 32:
                raise ConfigError(source, "hardware.encoder_bits", f"must be an integer in 8..32, got {b!r}")
            out["encoder_bits"] = b
        if "torque_limit" in d:
            out["torque_limit"] = _num(source, "hardware.torque_limit", d["torque_limit"], positive=True)
        if "torque_noise" in d:
            out["torque_noise"] = _num(source, "hardware.torque_noise", d["torque_noise"], non_negative=True)
        out["bus"] = BusConfig.from_dict(d.get("bus") or {}, n, source)
        return cls(**out)

    def to_dict(self) -> dict:
        out = {k: v for k, v in dataclasses.asdict(self).items() if k != "bus"}
        out["bus"] = self.bus.to_dict()
        return out


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

    TOP_KEYS = ["joints", "rate_hz", "model", "estimator", "kinematics", "learning", "hardware"]

    @property
    def dt(self) -> float:
        return 1.0 / self.rate_hz

    @classmethod
    def from_dict(cls, d: Any, source: str = "<memory>") -> "ModelConfig":
        _check_keys(source, "", d, cls.TOP_KEYS, ["joints", "rate_hz", "model"])
        n = d["joints"]
        if isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= 16:
            raise ConfigError(source, "joints", f"must be an integer in 1..16, got {n!r}")
        rate = _num(source, "rate_hz", d["rate_hz"], lo=1.0, hi=100000.0)
        return cls(
            joints=n, rate_hz=rate,
            model=SEAParams.from_dict(d["model"], n, source),
            estimator=EstimatorConfig.from_dict(d.get("estimator") or {}, n, source),
            kinematics=KinematicsConfig.from_dict(d.get("kinematics") or {}, n, source),
            learning=LearningConfig.from_dict(d.get("learning") or {}, n, source),
            hardware=HardwareConfig.from_dict(d.get("hardware") or {}, n, source),
            source=source,
        )

    def to_dict(self) -> dict:
        return {
            "joints": self.joints, "rate_hz": self.rate_hz, "model": self.model.to_dict(),
            "estimator": self.estimator.to_dict(), "kinematics": self.kinematics.to_dict(),
            "learning": self.learning.to_dict(), "hardware": self.hardware.to_dict(),
        }

    def with_effects(self, effects) -> "ModelConfig":
        return dataclasses.replace(self, model=self.model.with_effects(effects))
