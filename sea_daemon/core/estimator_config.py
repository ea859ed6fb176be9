"""The ``estimator`` section of the model configuration (docs/interfaces.md §2): the AKF / GP-AKF
settings as a validated, frozen dataclass (:class:`EstimatorConfig`, re-exported by
:mod:`sea_daemon.core.config`).  Unknown keys and values out of range raise
:class:`~sea_daemon.errors.ConfigError` naming the key and the allowed values.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import numpy as np

from sea_daemon.core import validate
from sea_daemon.errors import ConfigError

#: the models of τ_h,act (``estimator.tau_h_act_model``): a random walk (5n states, the paper's)
#: or an integrated random walk (τ_h,act and τ̇_h,act, 6n states; core.model.StateLayout)
TAU_MODELS = ("walk", "integrated")


@dataclass(frozen=True)
class EstimatorConfig:
    """AKF / GP-AKF settings (Alg. 1, Alg. 2; Sec. V-B)."""

    R: np.ndarray                  # measurement noise, y = [θ_m, θ_s, θ̇_m, θ̇_s]   (4n×4n)
    Sigma_nom: np.ndarray          # nominal process noise per step, x order     (d×d, d = 5n or 6n)
    P0: np.ndarray                 # initial covariance                          (d×d)
    delta: float = 0.05            # probability level of the bounds (eq:bounds)
    sign_eps: float = 0.01         # [rad/s] smoothing of sign() in declared friction
    # estimator health (sea_daemon.core.estimators.health, docs/safety.md)
    nis_window: int = 100          # steps of the windowed mean NIS
    nis_alpha: float = 1e-3        # two-sided level of its chi2 band
    nis_scale: float = 10.0        # divergence: windowed mean > nis_scale x the band's upper edge
    gp_input_margin: float = 0.1   # GP inputs clipped to the training box +- this fraction of its width
    # GP error bound of the Theorem-1 bound (docs/bounds.md §2): "lederer" (LUH19, eq:gpmeanbounds)
    # or a number beta > 0 (|f - mu| <= beta sqrt(sigma^2 + sigma_n^2), e.g. a split-conformal beta)
    gp_beta: str | float = "lederer"
    # per-step process noise (docs/estimators.md, "Process noise"); the defaults keep Σ_nom as given
    Sigma_nom_dt: float = 0.01     # [s] step Σ_nom is given for: Σ_nom,k = Σ_nom·dt/Sigma_nom_dt (0: per step)
    tau_m_noise: float = 0.0       # [N m] std of the motor-torque error held over a step: + Γ_u σ² Γ_uᵀ
    gp_noise_in_Q: bool = True     # GP-AKF: Q with the residual's predictive variance σ² + σ_on² (false: σ², the paper's)
    init_after_kinematics: bool = True    # start when the differentiator is full: x̂₀ = y (false: at once, velocities 0)
    # Theorem-1 bound (docs/bounds.md §6): declared bound on how fast the active human torque
    # changes beyond the random walk of Σ_nom, |dτ_h,act/dt| <= tau_h_act_rate [N m/s]; it enters
    # the set of means as a bounded input (0: the paper's pure random walk)
    tau_h_act_rate: float = 0.0
    # the start-up gate (Estimate.valid): the largest |τ_h,act| [N m] when the filter starts or is
    # reset, i.e. the initial torque error the gate lets decay; None: hardware.torque_limit
    tau_h_act_max: float | None = None
    # the τ_h,act random walk [N² m²/s] while z = [q, q̇, q̈] lies outside the region the
    # calibration covered (a calibrated model's estimators; docs/calibration.md): off its data the
    # model is less accurate, and its error may change there as fast as a declared subject's
    # torque; 0: the walk of Sigma_nom everywhere
    tau_h_act_walk_outside: float = 0.0
    # where the real-time loop computes the Theorem-1 bound (docs/daemon.md, "The bound worker"):
    # "worker" (a process of its own, ρ_k published with its sample's cycle), "loop" (in the
    # estimator's step), "auto" (the worker in real-time pace, the loop in lock-step runs)
    bound_in: str = "auto"
    # the oldest bound the loop publishes, in cycles behind the estimate (worker only); older:
    # the estimate is not valid in that cycle
    bound_max_age: int = 3
    # the usefulness limit of the published bound (Estimate.valid): a ρ_k above this [N m] is not a
    # valid estimate; None: tau_h_act_max (hardware.torque_limit), a wider bound says less than the limit
    bound_limit: float | None = None
    # a plain AKF's declared bound on its model's load-side torque error [N m] (|f_true − f_model|,
    # the term the Theorem-1 bound needs for its estimate to be valid; a GP-AKF's GP error takes its
    # place); 0: none declared, and the AKF's estimate is never valid
    model_error: float = 0.0
    # the model of τ_h,act (docs/estimators.md, "The human torque's model"): "walk" (a random walk,
    # 5n states) or "integrated" (an integrated random walk: τ_h,act and τ̇_h,act, 6n states, the
    # walk of Sigma_nom on τ̇_h,act)
    tau_h_act_model: str = "walk"
    # Theorem-1 bound of the integrated model (docs/bounds.md §6): declared bound on the active human
    # torque's second derivative, |d²τ_h,act/dt²| <= tau_h_act_accel [N m/s²] (0: none)
    tau_h_act_accel: float = 0.0

    @property
    def d(self) -> int:
        """The state's dimension per the τ_h,act model (5n or 6n)."""
        return self.Sigma_nom.shape[0]

    @property
    def integrated(self) -> bool:
        """Whether the filter tracks τ̇_h,act too (``tau_h_act_model: integrated``)."""
        return self.tau_h_act_model == "integrated"

    KEYS = ["R", "Sigma_nom", "P0", "P0_tau", "delta", "sign_eps", "nis_window", "nis_alpha", "nis_scale",
            "gp_input_margin", "Sigma_nom_dt", "tau_m_noise", "gp_noise_in_Q", "init_after_kinematics", "gp_beta",
            "tau_h_act_rate", "tau_h_act_max", "tau_h_act_walk_outside", "bound_in", "bound_max_age",
            "bound_limit", "model_error", "tau_h_act_model", "tau_h_act_accel", "P0_dtau"]
    BOUND_IN = ("auto", "worker", "loop")

    @classmethod
    def default(cls, n: int) -> "EstimatorConfig":
        return cls.from_dict({}, n, "<default>")

    @classmethod
    def from_dict(cls, d: Mapping, n: int, source: str) -> "EstimatorConfig":
        validate.check_keys(source, "estimator.", d, cls.KEYS, [])
        # Sec. V-B: R identified by ALS, Sigma_nom hand-set, P0 = R (plus τ_h,act)
        # every measurement has noise: R positive definite (eq:nonlinkOsys)
        R = validate.diag_or_matrix(source, "estimator.R", d.get("R", np.repeat([0.0461, 3.6e-6, 0.1288, 1.01e-5], n)),
                            4 * n, positive_definite=True)
        S, P0, tau_model = _state_covariances(d, n, source, R)
        delta = validate.num(source, "estimator.delta", d.get("delta", 0.05))
        if not 0 < delta < 1:
            raise ConfigError(source, "estimator.delta", f"must be in (0, 1), got {delta}")
        def _int(key, default, lo, hi):
            v = d.get(key, default)
            if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
                raise ConfigError(source, f"estimator.{key}", f"must be an integer in {lo}..{hi}, got {v!r}")
            return v
        nis_alpha = validate.num(source, "estimator.nis_alpha", d.get("nis_alpha", 1e-3))
        if not 0 < nis_alpha < 1:
            raise ConfigError(source, "estimator.nis_alpha", f"must be in (0, 1), got {nis_alpha}")
        nis_scale = validate.num(source, "estimator.nis_scale", d.get("nis_scale", 10.0))
        if not nis_scale >= 1:
            raise ConfigError(source, "estimator.nis_scale", f"must be >= 1, got {nis_scale}")
        def _nonneg(key, default, unit=""):
            v = validate.num(source, f"estimator.{key}", d.get(key, default))
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
        S_dt = _nonneg("Sigma_nom_dt", 0.01, " [s] (0: Sigma_nom per step)")
        tau_m_noise = _nonneg("tau_m_noise", 0.0, " [N m]")
        rate = _nonneg("tau_h_act_rate", 0.0, " [N m/s]")
        accel = _nonneg("tau_h_act_accel", 0.0, " [N m/s^2]")
        walk_out = _nonneg("tau_h_act_walk_outside", 0.0, " [N^2 m^2/s]")
        t_max = d.get("tau_h_act_max")
        if t_max is not None:
            t_max = validate.num(source, "estimator.tau_h_act_max", t_max, positive=True)
        b_lim = d.get("bound_limit")
        if b_lim is not None:
            b_lim = validate.num(source, "estimator.bound_limit", b_lim, positive=True, hi=1e6)
        model_error = validate.num(source, "estimator.model_error", d.get("model_error", 0.0), lo=0.0, hi=1e6)
        def _bool(key):
            v = d.get(key, True)
            if not isinstance(v, bool):
                raise ConfigError(source, f"estimator.{key}", f"must be true or false, got {v!r}")
            return v
        gp_noise, init_kin = _bool("gp_noise_in_Q"), _bool("init_after_kinematics")
        bound_in = d.get("bound_in", "auto")
        if bound_in not in cls.BOUND_IN:
            raise ConfigError(source, "estimator.bound_in", f"must be one of {', '.join(cls.BOUND_IN)}, got {bound_in!r}")
        return cls(R=R, Sigma_nom=S, P0=P0, delta=delta,
                   sign_eps=validate.num(source, "estimator.sign_eps", d.get("sign_eps", 0.01), positive=True),
                   nis_window=_int("nis_window", 100, 1, 100000), nis_alpha=nis_alpha, nis_scale=nis_scale,
                   gp_input_margin=margin,
                   gp_beta=gp_beta,
                   Sigma_nom_dt=S_dt, tau_m_noise=tau_m_noise, gp_noise_in_Q=gp_noise,
                   init_after_kinematics=init_kin, tau_h_act_rate=rate, tau_h_act_max=t_max,
                   tau_h_act_walk_outside=walk_out,
                   bound_in=bound_in, bound_max_age=_int("bound_max_age", 3, 1, 100000),
                   bound_limit=b_lim, model_error=model_error, tau_h_act_model=tau_model,
                   tau_h_act_accel=accel)

    def with_tau_model(self, tau_model: str, n: int, source: str = "<tau_h_act_model>") -> "EstimatorConfig":
        """These settings with the τ_h,act model ``tau_model`` (:data:`TAU_MODELS`): unchanged when it
        is this one's, else with that model's default Sigma_nom and P0 (from R) and the rest kept."""
        if tau_model == self.tau_h_act_model:
            return self
        d = {k: v for k, v in self.to_dict().items() if k not in ("Sigma_nom", "P0", "tau_h_act_model")}
        return EstimatorConfig.from_dict({**d, "tau_h_act_model": tau_model}, n, source)

    def to_dict(self) -> dict:
        def dg(a):
            return np.diag(a).tolist() if np.allclose(a, np.diag(np.diag(a))) else a.tolist()
        return {"R": dg(self.R), "Sigma_nom": dg(self.Sigma_nom), "P0": dg(self.P0),
                "delta": self.delta, "sign_eps": self.sign_eps, "nis_window": self.nis_window,
                "nis_alpha": self.nis_alpha, "nis_scale": self.nis_scale,
                "gp_input_margin": self.gp_input_margin, "gp_beta": self.gp_beta,
                "Sigma_nom_dt": self.Sigma_nom_dt,
                "tau_m_noise": self.tau_m_noise, "gp_noise_in_Q": self.gp_noise_in_Q,
                "init_after_kinematics": self.init_after_kinematics, "tau_h_act_rate": self.tau_h_act_rate,
                **({"tau_h_act_walk_outside": self.tau_h_act_walk_outside} if self.tau_h_act_walk_outside else {}),
                **({} if self.tau_h_act_max is None else {"tau_h_act_max": self.tau_h_act_max}),
                **({} if self.bound_in == "auto" else {"bound_in": self.bound_in}),
                **({} if self.bound_max_age == 3 else {"bound_max_age": self.bound_max_age}),
                **({} if self.bound_limit is None else {"bound_limit": self.bound_limit}),
                **({"model_error": self.model_error} if self.model_error else {}),
                **({} if self.tau_h_act_model == "walk" else {"tau_h_act_model": self.tau_h_act_model}),
                **({"tau_h_act_accel": self.tau_h_act_accel} if self.tau_h_act_accel else {})}


