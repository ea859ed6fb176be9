"""The true plant of a URDF model (configs/exo_2dof.yaml) on its compiled path: each RK4 stage is
one compiled call and one Pinocchio ABA, and it integrates the same equations as the generic path
(SEAModel.accelerations)."""
import numpy as np
import pytest

from sea_daemon.core.rates import at_rate
from sea_daemon.core.sim.plant import Plant
from sea_daemon.io.configfile import load_config
from tests._paths import repo_root


@pytest.fixture(scope="module")
def cfg():
    return at_rate(load_config(repo_root() / "configs" / "exo_2dof.yaml"), 1000)


def _drive(plant, steps=300, dt=1e-3):
    rng = np.random.default_rng(7)
    hold = plant.hold_torque.copy()
    for i in range(steps):
        u = hold + rng.normal(0.0, 3.0, plant.n)
        plant.step(u, dt, np.array([0.5 * np.sin(0.01 * i), -0.3]))
    return np.concatenate([plant.q, plant.theta_m, plant.dq, plant.dtheta_m])


def test_rigid_path_matches_generic_equations(cfg):
    fast = Plant(cfg, q0=[0.3, 0.6], seed=3, torque_noise=0.05)
    ref = Plant(cfg, q0=[0.3, 0.6], seed=3, torque_noise=0.05)
    ref._rigid = False                      # the generic path: SEAModel.accelerations per stage
    y_fast, y_ref = _drive(fast), _drive(ref)
    assert np.all(np.isfinite(y_fast))
    assert np.abs(y_fast[:4]).max() > 0.2 and np.abs(y_fast - _drive(Plant(cfg, q0=[0.3, 0.6], seed=4, torque_noise=0.05))).max() > 0
    np.testing.assert_allclose(y_fast, y_ref, rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(fast.applied_torque, ref.applied_torque)
    assert fast.t == ref.t
    # several substeps per step (100 Hz samples, 1 kHz substeps) too
    fast, ref = Plant(cfg, q0=0.4, seed=5), Plant(cfg, q0=0.4, seed=5)
    ref._rigid = False
    np.testing.assert_allclose(_drive(fast, 30, 1e-2), _drive(ref, 30, 1e-2), rtol=1e-12, atol=1e-12)


def test_rigid_path_one_aba_per_stage(cfg, monkeypatch):
    import sea_daemon.core.sim.plant as plant_mod
    plant = Plant(cfg, q0=0.3, seed=1)
    calls = []
    aba = plant_mod.pinocchio_aba()
    monkeypatch.setattr(plant_mod, "pinocchio_aba", lambda: lambda *a: calls.append(1) or aba(*a))

    def generic(*a, **k):
        raise AssertionError("the URDF plant stepped through SEAModel.accelerations")
    monkeypatch.setattr(plant.model, "accelerations", generic)
    plant.step(plant.hold_torque, 5e-3)
    assert len(calls) == 4 * 5              # 5 substeps of 1 ms, four stages each


def test_device_model_samples_the_coupled_plant_per_joint_offsets(cfg, monkeypatch):
    """The device model's encoders and drives sample the coupled plant's state with an offset per
    joint: the counts of the plant's encoders (Encoders.counts), taken from its state vector
    without building arrays per SYNC."""
    import can
    from sea_daemon.hw.device_model import DeviceModel
    plant = Plant(cfg, q0=[0.3, 0.6], seed=2)
    plant.step(plant.hold_torque + 1.0, 1e-3)
    plant.encoders.offset_load = np.array([0.011, -0.027])
    plant.encoders.offset_motor = np.array([-0.003, 0.005])
    cl, cm = plant.encoders.counts(plant.q, plant.theta_m)
    bus = can.Bus(interface="virtual", channel="test-plant-rigid-offsets")
    try:
        dm = DeviceModel(bus, plant, drive_nodes=(1, 3), encoder_nodes=(2, 4))

        def no_arrays(*a):
            raise AssertionError("sampled through Encoders.counts (arrays per SYNC)")
        monkeypatch.setattr(plant.encoders, "counts", no_arrays)
        dm._sample()
        for j in range(2):
            assert dm.encoders[j].position == int(cl[j]) % dm.encoders[j].range
            assert dm.drives[j].position == int(cm[j]) + dm.drives[j].position_preset
    finally:
        bus.shutdown()
