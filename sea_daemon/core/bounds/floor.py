"""The tightest bound any estimator can guarantee: what the encoders cannot tell apart.

Two wearers whose active torques agree until t₀ and then part — one keeps its torque, the
other changes joint j's as fast as the declaration allows — move the arm apart by

    δx(t) = ∫₀^{t−t₀} e^{A s} E_τ δτ̇(t − s) ds                       (eq:linearization, at rest)

(A the model's Jacobian with τ_h,act a state, E_τ its joint-j column).  An encoder reads the
count it has passed (one count Δq = 2π/counts of q on the joint, Δθ_m = 2π/(counts·gear) of θ_m
on the motor shaft, :meth:`HardwareConfig.encoder_resolution`), so while every encoder's share
of δx stays within one count, an arm resting at the lower edge of its counts gives the same
counts for both wearers at every sample, whatever the rate.  Nothing the daemon receives then
tells them apart (velocities come from these angles, τ_m is what it commanded), every estimator
gives both the same τ̂, and a bound that holds for both is at least half their difference:

    ρ ≥ ρ_floor = δτ(T) / 2,   T = the first time an encoder's share of δx reaches one count.

The declared change (docs/bounds.md §6, §10): |dτ_h,act/dt| ≤ r (``estimator.tau_h_act_rate``,
what the Theorem-1 bound rests on) gives δτ̇ = r from t₀ on; with also |d²τ_h,act/dt²| ≤ a
(a band-limited wearer) δτ̇ rises at a to r.  Either is one path the declaration allows, so the
figure is a lower bound of what any estimator can guarantee (a cleverer path could part the
wearers further).  The model is the robot's inertia, the spring and gravity about the rest
position; declared friction, damping by tissue and the like are left out: holding the arm
back, they only hide the change longer.  A moving arm crosses count edges, which tells a
little more; measurement noise tells a little less.

Pure numerics (one 5n+2 block exponential per time point; ``scipy.linalg.expm``: this is done
once per configuration, not per cycle).
"""
from __future__ import annotations

import dataclasses

import numpy as np
from scipy.linalg import expm

from sea_daemon.core.config import ModelConfig
from sea_daemon.core.effects import Inertia
from sea_daemon.core.model import SEAModel

#: [s] the longest separation looked at: a change still hidden after this long is reported as
#: the change at this time (a lower bound all the same)
T_MAX = 2.0


@dataclasses.dataclass(frozen=True)
class BoundFloor:
    """Per joint: ``rho`` [N m] the floor ρ_floor, ``hidden_s`` [s] how long the change stays
    within one count (T), ``seen_by`` which encoder sees it first (``"load j"`` / ``"motor j"``,
    joints numbered from 1); ``rate`` [N m/s] and ``accel`` [N m/s², None: not declared] the
    declaration it was computed for."""

    rho: np.ndarray
    hidden_s: np.ndarray
    seen_by: tuple[str, ...]
    rate: float
    accel: float | None

    def to_dict(self) -> dict:
        return {"rho": [round(float(v), 5) for v in self.rho], "hidden_s": [round(float(v), 6) for v in self.hidden_s],
                "seen_by": list(self.seen_by), "tau_h_act_rate": self.rate, "tau_h_act_accel": self.accel}


def rest_jacobian(cfg: ModelConfig, q: np.ndarray) -> np.ndarray:
    """A (5n×5n) of the robot's inertia, spring and gravity at rest at q (declared inertia kept,
    every other declared effect dropped: see the module docstring)."""
    n = cfg.joints
    params = cfg.model.with_effects(tuple(e for e in cfg.model.effects if isinstance(e, Inertia)))
    model = SEAModel(params)
    x = np.zeros(5 * n)
    x[:n] = q                     # θ_m = q, θ_s = 0: a linear spring's Jacobian does not depend on θ_s
    model.at(x)
    return model.F_nom(x, np.zeros(n))


#: [s] the time step the separation is followed with (T is found to within it, then refined)
H = 2e-5


