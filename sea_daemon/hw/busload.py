"""The CAN frames of one cycle on each bus, and the bus load they make (docs/can.md "Bus load").

Per bus and cycle: one SYNC (0 bytes); per joint on the bus the drive's RPDO1 (controlword,
target torque: 4 bytes), the drive's TPDO1 (statusword, torque actual, position: 8 bytes) and the
load encoder's TPDO1 (position: 4 bytes); with ``hardware.bus.publish`` the daemon's TPDO of each
of those joints (τ̂_h,act, ρ_k: 8 bytes) and its status TPDO2 (8 bytes); and the heartbeats (1
byte) of the bus's nodes and the daemon's node, one per ``heartbeat_ms`` each.  Bits per frame:
:func:`sea_daemon.hw.bus.frame_bits` (11-bit identifiers), without stuffing and with worst-case
stuffing.
"""
from __future__ import annotations

from dataclasses import dataclass

from sea_daemon.core.config import BusConfig
from sea_daemon.hw.bus import frame_bits
from sea_daemon.hw.canopen_setup import DRIVE_RPDO, DRIVE_TPDO, ENCODER_TPDO

#: the daemon's published frames: 8 bytes each (sea_daemon.client TPDO_JOINT, TPDO_STATUS)
PUBLISHED_DLC = 8
#: the load a bus is planned for, with worst-case stuffing (room for SDO, EMCY, error frames)
PLANNED_LOAD = 0.70


@dataclass(frozen=True)
class BusLoad:
    """One bus's cycle: its channel, joints (0-based), frames per cycle and load (fraction of
    its bitrate) without stuffing and with worst-case stuffing."""

    channel: str
    joints: tuple[int, ...]
    frames_per_cycle: float
    load: float
    load_worst: float

    def to_dict(self) -> dict:
        return {"channel": self.channel, "joints": [j + 1 for j in self.joints],
                "frames_per_cycle": self.frames_per_cycle, "load": self.load, "load_worst_stuffing": self.load_worst}


def cycle_dlcs(joints: int, publish: bool) -> list[int]:
    """Data lengths of the frames one bus carries every cycle for ``joints`` joints (heartbeats apart)."""
    out = [0]                                                      # SYNC
    out += [DRIVE_RPDO.size, DRIVE_TPDO.size, ENCODER_TPDO.size] * joints
    if publish:
        out += [PUBLISHED_DLC] * (joints + 1)                       # a TPDO per joint, the status TPDO2
    return out


def bus_load(joints: int, rate_hz: float, *, publish: bool = True, heartbeat_ms: float = 50.0,
             bitrate: float = 1e6, channel: str = "", joint_ids: tuple[int, ...] = ()) -> BusLoad:
    """The load of one bus carrying ``joints`` joints at ``rate_hz`` (see the module docstring)."""
    dlcs = cycle_dlcs(joints, publish)
    hb_per_cycle = (2 * joints + 1) * 1e3 / (rate_hz * heartbeat_ms)   # the devices' and the daemon's
    bits = [sum(frame_bits(d, s) for d in dlcs) + hb_per_cycle * frame_bits(1, s) for s in ("none", "worst")]
    return BusLoad(channel, joint_ids or tuple(range(joints)), len(dlcs) + hb_per_cycle,
                   bits[0] * rate_hz / bitrate, bits[1] * rate_hz / bitrate)


def bus_loads(b: BusConfig, rate_hz: float) -> list[BusLoad]:
    """The load of every bus of ``hardware.bus`` at ``rate_hz`` (:meth:`BusConfig.buses`)."""
    return [bus_load(len(js), rate_hz, publish=b.publish, heartbeat_ms=b.heartbeat_ms, bitrate=b.bitrate,
                     channel=c, joint_ids=js) for c, js in b.buses()]


def measured_load(frames: float, data_bytes: float, syncs: int, rate_hz: float,
                  bitrate: float = 1e6) -> tuple[float, float, float]:
    """Frames per cycle and the load (fraction of ``bitrate``) without and with worst-case
    stuffing of ``frames`` frames carrying ``data_bytes`` data bytes in all, counted over
    ``syncs`` cycles at ``rate_hz``: :func:`~sea_daemon.hw.bus.frame_bits` is affine in the data
    length (47 + 8·DLC bits, 55 + 10·DLC with worst-case stuffing), so the totals suffice."""
    per_cycle = rate_hz / syncs / bitrate
    loads = [(frames * frame_bits(0, s) + data_bytes * (frame_bits(1, s) - frame_bits(0, s))) * per_cycle
             for s in ("none", "worst")]
    return frames / syncs, loads[0], loads[1]


def describe(loads: list[BusLoad]) -> str:
    """One line: per bus its joints, frames per cycle and load with worst-case stuffing."""
    return "; ".join(f"bus {x.channel} (joint{'s' if len(x.joints) > 1 else ''} "
                     f"{', '.join(str(j + 1) for j in x.joints)}): {x.frames_per_cycle:.2f} frames per cycle, "
                     f"{x.load * 100:.1f} % without stuffing, {x.load_worst * 100:.1f} % with worst-case stuffing"
                     for x in loads)
