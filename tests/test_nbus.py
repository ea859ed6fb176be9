"""Two joints on the bus: on one bus, and on a bus per joint (``hardware.bus.channel`` as a list).

The device model with a drive and a load encoder per joint around one plant, the driver
(:class:`~sea_daemon.hw.canopen_buses.CanopenBuses` for several buses), the daemon's published
TPDOs per bus, the bus-load arithmetic of docs/can.md, and the fault policy across joints: a fault
on joint 2 commands zero torque on every joint within its cycle and is logged.
"""
from __future__ import annotations

import dataclasses
import uuid

import can
import numpy as np
import pytest

from _hil import recording_plant
from test_loop import ListLog
from sea_daemon.client import decode_tpdo
from sea_daemon.core.config import BusConfig, ModelConfig
from sea_daemon.core.log import log_columns
from sea_daemon.errors import ConfigError, Fault
from sea_daemon.hw.busload import bus_load, bus_loads
from sea_daemon.hw.canopen_buses import CanopenBuses
from sea_daemon.hw.device_model import parse_fault
from sea_daemon.io.configfile import default_config_path, load_yaml
from sea_daemon.runtime.loop import FixedRateLoop
from sea_daemon.runtime.publish import make_publisher
from sea_daemon.runtime.rig import device_model_rig

LAYOUTS = {"one bus": lambda t: f"one-{t}", "a bus per joint": lambda t: [f"j1-{t}", f"j2-{t}"]}


def two_joint_config(channel, **bus) -> ModelConfig:
    raw = load_yaml(default_config_path())
    raw.update(joints=2, estimator={}, learning={})
    raw["hardware"]["bus"] = {"channel": channel, "heartbeat_ms": 20, "pdo_timeout_ms": 500,
                              "heartbeat_timeout_ms": 2000, "sdo_timeout_ms": 3000, **bus}
    return ModelConfig.from_dict(raw, "two.yaml")


class Opposite:
    """+1 N m on joint 1, −1 N m on joint 2."""

    def update(self, t, q, theta_m, est):
        return np.array([1.0, -1.0])


@pytest.fixture(scope="module", autouse=True)
def compiled_plant():
    """The two-joint plant's kernels compiled before a device model steps it in a SYNC handler."""
    recording_plant(0.2, joints=2).step(np.zeros(2), 0.01, np.zeros(2))


@pytest.fixture(params=list(LAYOUTS))
def rig(request):
    cfg = two_joint_config(LAYOUTS[request.param](uuid.uuid4().hex[:6]))
    r = device_model_rig(cfg, recording_plant(0.2, joints=2))
    yield r
    r.stop()


def test_torque_reaches_each_joint_and_positions_come_back_per_joint(rig):
    rig.start()
    hw = rig.hw
    for _ in range(40):
        m = hw.read()
        hw.write(np.array([1.0, -1.0]))
    assert m.valid and m.faults == 0
    assert m.tau_m_applied.tolist() == [1.0, -1.0]              # each drive got its own torque
    assert [d.target_permille for d in rig.device_model.drives] == [100, -100]
    plant_q = rig.plant.q
    assert m.q[0] > 0.25 and m.q[1] < 0.15                      # each joint moved its own way
    quantum = 2 * np.pi / 2 ** 19
    assert np.all(np.abs(m.q - plant_q) < 2 * quantum)          # the plant's angles, joint by joint


def test_buses_are_one_hardware_with_one_driver_per_bus():
    cfg = two_joint_config([f"a-{uuid.uuid4().hex[:6]}", f"b-{uuid.uuid4().hex[:6]}"])
    r = device_model_rig(cfg, recording_plant(0.2, joints=2))
    try:
        assert isinstance(r.hw, CanopenBuses) and r.hw.joints == [(0,), (1,)]
        assert [s.bus_cfg.drive_node for s in r.hw.subs] == [(1,), (3,)]
        assert r.device_model.joint_bus == (0, 1)
        r.start()
        for _ in range(5):
            r.hw.read()
            r.hw.write(np.zeros(2))
        per_bus = r.device_model.answer_stats()["buses"]
        assert [b["syncs"] for b in per_bus] == [6, 6]          # the priming cycle and five reads, per bus
        assert rig_plant_steps(r) == 5                           # the plant stepped once per cycle
    finally:
        r.stop()


def rig_plant_steps(r) -> int:
    return int(round(r.plant.t / r.cfg.dt))


def test_a_fault_on_joint_2_zeroes_every_joint_within_its_cycle_and_is_logged(rig):
    rig.start()
    log = ListLog()

    def on_cycle(k, meas, est, tau):
        if k == 29:
            rig.device_model.schedule(parse_fault("emcy:target=drive,joint=1,code=0x2310"))

    loop = FixedRateLoop(rig.hw, None, Opposite(), n=2, period=rig.cfg.dt, log=log, realtime=False,
                         initial_torque=np.zeros(2), on_cycle=on_cycle)
    loop.run(40)
    sup = loop.supervisor
    assert sup.latched == Fault.EMCY and "node 3" in sup.latched_detail   # joint 2's drive
    cols = log_columns(2)
    rows = np.array(log.rows)
    k = sup.latched_cycle
    tau = rows[:, [cols.index("tau_m_1"), cols.index("tau_m_2")]]
    fault = rows[:, cols.index("fault")]
    assert k == 30                                                # the cycle after the EMCY was sent
    assert np.all(tau[:k] == [1.0, -1.0])
    assert np.all(tau[k:] == 0.0)                                # both joints from the faulty cycle on
    assert np.all(fault[k:] == int(Fault.EMCY)) and np.all(fault[:k] == 0)
    # on the bus: both drives got zero torque (quick stop), not only the faulty one
    assert [d.target_permille for d in rig.device_model.drives] == [0, 0]


