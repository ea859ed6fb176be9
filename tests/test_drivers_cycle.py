"""HIL: the PDO-only cycle — torque to the plant, positions back, conversions, unwrapping."""
from __future__ import annotations

import math

import numpy as np
import pytest

from _hil import bus_kind, make_rig, recording_plant, remote_url  # noqa: F401  (fixtures)
from sea_daemon.hw.canopen_setup import interpolation_period

Q = 2 * math.pi / 2**19               # load encoder quantum [rad]
QM = 2 * math.pi / (2**19 * 100)      # motor encoder quantum, joint side [rad]


@pytest.mark.parametrize("sync_rpdo", [True, False])
def test_torque_reaches_plant_and_positions_come_back(make_rig, sync_rpdo):
    rig = make_rig(sync_rpdo=sync_rpdo)
    rig.hw.start()
    plant, hw = rig.plant, rig.hw
    assert hw.actuation_delay == (1 if sync_rpdo else 0)
    assert rig.drive.rpdos[0x201].trans_type == (1 if sync_rpdo else 255)
    taus = 3.0 * np.sin(np.arange(60) * 0.2)
    for k, tau in enumerate(taus):
        m = hw.read()
        # the TPDOs of SYNC k show the plant at t_k (the model steps before it samples)
        assert plant.q[0] - Q <= m.q[0] <= plant.q[0] + 1e-15
        assert plant.theta_m[0] - QM <= m.theta_m[0] <= plant.theta_m[0] + 1e-15
        assert m.t == pytest.approx((k + 1) * 0.01) and m.valid and m.faults == 0 and not m.late
        assert len(plant.steps) == k + 1
        hw.write(np.array([tau]))
    for _ in range(2):
        hw.read()
    # the torque written in cycle k acts over [t_k+d, t_k+d+1] = steps[k + d + 1] (steps[0] ends at SYNC 1 of the loop)
    d = hw.actuation_delay
    applied = np.array([plant.steps[k + d + 1][1][0] for k in range(len(taus))])
    assert np.allclose(applied, np.round(taus / 0.01) * 0.01, atol=1e-12)
    assert np.allclose(applied, [hw.actuated(np.array([t]))[0] for t in taus])
    assert np.ptp([s[3][0] for s in plant.steps]) > 0.01          # the link really moved


def test_counts_to_radians_exact(make_rig):
    rig = make_rig(plant=recording_plant(q0=1.0))
    rig.hw.start()
    m = rig.hw.read()
    qc, pc = int(m.q_counts[0]), int(m.theta_m_counts[0])
    assert m.q[0] == qc * (2 * math.pi / 2**19)
    assert m.theta_m[0] == pc * (2 * math.pi / (2**19 * 100.0))
    # and the counts are the floor-quantised true angles of that SYNC
    assert qc == math.floor(rig.plant.q[0] / Q) and pc == math.floor(rig.plant.theta_m[0] / QM)


def test_offsets_are_subtracted(make_rig):
    rig = make_rig(plant=recording_plant(q0=0.5), q_offset=(0.1,), theta_m_offset=(-0.2,))
    rig.hw.start()
    m = rig.hw.read()
    assert m.q[0] == pytest.approx(rig.plant.q[0] - 0.1, abs=Q)
    assert m.theta_m[0] == pytest.approx(rig.plant.theta_m[0] + 0.2, abs=QM)


def test_load_encoder_unwraps_across_zero(make_rig):
    # single-turn load encoder: q crossing 0 makes the raw count wrap between 0 and 2^19 - 1
    rig = make_rig(plant=recording_plant(q0=0.004))
    rig.hw.start()
    plant, raw, q = rig.plant, [], []
    for k in range(80):
        m = rig.hw.read()
        raw.append(int(m.q_counts[0]))
        q.append(m.q[0])
        assert abs(m.q[0] - plant.q[0]) <= Q
        rig.hw.write(np.array([-2.0]))
    assert max(raw) > 2**19 - 2**16 and min(raw) < 2**16          # the raw count wrapped
    assert min(q) < -0.01 and np.all(np.abs(np.diff(q)) < 0.05)   # the angle did not


def test_motor_position_unwraps_across_int32(make_rig):
    # 0x6064 is int32: start just below +2^31 and drive the motor forward through the wrap
    plant = recording_plant(0.3)
    counts0 = math.floor(plant.theta_m[0] / QM)
    preset = 2**31 - 200_000 - counts0
    rig = make_rig(plant=plant, position_preset=preset, theta_m_offset=(preset * QM,))
    rig.hw.start()
    raw, err = [], []
    for k in range(60):
        m = rig.hw.read()
        raw.append(int(m.theta_m_counts[0]))
        err.append(m.theta_m[0] - rig.plant.theta_m[0])
        rig.hw.write(np.array([4.0]))
    assert max(raw) > 2**31 - 200_000 and min(raw) < -2**31 + 2**24              # wrapped
    assert np.max(np.abs(err)) < QM * (1 + 1e-3) + abs(preset * QM) * 1e-15     # θ_m stayed continuous


