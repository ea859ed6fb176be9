"""What the CANopen start-up asks of each node over SDO, and the PDO layout it sets up.

:class:`NodeSetup` is the SDO side of :meth:`sea_daemon.hw.canopen_hw.CanopenHardware.start`
(steps 1–3 and the CiA 402 walk of its module docstring): the device checks — device type
0x1000 (profile 402 / 406), identity 0x1018 (vendor, product as in our EDS), encoder
resolution (drive 0x608F = 2^bits per motor turn, encoder 0x6501 = 2^bits, 0x6502 turns), gear
0x6091, supported modes 0x6502 (CST), rated torque 0x6076 — each difference a
:class:`~sea_daemon.hw.errors.DeviceMismatch` / :class:`~sea_daemon.hw.errors.WrongDevice` naming node and
object; interpolation period 0x60C2 and max torque 0x6072; the PDO mapping, written with
canopen's PDO API and read back; the state machine walked to OPERATION_ENABLED.  Every SDO
transfer first calls ``keepalive`` (the daemon's heartbeat, once the drives watch it).

The PDO layout (:data:`DRIVE_TPDO`, :data:`ENCODER_TPDO`, :data:`DRIVE_RPDO` and their
mappings) is what the cycle packs and unpacks.
"""
from __future__ import annotations

import struct
import time
from typing import Callable

import canopen
from canopen.sdo import SdoAbortedError, SdoCommunicationError

from sea_daemon.core.config import BusConfig
from sea_daemon.io.configfile import data_root

from sea_daemon.hw import cia402
from sea_daemon.hw.errors import DeviceMismatch, WrongDevice

EDS_DIR = data_root() / "configs" / "eds"
DRIVE_EDS = EDS_DIR / "sea_drive.eds"
ENCODER_EDS = EDS_DIR / "sea_load_encoder.eds"

PROFILE_DRIVE, PROFILE_ENCODER = 402, 406
ABORT_QUICK_STOP = 3                    # 0x6007: reaction of the drive to a lost connection

DRIVE_TPDO = struct.Struct("<Hhi")      # 0x6041 statusword, 0x6077 torque actual [‰], 0x6064 position
ENCODER_TPDO = struct.Struct("<I")      # 0x6004 position value
DRIVE_RPDO = struct.Struct("<Hh")       # 0x6040 controlword, 0x6071 target torque [‰]

DRIVE_TPDO_MAP = ((0x6041, 0), (0x6077, 0), (0x6064, 0))
ENCODER_TPDO_MAP = ((0x6004, 0),)
DRIVE_RPDO_MAP = ((0x6040, 0), (0x6071, 0))


def interpolation_period(period: float) -> tuple[int, int]:
    """0x60C2 (value, index) with value·10^index = period, value in 1..255, index -6..0."""
    for index in range(-3, -7, -1):
        value = period * 10.0 ** (-index)
        if 1 <= round(value) <= 255 and abs(round(value) - value) < 1e-6 * max(1.0, value):
            return int(round(value)), index
    for index in range(0, -7, -1):
        value = period * 10.0 ** (-index)
        if 1 <= round(value) <= 255:
            return int(round(value)), index
    raise ValueError(f"period {period} s cannot be written to 0x60C2 (1..255 · 10^-6..10^0 s)")


def _counts_key(counts: int, side: str) -> str:
    """The configuration key that sets an encoder's counts per turn, as an error names it."""
    bits = counts.bit_length() - 1
    if counts == 1 << bits:
        return f"hardware.encoder_bits = {bits} or hardware.encoder_counts.{side}"
    return f"hardware.encoder_counts.{side}"


