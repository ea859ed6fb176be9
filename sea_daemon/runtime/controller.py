"""The loop's controllers: what torque to command from a measurement (the ``update`` of read → update → write).

What :class:`~sea_daemon.runtime.loop.FixedRateLoop` calls (its ``Controller`` protocol):

* :class:`ZeroTorque` — estimation only: no torque of its own.
* :class:`ScenarioController` — a scenario's controller (PID on a minimum-jerk trajectory, or the
  open-loop cosine torque of Sec. V-C), the one the daemon, the offline simulator and the
  hardware-in-the-loop session all run.
* :class:`AssistController` — assist-as-needed (``assist`` in the model YAML, docs/assist.md):
  the compensation of the exoskeleton plus assistance from the last estimate, gated by its bound.
"""
from __future__ import annotations

import dataclasses
import logging

import numpy as np

from sea_daemon.core.assist import STATES, AssistLaw
from sea_daemon.core.bounds.floor import bound_floor
from sea_daemon.core.config import ModelConfig
from sea_daemon.core.control import PID, MinJerkTrajectory, OpenLoopTorque, ReferenceTracker, StillArm, cosine_torque
from sea_daemon.core.model import SEAModel
from sea_daemon.io.scenario import PIDSpec, Scenario
from sea_daemon.io.scenario_joints import JointsOpenLoop, JointsPID


class ZeroTorque:
    """Estimation only: the loop commands no torque of its own."""

    def __init__(self, n: int):
        self._zero = np.zeros(n)

    def update(self, t, q, theta_m, estimate):
        return self._zero


