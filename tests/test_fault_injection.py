"""Fault injection over the device model (shortened `sea-daemon bench faults`).

Every fault of the single fault policy, injected at seeded random cycles into the daemon's
FixedRateLoop + CanopenHardware + AKF running lock-step against the device model: each is
detected as its own type, the drive applies zero torque within one cycle of the fault's
condition and keeps it zero while latched, recovery is by operator reset only, and a
fault-free run raises no alarm.  Full figures: `sea-daemon bench faults` (docs/safety.md).
"""
from __future__ import annotations

import pytest

from sea_daemon.apps.bench.faults import FAULTS, run_suite, table


@pytest.fixture(scope="module")
def suite():
    return run_suite(cycles=900, seed=7, fault_free_cycles=1500, gap=(50, 120), max_wait=300, warmup=80)


@pytest.mark.parametrize("kind", list(FAULTS))
def test_every_injected_fault_is_detected_and_zeroes_torque_within_a_cycle(suite, kind):
    r = suite["kinds"][kind]
    detail = "\n".join(map(str, r["injections"] + r["false_alarms"]))
    assert r["injected"] >= 2, table(suite)
    assert r["detected"] == r["injected"], detail
    assert all(0 <= x <= 1 for x in r["reaction"]), detail
    assert r["held"] == 0, detail                          # no torque while latched
    assert not r["false_alarms"], detail


def test_no_false_alarm_without_faults(suite):
    ff = suite["fault_free"]
    assert ff["cycles"] == 1500 and ff["false_alarms"] == []


def test_the_stuck_condition_uses_the_joints_own_stuck_motion():
    """The evaluation's stuck condition reads joint 0's ``stuck_motion`` through the per-joint
    helper, whether the bus declares it for every joint (a number) or per joint (a tuple)."""
    import numpy as np
    from sea_daemon.apps.bench._fault_run import BUS, FaultRun, Injection
    from sea_daemon.apps.bench._rig import bench_config

    cycles = 60
    run = FaultRun.__new__(FaultRun)
    run.cycles = cycles
    run.qc = np.arange(cycles + 1, dtype=np.int64)
    run.qc[10:] = 10                               # the load count stuck from cycle 10 on ...
    run.mc = np.arange(cycles + 1, dtype=np.int64)
    run.qa = np.zeros(cycles + 1)
    run.ma = 0.004 * np.arange(cycles + 1)         # ... while the motor moves 4 mrad a cycle
    for stuck_motion, want in ((0.05, 30), ((0.05,), 30), ((0.1,), 36)):
        run.cfg = bench_config(**dict(BUS, stuck_motion=stuck_motion))
        # from the last change (cycle 10), 20 unchanged cycles (stuck_cycles) reach cycle 30,
        # where the motor has moved 0.08 rad > 0.05; more than 0.1 rad takes 26 cycles: cycle 36
        assert run._stuck_cond(Injection("encoder_stuck", 10)) == want, stuck_motion


def test_the_run_reads_back_its_own_log_of_an_arm_that_ran_away(tmp_path):
    """After a fault the unpowered arm may turn past a full turn (a plant without end stops): the
    run's check of its own log reads it all the same (no unit check on the daemon's own log),
    where a log handed in by a user is refused as one in degrees."""
    import numpy as np
    from sea_daemon.apps.bench._fault_run import FaultRun
    from sea_daemon.core.log import log_columns
    from sea_daemon.errors import LogFormatError
    from sea_daemon.io.logcsv import read_log, write_columns

    n = 50
    cols = {c: np.zeros(n) for c in log_columns(1)}
    cols["t"] = 0.01 * np.arange(n)
    cols["cycle"] = np.arange(n)
    cols["measured"] = np.ones(n)
    cols["q"] = np.linspace(0.3, 6.69, n)            # the arm turning past a full turn
    cols["fault"][10:] = 9
    path = tmp_path / "run.csv"
    write_columns(path, cols)
    with pytest.raises(LogFormatError, match="degrees instead of radians"):
        read_log(path, n=1)
    run = FaultRun.__new__(FaultRun)
    run.log_path = path
    run.loop = type("Loop", (), {"stats": type("Stats", (), {"cycles": n})()})()
    run.latched_at = np.arange(n + 1) >= 10
    run._check_log({"rows_lost": 0})
    assert run.log_check["rows"] == n and run.log_check["ok"]
