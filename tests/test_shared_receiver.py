"""The device model's buses on one receive thread (sea_daemon.hw.device_model.receiver), lock-step,
a bus per joint on the ipc bus and on python-can's virtual bus: every plant step acts with the torque each joint's drive was
last commanded before that step's SYNC, whichever bus it came on."""
from __future__ import annotations

import uuid

import numpy as np
import pytest

from _hil import recording_plant
from sea_daemon.hw.device_model.receiver import SharedReceiver
from sea_daemon.runtime.rig import device_model_rig
from test_nbus import two_joint_config


@pytest.fixture(scope="module", autouse=True)
def compiled_plant():
    """The two-joint plant's kernels compiled before a device model steps it in a SYNC handler."""
    recording_plant(0.2, joints=2).step(np.zeros(2), 0.01, np.zeros(2))


@pytest.mark.parametrize("interface", ["ipc", "virtual"])
def test_one_receive_thread_steps_the_plant_with_every_joints_last_command(interface):
    tag = uuid.uuid4().hex[:6]
    cfg = two_joint_config([f"sr1-{tag}", f"sr2-{tag}"], interface=interface)
    plant = recording_plant(0.2, joints=2)
    rig = device_model_rig(cfg, plant)
    sent = []
    try:
        rig.start()
        assert all(isinstance(n.notifier, SharedReceiver) for n in rig.device_model.networks)
        first = len(plant.steps)
        for k in range(60):
            m = rig.hw.read()
            assert m.valid and m.faults == 0
            cmd = np.array([0.5 + 0.01 * k, -0.3 - 0.02 * k])
            rig.hw.write(cmd)
            sent.append(rig.hw.actuated(cmd).copy())
        rig.hw.read()
    finally:
        rig.stop()
    # the step at SYNC k+1 acts with the commands written after SYNC k (asynchronous RPDO)
    stepped = np.array([s[1] for s in plant.steps[first + 1:first + 1 + len(sent)]])
    assert stepped.shape == (len(sent), 2)
    bad = np.flatnonzero(np.any(np.abs(stepped - np.array(sent)) > 1e-9, axis=1))
    assert bad.size == 0, [(int(i), stepped[i].tolist(), sent[i].tolist()) for i in bad[:4]]
