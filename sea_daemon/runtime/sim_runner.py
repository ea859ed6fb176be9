"""Run a scenario offline: the true plant in closed loop with the scenario's controller, sampled like the hardware.

The fixed-rate loop (:class:`~sea_daemon.runtime.loop.FixedRateLoop`, lock-step, no sleeping)
runs the :class:`~sea_daemon.runtime.controller.ScenarioController` over
:class:`sea_daemon.hw.sim_hw.SimHardware` on the scenario's plant, no estimator.  Per cycle k
(period dt = 1/rate_hz of the nominal model config), at t_k = k·dt:

1. ``read()`` steps the plant over [t_k-1, t_k] with the torque written in cycle k-1 (+ noise)
   and the subject's torque, then reads the encoders (19-bit quantisation, offsets);
2. the controller computes τ_m from the *measured* angles (PID) or from time (open loop);
3. ``write()``: τ_m is held over [t_k, t_k+1];
4. the row (t_k, q, θ_m, τ_m commanded, τ_h,act over [t_k, t_k+1], debug extras) is recorded;
   the applied torque of the interval (``tau_m_applied``) comes with the next cycle's step.

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
from sea_daemon.errors import InputError
from sea_daemon.io.scenario import Scenario, make_plant
from sea_daemon.runtime.controller import ScenarioController
from sea_daemon.runtime.loop import FixedRateLoop
from sea_daemon.runtime.recorder import PhaseRecorder

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
    rec = PhaseRecorder(rows, cfg.joints, EXTRA)
    c = rec.cols

    def record(k, m, est, tau) -> None:
        if k:
            c["tau_m_applied"][k - 1] = plant.applied_torque   # this cycle's read stepped [t_k-1, t_k]
        if k == rows:
            return                                            # the read that only steps the last row's interval
        c["t"][k] = m.t
        c["q"][k] = m.q
        c["theta_m"][k] = m.theta_m
        c["tau_m"][k] = tau
        c["tau_h_act"][k] = subject(m.t)
        c["q_ref"][k] = ctl.q_ref
        c["tau_des"][k] = ctl.tau_des
        c["q_true"][k] = plant.q
        c["theta_m_true"][k] = plant.theta_m
        c["dq_true"][k] = plant.dq
        c["dtheta_m_true"][k] = plant.dtheta_m
        c["tau_s_true"][k] = plant.tau_s

    loop = FixedRateLoop(hw, None, ctl, cfg.joints, cfg.dt, realtime=False, on_cycle=record, fail_fast=True)
    hw.start(initial_torque=plant.hold_torque)
    try:
        loop.run(rows + 1)
    finally:
        hw.stop()
    train, est = rec.phases(n_train)
    return SimResult(training=train, estimation=est, tau_comp=None if ctl.ol is None else ctl.ol.tau_comp)
