"""Scenario files of n joints (a model YAML with ``model.urdf``): per-joint values and the true arm.

A scenario of an n-joint model is a scenario file (:mod:`sea_daemon.io.scenario`) whose
per-joint values are numbers (the same for every joint) or lists of n values, and whose true
plant may differ from the description in its links' masses and lengths::

    model: ../exo_2dof.yaml
    human: passive                 # passive | resist (controller open_loop: the still arm, Sec. V-C)
    plant:
      substep_hz: 4000
      links:                       # the true arm: each named URDF link's mass and length x factor
        mass: {human_upper_arm: 1.2, human_forearm_hand: 0.85}
        length: {human_forearm_hand: 1.08}
      effects:                     # hidden effects, each with its joint (1..n)
        - {type: viscous, side: load, b: 0.3, joint: 1}
    controller:
      type: pid
      kp: [150.0, 80.0]            # per joint
      ki: [100.0, 60.0]
      kd: [8.0, 4.0]
      trajectory: {q_start_deg: [20, 30], q_end_deg: [70, 100], move_s: [3.5, 2.5], moves: 6}
    # controller: {type: open_loop, q0_deg: [40, 60],
    #              tau_des: {amplitude: [2.0, 1.0], frequency_hz: [0.1, 0.15], offset: [2.0, 1.0]}}

Each joint's trajectory runs its own minimum-jerk moves back and forth (its own duration
``move_s``, holds of ``hold_s`` after each move): joints with different durations move in ever
new combinations.  :func:`simulate_joints` runs the training then the estimation phase as one
session of the true plant (:func:`sea_daemon.core.sim.session.run_session`: the PID on every
joint, or the still-arm open loop τ_m = τ_comp + τ_des with the subject resisting on every
joint, τ_h,act = −τ_des, in the estimation phase).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from sea_daemon.core.control import PIDGains, cosine_torque
from sea_daemon.core.excitation import PerJoint, MoveSequence
from sea_daemon.core.log import MeasuredLog
from sea_daemon.core.rigid import link_masses
from sea_daemon.core.sim.session import run_session
from sea_daemon.core.validate import check_keys, vector
from sea_daemon.errors import ConfigError

#: the true arm's factors: allowed range of a link's mass or length factor
FACTOR_RANGE = (0.1, 10.0)


def links_from_dict(d: Any, urdf: str | None, source: str) -> tuple[tuple, tuple]:
    """``plant.links``: ((link, mass factor), ...), ((link, length factor), ...) for a URDF model."""
    if urdf is None:
        raise ConfigError(source, "plant.links", "needs a model with model.urdf (the links it scales)")
    if not isinstance(d, Mapping):
        raise ConfigError(source, "plant.links", f"must be a mapping with mass and/or length, got {d!r}")
    check_keys(source, "plant.links.", d, ["mass", "length"], [])
    names = sorted(link_masses(urdf, source))
    out = []
    for key in ("mass", "length"):
        m = d.get(key) or {}
        if not isinstance(m, Mapping):
            raise ConfigError(source, f"plant.links.{key}", f"must map link names to factors, got {m!r}")
        pairs = []
        for name, v in m.items():
            if name not in names:
                raise ConfigError(source, f"plant.links.{key}.{name}", f"no such link with a mass; allowed: "
                                                                      f"{', '.join(names)}")
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not FACTOR_RANGE[0] <= v <= FACTOR_RANGE[1]:
                raise ConfigError(source, f"plant.links.{key}.{name}",
                                  f"must be a factor in {FACTOR_RANGE[0]:g}..{FACTOR_RANGE[1]:g}, got {v!r}")
            pairs.append((str(name), float(v)))
        out.append(tuple(pairs))
    return out[0], out[1]


@dataclass(frozen=True)
class JointsPID:
    """The PID of n joints and each joint's back-and-forth moves (angles in degrees)."""

    gains: PIDGains
    q_start_deg: tuple
    q_end_deg: tuple
    move_s: tuple
    hold_s: tuple
    moves: int
    type: str = "pid"

    @property
    def q0(self) -> np.ndarray:
        return np.radians(self.q_start_deg)

    def reference(self) -> PerJoint:
        """Each joint's minimum-jerk moves, cyclic (:class:`~sea_daemon.core.excitation.MoveSequence`)."""
        parts = []
        for a, b, T, h in zip(np.radians(self.q_start_deg), np.radians(self.q_end_deg), self.move_s, self.hold_s):
            k = 2 * max(1, self.moves // 2)
            targets = tuple(float(b) if i % 2 == 0 else float(a) for i in range(k))
            parts.append(MoveSequence(float(a), targets, (float(T),) * k, (float(h),) * k, cyclic=True))
        return PerJoint(tuple(parts))


@dataclass(frozen=True)
class JointsOpenLoop:
    """The still-arm open loop of n joints: held at ``q0_deg``, τ_des per joint (Sec. V-C)."""

    q0_deg: tuple
    amplitude: tuple
    frequency_hz: tuple
    offset: tuple
    type: str = "open_loop"

    @property
    def q0(self) -> np.ndarray:
        return np.radians(self.q0_deg)

    def tau_des(self, t: float) -> np.ndarray:
        return np.array([cosine_torque(t, a, f, o) for a, f, o in zip(self.amplitude, self.frequency_hz, self.offset)])


def _vec(source: str, key: str, v: Any, n: int, **kw) -> tuple:
    return tuple(float(x) for x in vector(source, key, v, n, **kw))


def _angles(source: str, key: str, v: Any, n: int) -> tuple:
    out = _vec(source, key, v, n)
    bad = [x for x in out if not -360.0 <= x <= 360.0]
    if bad:
        raise ConfigError(source, key, f"must be angles in -360..360 deg, got {v!r}")
    return out


def controller_from_dict(d: Mapping, n: int, source: str) -> JointsPID | JointsOpenLoop:
    """``controller`` of an n-joint scenario (per-joint values: a number or a list of n)."""
    typ = d.get("type")
    if typ == "pid":
        check_keys(source, "controller.", d, ["type", "kp", "ki", "kd", "velocity_filter_hz", "derivative",
                                              "trajectory"], ["type", "kp", "ki", "kd", "trajectory"])
        der = d.get("derivative", "motor")
        if der not in ("motor", "load"):
            raise ConfigError(source, "controller.derivative", f"{der!r} is not allowed; allowed: motor, load")
        gains = PIDGains(*(np.array(_vec(source, f"controller.{k}", d[k], n, non_negative=True))
                           for k in ("kp", "ki", "kd")),
                         velocity_filter_hz=float(vector(source, "controller.velocity_filter_hz",
                                                         d.get("velocity_filter_hz", 20.0), 1, positive=True)[0]),
                         derivative=der)
        tr = d["trajectory"]
        p = "controller.trajectory."
        check_keys(source, p, tr, ["q_start_deg", "q_end_deg", "move_s", "moves", "hold_s"],
                   ["q_start_deg", "q_end_deg", "move_s", "moves"])
        moves = tr["moves"]
        if isinstance(moves, bool) or not isinstance(moves, int) or not 1 <= moves <= 100000:
            raise ConfigError(source, p + "moves", f"must be an integer in 1..100000, got {moves!r}")
        return JointsPID(gains, _angles(source, p + "q_start_deg", tr["q_start_deg"], n),
                         _angles(source, p + "q_end_deg", tr["q_end_deg"], n),
                         _vec(source, p + "move_s", tr["move_s"], n, positive=True),
                         _vec(source, p + "hold_s", tr.get("hold_s", 0.0), n, non_negative=True), moves)
    if typ == "open_loop":
        check_keys(source, "controller.", d, ["type", "q0_deg", "tau_des"], ["type", "q0_deg", "tau_des"])
        td = d["tau_des"]
        keys = ["amplitude", "frequency_hz", "offset"]
        check_keys(source, "controller.tau_des.", td, keys, keys)
        return JointsOpenLoop(_angles(source, "controller.q0_deg", d["q0_deg"], n),
                              _vec(source, "controller.tau_des.amplitude", td["amplitude"], n),
                              _vec(source, "controller.tau_des.frequency_hz", td["frequency_hz"], n, positive=True),
                              _vec(source, "controller.tau_des.offset", td["offset"], n))
    raise ConfigError(source, "controller.type", f"unknown controller type {typ!r}; allowed: pid, open_loop")


def simulate_joints(sc, seed: int | None = None) -> tuple[MeasuredLog, MeasuredLog]:
    """(training log, estimation log) of an n-joint scenario ``sc`` (module docstring)."""
    cfg = sc.nominal
    n_train, n_est = sc.training_samples, sc.estimation_samples
    dt = cfg.dt
    T = (n_train + n_est) * dt
    seed = sc.seed if seed is None else seed
    ctl = sc.controller
    kw = dict(seed=seed, substep_hz=sc.plant.substep_hz, sign_eps=sc.plant.sign_eps,
              torque_noise=sc.plant.torque_noise)
    t_est = n_train * dt
    try:
        if isinstance(ctl, JointsPID):
            log = run_session(sc.true_config(), T, reference=ctl.reference(), gains=ctl.gains, **kw)
        else:
            zero = np.zeros(cfg.joints)

            def subject(t: float) -> np.ndarray:
                # Sec. V-C: the subject resists and holds the arm, τ_h,act = −τ_des (estimation phase only)
                return -ctl.tau_des(t - t_est) if sc.human == "resist" and t >= t_est - 1e-9 else zero
            log = run_session(sc.true_config(), T, hold_q=ctl.q0, human=subject, **kw)
    except ValueError as e:
        raise ConfigError(sc.source, "plant.substep_hz", str(e)) from None
    return log.slice(0, n_train), log.slice(n_train, n_train + n_est)


def check_human(source: str, human: str, controller) -> None:
    """The subject modes an n-joint scenario allows with its controller (one line naming them)."""
    allowed = ("passive",) if isinstance(controller, JointsPID) else ("passive", "resist")
    if human not in allowed:
        raise ConfigError(source, "human", f"{human!r} with controller.type {controller.type} of {len(np.ravel(controller.q0))} "
                                           f"joints is not allowed; allowed: {', '.join(allowed)}")
