"""The end stops of the simulated arm: a joint with declared limits stops there, as a real arm does.

A model with ``model.urdf`` declares each revolute joint's range, ``<limit lower upper>`` [rad]
(:attr:`~sea_daemon.core.rigid.RigidBody.q_min`, ``q_max``).  The true plant (:mod:`.plant`) and so
the device model's arm stop there: beyond a limit a stiff spring with a damper pushes the joint
back,

    f = max(0, k (q − q_max) + b q̇)    for q > q_max
    f = min(0, k (q − q_min) + b q̇)    for q < q_min,      f = 0 within [q_min, q_max],

a load-side torque the joint must overcome (eq:unknwn_load, as an effect's).  The contact only
pushes: it never pulls the joint back into the stop as it leaves.  k is the joint's
``hardware.torque_limit`` over :data:`PENETRATION` (the joint's full motor torque presses it 1°
into the stop); b damps the joint's effective inertia at the zero pose, 1 / (M(0)⁻¹)_jj,
critically on that spring.  Within the limits f is exactly zero, so a motion that stays in the
declared range is integrated bit for bit as without stops.  A model without a URDF (or a joint
without limits) has no stops; the estimator never knows about them (what a stop pushes shows in
its residual, like any torque outside its model).
"""
from __future__ import annotations

import math

import numpy as np

from sea_daemon.core.jit import njit

#: how far the joint's full motor torque presses it into its stop [rad] (sets the stiffness)
PENETRATION = math.radians(1.0)


def end_stops(model, torque_limits) -> np.ndarray | None:
    """The stops of ``model`` (:class:`~sea_daemon.core.model.SEAModel`): an (n, 4) array of rows
    [q_min, q_max, k, b] per joint (±inf where a joint declares no range), or None when no joint
    declares one.  ``torque_limits``: each joint's motor-torque limit [N m]."""
    rigid = model.rigid
    if rigid is None:
        return None
    n = model.n
    lo, hi = np.asarray(rigid.q_min, dtype=float), np.asarray(rigid.q_max, dtype=float)
    declared = np.isfinite(lo) & np.isfinite(hi) & (hi > lo)
    if not declared.any():
        return None
    k = np.asarray(torque_limits, dtype=float).reshape(n) / PENETRATION
    inertia = 1.0 / np.diag(np.linalg.inv(rigid.mass_matrix(np.zeros(n))))
    b = 2.0 * np.sqrt(k * inertia)
    return np.column_stack([np.where(declared, lo, -np.inf), np.where(declared, hi, np.inf), k, b])


def stop_rate(stops: np.ndarray | None, Minv: np.ndarray) -> float:
    """The fastest mode the stops add [1/s]: sqrt(k (M⁻¹)_jj) (critically damped), for the plant's
    RK4 step check; 0 without stops."""
    if stops is None:
        return 0.0
    on = np.isfinite(stops[:, 0])
    return float(np.max(np.sqrt(stops[on, 2] * np.abs(np.diag(Minv))[on]), initial=0.0))


@njit
def stop_torque(stops, j: int, q: float, dq: float) -> float:
    """The torque f [N m] of joint j's stop at (q, q̇) (module docstring): 0 within its range."""
    if q > stops[j, 1]:
        f = stops[j, 2] * (q - stops[j, 1]) + stops[j, 3] * dq
        return f if f > 0.0 else 0.0
    if q < stops[j, 0]:
        f = stops[j, 2] * (q - stops[j, 0]) + stops[j, 3] * dq
        return f if f < 0.0 else 0.0
    return 0.0


@njit
def stop_torques(stops, q, dq, out) -> bool:
    """``out`` = every joint's stop torque; whether any is non-zero."""
    any_on = False
    for j in range(q.shape[0]):
        out[j] = stop_torque(stops, j, q[j], dq[j])
        any_on = any_on or out[j] != 0.0
    return any_on
