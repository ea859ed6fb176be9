"""The safety settings and the simulated torque noise per joint (``hardware.bus.max_joint_speed``,
``stuck_motion``, ``hardware.torque_noise``: a number or one per joint) and the published
"assistance engaged" flag per joint (docs/interfaces.md §6, docs/can.md)."""
from __future__ import annotations

import dataclasses
import math
import struct
import threading
import uuid

import can
import numpy as np
import pytest

from sea_daemon import client
from sea_daemon.core.config import ModelConfig
from sea_daemon.core.estimators.base import Estimate
from sea_daemon.core.hardware_config import BusConfig
from sea_daemon.core.sim.plant import Plant
from sea_daemon.errors import Fault, InputError
from sea_daemon.hw.canopen_positions import Positions
from sea_daemon.hw.device_model import FaultSpec
from sea_daemon.hw.errors import EncoderJump, EncoderStuck
from sea_daemon.hw.interface import Measurement
from sea_daemon.io.configfile import data_root, load_config
from sea_daemon.runtime.rig import device_model_rig
from test_hardware_joints import robot   # configs/exo_2dof.yaml with hardware settings

URDF = data_root() / "configs" / "exo_2dof_arm.urdf"


# ---------------------------------------------------------------------------- configuration
def test_per_joint_safety_and_noise_values_and_their_round_trip():
    cfg = robot({"torque_noise": [0.03, 0.01]}, {"max_joint_speed": [6.0, 12.0], "stuck_motion": [0.02, 0.08]})
    h = cfg.hardware
    assert h.torque_noise == (0.03, 0.01) and h.torque_noises(2).tolist() == [0.03, 0.01]
    assert h.bus.max_joint_speeds(2).tolist() == [6.0, 12.0] and h.bus.stuck_motions(2).tolist() == [0.02, 0.08]
    d = cfg.to_dict()["hardware"]
    assert d["torque_noise"] == [0.03, 0.01]
    assert d["bus"]["max_joint_speed"] == [6.0, 12.0] and d["bus"]["stuck_motion"] == [0.02, 0.08]
    assert ModelConfig.from_dict(cfg.to_dict(), cfg.source, urdf_text=URDF.read_text()).hardware == h
    # a bus per joint: each bus's configuration keeps its own joint's values
    one, two = (h.bus.for_joints((j,), f"c{j}") for j in range(2))
    assert (one.max_joint_speed, one.stuck_motion, two.max_joint_speed, two.stuck_motion) == (
        (6.0,), (0.02,), (12.0,), (0.08,))
    # a number stays every joint's
    plain = robot().hardware
    assert plain.bus.max_joint_speed == 20.0 and plain.bus.max_joint_speeds(2).tolist() == [20.0, 20.0]


def test_one_joint_files_keep_numbers():
    cfg = load_config(data_root() / "configs" / "exo_1dof.yaml")
    d = cfg.to_dict()["hardware"]
    assert isinstance(d["torque_noise"], float)
    assert isinstance(d["bus"]["max_joint_speed"], float) and isinstance(d["bus"]["stuck_motion"], float)


@pytest.mark.parametrize("check, value, words", [
    ({"positive": True}, [1.0, 0.0], "must be a number > 0 or a list of 2 such numbers (one per joint), got "
                                     "[1.0, 0.0] (joint 2: 0.0)"),
    ({"non_negative": True}, -1, "must be a number >= 0 or a list of 2 such numbers (one per joint), got -1"),
    ({"lo": 0.0, "hi": 10.0}, [1, 2, 3], "must be a number in [0.0, 10.0] or a list of 2 such numbers "
                                         "(one per joint), got [1, 2, 3]"),
    ({"lo": 1.0}, [0.5, 2.0], "must be a number >= 1.0 or a list of 2 such numbers (one per joint), got "
                              "[0.5, 2.0] (joint 1: 0.5)"),
    ({"hi": 2.0}, float("nan"), "must be a number <= 2.0 or a list of 2 such numbers (one per joint), got nan"),
])
def test_the_per_joint_validator_names_the_value_and_the_allowed_range(check, value, words):
    from sea_daemon.core.hardware_config import per_joint
    from sea_daemon.errors import ConfigError
    with pytest.raises(ConfigError) as e:
        per_joint("arm.yaml", "section.key", value, 2, **check)
    assert str(e.value) == f"arm.yaml: section.key: {words}"
    assert per_joint("arm.yaml", "section.key", [3.0], 1, lo=1.0) == 3.0       # one joint: its number


