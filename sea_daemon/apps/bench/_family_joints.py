"""A family of random two-joint (shoulder–elbow) exoskeleton plants and their test sessions.

:func:`draw_plant_joints` (seeded) draws one plant around ``configs/exo_2dof.yaml``:

* the robot the user declares: the example's URDF (exoskeleton links and the wearer's arm from
  anthropometric tables) with its SEA part per joint (J, D_m, K_s, D_s) each ±30 %;
* the true plant: that robot with every link's mass and length ±30 %
  (:func:`sea_daemon.core.rigid.random_factors`: the arm is not the tables' arm, the
  exoskeleton's links are not the CAD's) and hidden effects per joint from the vocabulary
  (load viscous and Coulomb friction on each joint, sometimes Stribeck friction, the elbow
  tissue's viscoelasticity, motor friction, a torque-constant error);
* hardware: encoder resolution 16–20 bit, motor-torque noise 0.005–0.05 N m;
* the declared working range per joint and the human-torque band.

:func:`sessions_joints` lists the test sessions of a plant, unlike its calibration (the
one-joint family's kinds, on both joints at once): slow and fast moves, wider ranges (8° past
the declared ones, clear of the end stops), sines about the ranges' middles, active subjects on
both joints (0.1–0.5 and 0.5–3 Hz) while moving, and still-arm active sessions (Sec. V-C: the
cosine on both joints, and a band-limited torque; the subject also holds the arm, :data:`HOLD`).
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from sea_daemon.apps.bench._family import PlantDraw, SessionSpec, one_direction_motion
from sea_daemon.apps.calibration.joints import plant_substep
from sea_daemon.core.effects import make_effect
from sea_daemon.core.excitation import PerJoint, WorkingRange, excitation_joints, paper_moves
from sea_daemon.core.rigid import random_factors
from sea_daemon.core.sim.session import BandLimitedTorque, SineReference, run_session
from sea_daemon.io.configfile import data_root, load_config

#: the joints' declared working ranges [deg] (shoulder flexion, elbow flexion) before the draw
RANGE_DEG = ((10.0, 80.0), (20.0, 110.0))
#: the revision of :func:`sessions_joints`' definitions: cached logs of another revision are simulated again
#: (2: ``sines`` swings about the middle of each joint's range; 3: the still-arm subject holds the arm, :data:`HOLD`)
SESSIONS_REV = 3
#: the still-arm sessions' subject holds the arm where it started [N m/rad, N m s/rad] (a relaxed
#: arm's stiffness and damping; ``run_session``'s ``hold``): without it an open-loop two-joint arm
#: can drift into its end stops
HOLD = (20.0, 2.0)


def _u(rng, lo, hi):
    return float(rng.uniform(lo, hi))


def draw_plant_joints(seed: int, rate_hz: float | None = None) -> PlantDraw:
    """Draw two-joint plant ``seed`` (deterministic; 100 Hz unless ``rate_hz``); its
    ``working_range`` is one :class:`WorkingRange` per joint."""
    rng = np.random.default_rng(30_000 + seed)
    base = load_config(data_root() / "configs" / "exo_2dof.yaml")
    rate_hz = 100.0 if rate_hz is None else float(rate_hz)
    p = base.model
    n = base.joints
    sc = {k: rng.uniform(0.7, 1.3, n) for k in ("J", "D_m", "K_s", "D_s")}
    model = dataclasses.replace(p, J=p.J * np.diag(sc["J"]), D_m=p.D_m * np.diag(sc["D_m"]),
                                K_s=p.K_s * np.diag(sc["K_s"]), D_s=p.D_s * np.diag(sc["D_s"]), effects=())
    bits = int(rng.integers(16, 21))
    tn = float(math.exp(rng.uniform(math.log(0.005), math.log(0.05))))
    hw = dataclasses.replace(base.hardware, encoder_bits=bits, torque_noise=tn)
    nominal = dataclasses.replace(base, rate_hz=rate_hz, model=model, hardware=hw,
                                  source=f"<two-joint family plant {seed}>")
    mass, length = random_factors(p.rigid.urdf, rng, 0.3)
    eff = []
    for j in range(n):
        eff.append(make_effect("viscous", "load", joint=j, b=_u(rng, 0.05, 0.4)))
        if rng.random() < 0.9:
            eff.append(make_effect("coulomb", "load", joint=j, F_c=_u(rng, 0.1, 0.5)))
        if rng.random() < 0.3:
            eff.append(make_effect("stribeck", "load", joint=j, F_s=_u(rng, 0.05, 0.2), v_s=_u(rng, 0.03, 0.15)))
        if rng.random() < 0.3:
            eff.append(make_effect("coulomb", "motor", joint=j, F_c=_u(rng, 0.02, 0.1)))
        if rng.random() < 0.2:
            eff.append(make_effect("torque_scale", "motor", joint=j, kappa=_u(rng, 0.93, 1.07)))
    if rng.random() < 0.6:      # the elbow's tissue
        eff.append(make_effect("human_viscoelastic", "load", joint=n - 1, k_h=_u(rng, 0.3, 2.0),
                               q_h0=_u(rng, 0.8, 1.6), b_h=_u(rng, 0.05, 0.3)))
    true = dataclasses.replace(nominal, model=nominal.model.with_rigid(p.rigid.scaled(mass=mass, length=length))
                               .with_effects(tuple(eff)))
    wrs = []
    for lo, hi in RANGE_DEG:
        wrs.append(WorkingRange(math.radians(lo + _u(rng, -5.0, 5.0)), math.radians(hi + _u(rng, -10.0, 5.0)),
                                v_max=_u(rng, 1.0, 1.6), a_max=_u(rng, 6.0, 12.0)))
    summary = {"seed": seed, "rate_hz": rate_hz, "encoder_bits": bits, "torque_noise": round(tn, 4),
               "joints": n, "sea_scale": {k: [round(float(x), 3) for x in v] for k, v in sc.items()},
               "link_mass": {k: round(v, 3) for k, v in mass.items()},
               "link_length": {k: round(v, 3) for k, v in length.items()},
               "effects": [f"{e.type}({e.side})[{e.joint + 1}]" for e in eff], "outside_vocabulary": [],
               "range_deg": [[round(math.degrees(w.q_min), 1), round(math.degrees(w.q_max), 1)] for w in wrs],
               "v_max": [round(w.v_max, 2) for w in wrs]}
    return PlantDraw(seed, nominal, true, wrs, (0.1, 3.0), 1.5, tn, summary)


def calibration_motion_joints(pd: PlantDraw, duration_s: float = 60.0, seed: int = 0) -> PerJoint:
    """The calibration excitation over each joint's declared working range (:func:`excitation_joints`)."""
    return excitation_joints(pd.working_range, duration_s, seed=seed)