class NodeSetup:
    """SDO checks and configuration of the drives and load encoders (see the module docstring).

    Per joint of the bus (``j``, 0-based in ``bus_cfg``): ``res_load`` / ``res_motor`` the load
    and motor encoders' counts per turn (``hardware.encoder_counts``, else 2^``encoder_bits``),
    ``gear`` the gear ratio, ``max_permille`` the max torque 0x6072 [‰ of rated torque];
    ``period``: the loop period [s].
    """

    def __init__(self, bus_cfg: BusConfig, *, res_load, res_motor, gear, period: float, max_permille,
                 keepalive: Callable[[], None]):
        self.bus_cfg = bus_cfg
        self.res_load, self.res_motor, self.gear = list(res_load), list(res_motor), list(gear)
        self.period, self.max_permille = period, list(max_permille)
        #: the drives' RPDO deadline 0x1400:5 [ms] (0: not written, off)
        self.rpdo_timeout_ms = int(round(bus_cfg.rpdo_timeout_s(period) * 1e3))
        self.rated = bus_cfg.rated_torques(len(self.gear)).tolist()
        self.keepalive = keepalive

    # ---------------------------------------------------------------- SDO transfers
    def read(self, node, index: int, sub: int, what: str) -> int:
        self.keepalive()
        try:
            var = node.sdo[index] if sub == 0 and not isinstance(node.sdo[index], canopen.sdo.SdoRecord) \
                else node.sdo[index][sub]
            return var.raw
        except SdoAbortedError as e:
            raise WrongDevice(node.id, f"0x{index:04X}:{sub:02X} {what}", f"SDO read aborted: {e}") from None
        except SdoCommunicationError as e:
            raise DeviceMismatch(node.id, f"0x{index:04X}:{sub:02X} {what}", f"no SDO answer: {e}") from None

    def write(self, node, index: int, sub: int, value: int, what: str) -> None:
        self.keepalive()
        try:
            obj = node.sdo[index]
            (obj[sub] if isinstance(obj, (canopen.sdo.SdoRecord, canopen.sdo.SdoArray)) else obj).raw = value
        except SdoAbortedError as e:
            raise WrongDevice(node.id, f"0x{index:04X}:{sub:02X} {what}",
                              f"SDO write of {value} aborted: {e}") from None
        except SdoCommunicationError as e:
            raise DeviceMismatch(node.id, f"0x{index:04X}:{sub:02X} {what}", f"no SDO answer: {e}") from None

    # ---------------------------------------------------------------- device checks
    def _check_identity(self, node, profile: int, kind: str) -> None:
        dtype = self.read(node, 0x1000, 0, "device type")
        if dtype & 0xFFFF != profile:
            raise WrongDevice(node.id, "0x1000 device type",
                              f"is 0x{dtype:08X} (profile {dtype & 0xFFFF}), expected profile {profile} ({kind})")
        info = node.object_dictionary.device_information
        for sub, what, expected in ((1, "vendor-ID", info.vendor_number), (2, "product code", info.product_number)):
            got = self.read(node, 0x1018, sub, what)
            if expected is not None and got != expected:
                raise WrongDevice(node.id, f"0x1018:{sub:02X} {what}",
                                  f"is 0x{got:08X}, expected 0x{expected:08X} ({kind} of our EDS)")

    def check_drive(self, d, j: int = 0) -> None:
        """Device type, identity, motor encoder resolution, gear, CST support, rated torque of
        joint ``j``'s drive."""
        self._check_identity(d, PROFILE_DRIVE, "CiA 402 drive")
        inc = self.read(d, 0x608F, 1, "position encoder resolution, encoder increments")
        rev = self.read(d, 0x608F, 2, "position encoder resolution, motor revolutions")
        res, gear = self.res_motor[j], self.gear[j]
        if rev == 0 or inc != res * rev:
            raise WrongDevice(d.id, "0x608F position encoder resolution",
                              f"is {inc} increments per {rev} motor revolution(s), expected {res} per 1 "
                              f"({_counts_key(res, 'motor')})")
        motor = self.read(d, 0x6091, 1, "gear ratio, motor revolutions")
        shaft = self.read(d, 0x6091, 2, "gear ratio, shaft revolutions")
        if shaft == 0 or abs(motor / shaft - gear) > 1e-9 * gear:
            raise WrongDevice(d.id, "0x6091 gear ratio",
                              f"is {motor}:{shaft}, expected {gear:g}:1 (hardware.gear_ratio)")
        modes = self.read(d, 0x6502, 0, "supported drive modes")
        if not modes & cia402.SUPPORTED_MODE_BIT[cia402.MODE_CST]:
            raise WrongDevice(d.id, "0x6502 supported drive modes",
                              f"is 0x{modes:08X}, needs bit 9 (cyclic synchronous torque, mode 10)")
        rated, want = self.read(d, 0x6076, 0, "motor rated torque"), self.rated[j]
        if abs(rated - want) > 1e-9 * want:
            raise WrongDevice(d.id, "0x6076 motor rated torque",
                              f"is {rated} mN m, expected {want:g} mN m (hardware.bus.rated_torque)")

    def check_encoder(self, e, j: int = 0) -> int:
        """Device type, identity, resolution of joint ``j``'s load encoder; returns the counts
        the position value spans."""
        self._check_identity(e, PROFILE_ENCODER, "CiA 406 encoder")
        res, want = self.read(e, 0x6501, 0, "singleturn resolution"), self.res_load[j]
        if res != want:
            raise WrongDevice(e.id, "0x6501 singleturn resolution",
                              f"is {res}, expected {want} ({_counts_key(want, 'load')})")
        turns = self.read(e, 0x6502, 0, "number of distinguishable revolutions")
        if not 1 <= turns <= (1 << 32) // res:
            raise WrongDevice(e.id, "0x6502 number of distinguishable revolutions",
                              f"is {turns}, allowed 1..{(1 << 32) // res}")
        return res * turns

    # ---------------------------------------------------------------- PDO configuration
    def map_pdo(self, network, node, pdo, number: int, entries, cob_id: int, expected_bytes: int | None,
                trans_type: int = 1) -> None:
        """Write one PDO's communication and mapping parameters; read the mapping back."""
        m = pdo[number]
        what = f"0x{m.map_array.od.index:04X} {'TPDO' if m.map_array.od.index >= 0x1A00 else 'RPDO'}{number} mapping"
        m.clear()
        for index, sub in entries:
            m.add_variable(index, sub)
        m.cob_id = cob_id
        m.trans_type = trans_type             # 1: synchronous, every SYNC; 255: on event / reception
        m.enabled = bool(entries)
        try:
            m.save()
        except SdoAbortedError as e:
            raise WrongDevice(node.id, what, f"rejected by the device: {e}") from None
        except SdoCommunicationError as e:
            raise DeviceMismatch(node.id, what, f"no SDO answer: {e}") from None
        if m.enabled:
            network.unsubscribe(cob_id, m.on_message)       # the cycle snapshots frames itself
        if expected_bytes is None:
            return
        count = self.read(node, m.map_array.od.index, 0, "number of mapped objects")
        bits = sum(self.read(node, m.map_array.od.index, s, "mapping entry") & 0xFF for s in range(1, count + 1))
        if count != len(entries) or bits != 8 * expected_bytes:
            raise WrongDevice(node.id, what, f"reads back {count} objects, {bits // 8} bytes; "
                                             f"expected {len(entries)} objects, {expected_bytes} bytes")

    def configure_drive(self, network, d, j: int = 0) -> None:
        """Interpolation period, max torque (joint ``j``'s), TPDO1 / RPDO1 mapped, the second ones disabled."""
        value, index = interpolation_period(self.period)
        self.write(d, 0x60C2, 1, value, "interpolation time period value")
        self.write(d, 0x60C2, 2, index, "interpolation time index")
        self.write(d, 0x6072, 0, self.max_permille[j], "max torque")
        self.map_pdo(network, d, d.tpdo, 1, DRIVE_TPDO_MAP, 0x180 + d.id, DRIVE_TPDO.size)
        self.map_pdo(network, d, d.tpdo, 2, (), 0x280 + d.id, None)
        self.map_pdo(network, d, d.rpdo, 1, DRIVE_RPDO_MAP, 0x200 + d.id, DRIVE_RPDO.size,
                     1 if self.bus_cfg.sync_rpdo else 255)
        self.map_pdo(network, d, d.rpdo, 2, (), 0x300 + d.id, None)
        if self.rpdo_timeout_ms:
            # RPDO deadline monitoring (CiA 301): no torque command for this long -> EMCY 0x8250 and
            # the reaction of 0x6007 (quick stop: torque to zero), as for a lost heartbeat
            self.write(d, 0x1400, 5, self.rpdo_timeout_ms, "RPDO1 event timer (deadline monitoring)")

    def configure_encoder(self, network, e) -> None:
        """TPDO1 mapped, TPDO2 disabled."""
        self.map_pdo(network, e, e.tpdo, 1, ENCODER_TPDO_MAP, 0x180 + e.id, ENCODER_TPDO.size)
        self.map_pdo(network, e, e.tpdo, 2, (), 0x280 + e.id, None)

    def enable(self, d) -> None:
        """Walk the CiA 402 state machine to OPERATION_ENABLED over SDO."""
        state = None
        for _ in range(8):
            sw = self.read(d, 0x6041, 0, "statusword")
            state = cia402.state_of(sw)
            if state is cia402.State.OPERATION_ENABLED:
                return
            cw = cia402.command_towards(state)
            if cw is None:
                time.sleep(self.period)
                continue
            self.write(d, 0x6040, 0, cw, "controlword")
        raise DeviceMismatch(d.id, "0x6041 statusword",
                             f"drive did not reach OPERATION_ENABLED, stays in {state.name if state else 'invalid state'}")
