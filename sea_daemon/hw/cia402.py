"""CiA 402 (drives and motion control) power state machine: both sides.

Master side: :func:`state_of` decodes the statusword (0x6041), :func:`command_towards` gives the
controlword (0x6040) that moves a drive one transition towards OPERATION_ENABLED.
Slave side: :class:`DriveStateMachine` applies controlwords and faults as a drive does
(used by the device model).  Bit patterns after CiA 402-2, section "device control".
"""
from __future__ import annotations

import enum

# modes of operation (0x6060 / 0x6061)
MODE_CST = 10                     # cyclic synchronous torque
SUPPORTED_MODE_BIT = {MODE_CST: 1 << 9, 4: 1 << 3}   # 0x6502 bit per mode (cst, profile torque)

# controlword commands (0x6040)
CW_SHUTDOWN = 0x0006
CW_SWITCH_ON = 0x0007
CW_ENABLE_OPERATION = 0x000F
CW_DISABLE_VOLTAGE = 0x0000
CW_QUICK_STOP = 0x0002
CW_DISABLE_OPERATION = 0x0007
CW_FAULT_RESET = 0x0080

# statusword bits (0x6041)
SW_READY_TO_SWITCH_ON = 1 << 0
SW_SWITCHED_ON = 1 << 1
SW_OPERATION_ENABLED = 1 << 2
SW_FAULT = 1 << 3
SW_VOLTAGE_ENABLED = 1 << 4
SW_QUICK_STOP = 1 << 5            # 1 = quick stop NOT active
SW_SWITCH_ON_DISABLED = 1 << 6
SW_WARNING = 1 << 7
SW_REMOTE = 1 << 9


class State(enum.Enum):
    NOT_READY_TO_SWITCH_ON = (0x4F, 0x00)
    SWITCH_ON_DISABLED = (0x4F, 0x40)
    READY_TO_SWITCH_ON = (0x6F, 0x21)
    SWITCHED_ON = (0x6F, 0x23)
    OPERATION_ENABLED = (0x6F, 0x27)
    QUICK_STOP_ACTIVE = (0x6F, 0x07)
    FAULT_REACTION_ACTIVE = (0x4F, 0x0F)
    FAULT = (0x4F, 0x08)

    @property
    def bits(self) -> int:
        return self.value[1]


_DECODE = list(State)


def state_of(statusword: int) -> State | None:
    """The power state a statusword reports (None if the pattern is not a valid state)."""
    for s in _DECODE:
        mask, value = s.value
        if statusword & mask == value:
            return s
    return None


def command_towards(state: State | None) -> int | None:
    """Controlword for one step towards OPERATION_ENABLED from ``state`` (None when there)."""
    return {
        State.FAULT: CW_FAULT_RESET,
        State.SWITCH_ON_DISABLED: CW_SHUTDOWN,
        State.READY_TO_SWITCH_ON: CW_SWITCH_ON,
        State.SWITCHED_ON: CW_ENABLE_OPERATION,
        State.QUICK_STOP_ACTIVE: CW_DISABLE_VOLTAGE,
        State.NOT_READY_TO_SWITCH_ON: None,
        State.FAULT_REACTION_ACTIVE: None,
        State.OPERATION_ENABLED: None,
        None: CW_DISABLE_VOLTAGE,
    }[state]


class DriveStateMachine:
    """The drive's side: controlword in, state (and statusword) out.

    Quick stop and fault reaction complete at once (a torque drive only has to remove torque):
    QUICK_STOP_ACTIVE → SWITCH_ON_DISABLED happens on the next *disable voltage*, the fault
    reaction ends in FAULT immediately.  Torque is applied only in OPERATION_ENABLED.
    """

    def __init__(self):
        self.state = State.SWITCH_ON_DISABLED     # NOT_READY_TO_SWITCH_ON passes at power-up
        self._last_cw = 0

    @property
    def statusword(self) -> int:
        sw = self.state.bits | SW_REMOTE
        if self.state in (State.READY_TO_SWITCH_ON, State.SWITCHED_ON, State.OPERATION_ENABLED):
            sw |= SW_VOLTAGE_ENABLED
        return sw

    @property
    def torque_enabled(self) -> bool:
        return self.state is State.OPERATION_ENABLED

    def fault(self) -> None:
        """A fault was detected in the drive: fault reaction, then FAULT."""
        self.state = State.FAULT

    def controlword(self, cw: int) -> State:
        """Apply a controlword (the transitions of the CiA 402 state machine)."""
        s = self.state
        rising_reset = bool(cw & 0x80) and not (self._last_cw & 0x80)
        self._last_cw = cw
        if s is State.FAULT:
            if rising_reset:
                self.state = State.SWITCH_ON_DISABLED                   # transition 15
            return self.state
        if s is State.FAULT_REACTION_ACTIVE:
            return s
        if cw & 0x80:                                                    # reset bit held: no-op
            return s
        if cw & 0x02 == 0:                                               # disable voltage
            self.state = State.SWITCH_ON_DISABLED                       # 7, 9, 10, 12
        elif cw & 0x04 == 0:                                             # quick stop
            if s is State.OPERATION_ENABLED:
                self.state = State.QUICK_STOP_ACTIVE                    # 11
            elif s in (State.READY_TO_SWITCH_ON, State.SWITCHED_ON):
                self.state = State.SWITCH_ON_DISABLED                   # 7, 10
        elif cw & 0x8F == 0x06:                                          # shutdown
            if s in (State.SWITCH_ON_DISABLED, State.SWITCHED_ON, State.OPERATION_ENABLED):
                self.state = State.READY_TO_SWITCH_ON                   # 2, 6, 8
        elif cw & 0x8F == 0x07:                                          # switch on / disable operation
            if s is State.READY_TO_SWITCH_ON:
                self.state = State.SWITCHED_ON                          # 3
            elif s is State.OPERATION_ENABLED:
                self.state = State.SWITCHED_ON                          # 5
        elif cw & 0x8F == 0x0F:                                          # enable operation
            if s is State.SWITCHED_ON:
                self.state = State.OPERATION_ENABLED                    # 4
            elif s is State.READY_TO_SWITCH_ON:
                self.state = State.OPERATION_ENABLED                    # 3 + 4 (switch on + enable)
            elif s is State.QUICK_STOP_ACTIVE:
                self.state = State.OPERATION_ENABLED                    # 16
        return self.state