class ScenarioController:
    """The scenario's controller: ``update(t, q, θ_m, estimate)`` → motor torque [N m], clipped.

    ``t`` is the hardware's sample time, a whole number k of periods since the run's first
    sample (plant time 0 of a simulated plant or of the device model; the CANopen driver's
    start-up sample is k = 0), so the controller and a simulated subject share one clock.

    * PID (``controller.type: pid``) tracks the minimum-jerk moves at t, back and forth for as
      long as the run goes, with the configuration's torque limit.
    * Open loop (``open_loop``): τ_comp + τ_des in the estimation phase, τ_comp alone before.
      τ_des is that of the interval the command acts over (``delay``: the hardware's actuation
      delay in periods) at the phase time (k + delay − ``estimation_from``)·dt.  With n joints
      (:class:`~sea_daemon.io.scenario_joints.JointsOpenLoop`) each joint has its own τ_comp and
      its own cosine τ_des; :attr:`tau_des` is then the (n,) array of the last command.

    ``estimation_from``: the sample k at which the estimation phase starts — 0 for a run of the
    estimation phase, the training length for a run of both phases, None for a training run.
    ``reference``: a trajectory the PID tracks instead of the scenario's moves.
    ``hold``: the torque already holding the arm; the controller starts bumplessly from it
    (:meth:`start`, by default at the first update).  Without it (real hardware) it is the
    nominal model's static load torque at the first sample.  After each update :attr:`q_ref`
    [rad] and :attr:`tau_des` [N m] hold what the command was computed for.
    """

    def __init__(self, sc: Scenario, cfg: ModelConfig, hold: np.ndarray | None = None, *, delay: int = 0,
                 estimation_from: int | None = 0, reference=None):
        if delay not in (0, 1):
            raise ValueError(f"delay must be 0 or 1 (the hardware's actuation delay), got {delay!r}")
        self.n = cfg.joints
        self.dt = cfg.dt
        self.delay = int(delay)
        self.estimation_from = estimation_from
        self.limit = cfg.hardware.torque_limits(self.n)           # each joint's
        self.hold = None if hold is None else np.asarray(hold, dtype=float).reshape(self.n)
        self._model = SEAModel.from_config(cfg)
        self._out = np.zeros(self.n)
        self._started = False
        self.spec = sc.controller
        self.pid: PID | None = None
        self.tracker: ReferenceTracker | None = None
        self.ol: OpenLoopTorque | None = None     # built at the start (τ_comp)
        self.still: StillArm | None = None        # the open loop on τ_comp, built at the start
        if isinstance(self.spec, JointsPID):
            # n joints (io.scenario_joints): each joint's moves, or ``reference``, with the per-joint gains
            self.traj = reference if reference is not None else self.spec.reference()
            self.tracker = ReferenceTracker(self.spec.gains, self.traj, cfg.dt, self.limit)
            self.pid = self.tracker.pid
        elif isinstance(self.spec, PIDSpec):
            tr = self.spec.trajectory
            # ``reference``: another trajectory with reference(t) -> (q, q̇, q̈) tracked by the
            # scenario's PID instead of its moves (the calibration excitation, calibrate --excitation)
            self.traj = reference if reference is not None else MinJerkTrajectory(
                np.radians(tr.q_start_deg), np.radians(tr.q_end_deg), tr.move_s, tr.moves, cyclic=True,
                hold_s=tr.hold_s)
            # the scenario's PID gains (PIDSpec is a PIDGains) on the trajectory
            self.tracker = ReferenceTracker(self.spec, self.traj, cfg.dt, self.limit)
            self.pid = self.tracker.pid
        self.q_ref = self.spec.q0
        # n joints open loop: τ_des per joint, written in place (no allocation per cycle)
        self._joints_ol = isinstance(self.spec, JointsOpenLoop)
        self._td = np.zeros(self.n)
        self.tau_des = self._td if self._joints_ol else 0.0

    def _hold(self, q) -> np.ndarray:
        if self.hold is not None:
            return self.hold
        z = np.zeros(self.n)
        # static load torque of the nominal model at rest (eq:loadsidewmotor with q̇ = q̈ = 0)
        return np.clip(self._model.load_torque(np.asarray(q, dtype=float), z, z), -self.limit, self.limit)

    def start(self, q, theta_m) -> None:
        """Start bumplessly from this measurement: the first command is the holding torque."""
        self._started = True
        u0 = self._hold(q)
        if self.tracker is not None:
            self.tracker.start(q, theta_m, u0)
        else:
            c = self.spec
            if self._joints_ol:
                # each joint's cosine (io.scenario_joints.JointsOpenLoop), τ_des of every joint in _tau_des
                self.ol = OpenLoopTorque(tau_comp=u0.copy(), amplitude=0.0, offset=0.0)
            else:
                self.ol = OpenLoopTorque(tau_comp=u0.copy(), amplitude=c.amplitude, frequency_hz=c.frequency_hz,
                                         offset=c.offset)
            self.still = StillArm(self.ol.tau_comp, self._tau_des, self.limit, self.spec.q0)

    def _tau_des(self, t: float) -> float | np.ndarray:
        """τ_des of the interval the command acts over: 0 before the estimation phase, else the
        cosine at the phase time (class docstring)."""
        k = round(t / self.dt)                    # t is k whole periods (class docstring)
        k0 = self.estimation_from
        active = k0 is not None and k + self.delay >= k0
        tp = (k - k0) * self.dt + self.delay * self.dt if active else t
        if self._joints_ol:
            c = self.spec
            for j in range(self.n):
                self._td[j] = cosine_torque(tp, c.amplitude[j], c.frequency_hz[j], c.offset[j]) if active else 0.0
            return self._td
        return self.ol.tau_des(tp, active=active)

    def update(self, t: float, q, theta_m, estimate) -> np.ndarray:
        if not self._started:
            self.start(q, theta_m)
        if self.tracker is not None:
            # the PID's command is already within ±limit (the same limit): no clip needed
            self._out[:] = self.tracker.update(t, q, theta_m)
            self.q_ref = self.tracker.q_ref
        else:
            # Sec. V-C: τ_comp + τ_des, clipped
            self._out[:] = self.still.update(t)
            self.tau_des = self.still.tau_des
        return self._out


