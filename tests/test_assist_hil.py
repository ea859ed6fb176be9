"""Assistance in the loop through the CAN stack: the device model's tracking subject, the daemon's
loop and assist controller (docs/assist.md).  The estimator here is an oracle (the subject's true
torque with a fixed bound), so that these tests are about the controller and the loop; the GP-AKF
in the same loop is ``python -m benchmarks.assist``."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from sea_daemon.core.estimators.base import Estimate
from _paths import repo_root
from sea_daemon.runtime.controller import AssistController
from sea_daemon.runtime.loop import FixedRateLoop
from sea_daemon.runtime.rig import make_rig

pytestmark = pytest.mark.slow
TRACK = str(repo_root() / "configs" / "scenarios" / "assist_track.yaml")


class Oracle:
    """τ̂ = the device model subject's torque, ρ = ``rho``; valid from step 5."""

    n, name = 1, "oracle"

    def __init__(self, subject, rho=0.2):
        self.subject, self.rho = subject, rho
        self.est = Estimate.zeros(1)
        self.nis = 1.0

    def reset(self, *a, **k):
        return self.est

    def update(self, q, theta_m, tau_m, dt=None):
        self.est.k += 1
        self.est.valid = self.est.k > 5
        self.est.tau_h_act_hat[:] = self.subject.tau
        self.est.tau_h_act_bound[:] = self.rho
        return self.est


def run_task(gain: float, cycles: int = 1350):
    from sea_daemon.io.scenario import load_scenario
    sc = load_scenario(TRACK)
    cfg = dataclasses.replace(sc.nominal, assist=dataclasses.replace(sc.nominal.assist, enabled=True))
    rig = make_rig(cfg, device_model=TRACK, phase="estimation")
    subject = rig.tau_h_act
    ctl = AssistController(rig.cfg, gain=gain)
    rec = np.zeros((cycles, 4))

    def on(k, m, e, tau):
        rec[k] = (m.q[0], subject.q_target[0], subject(m.t)[0], ctl.tau_assist[0])
    try:
        rig.start()
        loop = FixedRateLoop(rig.hw, Oracle(subject), ctl, 1, cfg.dt, realtime=False, on_cycle=on,
                             initial_torque=rig.initial_torque, fail_fast=True)
        loop.run(cycles)
    finally:
        rig.stop()
    return rec


def test_assistance_halves_the_subjects_effort_and_settles():
    base, assisted = run_task(0.0), run_task(2.0)
    s = slice(200, None)
    rms = lambda x: float(np.sqrt(np.mean(np.square(x))))
    assert rms(assisted[s, 2]) < 0.55 * rms(base[s, 2])             # the subject's active torque
    err_b, err_a = base[s, 0] - base[s, 1], assisted[s, 0] - assisted[s, 1]
    assert rms(err_a) < rms(err_b)                                   # and it tracks better
    # no limit cycle: in the hold at 70 deg (t 4.5..6.5 s of the cycle) the arm settles
    hold = slice(int(5.3 / 0.01), int(6.4 / 0.01))
    assert np.ptp(assisted[hold, 0]) < math.radians(1.0)
    assert np.ptp(np.diff(assisted[hold, 3])) < 0.05
    # assistance in the direction of the subject's effort whenever it is more than the bound
    big = np.abs(assisted[:, 2]) > 0.6
    assert np.all(assisted[big, 3] * assisted[big, 2] >= 0)


@pytest.mark.parametrize("rad", [0.02, -0.005])
def test_sensor_bias_below_the_jump_detector_is_a_fault_in_its_cycle(rad):
    """A step bias of the load encoder the driver's jump check lets through (max_joint_speed·dt =
    0.2 rad) corrupts the estimate by K_s·bias; the innovation check latches the fault in the
    very cycle the biased sample is estimated, and the torque is zero from that cycle on."""
    from sea_daemon.hw.device_model import parse_fault
    from sea_daemon.core.assist import InnovationGuard
    from sea_daemon.core.estimators import make_estimator
    from sea_daemon.errors import Fault
    from sea_daemon.io.scenario import load_scenario

    sc = load_scenario(TRACK)
    cfg = dataclasses.replace(sc.nominal, assist=dataclasses.replace(sc.nominal.assist, enabled=True))
    rig = make_rig(cfg, device_model=TRACK, phase="estimation")
    subject = rig.tau_h_act
    est = InnovationGuard(make_estimator("akf", rig.cfg, dt=cfg.dt), cfg.assist.innovation_max)
    ctl = AssistController(rig.cfg, gain=0.0)          # the plain AKF's estimate is biased: compensation only
    taus = []
    loop = None
    try:
        rig.start()
        rig.device_model.schedule(parse_fault(f"jump:target=encoder,rad={rad},at=3.0"))
        loop = FixedRateLoop(rig.hw, est, ctl, 1, cfg.dt, realtime=False, initial_torque=rig.initial_torque,
                             on_cycle=lambda k, m, e, tau: taus.append((k, m.t if m is not None else None,
                                                                        float(tau[0]))))
        loop.run(400)
    finally:
        rig.stop()
    sup = loop.supervisor
    assert sup.latched is Fault.INNOVATION_OUTLIER, sup.status_line()
    assert est.max_seen < cfg.assist.innovation_max / 10          # healthy steps far below the limit
    k = sup.latched_cycle
    assert taus[k][1] == pytest.approx(3.0, abs=0.011)            # the first biased sample's cycle
    assert all(t == 0.0 for _, _, t in taus[k:])                   # zero torque from that cycle on
