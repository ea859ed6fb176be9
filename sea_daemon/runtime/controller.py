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

import numpy as np

from sea_daemon.core.assist import AssistLaw
from sea_daemon.core.config import ModelConfig
from sea_daemon.core.control import PID, MinJerkTrajectory, OpenLoopTorque, ReferenceTracker, StillArm
from sea_daemon.core.model import SEAModel
from sea_daemon.io.scenario import PIDSpec, Scenario


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
      delay in periods) at the phase time (k + delay − ``estimation_from``)·dt.

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
        self.limit = cfg.hardware.torque_limit
        self.hold = None if hold is None else np.asarray(hold, dtype=float).reshape(self.n)
        self._model = SEAModel.from_config(cfg)
        self._out = np.zeros(self.n)
        self._started = False
        self.spec = sc.controller
        self.pid: PID | None = None
        self.tracker: ReferenceTracker | None = None
        self.ol: OpenLoopTorque | None = None     # built at the start (τ_comp)
        self.still: StillArm | None = None        # the open loop on τ_comp, built at the start
        if isinstance(self.spec, PIDSpec):
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
        self.tau_des = 0.0

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
            self.ol = OpenLoopTorque(tau_comp=u0.copy(), amplitude=c.amplitude, frequency_hz=c.frequency_hz,
                                     offset=c.offset)
            self.still = StillArm(self.ol.tau_comp, self._tau_des, self.limit, self.spec.q0)

    def _tau_des(self, t: float) -> float:
        """τ_des of the interval the command acts over: 0 before the estimation phase, else the
        cosine at the phase time (class docstring)."""
        k = round(t / self.dt)                    # t is k whole periods (class docstring)
        k0 = self.estimation_from
        active = k0 is not None and k + self.delay >= k0
        tp = (k - k0) * self.dt + self.delay * self.dt if active else t
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

    After each update :attr:`tau_assist` (n,) [N m], :attr:`trust` (n,) and :attr:`tau_comp`
    (n,) [N m] hold what the command was made of.
    """

    def __init__(self, cfg: ModelConfig, *, gain: float | None = None):
        self.n = cfg.joints
        self.limit = cfg.hardware.torque_limit
        a = cfg.assist if gain is None else dataclasses.replace(cfg.assist, gain=float(gain))
        self.cfg = a
        self.law = AssistLaw(a, self.n, cfg.dt)
        self._model = SEAModel.from_config(cfg) if a.compensation == "nominal" else None
        self._z = np.zeros(self.n)
        self._out = np.zeros(self.n)
        self.tau_comp = np.zeros(self.n)
        self.tau_assist = self.law.tau
        self.trust = self.law.trust

    @property
    def gain(self) -> float:
        return self.law.gain

    def update(self, t: float, q, theta_m, estimate) -> np.ndarray:
        if self._model is not None:
            self.tau_comp[:] = self._model.load_torque(np.asarray(q, dtype=float), self._z, self._z)
        if estimate is None:
            self.law.step(self._z, self._z, False)
        else:
            self.law.step(estimate.tau_h_act_hat, estimate.tau_h_act_bound, bool(estimate.valid))
        np.add(self.tau_comp, self.law.tau, out=self._out)
        np.clip(self._out, -self.limit, self.limit, out=self._out)
        return self._out
