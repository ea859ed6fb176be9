"""HIL: every injected fault is detected by the driver, in its cycle, with the right exception."""
from __future__ import annotations

import time

import can
import numpy as np
import pytest

from _hil import bus_kind, make_rig, remote_url  # noqa: F401  (fixtures)
from sea_daemon.hw import cia402
from sea_daemon.hw.device_model import FaultSpec
from sea_daemon.hw.errors import (
    BusOff, DriveFault, EmcyReceived, EncoderJump, EncoderStuck, HeartbeatLost, PdoTimeout, SendFailed)
from sea_daemon.core.estimators.base import Estimate
from sea_daemon.runtime.loop import FixedRateLoop
from sea_daemon.errors import Fault


def started(make_rig, **kw):
    rig = make_rig(pdo_timeout_ms=kw.pop("pdo_timeout_ms", 300.0), **kw)
    rig.hw.start()
    for _ in range(3):
        rig.hw.read()
        rig.hw.write(np.zeros(1))
    return rig


def test_dropped_tpdo_raises_in_its_cycle(make_rig):
    rig = started(make_rig)
    cycle = rig.hw.meas.cycle
    rig.device_model.inject(FaultSpec("drop", target="encoder"))
    with pytest.raises(PdoTimeout, match=r"node 2: TPDO 0x182 missing in cycle") as e:
        rig.hw.read()
    assert e.value.cycle == cycle + 1 and e.value.fault is Fault.TPDO_MISSING


def test_missed_cycles_tolerated_up_to_the_limit(make_rig):
    rig = started(make_rig, max_missed_cycles=2)
    q_before = rig.hw.meas.q.copy()
    rig.device_model.inject(FaultSpec("drop", target="drive", params={"count": 3}))
    for _ in range(2):
        m = rig.hw.read()
        assert not m.valid and m.saw(Fault.TPDO_MISSING)
        assert np.array_equal(m.q, q_before)                      # values held
    with pytest.raises(PdoTimeout, match=r"node 1: TPDO 0x181 .* 3 consecutive"):
        rig.hw.read()
    m = rig.hw.read()                                             # frames flow again
    assert m.valid and m.faults == 0 and not m.late


def test_delayed_frame_is_missing_then_flagged_late(make_rig):
    rig = started(make_rig, max_missed_cycles=1)
    rig.device_model.inject(FaultSpec("delay", target="drive", params={"count": 1, "seconds": 0.5}))
    m = rig.hw.read()                                              # waits 0.3 s
    assert not m.valid and m.saw(Fault.TPDO_MISSING)
    time.sleep(0.5)                                                # the late frame lands between cycles
    m = rig.hw.read()
    assert m.valid and m.late


