"""Two joints on one bus, the simulator-backed hardware, the bus factory."""
from __future__ import annotations

import uuid

import can
import numpy as np
import pytest

from _hil import recording_plant
from sea_daemon.hw.bus import make_bus, socketcan_available
from sea_daemon.hw.canopen_hw import CanopenHardware
from sea_daemon.hw.device_model import DeviceModel
from sea_daemon.hw.errors import DeviceMismatch
from sea_daemon.hw.sim_hw import SimHardware
from sea_daemon.core.config import BusConfig, ModelConfig
from sea_daemon.io.configfile import default_config_path, load_yaml


def test_two_joints_on_one_bus():
    raw = load_yaml(default_config_path())
    raw.update(joints=2, estimator={}, learning={})
    raw["hardware"]["bus"] = {"channel": f"two-{uuid.uuid4().hex[:6]}", "heartbeat_ms": 20, "pdo_timeout_ms": 500}
    cfg = ModelConfig.from_dict(raw, "two.yaml")
    b = cfg.hardware.bus
    assert b.drive_node == (1, 3) and b.encoder_node == (2, 4)
    plant = recording_plant(0.2, joints=2)
    model = DeviceModel(can.Bus(interface="virtual", channel=b.channel), plant, drive_nodes=b.drive_node,
                        encoder_nodes=b.encoder_node, owns_bus=True).start()
    bus = can.Bus(interface="virtual", channel=b.channel)
    hw = CanopenHardware(cfg, bus)
    try:
        hw.start()
        for _ in range(40):
            m = hw.read()
            hw.write(np.array([1.0, -1.0]))
        assert m.tau_m_applied.tolist() == [1.0, -1.0]
        assert m.q[0] > 0.25 and m.q[1] < 0.15                 # each joint got its own torque
    finally:
        hw.stop()
        model.stop()
        bus.shutdown()


@pytest.mark.parametrize("delay", [0, 1])
def test_sim_hardware_timing(delay):
    plant = recording_plant(q0=0.1)
    hw = SimHardware(plant, 0.01, torque_limit=5.0, actuation_delay=delay)
    with hw:
        m = hw.read()                                       # t_0: nothing stepped yet
        assert m.q[0] == pytest.approx(0.1, abs=2e-5) and m.t == 0.0 and plant.t == 0.0
        for k, tau in enumerate([9.0, 1.0, 2.0, 3.0]):      # written in cycle k, acts over [t_k+d, t_k+d+1]
            hw.write(np.array([tau]))
            m = hw.read()
            assert m.q[0] == pytest.approx(plant.q[0], abs=2e-5)
        applied = [s[1][0] for s in plant.steps]            # steps[i] = [t_i, t_i+1]
        assert applied == ([5.0, 1.0, 2.0, 3.0] if delay == 0 else [0.0, 5.0, 1.0, 2.0])
        assert m.tau_m_applied[0] == applied[-1]            # 0x6077: the interval that just ended
        hw.safe_stop()
        hw.write(np.array([3.0]))
        hw.read()
        hw.read()
        assert plant.steps[-1][1][0] == 0.0
        hw.reset_fault()
        hw.write(np.array([3.0]))
        hw.read()
        hw.read()
        assert plant.steps[-1][1][0] == 3.0


def test_make_bus_reports_what_it_cannot_open():
    ok, why = socketcan_available("vcan0")
    if not ok:
        with pytest.raises(DeviceMismatch, match=r"bus: socketcan vcan0: no network interface 'vcan0'"):
            make_bus(BusConfig(interface="socketcan", channel="vcan0"))
    with pytest.raises(DeviceMismatch, match=r"bus: remote bus 'ws://127.0.0.1:9/': cannot open"):
        make_bus(BusConfig(interface="remote", channel="ws://127.0.0.1:9/"))
    bus = make_bus(BusConfig(interface="virtual", channel="x"))
    bus.shutdown()


def test_read_before_start_is_a_clear_error():
    from sea_daemon.io.configfile import load_config
    hw = CanopenHardware(load_config(default_config_path()), can.Bus(interface="virtual", channel="unused"))
    with pytest.raises(RuntimeError, match=r"call start\(\) before read\(\) / write\(\)"):
        hw.write(np.zeros(1))
    hw._bus.shutdown()


def test_free_running_device_model_with_the_driver_in_real_time():
    """Free-running physics (its own thread, real time); the driver samples it at SYNC."""
    import time

    from _hil import hil_config, hil_rig
    rig = hil_rig(hil_config("virtual"), recording_plant(0.3), lock_step=False)
    try:
        rig.hw.start(initial_torque=rig.plant.hold_torque)
        t0, ts, qs = time.monotonic(), [], []
        for _ in range(30):
            m = rig.hw.read()
            ts.append(rig.plant.t)
            qs.append(m.q[0])
            rig.hw.write(np.array([4.0]))
            time.sleep(0.01)
        wall = time.monotonic() - t0
        assert rig.device_model.syncs == 31
        assert rig.plant.t == pytest.approx(wall, abs=0.2 + 0.5 * wall)     # physics kept to the clock
        assert qs[-1] > qs[0] + 0.01                                       # and felt the torque
    finally:
        rig.stop()
