"""A simulator scenario run through the CAN stack: device model ↔ bus ↔ CanopenHardware.

:func:`run_scenario` is the hardware-in-the-loop twin of :func:`sea_daemon.runtime.sim_runner.simulate`:
the scenario's true plant and subject live in the device model (lock-step with SYNC), and the
fixed-rate loop (:class:`~sea_daemon.runtime.loop.FixedRateLoop`, lock-step) runs the scenario's
:class:`~sea_daemon.runtime.controller.ScenarioController` on what ``read()`` returns, the
torques going back as RPDOs.  It returns the training (calibration, passive phase) and
estimation logs in the measured-log shape (docs/interfaces.md §1), so every estimator and
``replay`` can use them; with ``estimator`` given, the estimator also runs online in the
cycle, as the daemon runs it.

Timing (see :mod:`sea_daemon.hw.interface`): sample 0 is the driver's start-up cycle (plant time 0,
the torque holding the arm in force); row k of the log carries the torque acting over
[t_k, t_k+1] — the command of cycle k-1 with a synchronous RPDO (``hw.actuation_delay`` = 1),
of cycle k without — and the estimator is updated in cycle k, after the write, with that torque.
"""
from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field

import numpy as np

from sea_daemon.core.log import MeasuredLog
from sea_daemon.io.scenario import human_torque, make_plant
from sea_daemon.runtime.controller import ScenarioController
from sea_daemon.runtime.loop import FixedRateLoop
from sea_daemon.core.sim.sampling import SampleRecorder
from sea_daemon.runtime.rig import device_model_rig, on_fresh_virtual_channel

ESTIMATE = ("tau_h_act_hat", "tau_h_act_bound", "tau_h_act_sigma")


@dataclass
class HilResult:
    training: MeasuredLog
    estimation: MeasuredLog
    cycle_s: np.ndarray = field(default_factory=lambda: np.zeros(0))   # read+control+write+update time per cycle
    startup_s: float = 0.0


def run_scenario(sc, *, bus_cfg=None, estimator=None, seed: int | None = None, sync_rpdo: bool | None = None,
                 training_samples: int | None = None, estimation_samples: int | None = None) -> HilResult:
    """Run ``sc`` (a loaded :class:`~sea_daemon.io.scenario.Scenario`) over CAN.

    ``bus_cfg`` (a :class:`~sea_daemon.core.config.BusConfig`): default the scenario model's bus with
    a fresh virtual channel.  The device model joins the same bus in this process.
    """
    cfg = sc.nominal
    if bus_cfg is None:
        cfg = on_fresh_virtual_channel(cfg, "hil")
    else:
        cfg = dataclasses.replace(cfg, hardware=dataclasses.replace(cfg.hardware, bus=bus_cfg))
    if sync_rpdo is not None:
        cfg = dataclasses.replace(cfg, hardware=dataclasses.replace(
            cfg.hardware, bus=dataclasses.replace(cfg.hardware.bus, sync_rpdo=sync_rpdo)))
    n = cfg.joints
    plant = make_plant(sc, seed)
    tau_h = human_torque(sc)
    n_train = sc.training_samples if training_samples is None else training_samples
    rows = n_train + (sc.estimation_samples if estimation_samples is None else estimation_samples)
    rig = device_model_rig(cfg, plant, tau_h_act=tau_h, initial_torque=plant.hold_torque)
    hw = rig.hw
    rec = SampleRecorder(rows, n, ("tau_m_applied",) + (ESTIMATE if estimator is not None else ()))
    c = rec.cols
    cycle_s = np.zeros(rows)
    loop = None

    def record(k, m, est, tau) -> None:
        cycle_s[k] = time.perf_counter() - loop.cycle_start
        c["t"][k] = m.t
        c["q"][k] = m.q
        c["theta_m"][k] = m.theta_m
        c["tau_m"][k] = tau
        c["tau_h_act"][k] = tau_h(m.t)               # what the device model's subject applies over it
        c["tau_m_applied"][k] = m.tau_m_applied
        if est is not None:
            c["tau_h_act_hat"][k] = est.tau_h_act_hat
            c["tau_h_act_bound"][k] = est.tau_h_act_bound
            c["tau_h_act_sigma"][k] = est.tau_h_act_sigma

    try:
        t0 = time.perf_counter()
        rig.start()                                  # the torque already holding the arm
        startup = time.perf_counter() - t0
        ctl = ScenarioController(sc, cfg, plant.hold_torque, delay=hw.actuation_delay, estimation_from=n_train)
        ctl.start(hw.meas.q, hw.meas.theta_m)        # bumpless from the start-up sample (plant time 0)
        loop = FixedRateLoop(hw, estimator, ctl, n, cfg.dt, realtime=False, clock=time.perf_counter,
                             on_cycle=record, initial_torque=hw.actuated(plant.hold_torque), fail_fast=True)
        loop.run(rows, start_sample=hw.meas)
    finally:
        rig.stop()
    train, est = rec.phases(n_train)
    return HilResult(training=train, estimation=est, cycle_s=cycle_s, startup_s=startup)
