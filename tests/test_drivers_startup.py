"""HIL: the CANopen start-up sequence against the device model (virtual / remote / vcan0)."""
from __future__ import annotations

import dataclasses

import pytest
from canopen.sdo import SdoAbortedError

from _hil import bus_kind, make_rig, remote_url  # noqa: F401  (fixtures)
from sea_daemon.hw import cia402
from sea_daemon.hw.canopen_hw import CanopenHardware
from sea_daemon.hw.errors import DeviceMismatch
from sea_daemon.core.config import ModelConfig
from sea_daemon.io.configfile import default_config_path, load_yaml
from sea_daemon.errors import ConfigError


def test_startup_configures_and_enables(make_rig):
    rig = make_rig()
    rig.hw.start()
    d, e = rig.drive, rig.encoder
    # CiA 402: operation enabled in cyclic synchronous torque
    assert d.sm.state is cia402.State.OPERATION_ENABLED
    assert d.mode == cia402.MODE_CST
    # NMT operational, heartbeat producer time written to every node
    for node in (d, e):
        assert node.nmt.state == "OPERATIONAL"
        assert node.sdo[0x1017].raw == 20
    # PDO mappings written into the devices' dictionaries (what the device itself now uses)
    assert [(i, s, n) for i, s, n in d.tpdos[0].entries] == [(0x6041, 0, 2), (0x6077, 0, 2), (0x6064, 0, 4)]
    assert d.tpdos[0].cob_id == 0x180 + d.id and d.tpdos[0].trans_type == 1
    assert len(d.tpdos) == 1 and len(e.tpdos) == 1                  # TPDO2 disabled on both
    assert e.tpdos[0].entries == [(0x6004, 0, 4)]
    rp = d.rpdos[0x200 + d.id]
    assert rp.entries == [(0x6040, 0, 2), (0x6071, 0, 2)] and rp.trans_type == 255   # actuated on reception
    # the drive watches the daemon's heartbeat (node 127, heartbeat_timeout_ms) and quick-stops without it
    assert d.sdo[0x1016][1].raw == (127 << 16) | 1000 and d.sdo[0x6007].raw == 3
    assert d.master_node == 127 and d.master_timeout == 1.0
    # interpolation period = loop period (10 ms), max torque from torque_limit (10 N m = 1000 ‰)
    assert d.period == pytest.approx(0.01)
    assert d.sdo[0x6072].raw == 1000
    # the priming cycle produced a first measurement of the true plant
    assert rig.hw.meas.q[0] == pytest.approx(0.3, abs=2e-5)
    assert rig.hw.meas.theta_m[0] == pytest.approx(rig.plant.theta_m[0], abs=2e-7)   # motor holds the link



def test_wrong_device_type_is_named(make_rig):
    rig = make_rig()
    rig.encoder.data_store.setdefault(0x1000, {})[0] = (0x00020192).to_bytes(4, "little")  # a drive, not an encoder
    with pytest.raises(DeviceMismatch, match=r"node 2: 0x1000 device type: is 0x00020192 \(profile 402\), "
                                             r"expected profile 406"):
        rig.hw.start()


def test_wrong_encoder_resolution_is_named(make_rig):
    rig = make_rig()
    rig.encoder.data_store.setdefault(0x6501, {})[0] = (1 << 17).to_bytes(4, "little")
    with pytest.raises(DeviceMismatch, match=r"node 2: 0x6501 singleturn resolution: is 131072, expected 524288"):
        rig.hw.start()


def test_wrong_motor_resolution_and_gear_are_named(make_rig):
    rig = make_rig()
    rig.drive.data_store.setdefault(0x608F, {})[1] = (1 << 16).to_bytes(4, "little")
    with pytest.raises(DeviceMismatch, match=r"node 1: 0x608F position encoder resolution: is 65536 increments"):
        rig.hw.start()


def test_wrong_gear_and_rated_torque_are_named(make_rig):
    rig = make_rig(rated_torque=150.0)
    with pytest.raises(DeviceMismatch, match=r"node 1: 0x6076 motor rated torque: is 100 mN m, expected 150 mN m"):
        rig.hw.start()


def test_sdo_abort_is_reported_by_node_and_object(make_rig):
    rig = make_rig()

    def refuse(index, subindex, od):
        if index == 0x6502:
            raise SdoAbortedError(0x06020000)          # object does not exist
    rig.drive.add_read_callback(refuse)
    with pytest.raises(DeviceMismatch, match=r"node 1: 0x6502:00 supported drive modes: SDO read aborted: "
                                             r"Code 0x06020000, Object does not exist"):
        rig.hw.start()


def test_rejected_pdo_mapping_is_reported(make_rig):
    rig = make_rig()

    def reject(index, subindex, od, data):
        if index == 0x1A00 and subindex == 3:
            raise SdoAbortedError(0x06040041)          # object cannot be mapped to the PDO
    rig.drive.add_write_callback(reject)
    with pytest.raises(DeviceMismatch, match=r"node 1: 0x1A00 TPDO1 mapping: rejected by the device"):
        rig.hw.start()


def test_missing_device_is_reported(make_rig):
    rig = make_rig()
    b = dataclasses.replace(rig.cfg.hardware.bus, encoder_node=(5,), sdo_timeout_ms=200)   # nobody answers as node 5
    rig.hw = CanopenHardware(dataclasses.replace(rig.cfg, hardware=dataclasses.replace(rig.cfg.hardware, bus=b)),
                             rig.drv_bus)
    with pytest.raises(DeviceMismatch, match=r"node 5: 0x1000:00 device type: no SDO answer"):
        rig.hw.start()


def test_bus_section_validation():
    raw = load_yaml(default_config_path())
    for key, value, msg in (("interface", "pcan", "must be one of virtual, socketcan, remote"),
                            ("drive_node", 200, "in 1..127"),
                            ("encoder_node", 1, "node ids must all differ"),
                            ("heartbeat_timeout_ms", 10, "must be > heartbeat_ms"),
                            ("channel", "127.0.0.1:5000", None)):
        d = dict(raw, hardware=dict(raw["hardware"], bus={key: value, **({"interface": "remote"} if key == "channel" else {})}))
        with pytest.raises(ConfigError, match=msg or "remote bus needs ws://"):
            ModelConfig.from_dict(d, "t.yaml")
    cfg = ModelConfig.from_dict(dict(raw, hardware=dict(raw["hardware"], bus={"rated_torque": 120})), "t.yaml")
    assert cfg.hardware.bus.rated_torque == 120.0
    assert ModelConfig.from_dict(cfg.to_dict(), "rt").hardware.bus == cfg.hardware.bus


def test_wrong_pdo_length_on_read_back_is_named(make_rig):
    rig = make_rig()

    def lie(index, subindex, od):                # a device that reports a 2-byte position value
        if index == 0x1A00 and subindex == 1:
            return 0x60040010
    rig.encoder.add_read_callback(lie)
    with pytest.raises(DeviceMismatch, match=r"node 2: 0x1A00 TPDO1 mapping: reads back 1 objects, 2 bytes; "
                                             r"expected 1 objects, 4 bytes"):
        rig.hw.start()
