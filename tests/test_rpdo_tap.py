"""The lock-step device model on the ipc bus takes its drives' RPDOs on a handle that no thread
waits on, in the SYNC handler (sea_daemon.hw.device_model.model): the master's torque command no
longer wakes the model between two SYNCs, and every plant step still acts with the command sent
after the SYNC before it."""
from __future__ import annotations

import numpy as np

from _hil import hil_config, hil_rig, recording_plant


def _run(kind: str, cycles: int = 60):
    plant = recording_plant(0.3)
    rig = hil_rig(hil_config(kind), plant)
    sent = []
    try:
        rig.hw.start()
        first = len(plant.steps)
        model = rig.device_model
        frames0 = model.network.frames
        for k in range(cycles):
            m = rig.hw.read()
            assert m.valid and m.faults == 0
            cmd = np.array([0.4 + 0.01 * k])
            rig.hw.write(cmd)
            sent.append(rig.hw.actuated(cmd).copy())
        rig.hw.read()
        frames = model.network.frames - frames0
        taps = list(model._rpdo_taps)
    finally:
        rig.stop()
    stepped = np.array([s[1] for s in plant.steps[first + 1:first + 1 + len(sent)]])
    return stepped, np.array(sent), frames, taps


def test_on_ipc_each_step_acts_with_the_command_sent_after_the_sync_before_taken_off_a_tap():
    stepped, sent, frames, taps = _run("ipc")
    assert taps[0] is not None                       # the RPDOs came on the tap
    assert stepped.shape == sent.shape
    bad = np.flatnonzero(np.abs(stepped - sent).max(axis=1) > 1e-9)
    assert bad.size == 0, [(int(i), stepped[i].tolist(), sent[i].tolist()) for i in bad[:4]]
    # the model counts every frame it received or sent, the RPDOs taken off the tap too: per
    # cycle a SYNC, an RPDO and two TPDOs (heartbeats aside)
    assert frames >= 4 * 60


def test_the_same_steps_as_on_the_in_process_bus_without_a_tap():
    ipc, sent_ipc, _, _ = _run("ipc")
    virt, sent_virt, _, taps = _run("virtual")
    assert taps == [None]
    assert np.array_equal(ipc, virt) and np.array_equal(sent_ipc, sent_virt)