def _block(A: np.ndarray, j: int) -> np.ndarray:
    """Z of the state [δx; δτ̇; δτ̈] for a change on joint j (δτ̈ held over each step)."""
    d = A.shape[0]
    n = d // 5
    Z = np.zeros((d + 2, d + 2))
    Z[:d, :d] = A
    Z[4 * n + j, d] = 1.0          # dδτ_j/dt = δτ̇ (τ_h,act is a state whose own row in A is zero)
    Z[d, d + 1] = 1.0              # dδτ̇/dt = δτ̈
    return Z


def _start(Z: np.ndarray, r: float, a: float | None) -> tuple[np.ndarray, float]:
    """The state at the start and the time δτ̇ reaches r (0 when only the rate is declared)."""
    d = Z.shape[0] - 2
    z0 = np.zeros(d + 2)
    if a is None:
        z0[d] = r
        return z0, 0.0
    z0[d + 1] = a
    return z0, r / a


def _state_at(Z: np.ndarray, z0: np.ndarray, t1: float, t: float) -> np.ndarray:
    """[δx; δτ̇; δτ̈] at time t, exactly (block exponential)."""
    if t <= t1:
        return expm(Z * t) @ z0
    z1 = expm(Z * t1) @ z0
    z1[-1] = 0.0                   # from t1 on δτ̇ = r, held
    return expm(Z * (t - t1)) @ z1


def _counts(z: np.ndarray, n: int, dq: np.ndarray, dth: np.ndarray) -> np.ndarray:
    """Each encoder's share of the separation, in counts (rows: times; columns: n load, n motor)."""
    q = z[:, :n] + z[:, n:2 * n]
    return np.hstack([np.abs(q) / dq, np.abs(z[:, :n]) / dth])


def _hidden(Z: np.ndarray, r: float, a: float | None, n: int, dq: np.ndarray, dth: np.ndarray) -> tuple[float, int]:
    """(T, the encoder that reaches one count first, −1 for none before :data:`T_MAX`): the
    separation followed in steps of :data:`H` (e^{Z H} once; the step that reaches t1, where δτ̇
    reaches r, is cut there), the crossing then refined by bisection on the exact state."""
    z0, t1 = _start(Z, r, a)
    step = expm(Z * H)
    z, t, prev = z0.copy(), 0.0, 0.0
    while t < T_MAX:
        if t < t1 < t + H:         # the rising part ends within this step
            z = expm(Z * (t1 - t)) @ z
            z[-1] = 0.0
            prev, t = t, t1
        else:
            z = step @ z
            prev, t = t, t + H
        if _counts(z[None], n, dq, dth).max() >= 1.0:
            break
    else:
        return T_MAX, -1
    lo, hi = prev, t
    for _ in range(30):            # bisection on the first crossing of one count
        mid = 0.5 * (lo + hi)
        if _counts(_state_at(Z, z0, t1, mid)[None], n, dq, dth).max() >= 1.0:
            hi = mid
        else:
            lo = mid
    return lo, int(np.argmax(_counts(_state_at(Z, z0, t1, hi)[None], n, dq, dth)[0]))


def bound_floor(cfg: ModelConfig, rate: float | None = None, accel: float | None = None,
                q: np.ndarray | float | None = None) -> BoundFloor | None:
    """ρ_floor per joint for the wearer declared by ``rate`` (default ``estimator.tau_h_act_rate``)
    and ``accel`` (None: only the rate declared) with the arm at rest at ``q`` [rad] (default:
    the middle of ``calibration``'s working range, else 0).  None when no rate is declared (no
    change is ruled out, and none is bounded: there is no floor to state)."""
    r = float(cfg.estimator.tau_h_act_rate if rate is None else rate)
    if not np.isfinite(r) or r <= 0.0:
        return None
    if accel is not None and (not np.isfinite(accel) or accel <= 0.0):
        raise ValueError(f"accel must be a finite number > 0 [N m/s^2] or None, got {accel!r}")
    n = cfg.joints
    if q is None:
        cal = cfg.calibration
        lo, hi = getattr(cal, "q_min_deg", None), getattr(cal, "q_max_deg", None)
        q = np.radians(0.5 * (np.asarray(lo, float) + np.asarray(hi, float))) if lo is not None and hi is not None else 0.0
    qv = np.broadcast_to(np.asarray(q, dtype=float), (n,)).copy()
    A = rest_jacobian(cfg, qv)
    dq, dth = cfg.hardware.encoder_resolution(n)
    names = [f"load {i + 1}" for i in range(n)] + [f"motor {i + 1}" for i in range(n)]
    rho, hidden, seen = np.empty(n), np.empty(n), []
    for j in range(n):
        Z = _block(A, j)
        T, first = _hidden(Z, r, accel, n, dq, dth)
        z0, t1 = _start(Z, r, accel)
        rho[j] = 0.5 * abs(_state_at(Z, z0, t1, T)[4 * n + j])
        hidden[j] = T
        seen.append(names[first] if first >= 0 else "none")
    return BoundFloor(rho, hidden, tuple(seen), r, None if accel is None else float(accel))


