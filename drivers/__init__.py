"""Hardware layer of sea-daemon: the SEA exoskeleton behind one narrow interface.

* :mod:`drivers.interface` — :class:`HardwareInterface` (``start/read/write/safe_stop/stop``) and
  the :class:`Measurement` a ``read()`` returns.
* :mod:`drivers.canopen_hw` — the CANopen implementation (CiA 402 drive + CiA 406 load encoder):
  start-up over SDO, then a PDO-only cycle (RPDO, SYNC, the cycle's TPDOs); with
  :mod:`drivers.canopen_setup` (what start-up asks of each node over SDO, the PDO layout),
  :mod:`drivers.canopen_rx` (the cycle's TPDO buffers) and :mod:`drivers.canopen_positions`
  (counts to joint-side angles, encoder jump and stuck checks).
* :mod:`drivers.sim_hw` — the same interface directly on the simulator, no CAN.
* :mod:`drivers.bus` — ``make_bus(config)`` for virtual / socketcan / remote buses.
* :mod:`drivers.device_model` — CANopen slaves (drive, encoder) on canopen's LocalNode with the
  pieces LocalNode lacks, their physics from the simulator, and fault injection.
* :mod:`drivers.errors` — the HardwareError subclasses, each naming node, object and range.

The hardware layer: may import :mod:`sea_daemon.io`, :mod:`sea_daemon.core` and
:mod:`sea_daemon.errors`, never the runtime or the applications.  See ``docs/can.md``.
"""
from drivers.errors import (
    BusOff, DeviceMismatch, DriveFault, EmcyReceived, EncoderJump, EncoderStuck, HeartbeatLost,
    PdoLengthError, PdoTimeout, SendFailed, WrongDevice)
from drivers.interface import FaultFlag, HardwareInterface, Measurement

__all__ = ["HardwareInterface", "Measurement", "FaultFlag", "PdoTimeout", "HeartbeatLost", "EmcyReceived",
           "EncoderJump", "EncoderStuck", "BusOff", "SendFailed", "DeviceMismatch", "WrongDevice",
           "PdoLengthError", "DriveFault"]
