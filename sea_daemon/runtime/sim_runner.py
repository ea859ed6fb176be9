"""Run a scenario: the true plant in closed loop with the controller, sampled like the hardware.

Per sample k (period dt = 1/rate_hz of the nominal model config), at t_k:
 1. the encoders are read (19-bit quantisation, offsets; :mod:`.sensors`);
 2. the controller computes τ_m from the *measured* angles (PID) or from time (open loop);
 3. the row (t_k, q, θ_m, τ_m commanded, τ_h,act) is logged;
 4. the plant advances to t_{k+1} with τ_m (+ noise) and τ_h,act held.

The training phase is followed seamlessly by the estimation phase (same plant, same
controller state; time keeps running, so the estimation log starts at t = N_train·dt).
Passive scenario (Sec. V-B): the moves continue back and forth, so with the training phase a
whole number of move pairs (2100 samples = 6 moves) the estimation phase runs the same
trajectory again.  Active scenario (Sec. V-C):
τ_des = 0 in training, the cosine profile (phase time) in estimation, and the subject
holds the arm: τ_h,act = −τ_des exactly.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sea_daemon.core.control import PID, MinJerkTrajectory, OpenLoopTorque
from sea_daemon.core.log import MeasuredLog
from sea_daemon.io.scenario import OpenLoopSpec, PIDSpec, Scenario, make_plant


@dataclass
class SimResult:
    """Training and estimation logs (docs/interfaces.md §1, with ``tau_h_act`` and debug extras)."""

    training: MeasuredLog
    estimation: MeasuredLog
    tau_comp: np.ndarray | None = None


def simulate(sc: Scenario, seed: int | None = None) -> SimResult:
    """Simulate the training then the estimation phase of a scenario."""
    plant = make_plant(sc, seed)
    dt = sc.nominal.dt
    ctrl = sc.controller
    pid = traj = ol = None
    if isinstance(ctrl, PIDSpec):
        tr = ctrl.trajectory
        # cyclic: the estimation phase continues the back-and-forth moves seamlessly (with the
        # shipped 2100 = 6 moves of training it starts again at q_start: the same trajectory)
        traj = MinJerkTrajectory(np.radians(tr.q_start_deg), np.radians(tr.q_end_deg), tr.move_s, tr.moves,
                                 cyclic=True)
        pid = PID(ctrl.kp, ctrl.ki, ctrl.kd, dt, sc.nominal.hardware.torque_limit, ctrl.velocity_filter_hz,
                  derivative=ctrl.derivative)
        q_meas, th_meas = plant.measure()
        pid.reset(q_meas if ctrl.derivative == "load" else th_meas, plant.hold_torque)           # bumpless: the controller already holds the arm
    else:
        assert isinstance(ctrl, OpenLoopSpec)
        # the experimenter's calibration: the static torque holding the system at q0
        ol = OpenLoopTorque(tau_comp=plant.hold_torque.copy(), amplitude=ctrl.amplitude,
                            frequency_hz=ctrl.frequency_hz, offset=ctrl.offset)

    def run_phase(n_samples: int, estimation: bool, k0: int) -> MeasuredLog:
        cols = {k: np.empty(n_samples) for k in (
            "t", "q", "theta_m", "tau_m", "tau_h_act", "q_ref", "tau_des", "q_true", "theta_m_true",
            "dq_true", "dtheta_m_true", "tau_s_true", "tau_m_applied")}
        for k in range(n_samples):
            tp = k * dt                                 # phase time
            q_meas, th_meas = plant.measure()
            tau_des = 0.0
            if pid is not None:
                q_ref, dq_ref, _ = traj.reference((k0 + k) * dt)
                u = pid.step(q_ref, q_meas, dq_ref, th_meas)
            else:
                q_ref = ctrl.q0
                tau_des = ol.tau_des(tp, active=estimation)
                u = ol.command(tp, active=estimation)
            # Sec. V-C: the subject resists and holds the arm, τ_h,act = −τ_des
            tau_h = -tau_des if sc.human == "resist" else 0.0
            cols["t"][k] = (k0 + k) * dt
            cols["q"][k] = q_meas[0]
            cols["theta_m"][k] = th_meas[0]
            cols["tau_m"][k] = u[0]
            cols["tau_h_act"][k] = tau_h
            cols["q_ref"][k] = q_ref
            cols["tau_des"][k] = tau_des
            cols["q_true"][k] = plant.q[0]
            cols["theta_m_true"][k] = plant.theta_m[0]
            cols["dq_true"][k] = plant.dq[0]
            cols["dtheta_m_true"][k] = plant.dtheta_m[0]
            cols["tau_s_true"][k] = plant.tau_s[0]
            plant.step(u, dt, tau_h)
            cols["tau_m_applied"][k] = plant.applied_torque[0]
        base = ("t", "q", "theta_m", "tau_m", "tau_h_act")
        return MeasuredLog(t=cols["t"], q=cols["q"][:, None], theta_m=cols["theta_m"][:, None],
                           tau_m=cols["tau_m"][:, None], tau_h_act=cols["tau_h_act"][:, None],
                           extra={k: v for k, v in cols.items() if k not in base})

    train = run_phase(sc.training_samples, False, 0)
    est = run_phase(sc.estimation_samples, True, sc.training_samples)
    return SimResult(training=train, estimation=est, tau_comp=None if ol is None else ol.tau_comp)