class _Torques:
    """τ_h,act (n,) from one torque profile per joint."""

    def __init__(self, parts):
        self.parts = parts
        self.out = np.zeros(len(parts))

    def __call__(self, t: float) -> np.ndarray:
        for j, p in enumerate(self.parts):
            self.out[j] = p(t)
        return self.out


def _cosine(t: float) -> float:
    """The paper's still-arm subject: τ_h,act = −τ_des, τ_des = −2 cos(2π 0.1 t) + 2 [N m]."""
    return -(-2.0 * math.cos(2 * math.pi * 0.1 * t) + 2.0)


def sessions_joints(pd: PlantDraw, duration_s: float | None = None) -> list[SessionSpec]:
    """The test sessions of a two-joint plant (seeded by the plant's seed): none repeats the calibration."""
    rng = np.random.default_rng(40_000 + pd.seed)
    wrs = pd.working_range
    T = duration_s if duration_s is not None else (20.0 if pd.nominal.rate_hz <= 200 else 12.0)
    d = math.radians
    mid = [0.5 * (w.q_min + w.q_max) for w in wrs]

    def moves(share_v: float, lo_s: float, hi_s: float, widen: float = 0.0, accel: float | None = None):
        parts = []
        for w in wrs:
            a, b = w.q_min + lo_s * w.width - widen, w.q_max - hi_s * w.width + widen
            mv = 1.875 * (b - a) / (share_v * w.v_max)
            if accel is not None:
                mv = max(mv, math.sqrt(5.774 * (b - a) / (accel * w.a_max)))
            parts.append(paper_moves(a, b, max(mv, 2.0) if accel is None else mv, 100))
        return PerJoint(tuple(parts))
    out = [SessionSpec("slow", T, moves(0.3, 0.1, 0.25), None, None, "passive"),
           SessionSpec("fast", T, moves(1.1, 0.15, 0.1, accel=1.2), None, None, "passive"),
           SessionSpec("wide", T, moves(0.6, 0.0, 0.0, widen=d(8)), None, None, "passive")]
    sines = []
    for j, w in enumerate(wrs):
        amp = 0.3 * w.width
        f1 = 0.6 * w.v_max / (2 * math.pi * amp)
        ph = (float(rng.uniform(0, 6.28)), float(rng.uniform(0, 6.28)))
        # the sines swing about the range's middle (SineReference starts at its centre and swings
        # about centre − Σ a sin φ): within mid ± 1.25 amp, inside the declared range and clear of the stops
        c = mid[j] + amp * math.sin(ph[0]) + 0.25 * amp * math.sin(ph[1])
        sines.append(SineReference(c, (amp, 0.25 * amp), (f1, 2.7 * f1), ph))
    out.append(SessionSpec("sines", T, PerJoint(tuple(sines)), None, None, "passive"))
    slow = PerJoint(tuple(SineReference(mid[j], (0.25 * w.width,), (0.12 + 0.03 * j,), (0.0,))
                             for j, w in enumerate(wrs)))
    s = pd.seed * 10
    out.append(SessionSpec("active_low", T, slow, None, _Torques(
        [BandLimitedTorque(pd.human_rms, 0.1, 0.5, seed=s + 1 + 100 * j) for j in range(len(wrs))]), "active"))
    out.append(SessionSpec("active_high", T, slow, None, _Torques(
        [BandLimitedTorque(0.7 * pd.human_rms, 0.5, 3.0, seed=s + 2 + 100 * j) for j in range(len(wrs))]), "active"))
    q0 = np.array([w.q_min + float(rng.uniform(0.1, 0.4)) * w.width for w in wrs])
    out.append(SessionSpec("still_cosine", T, None, q0, _Torques([_cosine] * len(wrs)), "still"))
    out.append(SessionSpec("still_band", T, None, q0 + 0.3 * np.array([w.width for w in wrs]), _Torques(
        [BandLimitedTorque(pd.human_rms, 0.3, 3.0, seed=s + 3 + 100 * j) for j in range(len(wrs))]), "still"))
    return out


