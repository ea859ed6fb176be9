"""The SEA motor drive as a CANopen slave: CiA 402 in cyclic synchronous torque (mode 10)."""
from __future__ import annotations

import math
import struct
import time
from fractions import Fraction

from canopen.sdo import SdoAbortedError

from sea_daemon.hw import cia402
from sea_daemon.hw.device_model.slave import SlaveNode

INT32 = 1 << 32


def wrap_int32(x: int) -> int:
    return (x + (1 << 31)) % INT32 - (1 << 31)


class DriveNode(SlaveNode):
    """Drive: CiA 402 state machine, torque in ‰ of 0x6076, 19-bit motor encoder on 0x6064.

    ``0x6064`` is the motor encoder's multi-turn count (single-turn count + 2^19 · shaft turns,
    as :meth:`sea_daemon.core.sim.sensors.Encoders.raw` reports them) plus an optional preset,
    wrapping as int32 (every 8192 motor turns, about 82 joint turns).
    """

    EDS = "sea_drive.eds"

    def __init__(self, node_id: int, eds=None, *, position_preset: int = 0):
        super().__init__(node_id, eds)
        self.sm = cia402.DriveStateMachine()
        self.mode = 0
        self.target_permille = 0
        self.applied_permille = 0            # torque over the cycle that just ended (0x6077)
        self.error_code = 0
        self.position_preset = int(position_preset)
        self._last_cw = None                 # the last controlword of the RPDO fast path
        self._period = None                  # 0x60C2 [s], cached
        self.increments = self._raw(0x608F, 1) // max(1, self._raw(0x608F, 2))
        self.gear = self._raw(0x6091, 1) / self._raw(0x6091, 2)
        self.rated_mNm = self._raw(0x6076, 0)
        self.position = 0                    # 0x6064 (int32)
        self.velocity = 0                    # 0x606C increments/s
        self.frozen: int | None = None       # stuck encoder fault
        self.jump_counts = 0                 # jumping encoder fault
        self.master_node = 0                 # 0x1016:1 consumer heartbeat: whose, and how long
        self.master_timeout = 0.0
        self.master_last: float | None = None  # time.monotonic() of its last heartbeat (None: not yet)
        # RPDO deadline monitoring (0x1400:5 event timer, CiA 301): armed once two torque RPDOs in a
        # row come within it while OPERATION ENABLED (the master cycles); disarmed when it fires
        self.rpdo_timeout = 0.0              # [s]; 0: off
        self.rpdo_last: float | None = None  # time.monotonic() of the last RPDO1
        self.rpdo_armed = False
        #: the clock of the deadline [s]: real time, or the device time of a lock-step model
        self.rpdo_clock = time.monotonic
        self.max_permille = self._raw(0x6072, 0)   # 0x6072, kept by _on_write
        self.add_read_callback(self._on_read)
        self.add_write_callback(self._on_write)

    def set_hardware(self, increments: int, gear: float, rated_mNm: float) -> None:
        """Another drive than the EDS's (the configured joint's): motor encoder increments per
        motor turn (0x608F), gear ratio (0x6091, motor:shaft revolutions), rated torque (0x6076)."""
        g = Fraction(float(gear)).limit_denominator(1000)
        for index, sub, value in ((0x608F, 1, int(increments)), (0x608F, 2, 1), (0x6091, 1, g.numerator),
                                  (0x6091, 2, g.denominator), (0x6076, 0, int(round(rated_mNm)))):
            obj = self.object_dictionary[index]
            obj = obj if sub == 0 and not hasattr(obj, "subindices") else obj[sub]
            self.set_data(index, sub, obj.encode_raw(value), check_writable=False)
        self.increments = int(increments)
        self.gear = g.numerator / g.denominator
        self.rated_mNm = int(round(rated_mNm))

    def fast_getters(self) -> dict:
        return {0x6041: lambda: self.sm.statusword, 0x6077: lambda: self.applied_permille,
                0x6064: lambda: self.position, 0x606C: lambda: self.velocity, 0x6061: lambda: self.mode,
                0x6071: lambda: self.target_permille, 0x603F: lambda: self.error_code}

    def fast_setters(self) -> dict:
        return {0x6040: self._set_controlword, 0x6071: self._set_target}

    def _set_controlword(self, cw: int) -> None:
        if cw == self._last_cw and self.sm.state is cia402.State.OPERATION_ENABLED:
            return                            # the same command again: nothing changes
        self._last_cw = cw
        was_fault = self.sm.state is cia402.State.FAULT
        self.sm.controlword(cw)
        if was_fault and self.sm.state is not cia402.State.FAULT:
            self.error_code = 0
            self.error_register = 0
            self.emcy.reset(0)

    def _set_target(self, permille: int) -> None:
        self.target_permille = permille

    # ------------------------------------------------------------ connection to the master
    def _on_master_heartbeat(self, can_id, data, timestamp) -> None:
        if not self.muted:
            self.master_last = time.monotonic()

    def check_master(self, now: float) -> bool:
        """Consumer heartbeat: the master silent for longer than 0x1016 → EMCY 0x8130 and the
        reaction of 0x6007 (1 fault, 2 disable voltage, 3 quick stop).  True when it fired."""
        if not self.master_timeout or self.master_last is None or now - self.master_last <= self.master_timeout:
            return False
        self.master_last = None                 # once per loss; re-armed by the next heartbeat
        self._connection_lost(0x8130)           # life guard / heartbeat error
        return True

    def _on_rpdo(self, can_id, data, timestamp) -> None:
        super()._on_rpdo(can_id, data, timestamp)
        if self.rpdo_timeout and can_id == 0x200 + self.id and not self.muted:
            now = self.rpdo_clock()
            enabled = self.sm.state is cia402.State.OPERATION_ENABLED
            # armed by the second of two RPDOs within the deadline while enabled: the master cycles
            # (not by the start-up's one priming command, hours before the loop may start)
            self.rpdo_armed = enabled and self.rpdo_last is not None and now - self.rpdo_last <= self.rpdo_timeout
            self.rpdo_last = now if enabled else None

    def rpdo_deadline(self) -> float | None:
        """When the RPDO deadline monitoring fires if no RPDO1 comes first (None: not armed)."""
        last = self.rpdo_last
        return last + self.rpdo_timeout if self.rpdo_armed and last is not None else None

    def check_rpdo(self, now: float) -> bool:
        """RPDO deadline monitoring (0x1400:5): no torque RPDO for longer than the event timer
        while armed → EMCY 0x8250 (RPDO timeout) and the reaction of 0x6007, as for a lost
        heartbeat (quick stop: the torque goes to zero; a drive does not hold a command the master
        stopped renewing).  True when it fired."""
        deadline = self.rpdo_deadline()
        if deadline is None or now <= deadline:
            return False
        self.rpdo_armed, self.rpdo_last = False, None   # once per loss; re-armed by cycling RPDOs
        if self.sm.state is not cia402.State.OPERATION_ENABLED:
            return False                        # no torque to stop (a master's quick stop, a disable)
        self._connection_lost(0x8250)
        return True

    def _connection_lost(self, code: int) -> None:
        """The reaction of 0x6007 (1 fault, 2 disable voltage, 3 quick stop) and EMCY ``code``
        with the communication bit of the error register."""
        option = self._raw(0x6007, 0)
        if option == 1:
            self.error_code = code
            self.sm.fault()
        elif option == 2:
            self.sm.controlword(cia402.CW_DISABLE_VOLTAGE)
        elif option == 3 and self.sm.state is cia402.State.OPERATION_ENABLED:
            self.sm.controlword(cia402.CW_QUICK_STOP)
        self.emergency(code, 0x11)

    # ------------------------------------------------------------ physics side
    def set_motor_counts(self, counts: int, dtheta_m_joint: float) -> None:
        """Sample the motor encoder: total increments of the motor shaft (multi-turn)."""
        pos = counts + self.position_preset + self.jump_counts
        self.position = wrap_int32(pos) if self.frozen is None else self.frozen
        self.velocity = wrap_int32(round(dtheta_m_joint * self.gear / (2 * math.pi) * self.increments))

    def torque_command(self) -> float:
        """Joint-side torque [N m] the drive applies until the next SYNC; latches 0x6077."""
        if self.sm.torque_enabled and self.mode == cia402.MODE_CST:
            limit = self.max_permille
            self.applied_permille = max(-limit, min(limit, self.target_permille))
        else:
            self.applied_permille = 0
        return self.applied_permille / 1000.0 * self.rated_mNm / 1000.0 * self.gear

    @property
    def period(self) -> float:
        """Interpolation time period 0x60C2 [s] (cached; a write of 0x60C2 clears it)."""
        if self._period is None:
            self._period = self._raw(0x60C2, 1) * 10.0 ** self._raw(0x60C2, 2)
        return self._period

    def drive_fault(self, code: int, data: bytes = b"") -> None:
        """Fault inside the drive: EMCY, fault reaction, torque off."""
        self.error_code = code
        self.sm.fault()
        self.emergency(code, 0x01 | (0x02 if code & 0xF000 == 0x2000 else 0) | (0x80 if code & 0xF000 == 0xF000 else 0), data)

    # ------------------------------------------------------------ dictionary
    def _on_read(self, index: int, subindex: int, od):
        if index == 0x6041:
            return self.sm.statusword
        if index == 0x6061:
            return self.mode
        if index == 0x6064:
            return self.position
        if index == 0x606C:
            return self.velocity
        if index == 0x6077:
            return self.applied_permille
        if index == 0x6071:
            return self.target_permille
        if index == 0x603F:
            return self.error_code
        return None

    def _on_write(self, index: int, subindex: int, od, data: bytes):
        if index == 0x6040:
            self._last_cw = None
            self._set_controlword(struct.unpack_from("<H", data)[0])
        elif index == 0x6072:
            self.max_permille = struct.unpack_from("<H", data)[0]
        elif index == 0x6060:
            mode = struct.unpack_from("<b", data)[0]
            if mode not in (0, cia402.MODE_CST):
                raise SdoAbortedError(0x06090030)              # value range exceeded
            self.mode = mode
        elif index == 0x6071:
            self.target_permille = struct.unpack_from("<h", data)[0]
        elif index == 0x1016 and subindex == 1:
            value = struct.unpack_from("<I", data)[0]
            node, ms = (value >> 16) & 0x7F, value & 0xFFFF
            if self.master_node:
                try:
                    self.network.unsubscribe(0x700 + self.master_node, self._on_master_heartbeat)
                except (KeyError, ValueError):
                    pass
            self.master_node, self.master_timeout, self.master_last = node, ms / 1000.0, None
            if node and ms:
                self.network.subscribe(0x700 + node, self._on_master_heartbeat)
        elif index == 0x1400 and subindex == 5:
            self.rpdo_timeout = struct.unpack_from("<H", data)[0] / 1000.0
            self.rpdo_armed, self.rpdo_last = False, None
        elif index == 0x60C2 and subindex == 2:
            if not -6 <= struct.unpack_from("<b", data)[0] <= 0:
                raise SdoAbortedError(0x06090030)
        if index == 0x60C2:
            self._period = None
