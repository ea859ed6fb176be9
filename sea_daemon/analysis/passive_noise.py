"""What a passive wearer costs the τ_h,act estimate: the encoders' counts and the motor-torque
noise through a filter with a given random walk.

With the wearer passive (τ_h,act = 0) every τ̂_h,act is error.  On a model the filter knows
exactly (the oracle AKF), what is left is the measurement noise passed through the filter's
gain: the two encoders read the count they have passed (variance Δ²/12 each, Δq = 2π/counts
of q, Δθ_m = 2π/(counts·gear) of θ_m; :meth:`HardwareConfig.encoder_resolution`) and the motor
applies its command plus a torque noise σ_u held over the sample.  How much of that reaches τ̂
is set by the walk q_τ [N² m²/s] the filter assumes for τ_h,act: a fast walk (a filter that
follows a quick wearer) takes the counts' noise as torque, a slow one lags an active wearer.

:func:`passive_noise` computes, per joint, the steady-state RMS of τ̂_h,act for a passive arm
at rest, of the linear Kalman filter of the robot about that rest (its inertia, spring and
gravity: :func:`~sea_daemon.core.bounds.floor.rest_jacobian`) with the walk q_τ per joint, the
input noise σ_u and the two encoders' angles as its measurements:

    filter  P = DARE(F, H, Q_walk + Γ_u σ_u² Γ_uᵀ, R),  K = P Hᵀ (H P Hᵀ + R)⁻¹
    error   e_k = (I − K H)(F e_{k−1} + Γ_u w_k) − K v_k          (no walk: the wearer is passive)
    X = T X Tᵀ + (I − KH) Γ_u σ_u² Γ_uᵀ (I − KH)ᵀ + K R Kᵀ,  T = (I − KH) F   (discrete Lyapunov, by doubling)

and the noise is √X_ττ per joint; and, for the same filter, the lag a wearer changing joint j's
torque at 1 N m/s leaves in τ̂_j (the ℓ1 norm of the τ error's response to the held rate: the
Theorem-1 bound's lag term per N m/s of the declared rate, docs/bounds.md §6).
:func:`walk_for_noise` inverts the first: the largest walk (one for all joints) whose passive
noise on joint j stays at a target.

The daemon's filter also uses the differentiator's velocities, a moving arm's friction and
M(q) along the motion, so its passive error is not this figure: on the two-joint family's
development plants (16-bit encoders, walks 0.1–3.16) the oracle AKF's passive RMSE was 1.2–1.6 ×
it on the shoulder and 0.8–1.8 × on the elbow (docs/calibration.md, "Two joints").  It is an estimate, not
a bound; it shows which walk and which encoders a passive accuracy needs before any session is
run.  Pure numerics, one Riccati and one Lyapunov sum per walk (milliseconds).
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np
from scipy.linalg import solve_discrete_are

from sea_daemon.core.bounds.floor import rest_jacobian
from sea_daemon.core.config import ModelConfig
from sea_daemon.core.effects import Inertia
from sea_daemon.core.linalg import discretize
from sea_daemon.core.model import SEAModel


@dataclasses.dataclass(frozen=True)
class PassiveNoise:
    """Per joint: ``rms`` [N m] the passive arm's τ̂_h,act RMS, ``lag_per_rate`` [s] the lag per
    N m/s of a wearer's torque rate; for the walk ``q_tau`` [N² m²/s] per joint, the input noise
    ``sigma_u`` [N m] and the encoders' quanta ``quanta`` [rad] (load, motor per joint)."""

    rms: np.ndarray
    lag_per_rate: np.ndarray
    q_tau: np.ndarray
    sigma_u: float
    quanta: tuple

    def to_dict(self) -> dict:
        return {"rms": [round(float(v), 5) for v in self.rms], "lag_per_rate_s": [round(float(v), 5) for v in self.lag_per_rate],
                "q_tau": [float(v) for v in self.q_tau], "sigma_u": self.sigma_u}