class AssistController:
    """Assist-as-needed: ``update(t, q, θ_m, estimate)`` → compensation + τ_assist [N m], clipped.

    The compensation is the nominal model's static load torque at the measured angle (what the
    configuration knows of the exoskeleton: its link's gravity and declared effects;
    ``assist.compensation: none`` leaves it out).  τ_assist is :class:`~sea_daemon.core.assist.AssistLaw`
    of the last estimate the loop passes — τ̂_h,act and its bound ρ_k — and zero while there is
    none (start-up, a latched fault) or it is not valid.  ``gain`` overrides ``assist.gain``
    (0: the exoskeleton only compensates itself, the "transparent" baseline of a task).
    ``dry_run`` overrides ``assist.dry_run``: τ_assist is computed (logged and published by the
    loop) but not commanded — the motor torque is the compensation alone.

    After each update :attr:`tau_assist` (n,) [N m], :attr:`trust` (n,) and :attr:`tau_comp`
    (n,) [N m] hold what the command was made of.  ``subject``: where a simulated subject's
    active torque τ_h,act (n,) is read (an array updated in place, e.g. the tracking subject's
    ``tau``): the effort figures of :meth:`summary` need it.
    """

    def __init__(self, cfg: ModelConfig, *, gain: float | None = None, dry_run: bool | None = None,
                 subject: np.ndarray | None = None):
        self.n = cfg.joints
        self.limit = cfg.hardware.torque_limits(self.n)           # each joint's
        a = cfg.assist if gain is None else dataclasses.replace(cfg.assist, gain=float(gain))
        if dry_run is not None:
            a = dataclasses.replace(a, dry_run=bool(dry_run))
        self.cfg = a
        self.dry_run = a.dry_run
        self.law = AssistLaw(a, self.n, cfg.dt)
        self._model = SEAModel.from_config(cfg) if a.compensation == "nominal" else None
        self._z = np.zeros(self.n)
        self._out = np.zeros(self.n)
        self.tau_comp = np.zeros(self.n)
        self.tau_assist = self.law.tau
        self.trust = self.law.trust
        self.subject = subject
        self.steps = 0                              # updates since the start (the cycles it ran)
        #: the tightest bound the encoders allow for the declared wearer, per joint [N m]
        #: (core/bounds/floor.py; None without a declared rate or without assistance)
        self.rho_floor = self._check_floor(cfg) if self.gain > 0.0 else None
        self._effort = np.zeros((self.n, 2))        # per joint Σ τ_h,act², Σ (τ_h,act + τ_assist)² (with a subject)

    def _check_floor(self, cfg: ModelConfig) -> np.ndarray | None:
        """ρ_floor per joint; a joint whose ``rho_max`` is below it can never be assisted: say so."""
        f = bound_floor(cfg)
        if f is None:
            return None
        for j in np.flatnonzero(self.law.rho_maxes < f.rho):
            logging.getLogger("sea_daemon.assist").warning(
                "assist.rho_max %.3g N m (joint %d) is below the tightest bound these encoders allow for the declared "
                "wearer (%.3g N m for |dtau_h,act/dt| <= %.3g N m/s): the assistance can never engage on that joint; "
                "raise assist.rho_max above it or declare a slower wearer (estimator.tau_h_act_rate)",
                self.law.rho_maxes[j], j + 1, f.rho[j], f.rate)
        return f.rho

    @property
    def gain(self) -> float:
        """The assistance's gain: the largest of the joints' (0: no joint is assisted)."""
        return float(self.law.gains.max())

    def update(self, t: float, q, theta_m, estimate) -> np.ndarray:
        if self._model is not None:
            self.tau_comp[:] = self._model.load_torque(np.asarray(q, dtype=float), self._z, self._z)
        if estimate is None:
            self.law.step(self._z, self._z, False)
        else:
            self.law.step(estimate.tau_h_act_hat, estimate.tau_h_act_bound, bool(estimate.valid))
        self.steps += 1
        if self.subject is not None:
            h = self.subject
            a = self.law.tau
            for j in range(self.n):
                self._effort[j, 0] += h[j] * h[j]
                self._effort[j, 1] += (h[j] + a[j]) * (h[j] + a[j])
        if self.dry_run:
            self._out[:] = self.tau_comp
        else:
            np.add(self.tau_comp, self.law.tau, out=self._out)
        np.clip(self._out, -self.limit, self.limit, out=self._out)
        return self._out

    def summary(self, cycles: int) -> dict:
        """The run's assistance figures over ``cycles`` loop cycles (docs/assist.md, "The run's
        figures"): the share of joint-cycles the assistance was engaged, the share it was
        available (the gate open: engaged or ``below_bound``) and, for the others, why not —
        ``fault`` (the controller did not run: a latched fault, no sample), ``invalid`` (no
        valid estimate), ``rho_above_max``, ``below_bound`` — with counts; the mean averaged
        bound; the effort reduction where the subject's torque is known (None otherwise, with
        the reason).  Over all joints, and the same figures per joint in ``joints``."""
        per = max(int(cycles), self.steps)
        c = self.law.counts
        law = self.law
        out = {"mode": "dry_run" if self.dry_run else ("transparent" if self.gain == 0.0 else "assist"),
               "gain": _one_or_each(law.gains), "rho_max": _one_or_each(law.rho_maxes),
               "rho_floor": None if self.rho_floor is None else _one_or_each(self.rho_floor),
               **self._figures(c.sum(axis=0), per * self.n, float(law.rho_sum.sum()), self._effort.sum(axis=0))}
        out["joints"] = [{"joint": j + 1, "gain": float(law.gains[j]), "rho_max": float(law.rho_maxes[j]),
                          **self._figures(c[j], per, float(law.rho_sum[j]), self._effort[j])} for j in range(self.n)]
        return out

    def _figures(self, c, total: int, rho_sum: float, effort) -> dict:
        """The figures of :meth:`summary` from the state counts ``c`` over ``total`` joint-cycles."""
        ran = int(c.sum())
        counts = {name: int(c[i]) for i, name in enumerate(STATES)}
        valid = ran - counts["invalid"]
        out = {"joint_cycles": total,
               "engaged_share": counts["engaged"] / total if total else 0.0,
               # the gate open: a valid estimate with ρ̄ within rho_max (engaged, or nothing certified)
               "available_share": (counts["engaged"] + counts["below_bound"]) / total if total else 0.0,
               "not_engaged": {"fault": total - ran, "invalid": counts["invalid"],
                               "rho_above_max": counts["rho_above_max"], "below_bound": counts["below_bound"]},
               "rho_avg_mean": rho_sum / valid if valid else None}
        out["effort_reduction"], out["effort_note"] = self._effort_reduction(effort)
        return out

    def _effort_reduction(self, effort) -> tuple[float | None, str]:
        """1 − RMS(τ_h,act) / RMS(τ_h,act + τ_assist) from ``effort`` = (Σ τ_h,act², Σ (τ_h,act +
        τ_assist)²): the share of the active torque the task took that the assistance gave, where
        the subject's torque is known."""
        if self.subject is None:
            return None, "not measurable in this run: the subject's torque is not known (sea-daemon bench assist measures it)"
        if self.dry_run:
            return None, "dry run: no assistance commanded"
        h, both = effort
        if not both > 0.0:
            return None, "not measurable in this run: no active torque"
        return float(1.0 - np.sqrt(h / both)), "1 - RMS(tau_h_act) / RMS(tau_h_act + tau_assist), simulated subject"


