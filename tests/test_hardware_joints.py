"""The SEA hardware per joint: ``hardware.gear_ratio``, ``hardware.torque_limit`` and
``hardware.bus.rated_torque`` as a number (every joint) or a list of n, with ``encoder_counts``
per joint, through the configuration, the simulated encoders and plant, the controllers, the
device model and the CANopen driver (counts → angles, torque → per mille of each drive)."""
from __future__ import annotations

import dataclasses
import math
import uuid

import numpy as np
import pytest

from sea_daemon.core.config import ModelConfig
from sea_daemon.core.control import PID, StillArm
from sea_daemon.core.sim.plant import Plant
from sea_daemon.errors import ConfigError
from sea_daemon.hw.errors import WrongDevice
from sea_daemon.io.configfile import data_root, load_config, load_yaml
from sea_daemon.runtime.rig import device_model_rig

#: shoulder and elbow with different drives: gear, encoders, rated torque, torque limit
HW = {"gear_ratio": [100, 50], "torque_limit": [40.0, 5.0], "encoder_bits": 19,
      "encoder_counts": {"load": [524288, 131072], "motor": [524288, 4096]}}


def robot(hw: dict | None = None, bus: dict | None = None) -> ModelConfig:
    """configs/exo_2dof.yaml with ``hw`` (and ``bus``) in its hardware section."""
    path = data_root() / "configs" / "exo_2dof.yaml"
    raw = load_yaml(path)
    raw["hardware"].update(hw or {})
    raw["hardware"]["bus"] = {"heartbeat_ms": 20, "pdo_timeout_ms": 500, "heartbeat_timeout_ms": 2000,
                              "sdo_timeout_ms": 3000, **(bus or {})}
    return ModelConfig.from_dict(raw, str(path), urdf_text=(data_root() / "configs" / "exo_2dof_arm.urdf").read_text())


def test_per_joint_values_and_their_round_trip():
    cfg = robot(HW, {"rated_torque": [100, 200]})
    h = cfg.hardware
    assert h.gear_ratio == (100.0, 50.0) and h.gear_ratios(2).tolist() == [100.0, 50.0]
    assert h.torque_limits(2).tolist() == [40.0, 5.0] and h.torque_limit_max == 40.0
    dq, dm = h.encoder_resolution(2)
    assert dq.tolist() == [2 * math.pi / 524288, 2 * math.pi / 131072]
    assert dm.tolist() == [2 * math.pi / (524288 * 100), 2 * math.pi / (4096 * 50)]
    d = cfg.to_dict()["hardware"]
    assert d["gear_ratio"] == [100.0, 50.0] and d["torque_limit"] == [40.0, 5.0]
    assert d["bus"]["rated_torque"] == [100.0, 200.0]
    assert h.bus.rated_torques(2).tolist() == [100.0, 200.0]
    assert robot(HW).hardware.bus.rated_torques(2).tolist() == [100.0, 100.0]
    assert ModelConfig.from_dict(cfg.to_dict(), cfg.source,
                                 urdf_text=(data_root() / "configs" / "exo_2dof_arm.urdf").read_text()).hardware == h


def test_one_joint_files_keep_their_numbers():
    cfg = load_config(data_root() / "configs" / "exo_1dof.yaml")
    d = cfg.to_dict()["hardware"]
    assert isinstance(d["gear_ratio"], float) and isinstance(d["torque_limit"], float)
    assert isinstance(d["bus"]["rated_torque"], float)
    assert cfg.hardware.gear_ratios(1).tolist() == [cfg.hardware.gear_ratio]


#: what every per-joint setting refused says: the key, the allowed values, the value (and the joint)
PER_JOINT_WORDS = "{key}: must be a number {allowed} or a list of 2 such numbers (one per joint), got {got}"


@pytest.mark.parametrize("key, value, allowed, got", [
    ("gear_ratio", [100, 50, 20], "> 0", "[100, 50, 20]"),
    ("gear_ratio", 0, "> 0", "0"),
    ("torque_limit", [40.0, -5.0], "> 0", "[40.0, -5.0] (joint 2: -5.0)"),
    ("torque_limit", [40.0, "x"], "> 0", "[40.0, 'x'] (joint 2: 'x')"),
    ("torque_noise", [0.02, -0.01], ">= 0", "[0.02, -0.01] (joint 2: -0.01)"),
    ("bus.max_joint_speed", [20.0], "> 0", "[20.0]"),
    ("bus.stuck_motion", [0.05, 0.0], "> 0", "[0.05, 0.0] (joint 2: 0.0)"),
    ("bus.rated_torque", "a lot", "> 0", "'a lot'"),
])
def test_bad_per_joint_values_are_one_line_config_errors(key, value, allowed, got):
    *section, name = key.split(".")
    hw, bus = ({}, {name: value}) if section else ({name: value}, {})
    with pytest.raises(ConfigError) as e:
        robot(hw, bus)
    words = PER_JOINT_WORDS.format(key="hardware." + key, allowed=allowed, got=got)
    assert str(e.value).endswith(words) and "\n" not in str(e.value)