def _state_covariances(d: Mapping, n: int, source: str, R: np.ndarray):
    """(Sigma_nom, P0, tau_h_act_model) of the ``estimator`` mapping ``d``: d × d with d = 5n for the
    random walk of τ_h,act, 6n for the integrated one (τ̇_h,act last; its walk 1.0 per 10 ms and
    P0_dtau by default, τ_h,act's walk then 0); P0's measured block R unless P0 is given."""
    tau_model = d.get("tau_h_act_model", "walk")
    if tau_model not in TAU_MODELS:
        raise ConfigError(source, "estimator.tau_h_act_model",
                          f"must be one of {', '.join(TAU_MODELS)}, got {tau_model!r}")
    irw = tau_model == "integrated"
    dim = (6 if irw else 5) * n
    # the walk of τ̇_h,act per 10 ms (integrated): its own default; τ_h,act itself then has none
    S = validate.diag_or_matrix(source, "estimator.Sigma_nom",
                        d.get("Sigma_nom", np.repeat([1e-1, 1e3, 1e2, 1e-9, 0.0, 1.0] if irw
                                                     else [1e-1, 1e3, 1e2, 1e-9, 1e-2], n)), dim)
    P0_tau = validate.num(source, "estimator.P0_tau", d.get("P0_tau", 1.0), positive=True)
    P0_dtau = validate.num(source, "estimator.P0_dtau", d.get("P0_dtau", 100.0), positive=True)
    if "P0" in d:
        P0 = validate.diag_or_matrix(source, "estimator.P0", d["P0"], dim)
    else:
        P0 = np.zeros((dim, dim))
        P0[: 4 * n, : 4 * n] = R
        P0[4 * n:5 * n, 4 * n:5 * n] = np.eye(n) * P0_tau
        if irw:
            P0[5 * n:, 5 * n:] = np.eye(n) * P0_dtau
        P0.setflags(write=False)
    return S, P0, tau_model
