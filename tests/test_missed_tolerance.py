"""The missed-cycle tolerance as a duration (``hardware.bus.max_missed_ms``) and the drives' RPDO
deadline monitoring (``hardware.bus.rpdo_timeout_ms``, 0x1400:5): what a stall of the loop may
last, and what stops a drive whose master stopped renewing its torque command (docs/daemon.md
"Missed cycles")."""
from __future__ import annotations

import dataclasses
import time

import numpy as np
import pytest

from _hil import hil_config, hil_rig
from sea_daemon.core.hardware_config import BusConfig
from sea_daemon.errors import ConfigError, Fault, InputError
from sea_daemon.hw import cia402
from sea_daemon.hw.errors import EmcyReceived
from sea_daemon.runtime.loop import FixedRateLoop
from test_stall import StallClock, StillHardware


@pytest.mark.parametrize("rate,cycles", [(100, 0), (200, 1), (500, 4), (1000, 9)])
def test_the_default_tolerance_is_a_duration_the_same_at_every_rate(rate, cycles):
    # 10 ms from one sample and command to the next: (missed + 1) periods <= 10 ms
    b = BusConfig.default(1)
    assert b.missed_cycles(1.0 / rate) == cycles
    assert BusConfig.from_dict({"max_missed_ms": 5.0}, 1, "t").missed_cycles(1.0 / rate) == max(0, rate // 200 - 1)


def test_max_missed_cycles_keeps_working_and_excludes_the_duration():
    b = BusConfig.from_dict({"max_missed_cycles": 3}, 1, "t")
    assert b.missed_cycles(0.001) == 3 and b.missed_cycles(0.01) == 3
    assert BusConfig.from_dict(b.to_dict(), 1, "t") == b
    assert "max_missed_ms" not in b.to_dict() and "rpdo_timeout_ms" not in b.to_dict()
    with pytest.raises(ConfigError, match=r"hardware\.bus\.max_missed_ms: give max_missed_ms or max_missed_cycles"):
        BusConfig.from_dict({"max_missed_cycles": 3, "max_missed_ms": 5.0}, 1, "t")
    with pytest.raises(ConfigError, match=r"hardware\.bus\.max_missed_ms: .*got -1"):
        BusConfig.from_dict({"max_missed_ms": -1}, 1, "t")


def test_the_rpdo_deadline_is_never_shorter_than_the_tolerance_allows():
    # derived: the longest gap between two torque commands of a run that keeps its tolerance
    b = dataclasses.replace(BusConfig.default(1), pdo_timeout_ms=0.6)
    gap = b.longest_rpdo_gap(0.001)
    assert gap == pytest.approx((9 + 1) * 0.001 + 0.6e-3 + 2 * 0.001)
    assert b.rpdo_timeout_s(0.001) == 0.013
    assert BusConfig.default(1).rpdo_timeout_s(0.01) == 0.038          # 100 Hz, pdo_timeout_ms 8
    assert dataclasses.replace(b, rpdo_timeout_ms=0).rpdo_timeout_s(0.001) == 0.0   # off
    assert dataclasses.replace(b, rpdo_timeout_ms=50).rpdo_timeout_s(0.001) == 0.05
    with pytest.raises(InputError) as e:
        dataclasses.replace(b, rpdo_timeout_ms=5).rpdo_timeout_s(0.001)
    assert str(e.value) == ("hardware.bus.rpdo_timeout_ms: must be 0 (off) or >= 13 ms (the longest gap between two "
                            "torque commands the missed-cycle tolerance allows at 1000 Hz: 9 missed cycles), got 5")
    # a tolerance longer than the drive's event timer can hold (UNSIGNED16 ms): one line, not an SDO abort
    long = BusConfig.from_dict({"max_missed_cycles": 1000}, 1, "t")
    with pytest.raises(InputError, match=r"needs a drive RPDO deadline of 100308 ms, more than 0x1400:5 holds"):
        long.rpdo_timeout_s(0.1)
    assert dataclasses.replace(long, rpdo_timeout_ms=0).rpdo_timeout_s(0.1) == 0.0


def test_the_loop_takes_its_stall_tolerance_from_the_driver():
    # 1 kHz, the default 10 ms: 9 deadlines skipped in a row are survived, 10 latch LOOP_STALL
    from sea_daemon.core.rates import at_rate
    from sea_daemon.hw.canopen_hw import CanopenHardware
    cfg = at_rate(hil_config(), 1000)
    hw = CanopenHardware(cfg)                       # not started: no bus opened
    assert hw.stall_cycles == hw.max_missed == 9
    for stall, latches in ((10.5, False), (11.5, True)):
        clock = StallClock(0.001, at=50, stall=stall)
        still = StillHardware(max_missed_cycles=hw.stall_cycles)
        loop = FixedRateLoop(still, None, clock, n=1, period=0.001, clock=clock, sleep=clock.sleep, realtime=True)
        loop.run(100)
        assert loop.stats.skipped == int(stall) - 1
        assert (loop.supervisor.latched == Fault.LOOP_STALL) == latches, loop.supervisor.status_line()


def _cycle(rig, k):
    for _ in range(k):
        rig.hw.read()
        rig.hw.write(np.zeros(1))


def test_a_drive_whose_master_stops_renewing_the_torque_quick_stops_with_emcy_0x8250():
    # free-running device model (real time): the daemon writes a torque every 20 ms; it stops
    # (a stall of the loop: no SYNC, no RPDO) -> after 0x1400:5 the drive quick-stops (zero torque)
    # and sends EMCY 0x8250, which the next read() raises
    cfg = hil_config(rpdo_timeout_ms=60, pdo_timeout_ms=20.0, max_missed_cycles=0)
    rig = hil_rig(cfg, lock_step=False)
    try:
        rig.hw.start()
        drive = rig.device_model.drives[0]
        assert drive.rpdo_timeout == 0.06 and not drive.rpdo_armed       # the priming command alone
        for _ in range(5):
            rig.hw.read()
            rig.hw.write(np.array([0.5]))
            time.sleep(0.02)
        assert drive.rpdo_armed and drive.sm.state is cia402.State.OPERATION_ENABLED
        assert drive.torque_command() != 0.0
        time.sleep(0.3)
        assert drive.sm.state is cia402.State.QUICK_STOP_ACTIVE and drive.torque_command() == 0.0
        with pytest.raises(EmcyReceived, match=r"node 1: EMCY 0x8250"):
            rig.hw.read()
    finally:
        rig.stop()


def test_the_deadline_is_not_armed_by_the_priming_command_alone():
    # start-up primes one command; the loop may start long after (its own start-up): no EMCY
    cfg = hil_config(rpdo_timeout_ms=60, pdo_timeout_ms=20.0)
    rig = hil_rig(cfg, lock_step=False)
    try:
        rig.hw.start()
        time.sleep(0.25)
        assert rig.device_model.drives[0].sm.state is cia402.State.OPERATION_ENABLED
        m = rig.hw.read()
        assert m.valid and m.faults == 0
    finally:
        rig.stop()


def test_lock_step_the_deadline_runs_on_the_device_time():
    # lock-step: a pause of the master (no SYNC, no RPDO) holds the plant still, not its torque:
    # no EMCY however long; SYNCs without a torque command for longer than 0x1400:5: EMCY 0x8250
    cfg = hil_config(rpdo_timeout_ms=60, pdo_timeout_ms=30.0)
    rig = hil_rig(cfg)
    try:
        rig.hw.start()
        _cycle(rig, 5)
        time.sleep(0.2)                                # 20 periods of wall time, no SYNC
        _cycle(rig, 2)
        drive = rig.device_model.drives[0]
        assert drive.sm.state is cia402.State.OPERATION_ENABLED
        with pytest.raises(EmcyReceived, match=r"node 1: EMCY 0x8250"):
            for _ in range(10):                        # reads only: 10 ms of device time each
                rig.hw.read()
        assert drive.sm.state is cia402.State.QUICK_STOP_ACTIVE
    finally:
        rig.stop()
