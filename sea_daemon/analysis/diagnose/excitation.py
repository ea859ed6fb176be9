"""The motion a log holds, and which effects that motion can reveal.

An effect of the vocabulary shows in a log only through the motion that excites it: friction
through sliding in both directions (its sign flips with the velocity, which tells it from a
constant torque) and, for a Stribeck hump, over a range of speeds; a weight or a stiffness of
the limb through a range of q; an inertia through accelerations above the encoders'
quantisation noise; a torque gain or a delay through a command that varies; a spring term
through a range of deflections.  Without that motion the effect is no candidate at all: a
constant residual of a joint that never moved is whatever its static friction held, and any
effect fitted to it is a guess.

:func:`measure` reads the motion of each side (over a time mask, so a cross-validation fold
is judged on its own samples); :meth:`Excitation.missing` says, per candidate, what motion
is missing (None: the log can reveal it).

The thresholds are physical magnitudes, chosen on the development logs (the shortened passive
scenario of ``tests/diagnose_sim.py``, seeds 1–3, and the bench's ``reference_head.csv``:
every effect found there passes them with a wide margin) and evaluated on logs that chose
nothing (constant angles, a joint held still, ``inner_loop.csv``, swapped columns).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sea_daemon.analysis.sufficiency import finite

#: [rad] smallest range of an angle (joint side) that counts as motion: below it the joint
#: "hardly moves" (the statement of :func:`.summary.statements`), every effect of that angle
#: looks like a constant torque
MIN_SPAN = 0.05
#: smallest share of the samples a side must spend moving in each direction for friction
#: (its sign) to be told from a constant torque
MIN_DIRECTION_SHARE = 0.05
#: smallest share of the samples a side must spend moving at all
MIN_MOVING_SHARE = 0.10
#: a speed-dependent friction needs speeds spread over at least this ratio (90th / 10th
#: percentile of the moving samples' speed)
MIN_SPEED_RATIO = 3.0
#: RMS acceleration over its quantisation noise an inertia needs
MIN_ACC_SNR = 3.0
#: the smoothed command's standard deviation over its RMS a gain or a delay needs (a
#: constant command times κ is a constant offset)
MIN_COMMAND_VARIATION = 0.2
#: a spring term needs the deflection to span this many encoder steps (both encoders) ...
MIN_SPRING_STEPS = 10.0
#: ... and, for a curvature (cubic, stop), this share of its largest magnitude
MIN_SPRING_RANGE = 0.25


@dataclass
class SideMotion:
    """How one side (load or motor) of one joint moved over the samples measured."""

    span: float            # [rad] range of the angle
    up: float              # share of samples faster than the stick speed, positive direction
    down: float            # ... negative direction
    reversals: int         # changes of direction between moving samples
    speed_ratio: float     # 90th / 10th percentile of the moving samples' speed (0: none)
    acc_snr: float         # RMS smoothed acceleration / its quantisation noise

    @property
    def moving(self) -> float:
        return self.up + self.down

    def to_json(self) -> dict:
        return {"span_rad": finite(self.span), "moving_share": finite(self.moving),
                "positive_share": finite(self.up), "negative_share": finite(self.down),
                "reversals": int(self.reversals), "speed_ratio": finite(self.speed_ratio),
                "acceleration_snr": finite(self.acc_snr)}


@dataclass
class JointMotion:
    """One joint: both sides, the spring and the command."""

    load: SideMotion
    motor: SideMotion
    spring_span: float          # [rad] range of θ_s
    spring_max: float           # [rad] largest |θ_s|
    spring_step: float          # [rad] encoder step of θ_s (both encoders')
    spring_both_signs: bool     # θ_s takes both signs on ≥ 2 % of the samples each
    command_variation: float    # std / RMS of the smoothed command

    def to_json(self) -> dict:
        return {"load": self.load.to_json(), "motor": self.motor.to_json(),
                "spring_span_rad": finite(self.spring_span),
                "spring_span_steps": finite(self.spring_span / self.spring_step) if self.spring_step > 0 else None,
                "spring_both_signs": bool(self.spring_both_signs),
                "command_variation": finite(self.command_variation)}


class Excitation:
    """The motion of every joint of a log (:func:`measure`) and what it can reveal."""

    def __init__(self, joints: list[JointMotion]):
        self.joints = joints

    def to_json(self) -> list[dict]:
        return [j.to_json() for j in self.joints]

    def missing(self, typ: str, side: str, joint: int) -> str | None:
        """What motion a ``typ`` effect on ``side`` of ``joint`` needs and this log lacks, in
        words; None when the log has it."""
        jm = self.joints[joint]
        rule = _RULES.get(typ)
        return rule(jm, side) if rule is not None else None


# ------------------------------------------------------------------------- the rules

def _sname(side: str) -> str:
    return {"load": "the load (q)", "motor": "the motor (θ_m)"}.get(side, side)


def _moves(m: SideMotion, side: str) -> str | None:
    if m.span < MIN_SPAN:
        return f"{_sname(side)} never moves more than {m.span:.3g} rad (needs {MIN_SPAN:g} rad)"
    if m.moving < MIN_MOVING_SHARE:
        return (f"{_sname(side)} moves on {100 * m.moving:.0f} % of the samples "
                f"(needs {100 * MIN_MOVING_SHARE:.0f} %)")
    return None


def _both_ways(m: SideMotion, side: str) -> str | None:
    why = _moves(m, side)
    if why:
        return why
    if min(m.up, m.down) < MIN_DIRECTION_SHARE or m.reversals < 1:
        return (f"{_sname(side)} does not move in both directions (positive on {100 * m.up:.0f} %, negative "
                f"on {100 * m.down:.0f} % of the samples, {m.reversals} reversal(s); needs "
                f"{100 * MIN_DIRECTION_SHARE:.0f} % each way)")
    return None


def _speed_range(m: SideMotion, side: str) -> str | None:
    if m.speed_ratio < MIN_SPEED_RATIO:
        return (f"the speeds of {_sname(side)} span only {m.speed_ratio:.2g}× (needs {MIN_SPEED_RATIO:g}×: "
                "slow and fast motion)")
    return None


#: a Stribeck hump's reach in units of v_s: beyond it the hump is below e^-4 ≈ 2 % of F_s
HUMP_REACH = 2.0


def hump_unseen(vel: np.ndarray, v_stick: float, v_s: float, n_params: int, side: str) -> str | None:
    """Why a Stribeck hump of speed ``v_s`` is not identified by a side moving at ``vel``, or None.

    Only samples that move (faster than ``v_stick``: below it friction is set-valued) and are
    slower than :data:`HUMP_REACH` v_s see the hump's shape; with fewer of them than the hump has
    parameters (``n_params``: F_s, v_s) its least-squares fit is underdetermined, and F_s only
    raises the static limit of the sticking samples."""
    a = np.abs(np.asarray(vel, dtype=float))
    reach = HUMP_REACH * v_s
    seen = int(np.count_nonzero((a > v_stick) & (a < reach)))
    if seen >= n_params:
        return None
    return (f"v_s = {v_s:.3g} rad/s: {seen} samples move between the {side} side's stick speed ({v_stick:.3g} rad/s) "
            f"and {HUMP_REACH:g} v_s ({reach:.3g} rad/s), where the hump acts (needs {n_params}, one per parameter): "
            "F_s is not identified by this log, only a static limit")


def _coulomb(jm: JointMotion, side: str) -> str | None:
    return _both_ways(getattr(jm, side), side)


def _stribeck(jm: JointMotion, side: str) -> str | None:
    m = getattr(jm, side)
    return _both_ways(m, side) or _speed_range(m, side)


def _viscous(jm: JointMotion, side: str) -> str | None:
    m = getattr(jm, side)
    return _moves(m, side) or _speed_range(m, side)


def _inertia(jm: JointMotion, side: str) -> str | None:
    m = getattr(jm, side)
    return _moves(m, side) or (
        f"the accelerations of {_sname(side)} are {m.acc_snr:.2g}× their quantisation noise (needs {MIN_ACC_SNR:g}×)"
        if m.acc_snr < MIN_ACC_SNR else None)


def _load_range(jm: JointMotion, side: str) -> str | None:
    """Gravity, a limb's stiffness: a range of q."""
    return _moves(jm.load, "load")