def test_published_tpdos_go_on_each_joints_bus():
    t = uuid.uuid4().hex[:6]
    cfg = two_joint_config([f"p1-{t}", f"p2-{t}"])
    r = device_model_rig(cfg, recording_plant(0.2, joints=2))
    readers = [can.Bus(interface="virtual", channel=c) for c in (f"p1-{t}", f"p2-{t}")]
    try:
        r.start()
        pub = make_publisher(r, cfg, None, socket_path=None)
        est = type("E", (), {"tau_h_act_hat": np.array([0.5, -0.25]), "tau_h_act_bound": np.array([0.1, 0.2]),
                             "valid": True})()
        pub.publish(7, r.hw.meas, est, np.zeros(2), 0)
        got = []
        for bus in readers:
            frames = []
            while len(frames) < 2 and (msg := bus.recv(2.0)) is not None:   # the bus's heartbeats go on
                if msg.arbitration_id in (0x1FF, 0x2FF, 0x3FF):
                    frames.append((msg.arbitration_id, decode_tpdo(msg.arbitration_id, bytes(msg.data))))
            got.append(frames)
        assert [f[0] for f in got[0]] == [0x1FF, 0x2FF] and [f[0] for f in got[1]] == [0x3FF, 0x2FF]
        assert got[0][0][1]["joint"] == 1 and got[1][0][1]["joint"] == 2
        assert got[1][0][1]["tau_h_act_hat"] == -0.25 and got[1][1][1]["cycle"] == 7
        assert pub.tpdo.sent == 4 and pub.tpdo.dropped == 0
    finally:
        for bus in readers:
            bus.shutdown()
        r.stop()


def test_channel_list_is_checked():
    assert BusConfig.from_dict({"channel": ["a", "b"]}, 2, "x").buses() == [("a", (0,)), ("b", (1,))]
    assert BusConfig.from_dict({"channel": ["a", "a"]}, 2, "x").buses() == [("a", (0, 1))]
    assert BusConfig.from_dict({"channel": ["a", "b"]}, 2, "x").to_dict()["channel"] == ["a", "b"]
    for bad in (["a"], ["a", ""], ["a", 3]):
        with pytest.raises(ConfigError, match="hardware.bus.channel"):
            BusConfig.from_dict({"channel": bad}, 2, "x")


def test_bus_load_arithmetic():
    one = bus_load(1, 1000)
    assert one.frames_per_cycle == pytest.approx(6.06)            # SYNC, RPDO, 2 TPDOs, 2 published + heartbeats
    assert (round(one.load, 4), round(one.load_worst, 4)) == (0.5413, 0.6539)
    two = bus_load(2, 1000)
    assert two.load_worst > 1.0                                   # two joints do not fit one bus at 1 kHz
    per_joint = bus_loads(BusConfig.from_dict({"channel": ["a", "b"]}, 2, "x"), 1000)
    assert [x.load_worst for x in per_joint] == [one.load_worst] * 2
    assert bus_load(2, 1000, publish=False).load_worst > 0.70     # not even without the publication


def test_the_coupled_two_joint_plant_behind_a_bus_per_joint():
    # the 2-DoF shoulder-elbow example (URDF: M(q), Coriolis, gravity coupled): a torque step on
    # the shoulder alone moves the elbow too, and each bus brings back its joint's angle
    from sea_daemon.core.sim.plant import Plant
    from sea_daemon.io.configfile import data_root, load_config
    t = uuid.uuid4().hex[:6]
    cfg = load_config(data_root() / "configs" / "exo_2dof.yaml")
    b = dataclasses.replace(cfg.hardware.bus, heartbeat_ms=20, pdo_timeout_ms=500.0, heartbeat_timeout_ms=2000,
                            sdo_timeout_ms=3000).with_channel(f"c1-{t},c2-{t}")
    cfg = dataclasses.replace(cfg, hardware=dataclasses.replace(cfg.hardware, bus=b))
    plant = Plant(cfg, q0=[0.3, 0.5], seed=0, torque_noise=0.0)
    r = device_model_rig(cfg, plant, initial_torque=plant.hold_torque)
    try:
        r.start()
        tau = plant.hold_torque + [2.0, 0.0]
        for _ in range(30):
            m = r.hw.read()
            r.hw.write(tau)
        quantum = 2 * np.pi / 2 ** 19
        assert np.all(np.abs(m.q - plant.q) < 2 * quantum)
        assert m.q[0] > 0.35 and m.q[1] < 0.45     # the elbow moved with the shoulder (at rest without the step)
        assert [d.target_permille for d in r.device_model.drives] == \
            [round(x / r.hw.subs[0].nm_per_permille[0]) for x in tau]
    finally:
        r.stop()


def test_an_instance_owns_every_one_of_its_buses(tmp_path, monkeypatch):
    import types

    from sea_daemon.apps.commands.daemon_args import bus_key
    from sea_daemon.errors import InputError
    from sea_daemon.runtime.service import StateFile
    monkeypatch.setenv("SEA_DAEMON_LOCK_DIR", str(tmp_path))
    cfg = two_joint_config(["can7", "can8"], interface="socketcan")
    key = bus_key(types.SimpleNamespace(device_model=None, sim=None), cfg)
    assert key == [("socketcan", "can7"), ("socketcan", "can8")]
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    with StateFile(tmp_path / "a").claim(key):
        with pytest.raises(InputError, match="bus socketcan can8"):
            StateFile(tmp_path / "b").claim(("socketcan", "can8"))