# ---------------------------------------------------------------------------- the encoder checks per joint
def positions(bus: BusConfig, period=0.01) -> tuple[Positions, Measurement]:
    """Counts -> angles of two joints with 2^16 counts per turn on both encoders and gear 1."""
    p = Positions(2, [1 << 16] * 2, [1 << 16] * 2, [1.0, 1.0], bus, period)
    m = Measurement(2)
    for j in range(2):
        p.reference(m, j, 0, 0)
    return p, m


def counts(rad: float) -> int:
    return int(round(rad / (2 * math.pi) * (1 << 16)))


def test_each_joint_is_checked_for_jumps_with_its_own_max_joint_speed():
    bus = dataclasses.replace(BusConfig.default(2), max_joint_speed=(20.0, 2.0))
    p, m = positions(bus)
    step = counts(0.1)              # 0.1 rad in 10 ms: within joint 1's 0.2 rad, beyond joint 2's 0.02
    p.update(m, 0, step, step, 2, 1, 1)
    with pytest.raises(EncoderJump, match=r"node 4: 0x6004 .* allowed \|step\| <= 0\.02"):
        p.update(m, 1, step, step, 4, 3, 1)


def test_each_joint_is_checked_for_a_stuck_encoder_with_its_own_stuck_motion():
    bus = dataclasses.replace(BusConfig.default(2), stuck_cycles=5, stuck_motion=(1.0, 0.02))
    p, m = positions(bus)
    # both joints' load encoders stuck at 0 while their motors turn 0.01 rad per cycle
    for k in range(1, 6):
        p.update(m, 0, 0, counts(0.01 * k), 2, 1, k)        # 0.05 rad: within joint 1's 1.0 rad
    with pytest.raises(EncoderStuck, match=r"node 4: 0x6004 .* allowed <= 0\.0200 rad"):
        for k in range(1, 6):
            p.update(m, 1, 0, counts(0.01 * k), 4, 3, k)


def test_the_driver_of_a_bus_per_joint_checks_each_joint_with_its_own_limit():
    """A 0.1 rad step of a load encoder on the device model: within the shoulder's 20 rad/s,
    beyond the elbow's 5 rad/s (0.05 rad in 10 ms); each joint on its own bus."""
    cfg = robot(bus={"max_joint_speed": [20.0, 5.0]})
    t = uuid.uuid4().hex[:6]
    cfg = dataclasses.replace(cfg, hardware=dataclasses.replace(
        cfg.hardware, bus=cfg.hardware.bus.with_channel(f"js1-{t},js2-{t}")))
    plant = Plant(cfg, q0=[0.3, 0.5], seed=0, torque_noise=0.0)
    rig = device_model_rig(cfg, plant, initial_torque=plant.hold_torque)
    try:
        rig.start()
        for _ in range(3):
            rig.hw.read()
            rig.hw.write(plant.hold_torque)
        rig.device_model.inject(FaultSpec("jump", target="encoder", joint=0, params={"rad": 0.1}))
        rig.hw.read()                                                 # the shoulder's step is allowed
        rig.hw.write(plant.hold_torque)
        rig.device_model.inject(FaultSpec("jump", target="encoder", joint=1, params={"rad": 0.1}))
        with pytest.raises(EncoderJump, match=r"node 4: 0x6004 .* allowed \|step\| <= 0\.05"):
            rig.hw.read()
    finally:
        rig.stop()