def test_stuck_encoder(make_rig):
    rig = started(make_rig, stuck_cycles=10, stuck_motion=0.01)
    rig.device_model.inject(FaultSpec("stuck", target="encoder"))
    with pytest.raises(EncoderStuck, match=r"node 2: 0x6004 load position value stuck at count \d+ for \d+ cycles"
                                           r" while the other encoder moved 0\.\d+ rad, allowed <= 0\.0100 rad") as e:
        for k in range(60):
            rig.hw.read()
            rig.hw.write(np.array([4.0 * (1 if (k // 15) % 2 == 0 else -1)]))
    assert e.value.cycles >= 10 and e.value.other_motion_rad > 0.01


def test_stuck_motor_encoder(make_rig):
    rig = started(make_rig, stuck_cycles=10, stuck_motion=0.01)
    rig.device_model.inject(FaultSpec("stuck", target="drive"))
    with pytest.raises(EncoderStuck, match=r"node 1: 0x6064 motor position actual value stuck"):
        for k in range(60):
            rig.hw.read()
            rig.hw.write(np.array([4.0 * (1 if (k // 15) % 2 == 0 else -1)]))


@pytest.mark.parametrize("target,node,obj", [("encoder", 2, "0x6004"), ("drive", 1, "0x6064")])
def test_jumping_encoder_raises_in_its_cycle(make_rig, target, node, obj):
    rig = started(make_rig)
    rig.device_model.inject(FaultSpec("jump", target=target, params={"rad": 0.5}))
    with pytest.raises(EncoderJump, match=rf"node {node}: {obj} .* jumped \+0\.(49|50)\d\d rad .* allowed \|step\| <= 0\.\d{{4}}") as e:
        rig.hw.read()
    # 20 rad/s over one period (10 ms), and over the time since the sample before when this read
    # came late (an emulated kernel's slow cycle: max_joint_speed over that time, docs/daemon.md)
    allowed = float(str(e.value).split("<= ")[1].split()[0])
    assert 0.2 <= allowed < 0.4


def test_small_steps_are_not_jumps(make_rig):
    rig = started(make_rig)
    rig.device_model.inject(FaultSpec("jump", target="encoder", params={"rad": 0.1}))   # < 20 rad/s · 10 ms
    rig.hw.read()


def test_drive_emcy(make_rig):
    rig = started(make_rig)
    rig.device_model.inject(FaultSpec("emcy", target="drive", params={"code": 0x2310}))
    with pytest.raises(EmcyReceived, match=r"node 1: EMCY 0x2310 \(.*[Cc]urrent.*\), error register 0x03") as e:
        rig.hw.read()
    assert e.value.fault is Fault.EMCY
    with pytest.raises(DriveFault, match=r"node 1: drive state FAULT"):   # and the statusword says so
        rig.hw.read()
    rig.hw.reset_fault()                                            # operator reset re-enables
    assert rig.drive.sm.state is cia402.State.OPERATION_ENABLED
    assert rig.hw.read().valid


def test_encoder_emcy(make_rig):
    rig = started(make_rig)
    rig.device_model.inject(FaultSpec("emcy", target="encoder", params={"code": 0x7305}))
    with pytest.raises(EmcyReceived, match=r"node 2: EMCY 0x7305"):
        rig.hw.read()


def _cycle(rig, cycles, starts):
    """Up to ``cycles`` read/write cycles of 5 ms, each start time appended to ``starts``
    (the caller expects one to raise)."""
    for _ in range(cycles):
        starts.append(time.monotonic())
        try:
            rig.hw.read()
        except Exception:
            starts.append(time.monotonic())            # when the raising read() returned
            raise
        rig.hw.write(np.zeros(1))
        time.sleep(0.005)


def test_heartbeat_loss_detected_at_the_first_cycle_past_the_timeout(make_rig):
    rig = started(make_rig, heartbeat_ms=20, heartbeat_timeout_ms=250)
    rig.device_model.inject(FaultSpec("heartbeat", target="encoder"))
    starts = []
    with pytest.raises(HeartbeatLost, match=r"node 2: heartbeat \(0x702\): no heartbeat for \d+ ms, allowed <= 250 ms"):
        _cycle(rig, 200, starts)
    last_hb = rig.hw.heartbeat_arrival(rig.encoder.id)
    # the raising read() started no later than the timeout after the last heartbeat plus one cycle
    # (the cycle before did not raise, so it checked in time) and returned past the timeout
    assert starts[-3] - last_hb <= 0.25 < starts[-1] - last_hb


def test_heartbeat_timeout_runs_from_the_last_heartbeats_arrival_not_from_when_it_was_taken(make_rig):
    """The loop stalls and the encoder falls silent during the stall: its last heartbeat is taken
    late (after the stall), yet every read() that starts later than the timeout after that
    heartbeat's arrival on the bus (a sniffer of its own: python-can's receive thread, the frame's
    timestamp) raises — the timeout does not grow by the stall."""
    from sea_daemon.hw.bus import make_bus
    from sea_daemon.apps.bench._rig import HeartbeatSniffer
    rig = started(make_rig, heartbeat_ms=20, heartbeat_timeout_ms=500)
    sniffer = HeartbeatSniffer(make_bus(rig.hw.bus_cfg))
    try:
        time.sleep(0.15)                              # the loop stalls (the drive's watch of us: 500 ms) ...
        rig.device_model.inject(FaultSpec("heartbeat", target="encoder"))   # ... and the encoder falls silent
        time.sleep(0.15)
        starts = []
        with pytest.raises(HeartbeatLost, match=r"node 2: heartbeat \(0x702\): no heartbeat for \d+ ms"):
            _cycle(rig, 400, starts)
        last = sniffer.hb_seen[rig.encoder.id]        # the encoder's last heartbeat on the bus
    finally:
        sniffer.close()
    assert len(starts) >= 3 and starts[-3] <= last + 0.5       # the cycle before the raising one started in time


def test_device_bus_off_is_seen_as_missing_frames(make_rig):
    rig = started(make_rig)
    rig.device_model.inject(FaultSpec("busoff", target="drive"))
    with pytest.raises(PdoTimeout, match=r"node 1: TPDO 0x181 missing"):
        rig.hw.read()


def test_send_failure(make_rig, monkeypatch):
    rig = started(make_rig)

    def refuse(msg, timeout=None):
        raise can.CanOperationError("Transmit buffer full")
    monkeypatch.setattr(rig.drv_bus, "send", refuse)
    with pytest.raises(SendFailed, match=r"sending RPDO1 .* \(COB-ID 0x201\) failed: Transmit buffer full") as e:
        rig.hw.write(np.zeros(1))
    assert e.value.fault is Fault.SEND_FAILED
    with pytest.raises(SendFailed, match=r"sending SYNC \(COB-ID 0x080\)"):
        rig.hw.read()

    def bus_off(msg, timeout=None):
        raise can.CanOperationError("controller is bus-off")
    monkeypatch.setattr(rig.drv_bus, "send", bus_off)
    with pytest.raises(BusOff) as e:
        rig.hw.write(np.zeros(1))
    assert e.value.fault is Fault.BUS_OFF


def test_bus_off_error_frame(make_rig):
    rig = started(make_rig)
    rig.dev_bus.send(can.Message(arbitration_id=0x40, is_error_frame=True, is_extended_id=False, data=bytes(8)))
    deadline = time.monotonic() + 2
    with pytest.raises(BusOff, match="bus-off"):
        while time.monotonic() < deadline:
            rig.hw.read()
            rig.hw.write(np.zeros(1))


def test_loop_latches_and_quick_stops_the_drive(make_rig):
    """The daemon's fixed-rate loop turns a driver fault into zero torque / quick stop at once."""
    rig = started(make_rig)

    class Est:                       # an estimator still starting: its estimate not valid
        def update(self, q, theta_m, tau_m):
            return Estimate.zeros(1)

    class Push:
        def update(self, t, q, theta_m, est):
            return np.array([2.0])

    def on_cycle(k, meas, est, tau):
        if k == 5:
            rig.device_model.inject(FaultSpec("jump", target="encoder", params={"rad": 1.0}))

    loop = FixedRateLoop(rig.hw, Est(), Push(), n=1, period=0.01, realtime=False, on_cycle=on_cycle)
    loop.run(cycles=10)
    assert loop.supervisor.latched is Fault.ENCODER_JUMP and loop.supervisor.latched_cycle == 6
    assert rig.drive.sm.state is cia402.State.QUICK_STOP_ACTIVE
    assert rig.drive.torque_command() == 0.0


def test_after_safe_stop_reads_go_on_with_zero_torque(make_rig):
    rig = started(make_rig)
    rig.hw.safe_stop()
    m = rig.hw.read()
    assert rig.drive.sm.state is cia402.State.QUICK_STOP_ACTIVE
    assert m.valid and m.saw(Fault.DEVICE_FAULT)            # flagged, not raised: it was asked for
    rig.hw.write(np.array([3.0]))
    rig.hw.read()
    assert rig.drive.applied_permille == 0
    rig.hw.reset_fault()                                            # operator reset: enabled again
    rig.hw.write(np.array([3.0]))
    rig.hw.read()
    m = rig.hw.read()
    assert m.faults == 0 and not m.late and rig.drive.applied_permille == 300


def test_drive_quick_stops_when_the_daemon_goes_silent(make_rig):
    """The daemon's heartbeat comes from its cycle; without it the drive quick-stops (0x1016/0x6007).
    The watch (1 s) spans the start-up's SDO walk and first cycles on a slow or emulated machine."""
    rig = started(make_rig, heartbeat_ms=20, heartbeat_timeout_ms=1000)
    rig.hw.write(np.array([2.0]))
    rig.hw.read()
    deadline = time.monotonic() + 4.0
    while rig.drive.sm.state is cia402.State.OPERATION_ENABLED:      # the loop hangs: no read()
        assert time.monotonic() < deadline, "the drive kept its torque without the daemon's heartbeat"
        time.sleep(0.01)
    assert rig.drive.sm.state is cia402.State.QUICK_STOP_ACTIVE and rig.drive.torque_command() == 0.0
    with pytest.raises(EmcyReceived, match=r"node 1: EMCY 0x8130"):     # and the daemon learns why
        rig.hw.read()
    rig.hw.reset_fault()
    assert rig.drive.sm.state is cia402.State.OPERATION_ENABLED


def test_clean_stop_ends_the_watch(make_rig):
    rig = started(make_rig, heartbeat_ms=20, heartbeat_timeout_ms=1000)
    rig.hw.stop()
    time.sleep(1.3)                                                 # past the watch's 1 s
    assert rig.drive.master_timeout == 0.0 and rig.drive.error_register == 0      # no EMCY after a clean stop