def _both_sides_both_ways(jm: JointMotion, side: str) -> str | None:
    """A constant torque (an offset) is told from static friction only where the sides slide
    both ways (friction flips, the offset does not)."""
    return _both_ways(jm.load, "load") or _both_ways(jm.motor, "motor")


def _torque_offset(jm: JointMotion, side: str) -> str | None:
    return _both_ways(jm.motor, "motor")


def _command(jm: JointMotion, side: str) -> str | None:
    return _moves(jm.motor, "motor") or (
        f"the torque command hardly varies (standard deviation {100 * jm.command_variation:.0f} % of its RMS; needs "
        f"{100 * MIN_COMMAND_VARIATION:.0f} %): a gain or a delay of a constant command is an offset"
        if jm.command_variation < MIN_COMMAND_VARIATION else None)


def _cogging(jm: JointMotion, side: str) -> str | None:
    return _moves(jm.motor, "motor")


def _spring(jm: JointMotion, side: str) -> str | None:
    if jm.spring_step > 0 and jm.spring_span < MIN_SPRING_STEPS * jm.spring_step:
        return (f"the spring deflection θ_s spans {jm.spring_span:.3g} rad, under {MIN_SPRING_STEPS:g} encoder steps "
                f"({MIN_SPRING_STEPS * jm.spring_step:.3g} rad)")
    if jm.spring_span <= 0:
        return "the spring deflection θ_s never changes"
    return None


