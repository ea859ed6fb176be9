"""Faults of the hardware layer, one class per cause (python-can style hierarchy).

Every class derives from :class:`sea_daemon.errors.HardwareError`, names the CANopen node and
object involved, the value seen and the allowed range, and carries ``fault`` — the code of the
daemon's single fault policy (:class:`sea_daemon.errors.Fault`); the driver also sets that
code's bit (``fault.bit``) in :attr:`sea_daemon.hw.interface.Measurement.faults`.
"""
from __future__ import annotations

from sea_daemon.errors import Fault
from sea_daemon.errors import HardwareError, InputError


def _node(node: int | None) -> str:
    return f"node {node}" if node is not None else "bus"


class PdoTimeout(HardwareError):
    """A TPDO of this cycle did not arrive within the PDO timeout after SYNC."""

    fault = Fault.TPDO_MISSING

    def __init__(self, node: int, cob_id: int, cycle: int, timeout_s: float, missed: int = 1):
        self.node, self.cob_id, self.cycle, self.timeout_s, self.missed = node, cob_id, cycle, timeout_s, missed
        super().__init__(f"{_node(node)}: TPDO 0x{cob_id:03X} missing in cycle {cycle} "
                         f"(waited {timeout_s * 1e3:.1f} ms after SYNC; {missed} consecutive cycle(s) missed)")


class PdoLengthError(HardwareError):
    """A TPDO of this cycle arrived with a length other than its mapping's (CiA 301: a PDO
    length error; the data cannot be decoded).  Treated as a missing TPDO."""

    fault = Fault.TPDO_MISSING

    def __init__(self, node: int, cob_id: int, got: int, expected: int, cycle: int):
        self.node, self.cob_id, self.got, self.expected, self.cycle = node, cob_id, got, expected, cycle
        super().__init__(f"{_node(node)}: TPDO 0x{cob_id:03X} has {got} bytes, expected {expected} "
                         f"(PDO length error in cycle {cycle}: mapping on the device differs)")


class HeartbeatLost(HardwareError):
    """No heartbeat from a node within its consumer time (canopen itself does not check)."""

    fault = Fault.HEARTBEAT_LOST

    def __init__(self, node: int, silent_s: float, timeout_s: float, state: int | None = None):
        self.node, self.silent_s, self.timeout_s, self.state = node, silent_s, timeout_s, state
        what = (f"reports NMT state 0x{state:02X}, allowed 0x05 (operational)" if state is not None
                else f"no heartbeat for {silent_s * 1e3:.0f} ms, allowed <= {timeout_s * 1e3:.0f} ms")
        super().__init__(f"{_node(node)}: heartbeat (0x{0x700 + node:03X}): {what}")


class EmcyReceived(HardwareError):
    """An emergency (EMCY) frame arrived from a node."""

    fault = Fault.EMCY

    def __init__(self, node: int, code: int, register: int, data: bytes = b"", description: str = ""):
        self.node, self.code, self.register, self.data = node, code, register, bytes(data)
        desc = f" ({description})" if description else ""
        super().__init__(f"{_node(node)}: EMCY 0x{code:04X}{desc}, error register 0x{register:02X}, "
                         f"data {self.data.hex() or '-'}")


class EncoderJump(HardwareError):
    """An encoder moved further in one cycle than the joint's maximum speed allows."""

    fault = Fault.ENCODER_JUMP

    def __init__(self, node: int, obj: str, step_rad: float, allowed_rad: float, cycle: int):
        self.node, self.obj, self.step_rad, self.allowed_rad, self.cycle = node, obj, step_rad, allowed_rad, cycle
        super().__init__(f"{_node(node)}: {obj} jumped {step_rad:+.4f} rad (joint side) in cycle {cycle}, "
                         f"allowed |step| <= {allowed_rad:.4f} rad")


class EncoderStuck(HardwareError):
    """An encoder's raw count stayed constant while the other encoder of the joint moved."""

    fault = Fault.ENCODER_STUCK

    def __init__(self, node: int, obj: str, count: int, cycles: int, other_motion_rad: float, allowed_rad: float):
        self.node, self.obj, self.count, self.cycles = node, obj, count, cycles
        self.other_motion_rad, self.allowed_rad = other_motion_rad, allowed_rad
        super().__init__(f"{_node(node)}: {obj} stuck at count {count} for {cycles} cycles while the other "
                         f"encoder moved {other_motion_rad:.4f} rad, allowed <= {allowed_rad:.4f} rad")


class SendFailed(HardwareError):
    """Writing a frame to the bus raised (controller error, buffer full, link down)."""

    fault = Fault.SEND_FAILED

    def __init__(self, cob_id: int, what: str, cause: BaseException | str):
        self.cob_id, self.what, self.cause = cob_id, what, cause
        super().__init__(f"bus: sending {what} (COB-ID 0x{cob_id:03X}) failed: {cause}")


class BusOff(SendFailed):
    """The CAN controller went bus-off (error frame with the bus-off flag, or bus state ERROR)."""

    fault = Fault.BUS_OFF

    def __init__(self, detail: str):
        HardwareError.__init__(self, f"bus: controller is bus-off: {detail}")
        self.cob_id, self.what, self.cause = 0, "", detail


class DeviceMismatch(HardwareError):
    """A device is not what the configuration expects: wrong type, resolution, PDO length, an
    SDO abort, or no answer at start-up.  Named by node and object."""

    fault = Fault.DEVICE_FAULT

    def __init__(self, node: int, obj: str, problem: str):
        self.node, self.obj, self.problem = node, obj, problem
        super().__init__(f"{_node(node)}: {obj}: {problem}")


class WrongDevice(DeviceMismatch, InputError):
    """A device answers, but is not the one the configuration and our EDS describe (device type,
    identity, resolution, gear, modes, rated torque, an object it refuses, a PDO mapping it
    rejects or reads back differently).  Also an :class:`InputError`: the bus does not match
    the configuration, so the CLI exits 2 with this one line (docs/interfaces.md §3).  A device that does
    not answer, or a bus that cannot be opened, stays a :class:`DeviceMismatch` (exit 1)."""


class DriveFault(HardwareError):
    """The drive left *operation enabled* (CiA 402 fault, quick stop, disabled) during the cycle."""

    fault = Fault.DEVICE_FAULT

    def __init__(self, node: int, statusword: int, state: str):
        self.node, self.statusword, self.state = node, statusword, state
        super().__init__(f"{_node(node)}: drive state {state} (statusword 0x{statusword:04X}), "
                         f"allowed OPERATION_ENABLED")
