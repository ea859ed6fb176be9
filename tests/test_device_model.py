"""The device model's own CANopen behaviour, seen with a plain canopen master on a virtual bus."""
from __future__ import annotations

import time
import uuid

import can
import canopen
import numpy as np
import pytest
from canopen.sdo import SdoAbortedError

from _hil import recording_plant
from sea_daemon.hw import cia402
from sea_daemon.hw.canopen_setup import DRIVE_EDS
from sea_daemon.hw.device_model import DeviceModel, parse_fault
from sea_daemon.errors import InputError


@pytest.fixture
def bench():
    """Device model + a bare canopen master (RemoteNode for the drive) on one virtual channel."""
    ch = f"dm-{uuid.uuid4().hex[:8]}"
    plant = recording_plant(q0=0.2)
    model = DeviceModel(can.Bus(interface="virtual", channel=ch), plant, owns_bus=True).start()
    net = canopen.Network(can.Bus(interface="virtual", channel=ch))
    net.NOTIFIER_CYCLE = 0.05
    net.connect()
    drive = net.add_node(1, str(DRIVE_EDS))
    yield model, net, drive, plant
    net.disconnect()
    model.stop()


def wait(cond, timeout=2.0):
    deadline = time.monotonic() + timeout
    while not cond():
        assert time.monotonic() < deadline
        time.sleep(0.001)


def test_state_machine_transitions():
    sm = cia402.DriveStateMachine()
    S = cia402.State
    assert sm.state is S.SWITCH_ON_DISABLED and cia402.state_of(sm.statusword) is S.SWITCH_ON_DISABLED
    for cw, expect in ((cia402.CW_ENABLE_OPERATION, S.SWITCH_ON_DISABLED),   # not allowed from here
                       (cia402.CW_SHUTDOWN, S.READY_TO_SWITCH_ON), (cia402.CW_SWITCH_ON, S.SWITCHED_ON),
                       (cia402.CW_ENABLE_OPERATION, S.OPERATION_ENABLED), (cia402.CW_QUICK_STOP, S.QUICK_STOP_ACTIVE),
                       (cia402.CW_ENABLE_OPERATION, S.OPERATION_ENABLED),
                       (cia402.CW_DISABLE_OPERATION, S.SWITCHED_ON), (cia402.CW_DISABLE_VOLTAGE, S.SWITCH_ON_DISABLED)):
        sm.controlword(cw)
        assert sm.state is expect, hex(cw)
        assert cia402.state_of(sm.statusword) is expect
    sm.fault()
    assert cia402.state_of(sm.statusword) is S.FAULT and not sm.torque_enabled
    sm.controlword(cia402.CW_SHUTDOWN)
    assert sm.state is S.FAULT                                   # only a rising fault-reset edge leaves FAULT
    sm.controlword(cia402.CW_FAULT_RESET)
    assert sm.state is S.SWITCH_ON_DISABLED
    # the master's walk reaches OPERATION_ENABLED from every state
    for start in (S.FAULT, S.SWITCH_ON_DISABLED, S.READY_TO_SWITCH_ON, S.SWITCHED_ON, S.QUICK_STOP_ACTIVE):
        sm.state = start
        sm._last_cw = 0
        for _ in range(6):
            cw = cia402.command_towards(cia402.state_of(sm.statusword))
            if cw is None:
                break
            sm.controlword(cw)
        assert sm.state is S.OPERATION_ENABLED, start


def test_boot_heartbeat_and_nmt(bench):
    model, net, drive, plant = bench
    drive.sdo[0x1017].raw = 10
    drive.nmt.wait_for_heartbeat(1.0)
    assert drive.nmt.state == "PRE-OPERATIONAL"
    drive.nmt.state = "OPERATIONAL"
    wait(lambda: drive.nmt.wait_for_heartbeat(1.0) == "OPERATIONAL")
    drive.nmt.state = "RESET COMMUNICATION"                      # reboot: communication objects back to EDS
    wait(lambda: model.drives[0].nmt.state == "PRE-OPERATIONAL")
    assert drive.sdo[0x1017].raw == 0


def test_mapping_entries_are_checked(bench):
    model, net, drive, plant = bench
    with pytest.raises(SdoAbortedError, match="0x06040041"):
        drive.sdo[0x1A00][1].raw = 0x10000020                  # 0x1000 device type is not PDO-mappable
    with pytest.raises(SdoAbortedError, match="0x06040042"):
        drive.sdo[0x1A00][1].raw = 0x60410020                  # statusword is 16 bit, not 32
    with pytest.raises(SdoAbortedError, match="0x06090030"):
        drive.sdo[0x6060].raw = 8                                # only mode 10 (CST) is supported