def _rest(cfg: ModelConfig, q) -> np.ndarray:
    """The rest angles (n,): ``q`` [rad] (one or per joint), else the middle of the calibration's range, else 0."""
    n = cfg.joints
    if q is None:
        cal = cfg.calibration
        lo, hi = getattr(cal, "q_min_deg", None), getattr(cal, "q_max_deg", None)
        q = np.radians(0.5 * (np.asarray(lo, float) + np.asarray(hi, float))) if lo is not None and hi is not None else 0.0
    return np.broadcast_to(np.asarray(q, dtype=float), (n,)).copy()


def _input_matrix(cfg: ModelConfig, q: np.ndarray) -> np.ndarray:
    """∂f/∂τ_m (5n × n) of the model :func:`rest_jacobian` linearises (declared inertia kept)."""
    n = cfg.joints
    model = SEAModel(cfg.model.with_effects(tuple(e for e in cfg.model.effects if isinstance(e, Inertia))))
    x = np.zeros(5 * n)
    x[:n] = q
    model.at(x)
    return model.B_nom()


def steady_filter(F: np.ndarray, H: np.ndarray, Q: np.ndarray, R: np.ndarray):
    """(K, I − K H, T = (I − K H) F) of the steady-state Kalman filter of (F, H, Q, R), or None
    where it does not settle (no finite Riccati solution, or T not stable)."""
    P = _riccati(F, H, Q, R)
    if P is None:
        return None
    K = P @ H.T @ np.linalg.inv(H @ P @ H.T + R)
    IKH = np.eye(len(F)) - K @ H
    T = IKH @ F
    if not np.all(np.isfinite(T)) or np.max(np.abs(np.linalg.eigvals(T))) >= 1.0:
        return None
    return K, IKH, T


def l1_response(T: np.ndarray, E: np.ndarray, rows, cols) -> np.ndarray:
    """Σ_k |(T^k E)[rows, cols]|: the ℓ1 norm of a stable filter's error response, entry by entry, to
    inputs held at the columns of ``E`` (the first step's error), summed until it has died out."""
    out = np.zeros(np.shape(E[rows, cols]))
    for _ in range(200000):
        out += np.abs(E[rows, cols])
        E = T @ E
        if np.max(np.abs(E)) < 1e-15:
            break
    return out


def _riccati(F: np.ndarray, H: np.ndarray, Q: np.ndarray, R: np.ndarray) -> np.ndarray | None:
    """The steady-state prior covariance of the Kalman filter (scipy's DARE; where its Schur
    reordering fails on the encoders' very different scales, the Riccati recursion to convergence)."""
    try:
        P = solve_discrete_are(F.T, H.T, Q, R)
        if np.all(np.isfinite(P)):
            return P
    except (np.linalg.LinAlgError, ValueError):
        pass
    P = Q + np.eye(len(Q))
    for _ in range(200000):
        S = H @ P @ H.T + R
        Pn = F @ (P - P @ H.T @ np.linalg.solve(S, H @ P)) @ F.T + Q
        Pn = 0.5 * (Pn + Pn.T)
        if not np.all(np.isfinite(Pn)):
            return None
        if np.max(np.abs(Pn - P)) <= 1e-12 * np.max(np.abs(Pn)):
            return Pn
        P = Pn
    return None


def lyapunov_sum(T: np.ndarray, W: np.ndarray) -> np.ndarray:
    """X = Σ_k T^k W (T^k)ᵀ (X = T X Tᵀ + W, T stable) by doubling: the encoders' scales (10⁻⁷ rad)
    and the torque's (10⁻² N m) make the direct solve's Kronecker system too ill-conditioned."""
    X, A = W.copy(), T.copy()
    for _ in range(64):
        X = X + A @ X @ A.T
        A = A @ A
        if np.max(np.abs(A)) < 1e-18:
            break
    return X


