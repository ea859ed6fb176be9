"""Run a scenario offline: the true plant in closed loop with the scenario's controller, sampled like the hardware.

The fixed-rate loop (:class:`~sea_daemon.runtime.loop.FixedRateLoop`, lock-step, no sleeping)
runs the :class:`~sea_daemon.runtime.controller.ScenarioController` over
:class:`sea_daemon.hw.sim_hw.SimHardware` on the scenario's plant, no estimator.  Per cycle k
(period dt = 1/rate_hz of the nominal model config), at t_k = k·dt:

1. ``read()`` steps the plant over [t_k-1, t_k] with the torque written in cycle k-1 (+ noise)
   and the subject's torque, then reads the encoders (19-bit quantisation, offsets);
2. the controller computes τ_m from the *measured* angles (PID) or from time (open loop);
3. ``write()``: τ_m is held over [t_k, t_k+1];
4. the row (t_k, q, θ_m, τ_m commanded, debug extras) is recorded; what acted over
   [t_k, t_k+1] — τ_h,act and the applied torque (``tau_m_applied``) — comes with the next
   cycle's step.

These are the steps of every simulated run (:mod:`sea_daemon.core.sim.sampling`): SimHardware
reads through its :class:`~sea_daemon.core.sim.sampling.SampledPlant`, the rows go into a
:class:`~sea_daemon.core.sim.sampling.SampleRecorder`, and the scenario's controller runs the
core's :class:`~sea_daemon.core.control.ReferenceTracker` / :class:`~sea_daemon.core.control.StillArm`,
as :func:`sea_daemon.core.sim.session.run_session` does without the daemon's loop.

The training phase is followed seamlessly by the estimation phase (same plant, same
controller state; time keeps running, so the estimation log starts at t = N_train·dt).
Passive scenario (Sec. V-B): the moves continue back and forth, so with the training phase a
whole number of move pairs (2100 samples = 6 moves) the estimation phase runs the same
trajectory again.  Active scenario (Sec. V-C): τ_des = 0 in training, the cosine profile
(phase time) in estimation, and the subject holds the arm: τ_h,act = −τ_des exactly.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sea_daemon.hw.sim_hw import SimHardware
from sea_daemon.core.log import MeasuredLog
from sea_daemon.core.sim.sampling import SampleRecorder
from sea_daemon.errors import InputError
from sea_daemon.io.scenario import Scenario, make_plant
from sea_daemon.io.scenario_joints import simulate_joints
from sea_daemon.runtime.controller import ScenarioController
from sea_daemon.runtime.loop import FixedRateLoop

#: debug extras of the simulator's logs (the readers of docs/interfaces.md §1 ignore them)
EXTRA = ("q_ref", "tau_des", "q_true", "theta_m_true", "dq_true", "dtheta_m_true", "tau_s_true", "tau_m_applied")


@dataclass
class SimResult:
    """Training and estimation logs (docs/interfaces.md §1, with ``tau_h_act`` and debug extras)."""

    training: MeasuredLog
    estimation: MeasuredLog
    tau_comp: np.ndarray | None = None


def simulate(sc: Scenario, seed: int | None = None) -> SimResult:
    """Simulate the training then the estimation phase of a scenario."""
    if sc.human == "track":
        raise InputError(f"scenario {sc.source}: human 'track' (a subject that reacts to the exoskeleton) runs "
                         "with the assist controller: sea-daemon run --device-model / --sim (docs/assist.md)")
    if sc.nominal.joints > 1:         # n joints: the session of io.scenario_joints
        training, estimation = simulate_joints(sc, seed)
        return SimResult(training=training, estimation=estimation)
    plant = make_plant(sc, seed)
    cfg = sc.nominal
    n_train = sc.training_samples
    rows = n_train + sc.estimation_samples
    ctl = ScenarioController(sc, cfg, plant.hold_torque, estimation_from=n_train)
    resist = sc.human == "resist"

    def subject(t: float) -> float:
        # Sec. V-C: the subject resists and holds the arm, τ_h,act = −τ_des of the same interval
        return -ctl.tau_des if resist else 0.0

    hw = SimHardware(plant, cfg.dt, torque_limit=cfg.hardware.torque_limit, tau_h_act=subject)
    rec = SampleRecorder(rows, cfg.joints, EXTRA)

    def record(k, m, est, tau) -> None:
        rec.acted(hw.sampled)                                 # this cycle's read stepped [t_k-1, t_k]
        if k < rows:                                          # the last read only steps the last row's interval
            rec.sample(k, m.t, m.q, m.theta_m, tau, hw.sampled, ctl)

    loop = FixedRateLoop(hw, None, ctl, cfg.joints, cfg.dt, realtime=False, on_cycle=record, fail_fast=True)
    hw.start(initial_torque=plant.hold_torque)
    try:
        loop.run(rows + 1)
    finally:
        hw.stop()
    train, est = rec.phases(n_train)
    return SimResult(training=train, estimation=est, tau_comp=None if ctl.ol is None else ctl.ol.tau_comp)
