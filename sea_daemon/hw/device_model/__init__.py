"""CANopen device model of the SEA exoskeleton (drive + load encoder) with fault injection.

Built on canopen's :class:`~canopen.LocalNode` with what it lacks (SYNC-triggered TPDOs,
RPDO → dictionary, CiA 402 state machine, EMCY, device faults); physics from the simulator's
true plant, stepped in lock-step with SYNC or free-running.  Runnable on its own:
``sea-daemon device-model --bus virtual|remote|socketcan --channel ...``.
"""
from sea_daemon.hw.device_model.drive import DriveNode
from sea_daemon.hw.device_model.encoder import EncoderNode
from sea_daemon.hw.device_model.faults import FaultSpec, parse_fault
from sea_daemon.hw.device_model.model import DeviceModel
from sea_daemon.hw.device_model.slave import DeviceNetwork, SlaveNode

__all__ = ["DeviceModel", "DriveNode", "EncoderNode", "SlaveNode", "DeviceNetwork", "FaultSpec", "parse_fault"]
