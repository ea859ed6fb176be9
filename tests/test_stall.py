"""A stall of the host survived as the missed-cycle tolerance allows, not latched on its first cycle;
a stall of the loop beyond it latches LOOP_STALL.

The arm keeps moving while no sample is taken — cycles whose TPDOs were held
(``max_missed_cycles``), or a loop that stalled and sent no SYNC — so the first sample after them
is further away than one period's motion: the encoder-jump check allows ``max_joint_speed`` over
the time since the sample before, not over one period.
"""
from __future__ import annotations

import time
import uuid

import numpy as np
import pytest

from _hil import true_config
from sea_daemon.core.config import ModelConfig
from sea_daemon.errors import Fault
from sea_daemon.hw.device_model import parse_fault
from sea_daemon.io.configfile import default_config_path, load_yaml
from sea_daemon.runtime.loop import FixedRateLoop
from sea_daemon.runtime.rig import device_model_rig

SPEED = 0.4            # the arm's speed [rad/s]: at most 2 steps of its 100 Hz physics per period (free-running)
MAX_SPEED = 1.0        # hardware.bus.max_joint_speed: one period's step allows 0.01 rad at 100 Hz


class RampPlant:
    """An arm moving at :data:`SPEED` whatever the torque (the plant API the device model uses)."""

    def __init__(self, q0: float = 0.1):
        self.t, self.q0 = 0.0, q0
        self.hold_torque = np.zeros(1)
        self.dtheta_m = np.full(1, SPEED)

    @property
    def q(self):
        return np.array([self.q0 + SPEED * self.t])

    @property
    def theta_m(self):
        return self.q

    def step(self, tau_m, dt, tau_h_act=None):
        self.t += dt


def stall_config(max_missed: int) -> ModelConfig:
    raw = load_yaml(default_config_path())
    raw["hardware"]["bus"] = {"channel": f"stall-{uuid.uuid4().hex[:6]}", "heartbeat_ms": 20,
                              "heartbeat_timeout_ms": 2000, "sdo_timeout_ms": 3000, "pdo_timeout_ms": 6.0,
                              "max_missed_cycles": max_missed, "max_joint_speed": MAX_SPEED}
    cfg = ModelConfig.from_dict(raw, "stall.yaml")
    assert cfg.dt == 0.01 and true_config().dt == cfg.dt
    return cfg


class Hold:
    """Zero torque; sleeps ``stall`` seconds in cycle ``at`` (the loop's thread stalls)."""

    def __init__(self, at: int | None = None, stall: float = 0.0):
        self.k, self.at, self.stall = 0, at, stall

    def update(self, t, q, theta_m, est):
        if self.k == self.at:
            time.sleep(self.stall)
        self.k += 1
        return np.zeros(1)


@pytest.mark.parametrize("tolerance", [3, 1])
def test_held_cycles_within_the_tolerance_do_not_latch_a_jump_at_the_next_sample(tolerance):
    # lock-step: the arm moves 4 mrad per SYNC; the encoder's TPDO missing for 2 cycles (held
    # within a tolerance of 3): the next sample is 12 mrad on, more than one period allows (10
    # mrad + 2 quanta); beyond a tolerance of 1 the missing TPDO itself latches
    rig = device_model_rig(stall_config(tolerance), RampPlant())
    try:
        rig.start()
        loop = FixedRateLoop(rig.hw, None, Hold(), n=1, period=0.01, realtime=False)
        loop.run(20)
        rig.device_model.schedule(parse_fault("drop:target=encoder,count=2"))
        loop.run(20)
        if tolerance >= 2:
            assert loop.supervisor.ok, loop.supervisor.status_line()
            assert rig.hw.missed_cycles == 2 and loop.stats.extrapolated == 2
        else:
            assert loop.supervisor.latched == Fault.TPDO_MISSING, loop.supervisor.status_line()
    finally:
        rig.stop()


def test_a_stalled_loop_goes_on_after_the_stall():
    # real time: the device model's arm moves in real time (free-running) while the loop's thread
    # stalls for 60 ms (6 periods at 100 Hz); the first sample after it is about 24 mrad on
    rig = device_model_rig(stall_config(8), RampPlant(), lock_step=False)
    try:
        rig.start()
        loop = FixedRateLoop(rig.hw, None, Hold(at=20, stall=0.06), n=1, period=0.01, realtime=True)
        loop.run(40)
        assert loop.stats.skipped >= 3, loop.supervisor.status_line()     # the stall happened
        assert loop.supervisor.ok, loop.supervisor.status_line()
    finally:
        rig.stop()


class StallClock:
    """A monotonic clock that moves only when the loop sleeps, or by ``stall`` periods in cycle
    ``at`` (the loop's thread stalls there): the loop's pacing without wall time."""

    def __init__(self, period: float, at: int, stall: float):
        self.t, self.period, self.at, self.stall = 0.0, period, at, stall
        self.k = 0

    def __call__(self) -> float:
        return self.t

    def sleep(self, s: float) -> None:
        self.t += s

    def update(self, t, q, theta_m, est):          # the controller: the stall is in cycle `at`
        if self.k == self.at:
            self.t += self.stall * self.period
        self.k += 1
        return np.zeros(1)