def wearer_rate(band_hz, rms: float) -> float:
    """A bound of |dτ_h,act/dt| [N m/s] for a wearer's torque of this band [Hz] and RMS [N m]:
    2π f_max √2 RMS (a sine at the band's top with the RMS's amplitude)."""
    return float(2.0 * np.pi * float(band_hz[1]) * np.sqrt(2.0) * float(rms))


def wearer_accel(band_hz, rms: float) -> float:
    """The same for |d²τ_h,act/dt²| [N m/s²]: (2π f_max)² √2 RMS."""
    return float(2.0 * np.pi * float(band_hz[1]) * wearer_rate(band_hz, rms))


def floor_record(cfg: ModelConfig, band_hz: tuple[float, float] | None = None, rms: float | None = None) -> dict | None:
    """The floor for the calibration's report and summaries (:meth:`BoundFloor.to_dict`): for
    the declared rate the bound rests on and, given the wearer's band [Hz] and RMS [N m], also
    for the same wearer's |d²τ_h,act/dt²| ≤ (2π f_max)² √2 RMS (``band_limited``: what a filter
    that tracks τ̇_h,act could be held to; with the integrated walk and a declared
    ``tau_h_act_accel``, for that one, and ``integrated`` true: the floor of the filter's own bound).
    None without a declared rate."""
    f = bound_floor(cfg)
    if f is None:
        return None
    out = f.to_dict()
    est = cfg.estimator
    if est.integrated and est.tau_h_act_accel > 0:
        out["band_limited"] = bound_floor(cfg, accel=est.tau_h_act_accel).to_dict()
        out["integrated"] = True
    elif band_hz is not None and rms is not None and rms > 0:
        out["band_limited"] = bound_floor(cfg, accel=wearer_accel(band_hz, rms)).to_dict()
    return out


def floor_line(rec: dict | None) -> str | None:
    """The floor in plain words (one line), or None without one."""
    if not rec:
        return None
    rho = ", ".join(f"{v:.3g}" for v in rec["rho"])
    per = " (per joint)" if len(rec["rho"]) > 1 else ""
    line = (f"Tightest bound any estimator can guarantee with these encoders for the declared wearer "
            f"(|dtau_h,act/dt| <= {rec['tau_h_act_rate']:.3g} N m/s): {rho} N m{per}; a change that fast stays within "
            f"one encoder count for {1e3 * min(rec['hidden_s']):.2g} ms, so a smaller bound cannot hold for every "
            f"wearer so declared.")
    bl = rec.get("band_limited")
    if bl and rec.get("integrated"):
        line += (f" The filter tracks dtau_h,act/dt and its bound rests on |d2tau_h,act/dt2| <= {bl['tau_h_act_accel']:.3g} "
                 f"N m/s^2: for that declaration it is {', '.join(f'{v:.3g}' for v in bl['rho'])} N m.")
    elif bl:
        line += (f" For the declared band (|d2tau_h,act/dt2| <= {bl['tau_h_act_accel']:.3g} N m/s^2) it would be "
                 f"{', '.join(f'{v:.3g}' for v in bl['rho'])} N m, but the filter models the torque as a random walk "
                 f"and its bound rests on the rate alone (estimator.tau_h_act_model: integrated rests it on the band; "
                 f"docs/bounds.md §6).")
    return line
