"""The subject's active torque τ_h,act(t) for the device model, from a simulator scenario.

``passive``: τ_h,act = 0.  ``resist`` (Sec. V-C, open-loop controller): in the estimation phase
the subject resists the desired torque, τ_h,act(t) = −τ_des(t − t_est) with τ_des the scenario's
cosine torque and t_est = training samples · dt, exactly as the offline simulator does it.
"""
from __future__ import annotations

from typing import Callable

import numpy as np

from sea_daemon.control import cosine_torque


def human_torque(scenario) -> Callable[[float], np.ndarray]:
    """τ_h,act(t) [N m] per joint for the device model's plant time t."""
    n = scenario.nominal.joints
    zero = np.zeros(n)
    if scenario.human != "resist":
        return lambda t: zero
    ctrl = scenario.controller
    dt = scenario.nominal.dt
    t_est = scenario.training_samples * dt
    out = np.zeros(n)

    def resist(t: float) -> np.ndarray:
        tp = t - t_est
        # Sec. V-C: the subject resists and holds the arm, τ_h,act = −τ_des (estimation phase only)
        out[:] = -cosine_torque(tp, ctrl.amplitude, ctrl.frequency_hz, ctrl.offset) if tp >= -1e-9 else 0.0
        return out
    return resist