def test_a_list_for_one_joint_is_refused():
    raw = load_yaml(data_root() / "configs" / "exo_1dof.yaml")
    raw["hardware"]["gear_ratio"] = [100, 50]
    with pytest.raises(ConfigError, match="hardware.gear_ratio"):
        ModelConfig.from_dict(raw, "one.yaml")


def test_simulated_encoders_and_torque_limit_per_joint():
    cfg = robot(HW)
    plant = Plant(cfg, q0=[0.3, 0.5], seed=0, torque_noise=0.0)
    enc = plant.encoders
    assert enc.q_loads.tolist() == [2 * math.pi / 524288, 2 * math.pi / 131072]
    q, th = plant.measure()
    assert np.all(np.abs(q - plant.q) <= enc.q_loads) and np.all(np.abs(th - plant.theta_m) <= enc.q_motors)
    assert abs(th[1] - plant.theta_m[1]) > enc.q_motors[0]        # the elbow's coarse motor encoder
    plant.step(np.array([60.0, 60.0]), 0.01, np.zeros(2))
    assert plant.applied_torque.tolist() == [40.0, 5.0]           # each joint clipped at its own limit


def test_controllers_clip_each_joint_at_its_limit():
    pid = PID([100.0, 100.0], [0.0, 0.0], [0.0, 0.0], 0.01, np.array([40.0, 5.0]), derivative="load")
    pid.reset(np.zeros(2))
    u = pid.step(np.array([1.0, 1.0]), np.zeros(2))
    assert u.tolist() == [40.0, 5.0]
    still = StillArm(np.array([1.0, 1.0]), lambda t: np.array([50.0, 50.0]), np.array([40.0, 5.0]))
    assert still.update(0.0).tolist() == [40.0, 5.0]


def _rig(daemon_cfg, plant_cfg):
    t = uuid.uuid4().hex[:6]
    b = daemon_cfg.hardware.bus.with_channel(f"h1-{t},h2-{t}")
    daemon_cfg = dataclasses.replace(daemon_cfg, hardware=dataclasses.replace(daemon_cfg.hardware, bus=b))
    plant = Plant(plant_cfg, q0=[0.3, 0.5], seed=0, torque_noise=0.0)
    return device_model_rig(daemon_cfg, plant, initial_torque=plant.hold_torque), plant


def test_the_driver_converts_each_joint_with_its_own_drive():
    """Counts → angles with each joint's encoders and gear; torque → ‰ of each drive's rated
    torque through its gear, clipped at each joint's limit (the elbow's 5 N m)."""
    cfg = robot(HW, {"rated_torque": [100, 200]})
    r, plant = _rig(cfg, cfg)
    try:
        r.start()
        enc = plant.encoders
        drives = r.device_model.drives
        assert [(d.gear, d.increments, d.rated_mNm) for d in drives] == [(100.0, 524288, 100), (50.0, 4096, 200)]
        assert [e.resolution for e in r.device_model.encoders] == [524288, 131072]
        for _ in range(10):
            m = r.hw.read()
            r.hw.write(plant.hold_torque)
        assert np.all(np.abs(m.q - plant.q) < 2 * enc.q_loads)
        assert np.all(np.abs(m.theta_m - plant.theta_m) < 2 * enc.q_motors)
        nm = [100 / 1e6 * 100, 200 / 1e6 * 50]                    # N m per ‰, joint side
        assert [s.nm_per_permille[0] for s in r.hw.subs] == pytest.approx(nm)
        r.hw.write(np.array([3.0, 8.0]))
        r.hw.read()
        assert [d.target_permille for d in drives] == [round(3.0 / nm[0]), math.ceil(5.0 / nm[1])]
        assert [d.max_permille for d in drives] == [math.ceil(40.0 / nm[0]), math.ceil(5.0 / nm[1])]
    finally:
        r.stop()


def test_a_drive_with_another_gear_than_configured_is_refused_naming_it():
    plant_cfg = robot({"gear_ratio": 100})
    r, _ = _rig(robot({"gear_ratio": [100, 50]}), plant_cfg)
    try:
        with pytest.raises(WrongDevice, match="0x6091 gear ratio.*is 100:1, expected 50:1"):
            r.start()
    finally:
        r.stop()
