"""The lock-step device model's receive thread paced by the SYNCs (sea_daemon.hw.device_model.receiver):
once a master keeps the drives' period it sleeps on its own timer instead of waiting on the bus
(the master's SYNC wakes no process), and the plant steps with the same commands as before."""
from __future__ import annotations

import time

import numpy as np

from _hil import hil_config, hil_rig, recording_plant
from sea_daemon.hw.device_model.receiver import SharedReceiver

P = 0.002


def _receiver() -> SharedReceiver:
    return SharedReceiver([object()], [object()], [0], period=lambda: P)


def test_the_timer_takes_over_after_the_syncs_keep_the_period_and_a_sync_off_it_ends_that():
    r = _receiver()
    t = 1000.0
    late = [0.0, 30e-6, 10e-6, 50e-6, 5e-6, 20e-6, 40e-6, 15e-6] * 8     # how late each SYNC comes [s]
    for k in range(SharedReceiver.PACE_RUN):
        r._synced(t + k * P + late[k])
        assert r._at_pace == k                      # the first interval is the first at the pace
    for k in range(SharedReceiver.PACE_RUN, len(late)):
        r._synced(t + k * P + late[k])
    assert r._at_pace >= SharedReceiver.PACE_RUN
    k = len(late)
    # the next SYNC expected at the earliest phase seen (it creeps later by PACE_CREEP a SYNC);
    # the timer ends after the running quantile of how late they came, within the largest
    assert abs(r._expect - (t + k * P)) < 0.05 * P
    assert 0.0 < r._late <= SharedReceiver.PACE_LATE_MAX * P
    # nine in ten of these SYNCs came before the timer's end, at most a tenth of the period late
    assert r._late >= 20e-6 and r._late < 0.1 * P
    r._synced(t + (k + 1) * P + 0.6 * P)           # off the period (a stall): the bus again
    assert r._at_pace == 0


def test_no_timer_without_a_period_or_descriptors():
    assert SharedReceiver.of([object()], [object()], period=None) is None        # one bus: canopen's Notifier
    r = SharedReceiver([object()], [object()], None, period=lambda: P)            # no descriptor: not paced
    assert r.period is None


def test_a_master_at_the_period_is_answered_off_the_timer_with_the_same_steps():
    cfg = hil_config("ipc")
    plant = recording_plant(0.3)
    rig = hil_rig(cfg, plant)
    sent = []
    try:
        rig.hw.start()
        recv = rig.device_model.networks[0].notifier
        assert isinstance(recv, SharedReceiver) and recv.period is not None
        first = len(plant.steps)
        t0 = time.monotonic()
        for k in range(60):
            # the master's pace: each SYNC at its deadline, as the loop in real-time pace sends it
            time.sleep(max(0.0, t0 + k * cfg.dt - time.monotonic()))
            m = rig.hw.read()
            assert m.valid and m.faults == 0
            cmd = np.array([0.4 + 0.01 * k])
            rig.hw.write(cmd)
            sent.append(rig.hw.actuated(cmd).copy())
        rig.hw.read()
        waits = recv.paced_waits
    finally:
        rig.stop()
    assert waits > 0                                  # SYNCs taken off the timer, not a wake-up
    stepped = np.array([s[1] for s in plant.steps[first + 1:first + 1 + len(sent)]])
    assert stepped.shape == (len(sent), 1)
    assert np.abs(stepped - np.array(sent)).max() <= 1e-9
