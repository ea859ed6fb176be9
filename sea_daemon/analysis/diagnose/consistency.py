"""Is the log consistent with the model at all?  (The motor pushes the way the spring pulls.)

In eq:motorside the motor is driven by the applied torque against the spring:
J θ̈_m + D_m θ̇_m + Σ_motor e = κ τ_m + τ_s, so over any stretch of motion the slow part of
κ τ_m − J θ̈_m − D_m θ̇_m follows −τ_s = K_s (θ_m − q) with gain about +1 (friction and an
offset aside, fitted alongside).  A log whose load and motor columns are swapped, or whose
encoder or torque counts the other way, gives a gain about −1: every effect fitted to it is
nonsense, and the estimator built on it errs by the whole spring torque.  :func:`check_motor_balance`
refuses such a log with one line.
"""
from __future__ import annotations

import math

import numpy as np

from sea_daemon.core.config import ModelConfig
from sea_daemon.core.model import SEAModel
from sea_daemon.errors import InputError
from sea_daemon.analysis.diagnose.residuals import Z95, Kinematics, applied_torque, inflated_lstsq, spring_torque

#: the spring term of the motor balance must reach at least this RMS [N m] for the check to
#: decide (below it the spring carries nothing the log can weigh)
MIN_SPRING_RMS = 1e-4


def motor_balance_gain(cfg: ModelConfig, kin: Kinematics) -> list[tuple[float, float]]:
    """Per joint: (g, 95 % half-width) of S(κ τ_m − J θ̈_m − D_m θ̇_m) = g · S(−τ_s) + c +
    f · sign(θ̇_m) by least squares over the log (the smoother's ends aside); (nan, nan) when the
    spring torque hardly varies."""
    model = SEAModel.from_config(cfg)
    q, th = model.correct_measurement(kin.q_raw, kin.theta_m_raw)
    tau_s = spring_torque(model, q - th, kin.dq - kin.dtheta_m)
    y = kin.smooth(applied_torque(model, kin) - kin.d2theta_m @ model.J.T - kin.dtheta_m @ model.D_m.T)
    x = kin.smooth(-tau_s)
    sg = kin.smooth(np.tanh(kin.dtheta_m / max(float(cfg.estimator.sign_eps), 1e-9)))
    N = kin.N
    e = min(kin.window, max(0, (N - 10) // 4))
    out = []
    for j in range(kin.n):
        xs = x[e:N - e, j]
        if xs.size < 10 or float(np.std(xs)) < MIN_SPRING_RMS:
            out.append((math.nan, math.nan))
            continue
        beta, cov = inflated_lstsq(np.column_stack([xs, np.ones_like(xs), sg[e:N - e, j]]), y[e:N - e, j])
        if cov is None:
            out.append((math.nan, math.nan))
            continue
        out.append((float(beta[0]), Z95 * math.sqrt(max(float(cov[0, 0]), 0.0))))
    return out


def check_motor_balance(cfg: ModelConfig, kin: Kinematics, path: str) -> list[tuple[float, float]]:
    """Raise InputError (one line) when the motor torque works against the spring torque on a
    joint (gain negative beyond its 95 % interval); return the gains otherwise."""
    gains = motor_balance_gain(cfg, kin)
    for j, (g, hw) in enumerate(gains):
        if math.isfinite(g) and math.isfinite(hw) and g + hw < 0:
            jn = f" (joint {j + 1})" if kin.n > 1 else ""
            raise InputError(
                f"{path}: the motor torque works against the spring{jn}: κ τ_m follows {g:.2f} × K_s (θ_m − q) "
                "where the model needs about +1; the q and theta_m columns are swapped, or an encoder or the torque "
                "counts the other way (docs/interfaces.md §1); diagnose refuses an inconsistent log")
    return gains