# ---------------------------------------------------------------------------- simulated noise per joint
def test_the_plant_draws_each_joints_torque_noise_with_its_own_std():
    cfg = robot()
    u = np.array([1.0, 1.0])

    def applied(noise):
        plant = Plant(cfg, q0=[0.3, 0.5], seed=4, torque_noise=noise)
        plant.step(u, 0.01, np.zeros(2))
        return plant.applied_torque.copy()

    quiet_elbow = applied([0.05, 0.0])
    assert quiet_elbow[1] == 1.0 and quiet_elbow[0] != 1.0
    # one value for every joint draws the same numbers as that value given per joint
    assert applied(0.05).tolist() == applied([0.05, 0.05]).tolist()
    assert applied(0.05)[0] == quiet_elbow[0]
    # from the configuration
    noisy = robot({"torque_noise": [0.0, 0.05]})
    plant = Plant(noisy, q0=[0.3, 0.5], seed=4)
    plant.step(u, 0.01, np.zeros(2))
    assert plant.applied_torque[0] == 1.0 and plant.applied_torque[1] != 1.0


# ---------------------------------------------------------------------------- the engaged flag per joint
class _Hw:
    """The bus a TpdoPublisher sends on, without CANopen's network."""

    def __init__(self, bus):
        self.network = type("Net", (), {})()
        self.network.bus = bus
        self.network.send_lock = threading.Lock()


class _Assist:
    def __init__(self, n):
        self.tau_assist = np.zeros(n)
        self.gain = 2.0


def _status_frames(n: int, assists: list, fault: int = 0) -> list[bytes]:
    """The TPDO2 data the daemon sends for each of ``assists`` (τ_assist per joint)."""
    from sea_daemon.hw.canopen_publish import TpdoPublisher
    from sea_daemon.runtime.publish import Publisher

    ch = f"eng-{uuid.uuid4().hex[:8]}"
    tx, rx = can.Bus(interface="virtual", channel=ch), can.Bus(interface="virtual", channel=ch)
    ctl = _Assist(n)
    pub = Publisher(n, 0.01, tpdo=TpdoPublisher(_Hw(tx), 127, n), controller=ctl)
    e = Estimate.zeros(n)
    e.valid = True
    out = []
    try:
        for k, a in enumerate(assists):
            ctl.tau_assist[:] = a
            pub.publish(k, None, e, np.zeros(n), fault)
            while True:
                m = rx.recv(timeout=1.0)
                if m.arbitration_id == 0x2FF:
                    out.append(bytes(m.data))
                    break
    finally:
        tx.shutdown()
        rx.shutdown()
    return out


def test_one_joint_status_frame_is_as_before():
    base = client.FLAG_ASSIST_ON | client.FLAG_ESTIMATOR
    idle, engaged = _status_frames(1, [[0.0], [0.4]])
    assert idle == struct.pack("<IHBB", 0, 0, 1, base)                   # cycle, fault, valid bits, flags
    assert engaged == struct.pack("<IHBB", 1, 0, 1, base | client.FLAG_ASSIST_ENGAGED)
    assert client.decode_tpdo(0x2FF, engaged)["engaged"] == [True, False, False]


def test_each_joint_has_its_own_engaged_bit():
    frames = _status_frames(2, [[0.0, 0.0], [0.3, 0.0], [0.0, -0.2], [0.1, 0.1]])
    flags = [client.decode_tpdo(0x2FF, f)["flags"] for f in frames]
    assert [client.decode_tpdo(0x2FF, f)["engaged"] for f in frames] == [
        [False, False, False], [True, False, False], [False, True, False], [True, True, False]]
    # "engaged on some joint" keeps its bit
    assert [bool(f & client.FLAG_ASSIST_ENGAGED) for f in flags] == [False, True, True, True]
    assert flags[2] == (client.FLAG_ASSIST_ON | client.FLAG_ESTIMATOR | client.FLAG_ASSIST_ENGAGED
                        | client.FLAG_ASSIST_ENGAGED_JOINT[1])


