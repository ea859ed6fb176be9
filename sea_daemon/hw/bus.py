"""``make_bus(config)``: a python-can bus for the configured interface.

* ``virtual`` — python-can's in-process virtual bus (tests, the in-process demo);
* ``socketcan`` — a real Linux CAN interface (``can0``) or a virtual one (``vcan0``);
* ``remote`` — python-can-remote's websocket client (``ws://127.0.0.1:PORT/``), joining
  separate processes through ``python -m can_remote`` where the kernel has no SocketCAN;
* ``ipc`` — :class:`sea_daemon.hw.ipc_bus.IpcBus`, separate processes of one machine over UNIX
  datagram sockets, one hop per frame (the 1 kHz benchmarks where the kernel has no SocketCAN).
"""
from __future__ import annotations

import os

import can

from sea_daemon.core.config import BusConfig
from sea_daemon.errors import ConfigError, InputError

from sea_daemon.hw.errors import DeviceMismatch
from sea_daemon.hw.ipc_bus import IpcBus

INTERFACES = BusConfig.INTERFACES


def socketcan_available(channel: str = "vcan0") -> tuple[bool, str]:
    """Whether a SocketCAN interface exists here; (False, reason) when not."""
    if not hasattr(__import__("socket"), "AF_CAN"):
        return False, "this Python has no socket.AF_CAN (not Linux?)"
    if not os.path.exists(f"/sys/class/net/{channel}"):
        return False, (f"no network interface {channel!r} (kernel without SocketCAN/vcan, or not set up: "
                       f"ip link add dev {channel} type vcan && ip link set up {channel})")
    return True, ""


def make_bus(cfg: BusConfig, *, receive_own_messages: bool = False) -> can.BusABC:
    """Open the bus of ``hardware.bus``; errors name the interface and channel."""
    iface, channel = cfg.interface, cfg.channel
    if iface not in INTERFACES:
        raise ConfigError("hardware.bus", "interface", f"must be one of {', '.join(INTERFACES)}, got {iface!r}")
    try:
        if iface == "virtual":
            return can.Bus(interface="virtual", channel=channel, receive_own_messages=receive_own_messages)
        if iface == "socketcan":
            ok, why = socketcan_available(channel)
            if not ok:
                raise DeviceMismatch(None, f"socketcan {channel}", why)
            return can.Bus(interface="socketcan", channel=channel, receive_own_messages=receive_own_messages)
        if iface == "ipc":
            return IpcBus(channel, receive_own_messages=receive_own_messages)
        return can.Bus(interface="remote", channel=channel, bitrate=cfg.bitrate,
                       receive_own_messages=receive_own_messages)
    except (DeviceMismatch, InputError):
        raise
    except (can.CanError, OSError, ValueError) as e:
        raise DeviceMismatch(None, f"{iface} bus {channel!r}", f"cannot open: {e}") from None


def descriptors(buses) -> list[int] | None:
    """The file descriptor of each bus handle (to wait on them in one ``poll`` / ``select``), or
    None when one has none (``virtual``, python-can-remote)."""
    fds = []
    for bus in buses:
        try:
            fd = bus.fileno()
        except (NotImplementedError, AttributeError, OSError, ValueError):
            return None
        if not isinstance(fd, int) or fd < 0:
            return None
        fds.append(fd)
    return fds


def set_controller_filters(bus: can.BusABC, filters: list[dict]) -> bool:
    """Set acceptance ``filters`` (python-can's ``can_filters``) on ``bus`` where the bus applies
    them below python-can, as a CAN controller's acceptance filter does: SocketCAN's kernel
    filter, the ``ipc`` bus (checked on the raw id, and published to the senders, which then
    send that member nothing it rejects).  Elsewhere (``virtual``, ``remote``) python-can's
    software filter would end a ``recv(0)`` at the first other frame: left unset, False."""
    if isinstance(bus, IpcBus) or type(bus).__name__ == "SocketcanBus":
        bus.set_filters(filters)
        return True
    return False


def frame_bits(dlc: int, stuffing: str = "none") -> int:
    """Bits of a CAN 2.0A data frame (11-bit id) with ``dlc`` data bytes, including the 3-bit IFS.

    SOF 1 + id 11 + RTR 1 + IDE 1 + r0 1 + DLC 4 + data 8·dlc + CRC 15 + CRC delimiter 1 +
    ACK 2 + EOF 7 + IFS 3 = 47 + 8·dlc.  ``stuffing="worst"`` adds ⌊(34 + 8·dlc − 1)/4⌋ stuff
    bits (the 34 + 8·dlc bits from SOF to the end of the CRC are stuffed; worst case one stuff
    bit per 4 bits after the first 5).
    """
    base = 47 + 8 * dlc
    if stuffing == "worst":
        return base + (34 + 8 * dlc - 1) // 4
    if stuffing != "none":
        raise ValueError(f"stuffing must be 'none' or 'worst', got {stuffing!r}")
    return base