def passive_noise(cfg: ModelConfig, q_tau, sigma_u: float | None = None, q=None,
                  dt: float | None = None) -> PassiveNoise:
    """The passive noise and the lag of the steady-state filter with walk ``q_tau`` [N² m²/s] (one,
    or one per joint) on the robot of ``cfg`` at rest at ``q`` (module docstring); ``sigma_u`` the
    motor-torque noise [N m] (default ``estimator.tau_m_noise``), ``dt`` the period (default the
    configuration's).  Raises ValueError for a walk or noise that is not finite and ≥ 0 (> 0 for
    the walk), or a filter that does not settle."""
    n = cfg.joints
    qt = np.broadcast_to(np.asarray(q_tau, dtype=float), (n,)).copy()
    su = float(cfg.estimator.tau_m_noise if sigma_u is None else sigma_u)
    if not (np.all(np.isfinite(qt)) and np.all(qt > 0)) or not (math.isfinite(su) and su >= 0):
        raise ValueError(f"q_tau must be finite and > 0, sigma_u finite and >= 0 (got {qt.tolist()}, {su!r})")
    dt = float(cfg.dt if dt is None else dt)
    q0 = _rest(cfg, q)
    A = rest_jacobian(cfg, q0)
    d = 5 * n
    tau = np.arange(4 * n, 5 * n)
    F, G = discretize(A, np.column_stack([np.eye(d)[:, tau], _input_matrix(cfg, q0)]), dt)
    Gw, Gu = G[:, :n], G[:, n:]           # a held rate of τ_h,act; a held motor torque
    dq, dth = cfg.hardware.encoder_resolution(n)
    H = np.zeros((2 * n, d))
    H[:n, :n] = np.eye(n)                              # θ_m
    H[n:, :n] = H[n:, n:2 * n] = np.eye(n)             # q = θ_m + θ_s
    R = np.diag(np.concatenate([np.asarray(dth, float) ** 2, np.asarray(dq, float) ** 2]) / 12.0)
    Qu = su * su * (Gu @ Gu.T)
    Q = Qu.copy()
    Q[tau, tau] += qt * dt
    kf = steady_filter(F, H, Q + 1e-18 * np.eye(d), R)
    if kf is None:
        raise ValueError(f"the filter with q_tau {qt.tolist()} does not settle")
    K, IKH, T = kf
    X = lyapunov_sum(T, IKH @ Qu @ IKH.T + K @ R @ K.T)
    # ℓ1 norm of τ_j's error response to joint j's held unit rate
    lag = l1_response(T, IKH @ Gw, tau, np.arange(n))
    rms = np.sqrt(np.maximum(np.diag(X)[tau], 0.0))
    return PassiveNoise(rms, lag, qt, su, (tuple(map(float, dq)), tuple(map(float, dth))))


def walk_for_noise(cfg: ModelConfig, target: float, sigma_u: float | None = None, q=None,
                   lo: float = 1e-6, hi: float = 1e4) -> np.ndarray:
    """Per joint j, the largest walk q_τ in [lo, hi] (one for all joints) whose passive noise on
    joint j (:func:`passive_noise`) is at most ``target`` [N m]: ``lo`` where even that is
    noisier, ``hi`` where every walk is quieter.  Bisection on log q_τ (the noise grows with the walk)."""
    n = cfg.joints
    out = np.empty(n)
    for j in range(n):
        def noise(w: float) -> float:
            return float(passive_noise(cfg, w, sigma_u, q).rms[j])
        if noise(hi) <= target:
            out[j] = hi
            continue
        if noise(lo) > target:
            out[j] = lo
            continue
        a, b = math.log(lo), math.log(hi)
        for _ in range(40):
            m = 0.5 * (a + b)
            if noise(math.exp(m)) <= target:
                a = m
            else:
                b = m
        out[j] = math.exp(a)
    return out