class StillHardware:
    """A sample in every cycle, nothing else: the loop's pacing alone (``stall_cycles`` the
    missed-cycle tolerance, as the CANopen driver's)."""

    actuation_delay = 0

    def __init__(self, max_missed_cycles: int):
        from sea_daemon.hw.interface import Measurement
        self.meas = Measurement(n=1, valid=True)
        self.stall_cycles = max_missed_cycles
        self.safe_stops = 0

    def read(self):
        self.meas.cycle += 1
        self.meas.t = self.meas.cycle * 0.001
        return self.meas

    def write(self, tau_m):
        pass

    def actuated(self, tau_m):
        return tau_m

    def safe_stop(self):
        self.safe_stops += 1


@pytest.mark.parametrize("stall,latches", [(4.5, False), (5.5, True), (40.5, True)])
def test_a_loop_stall_beyond_the_missed_cycle_tolerance_latches_loop_stall(stall, latches):
    # 1 kHz, max_missed_cycles 3: a cycle that takes 4.5 periods skips the 3 deadlines after its
    # own (3 cycles without a sample: survived, as 3 missing TPDOs are); 5.5 periods skip 4 —
    # the fault, zero torque in that cycle, named with the stall
    clock = StallClock(0.001, at=50, stall=stall)
    hw = StillHardware(max_missed_cycles=3)
    loop = FixedRateLoop(hw, None, clock, n=1, period=0.001, clock=clock, sleep=clock.sleep, realtime=True)
    loop.run(100)
    skipped = int(stall) - 1
    assert loop.stats.skipped == skipped
    if latches:
        assert loop.supervisor.latched == Fault.LOOP_STALL, loop.supervisor.status_line()
        assert loop.supervisor.latched_cycle == 50 and hw.safe_stops == 1
        assert f"{skipped} cycles skipped in a row, 3 tolerated" in loop.supervisor.latched_detail
    else:
        assert loop.supervisor.ok, loop.supervisor.status_line()


def test_a_slow_first_cycle_is_start_up_not_a_stall():
    # the first cycle of a run (the first calls into the estimator and the publisher) may take
    # several periods: skipped deadlines, no fault; the same in a later cycle latches
    for at, latches in ((0, False), (1, True)):
        clock = StallClock(0.001, at=at, stall=10.5)
        loop = FixedRateLoop(StillHardware(max_missed_cycles=3), None, clock, n=1, period=0.001, clock=clock,
                             sleep=clock.sleep, realtime=True)
        loop.run(20)
        assert loop.stats.skipped == 9
        assert (loop.supervisor.latched == Fault.LOOP_STALL) == latches, loop.supervisor.status_line()


def test_timing_faults_off_lets_a_stall_be_counted_not_latched():
    # --overrun-streak 0 (a run on a shared machine whose timing is not under test): the same
    # stall is skipped and counted, no LOOP_STALL
    from sea_daemon.apps.commands.daemon_args import supervisor

    class Args:
        overrun_streak = 0
    clock = StallClock(0.001, at=50, stall=10.5)
    loop = FixedRateLoop(StillHardware(max_missed_cycles=3), None, clock, n=1, period=0.001, clock=clock,
                         sleep=clock.sleep, realtime=True, supervisor=supervisor(Args()))
    loop.run(100)
    assert loop.stats.skipped == 9 and loop.supervisor.ok, loop.supervisor.status_line()


def test_a_stalled_loop_beyond_the_tolerance_commands_zero_torque_on_the_bus():
    # real time on the device model: the loop's thread stalls 60 ms (6 periods at 100 Hz) with a
    # tolerance of 3 missed cycles: LOOP_STALL latches, and the loop goes on writing zero torque
    rig = device_model_rig(stall_config(3), RampPlant(), lock_step=False)
    try:
        rig.start()
        loop = FixedRateLoop(rig.hw, None, Hold(at=20, stall=0.06), n=1, period=0.01, realtime=True)
        loop.run(40)
        assert loop.supervisor.latched == Fault.LOOP_STALL, loop.supervisor.status_line()
        assert loop.supervisor.latched_cycle == 20
        assert rig.device_model.drives[0].torque_command() == 0.0
    finally:
        rig.stop()


def test_freeze_heap_moves_what_exists_out_of_the_collectors_reach():
    # the device model's, the bound worker's and the loop's processes freeze their heap before
    # serving: a full collection over it takes tens of ms, longer than the 1 kHz tolerance
    import gc
    from sea_daemon.runtime.realtime import freeze_heap
    keep = [[i] for i in range(1000)]
    try:
        before = gc.get_freeze_count()
        freeze_heap()
        assert gc.get_freeze_count() >= before + len(keep)
    finally:
        gc.unfreeze()