def test_no_joint_is_engaged_while_a_fault_is_latched():
    frame, = _status_frames(2, [[0.3, 0.3]], fault=int(Fault.EMCY))
    d = client.decode_tpdo(0x2FF, frame)
    assert d["engaged"] == [False, False, False] and not d["flags"] & client.FLAG_ASSIST_ENGAGED


def test_a_local_sample_gives_each_joint_its_engagement():
    buf = bytearray(client.record_size(2))
    client.encode_into(buf, 2, 7, 0.07, 12.5, 0, client.FLAG_ASSIST_ON, 0b11,
                       [(0.1, 1.0, 0.5, 0.2, 0.05, 0.0), (0.2, 2.0, -0.5, 0.3, 0.05, -0.4)])
    assert client.decode(bytes(buf)).engaged == (False, True)


def test_watch_says_which_joints_are_engaged():
    from sea_daemon.apps.commands.watch import View

    def sample(assist):
        n = len(assist)
        engaged = client.FLAG_ASSIST_ENGAGED if any(assist) else 0
        return client.Sample(cycle=1, t=0.01, t_mono=0.0, fault=0, flags=client.FLAG_ASSIST_ON | engaged,
                             valid=(True,) * n, q=(0.5,) * n, tau_m=(1.0,) * n, tau_h_act_hat=(1.0,) * n,
                             tau_h_act_bound=(0.5,) * n, tau_h_act_sigma=(0.1,) * n, tau_assist=tuple(assist))
    sub = type("Sub", (), {"received": 1, "missed": 0, "rejected": 0})()

    def head(assist):
        v = View(window=1.0, height=9, y_range=2.0)
        v.add(sample(assist))
        return v.status("d.sock", sub)[0]
    assert "assist: on, engaged (joint 2)   " in head([0.0, 0.4])
    assert "assist: on, engaged (joints 1, 2)   " in head([0.3, 0.4])
    assert "assist: on, idle   " in head([0.0, 0.0])
    assert "assist: on, engaged   " in head([0.4])                           # one joint: as it was
    # more than 3 joints (no bit per joint in the flags): named from τ_assist all the same
    assert "assist: on, engaged (joints 4, 5)   " in head([0.0, 0.0, 0.0, 0.2, -0.1])
    # the flags say engaged and no joint's τ_assist names it: "on some joint", not a bare "engaged"
    v = View(window=1.0, height=9, y_range=2.0)
    v.add(dataclasses.replace(sample([0.0] * 5), flags=client.FLAG_ASSIST_ON | client.FLAG_ASSIST_ENGAGED))
    assert "assist: on, engaged (on some joint)   " in v.status("d.sock", sub)[0]


def test_engaged_joints_from_the_flags_of_any_model():
    """With the model's joints: one entry per joint; more than 3 joints have only "engaged on some
    joint" (bit 2) in the flags, so which joint is not said (None), never joint 1."""
    on, j2 = client.FLAG_ASSIST_ENGAGED, client.FLAG_ASSIST_ENGAGED_JOINT[1]
    assert client.engaged_joints(on) == [True, False, False]                  # without joints: as it was
    assert client.engaged_joints(on, 1) == [True]
    assert client.engaged_joints(on | j2, 2) == [False, True]
    assert client.engaged_joints(on | j2, 3) == [False, True, False]
    assert client.engaged_joints(on, 5) is None
    assert client.engaged_joints(client.FLAG_ASSIST_ON, 5) == [False] * 5
    for bad in (0, 17, 2.0):
        with pytest.raises(InputError, match=f"joints {bad!r}: allowed 1..16"):
            client.engaged_joints(on, bad)