def _spring_curve(jm: JointMotion, side: str) -> str | None:
    why = _spring(jm, side)
    if why:
        return why
    if jm.spring_span < MIN_SPRING_RANGE * jm.spring_max:
        return (f"the spring deflection θ_s spans {jm.spring_span:.3g} rad, under {100 * MIN_SPRING_RANGE:.0f} % of "
                f"its largest {jm.spring_max:.3g} rad: a curvature is not told from a straight line there")
    return None


def _backlash(jm: JointMotion, side: str) -> str | None:
    why = _spring(jm, side)
    if why:
        return why
    if not jm.spring_both_signs:
        return "the spring deflection θ_s keeps one sign (a dead band then equals an encoder offset)"
    return None


_RULES = {
    "coulomb": _coulomb, "stribeck": _stribeck, "viscous": _viscous, "inertia": _inertia,
    "gravity": _load_range, "human_viscoelastic": _load_range, "cogging": _cogging,
    "encoder_offset": _both_sides_both_ways, "torque_offset": _torque_offset,
    "torque_scale": _command, "delay": _command,
    "spring_cubic": _spring_curve, "spring_saturation": _spring_curve, "spring_backlash": _backlash,
}


# ------------------------------------------------------------------------- measuring

def _side(angle, vel, acc, v_stick: float, acc_noise: float) -> SideMotion:
    if angle.size == 0:
        return SideMotion(0.0, 0.0, 0.0, 0, 0.0, 0.0)
    span = float(np.ptp(angle))
    up_t, down_t = vel > v_stick, vel < -v_stick
    mov = up_t | down_t
    sgn = np.sign(vel[mov])
    rev = int(np.sum(sgn[1:] != sgn[:-1])) if sgn.size > 1 else 0
    sp = np.abs(vel[mov])
    ratio = 0.0
    if sp.size >= 10:
        lo, hi = np.percentile(sp, [10, 90])
        ratio = float(hi / max(lo, v_stick)) if hi > 0 else 0.0
    acc_rms = float(np.sqrt(np.mean(acc ** 2)))
    snr = acc_rms / acc_noise if acc_noise > 0 else (math.inf if acc_rms > 0 else 0.0)
    return SideMotion(span, float(np.mean(up_t)), float(np.mean(down_t)), rev, ratio, snr)


def acceleration_noise(kin, step: float) -> float:
    """RMS [rad/s²] of the smoothed acceleration that an encoder step ``step`` [rad] alone
    makes (quantisation Δ²/12, white, through the second difference and the smoother S)."""
    L = 4 * kin.window + 3
    d = np.zeros((L, 1))
    c = L // 2
    d[c - 1, 0], d[c, 0], d[c + 1, 0] = 1.0, -2.0, 1.0
    h = kin.smooth(d / kin.dt ** 2)[:, 0]
    return float(step / math.sqrt(12.0) * np.linalg.norm(h))


def measure(kin, q: np.ndarray, theta_m: np.ndarray, v_stick: tuple[float, float], steps: dict,
            mask: np.ndarray | None = None) -> Excitation:
    """The motion of the log over ``mask`` (default every sample).

    ``q``, ``theta_m``: the angles with declared offsets removed (N, n); ``v_stick``: (load,
    motor) stick speeds [rad/s]; ``steps``: {"load": [step per joint], "motor": [...]} encoder
    steps [rad] (joint side)."""
    m = np.ones(kin.N, dtype=bool) if mask is None else np.asarray(mask, dtype=bool)
    out = []
    for j in range(kin.n):
        sl, sm = float(steps["load"][j]), float(steps["motor"][j])
        load = _side(q[m, j], kin.dq[m, j], kin.ddq[m, j], v_stick[0], acceleration_noise(kin, sl))
        motor = _side(theta_m[m, j], kin.dtheta_m[m, j], kin.ddtheta_m[m, j], v_stick[1],
                      acceleration_noise(kin, sm))
        th = (q - theta_m)[m, j]
        tau = kin.smooth(kin.tau_m[:, j:j + 1])[m, 0]
        rms = float(np.sqrt(np.mean(tau ** 2))) if tau.size else 0.0
        var = float(np.std(tau)) / rms if rms > 0 else 0.0
        both = bool(th.size and np.mean(th > 0) >= 0.02 and np.mean(th < 0) >= 0.02)
        out.append(JointMotion(load, motor, float(np.ptp(th)) if th.size else 0.0,
                               float(np.max(np.abs(th))) if th.size else 0.0, sl + sm, both, var))
    return Excitation(out)