def test_torque_permille_round_trip_and_limit(make_rig):
    rig = make_rig(sync_rpdo=True)
    rig.hw.start()
    hw, plant = rig.hw, rig.plant
    for tau, expect in ((1.234, 1.23), (-0.016, -0.02), (50.0, 10.0), (-50.0, -10.0), (float("nan"), 0.0)):
        hw.write(np.array([tau]))
        hw.read()                                          # SYNC that actuates it (synchronous RPDO)
        assert rig.drive.target_permille == round(expect * 100) or not math.isfinite(tau) or abs(tau) > 10
        hw.write(np.array([0.5]))
        m = hw.read()                                      # the interval it acted over ends here
        assert plant.steps[-1][1][0] == pytest.approx(expect, abs=1e-12)
        assert m.tau_m_applied[0] == pytest.approx(expect, abs=1e-12)      # 0x6077
        assert hw.actuated(np.array([tau]))[0] == pytest.approx(expect, abs=1e-12)
    assert hw.nm_per_permille == pytest.approx([100 / 1e6 * 100])


def test_interpolation_period_encoding():
    assert interpolation_period(0.01) == (10, -3)
    assert interpolation_period(0.001) == (1, -3)
    assert interpolation_period(0.0025) == (25, -4)
    assert interpolation_period(0.5) == (5, -1)
    with pytest.raises(ValueError):
        interpolation_period(1000.0)


def _scripted_window(queue: list, calls: list):
    """A TPDO window (drive 0x181, encoder 0x182) whose handle hands out ``queue``, each call's
    (timeout, ready) appended to ``calls``; (window, drive slot, encoder slot)."""
    from sea_daemon.hw.canopen_rx import TpdoWindow
    w = TpdoWindow()
    drive, enc = w.add(1, 0x181, 8), w.add(2, 0x182, 4)

    def recv(timeout, ready=False):
        calls.append((timeout, ready))
        return queue.pop(0) if queue else None
    w._recv = recv
    w.drain(queued=False)
    return w, drive, enc


def test_collect_reads_the_rest_of_the_burst_before_waiting_again():
    """The devices answer a SYNC with a burst of TPDOs: collect asks the handle for the first one
    without the ready hint (wait for it) and for every one after a frame with it (read on before
    waiting: one wake-up for the burst)."""
    calls = []
    w, drive, enc = _scripted_window([(0x181, bytes(range(8)), 0.0), (0x182, b"\x01\x02\x03\x04", 0.0)], calls)
    w.collect(deadline=1.0, clock=lambda: 0.0)
    assert (drive.snap_count, enc.snap_count) == (1, 1) and [r for _, r in calls] == [False, True]


def test_tpdos_queued_by_a_late_collect_are_taken_without_waiting():
    """The TPDO deadline bounds the wait, not the taking: a loop thread that comes to collect
    after its deadline (preempted after the SYNC) takes the frames already queued, and does not
    wait for more."""
    from sea_daemon.hw.canopen_rx import LATE_TAKE
    calls = []
    queue = [(0x700 + 1, b"\x05", 0.0), (0x181, bytes(range(8)), 0.0), (0x182, b"\x01\x02\x03\x04", 0.0)]
    w, drive, enc = _scripted_window(queue, calls)
    w.collect(deadline=1.0, clock=lambda: 2.0)            # already past the deadline
    assert (drive.snap_count, enc.snap_count) == (1, 1)
    assert bytes(drive.snap) == bytes(range(8)) and bytes(enc.snap[:4]) == b"\x01\x02\x03\x04"
    assert all(t == 0.0 for t, _ in calls)                 # no waiting past the deadline
    # an empty queue ends it at once; a flood of other frames after at most LATE_TAKE per slot
    w.drain(queued=False)
    calls.clear()
    w.collect(deadline=1.0, clock=lambda: 2.0)
    assert (drive.snap_count, enc.snap_count) == (0, 0) and [t for t, _ in calls] == [0.0]
    queue[:] = [(0x123, b"", 0.0)] * 100
    w.drain(queued=False)
    calls.clear()
    w.collect(deadline=1.0, clock=lambda: 2.0)
    assert len(calls) == LATE_TAKE * 2 and len(queue) == 100 - LATE_TAKE * 2
