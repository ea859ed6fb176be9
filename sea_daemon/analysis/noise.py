"""Noise identification for the calibration: kinematics, R, motor-torque noise, τ_h,act walk.

* :func:`choose_kinematics` — the causal differentiator when the configuration gives none:
  Savitzky–Golay, quadratic, over ~45 ms (5 samples at 100 Hz, 45 at 1 kHz): the same time
  span at any rate, so acceleration noise (∝ 1/(dt² W^2.5)) does not explode at 1 kHz.
* :func:`measurement_noise` — R of y = [θ_m, θ_s, θ̇_m, θ̇_s].  Angles: the encoders'
  variances by ALS (:func:`sea_daemon.als.identify_noise`, angles mode) floored at the
  quantisation Δ²/12, the ALS run made robust (health monitor off, a process noise that keeps
  its filter stable) and dropped when it fails.  Velocities: what ALS cannot see — the causal
  differentiator's error on accelerating motion, measured on the log itself as the variance of
  (causal velocity − zero-phase velocity) (``kinematics.smooth_derivatives``, ~0.1 s window);
  the encoder-noise part (‖c_v‖² R_ang) is the floor.  On the simulator this equals the
  variance against the true velocity within ~20 % (tests/test_calibration.py), where ALS alone is
  10–1000× too small and makes the filter diverge.
* :func:`motor_torque_noise` — σ_u of the torque actually applied (held per sample) from the
  motor-side balance of the model (eq:motorside) over second differences at lag m
  (m dt ≈ 10 ms): the white part of that residual is the torque noise (its smooth part is
  model error), ``σ² = var(r_k − r_{k−2m}) / (2 Σ c_i²)`` with c_i the weights of the held
  samples in the second difference.
* :func:`~sea_daemon.apps.calibration.pipeline.human_walk` — the τ_h,act random walk q_τ
  [N² m²/s] chosen by replaying the identified model with synthetic human torques of the
  declared band and size (a simulated active session, moving and still), and the friction-sign
  smoothing chosen on the real passive calibration log.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from sea_daemon.analysis.als import encoder_R, identify_noise
from sea_daemon.core.config import KinematicsConfig, ModelConfig
from sea_daemon.errors import EstimatorFault, InputError
from sea_daemon.core.kinematics import CausalDifferentiator, smooth_derivatives
from sea_daemon.core.log import MeasuredLog
from sea_daemon.core.model import SEAModel


def choose_kinematics(rate_hz: float, span_s: float = 0.015) -> KinematicsConfig:
    """Savitzky–Golay, degree 2, window ≈ span_s (odd, ≥ 5): 5 samples at 100 Hz, 15 at 1 kHz.

    A short span: the window's error on accelerating motion grows like (span)⁴ jerk², so a long
    window that is best on the calibration's motion is ~10× off on a faster session (at 1 kHz,
    45 vs 15 samples: θ̇_m error ×15 from the calibration log to a fast session, ×3 with 15;
    docs/calibration.md), and the filter's NIS diverges there.  The encoder noise of a short window
    is white and the same on every session; R carries it."""
    W = max(5, int(round(span_s * rate_hz)))
    if W % 2 == 0:
        W += 1
    return KinematicsConfig(window=W, method="savgol", degree=2)


def _dyn_var(e: np.ndarray) -> np.ndarray:
    """max(variance, q95(e²)/3.84) per column: the error variance of the dynamic parts."""
    return np.maximum(np.var(e, axis=0), np.quantile(e ** 2, 0.95, axis=0) / 3.84)


def select_kinematics(log: MeasuredLog, cfg: ModelConfig, max_span_s: float = 0.045,
                      margin: float = 3.0) -> tuple[KinematicsConfig, dict]:
    """The causal differentiator's window from the log: Savitzky–Golay, degree 2, the odd W
    (5 … ``max_span_s``·rate) minimising noise(W) + ``margin`` × fit(W) over the two velocity
    channels of y.  noise(W) is the encoders' quantisation through the FIR (‖c_v‖² Δ²/12);
    fit(W) the rest of var(causal − zero-phase velocity) on this log: the window's error on
    accelerating motion, which grows with the motion (∝ jerk²) — ``margin`` = 9 keeps W right
    for sessions three times as jerky as the calibration (a long window that is best on the
    calibration's motion is 10× off on a faster one: docs/calibration.md)."""
    vq, vm = _quantisation(cfg)
    Wmax = max(5, int(round(max_span_s * cfg.rate_hz)))
    rows = []
    for W in range(5, Wmax + 1, 2):
        c = dataclasses.replace(cfg, kinematics=KinematicsConfig(window=W, method="savgol", degree=2))
        y, yref = causal_measurements(log, c)
        n = cfg.joints
        skip = max(W, int(round(0.1 / log.dt)))
        # robust to the dynamic parts: the 95th percentile of e² as a variance (÷ 3.84, its
        # value for white Gaussian noise), not the mean over a mostly slow log
        tot = _dyn_var((y - yref)[skip:len(y) - skip, 2 * n:])
        g2 = float(np.sum(CausalDifferentiator(log.dt, W, 1, "savgol", 2).C[1] ** 2))
        noise = g2 * np.concatenate([np.full(n, vm), np.full(n, vq + vm)])
        fit = np.maximum(tot - noise, 0.0)
        rows.append({"window": W, "score": float(np.sum(noise + margin * fit)), "total": tot.tolist(),
                     "noise": noise.tolist()})
    best = min(rows, key=lambda r: r["score"])
    return KinematicsConfig(window=best["window"], method="savgol", degree=2), {"scan": rows, "window": best["window"]}


def _quantisation(cfg: ModelConfig) -> tuple[np.ndarray, np.ndarray]:
    """Δ²/12 of the load and the motor encoder (joint side) of each joint."""
    dq, dm = cfg.hardware.encoder_resolution(cfg.joints)
    return dq * dq / 12.0, dm * dm / 12.0


def causal_measurements(log: MeasuredLog, cfg: ModelConfig) -> tuple[np.ndarray, np.ndarray]:
    """y = [θ_m, θ_s, θ̇_m, θ̇_s] (N, 4n) as the AKF forms it (causal differentiator) and the
    same from zero-phase smoothing (reference)."""
    n = cfg.joints
    kc = cfg.kinematics
    model = SEAModel.from_config(cfg)
    q, th = model.correct_measurement(np.asarray(log.q, float), np.asarray(log.theta_m, float))
    N = len(log)
    diff = CausalDifferentiator(log.dt, kc.window, 2 * n, kc.method, kc.degree)
    ang = np.empty((N, 2 * n))
    vel = np.empty((N, 2 * n))
    for k in range(N):
        a, v, _ = diff.update(np.concatenate([q[k], th[k]]))
        ang[k], vel[k] = a, v
    Wz = max(7, int(round(0.1 / log.dt)) | 1)
    qz, dqz, _ = (np.asarray(a).reshape(N, n) for a in smooth_derivatives(log.t, q, window=Wz, degree=3))
    mz, dmz, _ = (np.asarray(a).reshape(N, n) for a in smooth_derivatives(log.t, th, window=Wz, degree=3))
    y = np.hstack([ang[:, n:], ang[:, :n] - ang[:, n:], vel[:, n:], vel[:, :n] - vel[:, n:]])
    yref = np.hstack([mz, qz - mz, dmz, dqz - dmz])
    return y, yref


def measurement_noise(log: MeasuredLog, cfg: ModelConfig, als: bool = True) -> tuple[np.ndarray, dict]:
    """R (4n×4n, diagonal) and what it rests on (module docstring)."""
    n = cfg.joints
    enc_q, enc_m = _quantisation(cfg)
    same = n == 1 or (np.all(enc_q == enc_q[0]) and np.all(enc_m == enc_m[0]))
    info: dict = {"quantisation": {"q": float(enc_q[0]) if same else enc_q.tolist(),
                                   "theta_m": float(enc_m[0]) if same else enc_m.tolist()}, "als": None}
    if als:
        try:
            safe = dataclasses.replace(cfg, estimator=dataclasses.replace(
                cfg.estimator, nis_scale=1e12,
                Sigma_nom=np.diag(np.concatenate([np.full(2 * n, 1e-12), np.full(2 * n, 1e-4), np.full(n, 1e-2)])),
                Sigma_nom_dt=0.0, tau_m_noise=0.0,
                R=np.diag(np.concatenate([enc_m, enc_q + enc_m, np.full(2 * n, 1e-4)]))))
            res = identify_noise(safe, log)
            ev = res["encoder_variances"]
            enc_q = np.maximum(enc_q, np.asarray(ev["q"], float))
            enc_m = np.maximum(enc_m, np.asarray(ev["theta_m"], float))
            info["als"] = {"q": list(map(float, ev["q"])), "theta_m": list(map(float, ev["theta_m"]))}
        except (InputError, EstimatorFault, np.linalg.LinAlgError, ValueError, FloatingPointError) as e:
            info["als"] = f"failed: {e}"[:200]
    diff = CausalDifferentiator(log.dt, cfg.kinematics.window, 1, cfg.kinematics.method, cfg.kinematics.degree)
    R_enc = np.diag(encoder_R(enc_m, enc_q, diff.C))
    y, yref = causal_measurements(log, cfg)
    skip = max(diff.L, int(round(0.1 / log.dt)))
    e = (y - yref)[skip:len(y) - skip]
    v_data = _dyn_var(e)
    R = np.maximum(R_enc, np.concatenate([R_enc[:2 * n], v_data[2 * n:]]))
    info["velocity_error_var"] = v_data[2 * n:].tolist()
    info["encoder_variances"] = {"q": enc_q.tolist(), "theta_m": enc_m.tolist()}
    return np.diag(R), info


def _second_difference_weights(m: int) -> np.ndarray:
    """c_i (2m,): the weight of the torque held over sample interval i in the lag-m second
    difference of a double integrator, x(t+h) − 2x(t) + x(t−h) = h² Σ c_i a_i (Σ c_i = 1)."""
    c = np.empty(2 * m)
    for i in range(2 * m):
        s0, s1 = (i - m) / m, (i - m + 1) / m      # interval in units of h
        # ∫ (1 − |s|) ds over [s0, s1]
        f = lambda s: s - 0.5 * s * abs(s)
        c[i] = f(s1) - f(s0)
    return c / c.sum()


def motor_torque_noise(log: MeasuredLog, cfg: ModelConfig, span_s: float = 0.01) -> tuple[float, dict]:
    """σ_u [N m] from the motor-side balance (eq:motorside) at lag m (module docstring)."""
    model = SEAModel.from_config(cfg)
    n = cfg.joints
    dt = log.dt
    m = max(1, int(round(span_s / dt)))
    q, th = model.correct_measurement(np.asarray(log.q, float), np.asarray(log.theta_m, float))
    u = np.asarray(log.tau_m, float)
    N = len(log)
    if N < 8 * m + 10:
        raise InputError(f"{log.path}: too short for the torque-noise estimate ({N} samples)")
    c = _second_difference_weights(m)
    h = m * dt
    k = np.arange(m, N - m)
    ddth = (th[k + m] - 2 * th[k] + th[k - m]) / h ** 2
    dth = (th[k + m] - th[k - m]) / (2 * h)
    ths = q - th
    dths = (ths[k + m] - ths[k - m]) / (2 * h)
    # torque held over the 2m intervals around k, weighted as in the second difference
    ubar = np.zeros((len(k), n))
    for i in range(2 * m):
        ubar += c[i] * u[k - m + i]
    r = np.empty((len(k), n))
    for j, kk in enumerate(k):
        tau_s = model.spring_torque(ths[kk], dths[j])
        mo, _, _ = model.motor_effects_torque(th[kk], dth[j])
        # eq:motorside: κ τ_m − (J θ̈_m + D_m θ̇_m + Σ_motor e − τ_s)
        r[j] = model.kappa * ubar[j] - (model.J @ ddth[j] + model.D_m @ dth[j] + mo - tau_s)
    d = r[2 * m:] - r[:-2 * m]
    # robust variance (median of squares; normal: median(x²) = 0.4549 σ²)
    var_d = np.median(d ** 2, axis=0) / 0.4549
    s2 = var_d / (2.0 * float(np.sum(c ** 2)))
    sigma = float(np.sqrt(np.max(s2)))
    return sigma, {"lag_samples": m, "per_joint": np.sqrt(s2).tolist()}