def _one_or_each(v: np.ndarray):
    """A per-joint setting for the summary: one number when every joint has it, else the list."""
    return float(v[0]) if np.all(v == v[0]) else [float(x) for x in v]


def _g(v) -> str:
    """A summary's setting (a number or one per joint) for a line."""
    return f"{v:g}" if not isinstance(v, list) else "[" + ", ".join(f"{x:g}" for x in v) + "]"


def describe_assist(a: dict) -> str:
    """One line of :meth:`AssistController.summary`: the engaged share and why it was not engaged."""
    ne = a["not_engaged"]
    why = {"rho_above_max": "the averaged bound above assist.rho_max", "invalid": "no valid estimate",
           "fault": "a fault latched or no sample", "below_bound": "the bound certified no effort"}
    parts = [f"{why[k]} {v} cycle(s)" for k, v in sorted(ne.items(), key=lambda kv: -kv[1]) if v]
    rho = a["rho_avg_mean"]
    line = (f"assistance ({a['mode']}, gain {_g(a['gain'])}) engaged {100 * a['engaged_share']:.1f} % of "
            f"{a['joint_cycles']} joint-cycles, available {100 * a['available_share']:.1f} %; not engaged: "
            + ("; ".join(parts) if parts else "never"))
    if rho is not None:
        line += f"; mean averaged bound {rho:.3g} N m (rho_max {_g(a['rho_max'])})"
    if a["effort_reduction"] is not None:
        line += f"; effort reduction {100 * a['effort_reduction']:.1f} %"
    joints = a.get("joints", [])
    if len(joints) > 1:
        line += "; per joint: " + ", ".join(_describe_joint(j, why) for j in joints)
    return line


def _describe_joint(j: dict, why: dict) -> str:
    """Joint ``j``'s part of :func:`describe_assist`: its shares and the most frequent reason it was not engaged."""
    ne = {k: v for k, v in j["not_engaged"].items() if v}
    txt = (f"joint {j['joint']} engaged {100 * j['engaged_share']:.1f} %, available "
           f"{100 * j['available_share']:.1f} %")
    if ne:
        k = max(ne, key=ne.get)
        txt += f" (mostly {why[k]})"
    if j["effort_reduction"] is not None:
        txt += f", effort reduction {100 * j['effort_reduction']:.1f} %"
    return txt