def test_rpdo_acts_at_the_next_sync_and_tpdo_every_nth_sync(bench):
    model, net, drive, plant = bench
    d = model.drives[0]
    drive.tpdo.read()
    drive.rpdo.read()
    drive.tpdo[1].trans_type = 2                                 # every 2nd SYNC
    drive.tpdo.save()
    drive.nmt.state = "OPERATIONAL"
    wait(lambda: d.nmt.state == "OPERATIONAL")
    for cw in (cia402.CW_SHUTDOWN, cia402.CW_SWITCH_ON, cia402.CW_ENABLE_OPERATION):
        drive.sdo[0x6040].raw = cw
    drive.sdo[0x6060].raw = cia402.MODE_CST
    got = []
    net.subscribe(0x181, lambda cid, data, ts: got.append(bytes(data)))
    drive.rpdo[1]["Target torque"].raw = 250                     # 250 ‰ of 100 mN m · 100 = 2.5 N m
    drive.rpdo[1]["Controlword"].raw = cia402.CW_ENABLE_OPERATION
    drive.rpdo[1].transmit()
    wait(lambda: d._rpdo_pending)
    assert d.target_permille == 0                                # synchronous RPDO: not before SYNC
    for _ in range(4):
        net.sync.transmit()
        time.sleep(0.02)
    assert d.target_permille == 250 and plant.steps[-1][1][0] == pytest.approx(2.5)
    assert len(got) == 2 and len(plant.steps) == 3               # 4 SYNCs: 3 intervals, 2 TPDOs


def test_free_running_mode_steps_without_sync():
    ch = f"dm-{uuid.uuid4().hex[:8]}"
    plant = recording_plant()
    model = DeviceModel(can.Bus(interface="virtual", channel=ch), plant, lock_step=False, owns_bus=True).start()
    try:
        wait(lambda: plant.t >= 0.05)
        assert model.syncs == 0
    finally:
        model.stop()


def test_fault_spec_parsing():
    f = parse_fault("delay:target=encoder,count=3,seconds=0.2,at=1.5,joint=0")
    assert (f.kind, f.target, f.at, f["count"], f["seconds"]) == ("delay", "encoder", 1.5, 3, 0.2)
    assert parse_fault("jump:rad=-0.3")["rad"] == -0.3 and parse_fault("emcy").target == "drive"
    assert parse_fault("emcy:code=0x7305")["code"] == 0x7305
    for bad, msg in (("melt", "allowed drop, delay"), ("drop:target=motor", "allowed drive, encoder"),
                     ("drop:seconds=1", "unknown key"), ("drop:count", "not key=value"),
                     ("drop:at=-1", "at must be")):
        with pytest.raises(InputError, match=msg):
            parse_fault(bad)


def test_scheduled_fault_fires_at_device_time(bench):
    model, net, drive, plant = bench
    model.schedule(parse_fault("stuck:target=encoder,at=0.03"))
    e = model.encoders[0]
    for _ in range(2):
        net.sync.transmit()
    wait(lambda: model.syncs == 2)
    assert e.frozen is None
    for _ in range(3):
        net.sync.transmit()
    wait(lambda: model.syncs == 5)
    assert e.frozen is not None


def test_device_model_command_rejects_bad_input(capsys):
    from sea_daemon.apps.cli import main
    assert main(["device-model", "--bus", "remote", "--channel", "127.0.0.1:5000"]) == 2
    assert "the remote bus needs ws://HOST:PORT/" in capsys.readouterr().err
    assert main(["device-model", "--fault", "melt"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "fault kind 'melt': allowed drop, delay" in err


def test_human_torque_follows_the_scenario():
    from sea_daemon.io.scenario import human_torque
    from _paths import repo_root
    from sea_daemon.core.control import cosine_torque
    from sea_daemon.io.scenario import load_scenario
    active = load_scenario(repo_root() / "configs" / "scenarios" / "active.yaml")
    passive = load_scenario(repo_root() / "configs" / "scenarios" / "passive.yaml")
    assert active.human == "resist" and passive.human == "passive"
    f = human_torque(active)
    t_est = active.training_samples * active.nominal.dt
    c = active.controller
    assert f(0.5 * t_est)[0] == 0.0
    assert f(t_est + 2.5)[0] == pytest.approx(-cosine_torque(2.5, c.amplitude, c.frequency_hz, c.offset))
    assert not np.any(human_torque(passive)(t_est + 2.5))
