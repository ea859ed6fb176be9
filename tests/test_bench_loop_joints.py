"""bench loop --joints 2: the coupled shoulder-elbow exoskeleton of configs/exo_2dof.yaml on a bus
per joint (the device model's process reads the configuration the bench saves), --uncoupled the
one-joint exoskeleton twice."""
import numpy as np

from sea_daemon.apps.bench._loop_rig import Q0, joints_config, joints_plant
from sea_daemon.core.rates import at_rate
from sea_daemon.hw.device_model.split_plant import SplitPlant
from sea_daemon.io.configfile import load_config, save_config


def test_two_joints_are_the_coupled_urdf_arm(tmp_path):
    cfg = joints_config(2)
    assert cfg.joints == 2 and cfg.model.urdf and cfg.model.rigid is not None
    assert len(cfg.hardware.bus.channels()) == 2                 # a bus per joint
    # saved elsewhere (the device model's --config), it still finds its URDF
    save_config(at_rate(cfg, 1000), tmp_path / "device-model.yaml")
    again = load_config(tmp_path / "device-model.yaml")
    assert again.model.rigid is not None and again.hardware.bus.channels() == cfg.hardware.bus.channels()
    plant = joints_plant(at_rate(cfg, 1000))
    assert not isinstance(plant, SplitPlant) and np.allclose(plant.q, Q0)
    # coupled: the elbow's holding torque depends on the shoulder's angle
    hold = plant.hold_torque
    assert np.all(np.isfinite(hold)) and hold[0] > hold[1] > 0.0


def test_uncoupled_two_joints_and_three_joints_are_one_joint_copies():
    for cfg in (joints_config(2, uncoupled=True), joints_config(3)):
        assert cfg.model.urdf is None and cfg.joints in (2, 3)
        assert isinstance(joints_plant(at_rate(cfg, 1000)), SplitPlant)
    assert len(joints_config(2, one_bus=True).hardware.bus.buses()) == 1