# --------------------------------------------------------------- degenerate calibrations of two joints

#: the two-joint degenerate calibration logs: one joint frozen (held still by the drive at
#: mid-range while the other runs the calibration excitation), one joint moving one way only,
#: and a short log of the excitation on both joints
DEGENERATE_JOINTS = ("frozen_elbow", "frozen_shoulder", "one_direction_elbow", "short")
#: lengths [s] of the short log and of the others
SHORT_JOINTS_S, DEGENERATE_JOINTS_S = 3.0, 21.0


def degenerate_calibration_joints(pd: PlantDraw, case: str, cal_s: float = DEGENERATE_JOINTS_S):
    """(log, what it is in one line) of two-joint degenerate case ``case`` (one of
    :data:`DEGENERATE_JOINTS`, or ``full``: the calibration excitation on both joints for
    ``cal_s`` s, for comparison) of plant ``pd``: passive (τ_h,act = 0), seeded by the plant's seed."""
    wrs = pd.working_range
    mids = [0.5 * (w.q_min + w.q_max) for w in wrs]
    dur = SHORT_JOINTS_S if case == "short" else cal_s
    exc = calibration_motion_joints(pd, dur, seed=pd.seed).joints
    parts, what = list(exc), ""
    if case in ("frozen_elbow", "frozen_shoulder"):
        j = 1 if case == "frozen_elbow" else 0
        parts[j] = SineReference(mids[j], (), (), ())
        what = f"joint {j + 1} held still at {math.degrees(mids[j]):.0f} deg, the other moving, {dur:g} s"
    elif case == "one_direction_elbow":
        parts[1] = one_direction_motion(wrs[1], dur)
        what = (f"joint 2 from {math.degrees(wrs[1].q_min):.0f} to {math.degrees(wrs[1].q_max):.0f} deg, never back, "
                f"the other moving, {dur:g} s")
    elif case == "short":
        what = f"the calibration excitation on both joints for {dur:g} s"
    elif case == "full":        # not degenerate: the comparison (bench generalize --cases full)
        what = f"the calibration excitation on both joints for {dur:g} s (not degenerate)"
    else:
        raise ValueError(f"degenerate_calibration_joints: unknown case {case!r}; one of {', '.join(DEGENERATE_JOINTS)}")
    log = run_session(pd.true, dur, reference=PerJoint(tuple(parts)), seed=5000 + pd.seed,
                      substep_hz=plant_substep(pd.true, 3e-3, pd.nominal.rate_hz))
    return log, what
