"""A simulator scenario run through the CAN stack: device model ↔ bus ↔ CanopenHardware.

:func:`run_scenario` is the hardware-in-the-loop twin of :func:`sea_daemon.runtime.sim_runner.simulate`:
the scenario's true plant and subject live in the device model (lock-step with SYNC), the
scenario's controller runs on the daemon side on what ``read()`` returns, and the torques go
back as RPDOs.  It returns the training (calibration, passive phase) and estimation logs in the
measured-log shape (docs/interfaces.md §1), so every estimator and ``replay`` can use them; with ``estimator`` given,
the estimator also runs online in the cycle, as the daemon runs it.

Timing (see :mod:`drivers.interface`): row k of the log carries the torque acting over
[t_k, t_k+1] — the command of cycle k-1 with a synchronous RPDO (``hw.actuation_delay`` = 1),
of cycle k without — and the estimator is updated in cycle k, after the write, with that torque.
"""
from __future__ import annotations

import dataclasses
import time
import uuid
from dataclasses import dataclass, field

import numpy as np

from sea_daemon.core.control import PID, MinJerkTrajectory, OpenLoopTorque
from sea_daemon.core.log import MeasuredLog
from sea_daemon.io.scenario import make_plant
from sea_daemon.io.scenario import PIDSpec

from drivers.bus import make_bus
from drivers.canopen_hw import CanopenHardware
from drivers.device_model import DeviceModel
from sea_daemon.io.scenario import human_torque


@dataclass
class HilResult:
    training: MeasuredLog
    estimation: MeasuredLog
    cycle_s: np.ndarray = field(default_factory=lambda: np.zeros(0))   # write+read+update time per cycle
    startup_s: float = 0.0


def _controller(sc, plant, dt):
    """command(t_sample, t_act, q, theta_m) → torque [N m] for the interval starting at t_act."""
    ctrl = sc.controller
    t_est = sc.training_samples * dt
    if isinstance(ctrl, PIDSpec):
        tr = ctrl.trajectory
        traj = MinJerkTrajectory(np.radians(tr.q_start_deg), np.radians(tr.q_end_deg), tr.move_s, tr.moves)
        pid = PID(ctrl.kp, ctrl.ki, ctrl.kd, dt, sc.nominal.hardware.torque_limit, ctrl.velocity_filter_hz,
                  derivative=ctrl.derivative)
        q_meas, th_meas = plant.measure()
        pid.reset(q_meas if ctrl.derivative == "load" else th_meas, plant.hold_torque)   # bumpless

        def command(t_sample, t_act, q, th):
            # the trajectory restarts with each phase, at the sample time (as the offline runner)
            tp = t_sample - t_est if t_sample >= t_est - 1e-9 else t_sample
            q_ref, dq_ref, _ = traj.reference(tp)
            return pid.step(q_ref, q, dq_ref, th)
        return command
    ol = OpenLoopTorque(tau_comp=plant.hold_torque.copy(), amplitude=ctrl.amplitude,
                        frequency_hz=ctrl.frequency_hz, offset=ctrl.offset)

    def command(t_sample, t_act, q, th):
        # τ_des of the interval the command will act over (the subject resists that same τ_des)
        active = t_act >= t_est - 1e-9
        return ol.command(t_act - t_est if active else t_act, active=active)
    return command


def run_scenario(sc, *, bus_cfg=None, estimator=None, seed: int | None = None, sync_rpdo: bool | None = None,
                 training_samples: int | None = None, estimation_samples: int | None = None) -> HilResult:
    """Run ``sc`` (a loaded :class:`~sea_daemon.io.scenario.Scenario`) over CAN.

    ``bus_cfg`` (a :class:`~sea_daemon.core.config.BusConfig`): default the scenario model's bus with
    a fresh virtual channel.  The device model joins the same bus in this process.
    """
    cfg = sc.nominal
    b = bus_cfg or dataclasses.replace(cfg.hardware.bus, interface="virtual", channel=f"hil-{uuid.uuid4().hex[:8]}",
                                       pdo_timeout_ms=1000.0, heartbeat_timeout_ms=2000)
    if sync_rpdo is not None:
        b = dataclasses.replace(b, sync_rpdo=sync_rpdo)
    cfg = dataclasses.replace(cfg, hardware=dataclasses.replace(cfg.hardware, bus=b))
    dt = cfg.dt
    n = cfg.joints
    plant = make_plant(sc, seed)
    tau_h = human_torque(sc)
    command = _controller(sc, plant, dt)
    model = DeviceModel(make_bus(b), plant, drive_nodes=b.drive_node, encoder_nodes=b.encoder_node,
                        tau_h_act=tau_h, owns_bus=True).start()
    hw = CanopenHardware(cfg)
    n_train = sc.training_samples if training_samples is None else training_samples
    n_est = sc.estimation_samples if estimation_samples is None else estimation_samples
    cols = ("t", "q", "theta_m", "tau_m", "tau_h_act", "tau_h_act_hat", "tau_h_act_bound", "tau_h_act_sigma",
            "tau_m_applied")
    out = {k: np.zeros((n_train + n_est, n)) for k in cols}
    cycle_s = np.zeros(n_train + n_est)
    try:
        t0 = time.perf_counter()
        hw.start(initial_torque=plant.hold_torque)       # the torque already holding the arm
        startup = time.perf_counter() - t0
        d = hw.actuation_delay
        m = hw.meas                                      # sample 0: the priming cycle, plant time 0
        u_prev = u_act = hw.actuated(plant.hold_torque)  # in force over [t_0, t_1]
        for i in range(n_train + n_est):
            c0 = time.perf_counter()
            if i:
                m = hw.read()                            # sample i at plant time i·dt
                u = np.asarray(command(i * dt, (i + d) * dt, m.q, m.theta_m), dtype=float).reshape(n)
                hw.write(u)
                u_act = hw.actuated(u)                   # what the drive applies (per mille, max torque)
            tau_i = u_prev if (d and i) else u_act       # the torque over [t_i, t_i+1]
            if estimator is not None:
                e = estimator.update(m.q, m.theta_m, tau_i, dt) if i else estimator.reset(m.q, m.theta_m, tau_i)
                out["tau_h_act_hat"][i] = e.tau_h_act_hat
                out["tau_h_act_bound"][i] = e.tau_h_act_bound
                out["tau_h_act_sigma"][i] = e.tau_h_act_sigma
            cycle_s[i] = time.perf_counter() - c0
            out["t"][i] = i * dt
            out["q"][i] = m.q
            out["theta_m"][i] = m.theta_m
            out["tau_m"][i] = tau_i
            out["tau_h_act"][i] = tau_h(i * dt)          # what the device model's subject applies over it
            out["tau_m_applied"][i] = m.tau_m_applied
            u_prev = u_act
    finally:
        hw.stop()
        model.stop()

    def log(s: slice) -> MeasuredLog:
        extra = {"tau_m_applied": out["tau_m_applied"][s, 0]}
        if estimator is not None:
            for k in ("tau_h_act_hat", "tau_h_act_bound", "tau_h_act_sigma"):
                extra[k] = out[k][s, 0]
        return MeasuredLog(t=out["t"][s, 0].copy(), q=out["q"][s].copy(), theta_m=out["theta_m"][s].copy(),
                           tau_m=out["tau_m"][s].copy(), tau_h_act=out["tau_h_act"][s].copy(), extra=extra)
    return HilResult(training=log(slice(0, n_train)), estimation=log(slice(n_train, None)), cycle_s=cycle_s,
                     startup_s=startup)
