"""Hardware layer of sea-daemon: the SEA exoskeleton behind one narrow interface.

* :mod:`sea_daemon.hw.interface` — :class:`HardwareInterface` (``start/read/write/safe_stop/stop``) and
  the :class:`Measurement` a ``read()`` returns.
* :mod:`sea_daemon.hw.canopen_hw` — the CANopen implementation (CiA 402 drive + CiA 406 load encoder):
  start-up over SDO, then a PDO-only cycle (RPDO, SYNC, the cycle's TPDOs); with
  :mod:`sea_daemon.hw.canopen_setup` (what start-up asks of each node over SDO, the PDO layout),
  :mod:`sea_daemon.hw.canopen_rx` (the cycle's TPDO buffers) and :mod:`sea_daemon.hw.canopen_positions`
  (counts to joint-side angles, encoder jump and stuck checks).
* :mod:`sea_daemon.hw.sim_hw` — the same interface directly on the simulator, no CAN.
* :mod:`sea_daemon.hw.bus` — ``make_bus(config)`` for virtual / socketcan / remote buses.
* :mod:`sea_daemon.hw.device_model` — CANopen slaves (drive, encoder) on canopen's LocalNode with the
  pieces LocalNode lacks, their physics from the simulator, and fault injection.
* :mod:`sea_daemon.hw.errors` — the HardwareError subclasses, each naming node, object and range.

The hardware layer: may import :mod:`sea_daemon.io`, :mod:`sea_daemon.core` and
:mod:`sea_daemon.errors`, never the runtime or the applications.  See ``docs/can.md``.
"""
from sea_daemon.hw.errors import (
    BusOff, DeviceMismatch, DriveFault, EmcyReceived, EncoderJump, EncoderStuck, HeartbeatLost,
    PdoLengthError, PdoTimeout, SendFailed, WrongDevice)
from sea_daemon.hw.interface import HardwareInterface, Measurement

__all__ = ["HardwareInterface", "Measurement", "PdoTimeout", "HeartbeatLost", "EmcyReceived",
           "EncoderJump", "EncoderStuck", "BusOff", "SendFailed", "DeviceMismatch", "WrongDevice",
           "PdoLengthError", "DriveFault"]
