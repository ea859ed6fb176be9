"""``make_bus(config)``: a python-can bus for the configured interface.

* ``virtual`` — python-can's in-process virtual bus (tests, the in-process demo);
* ``socketcan`` — a real Linux CAN interface (``can0``) or a virtual one (``vcan0``);
* ``remote`` — python-can-remote's websocket client (``ws://127.0.0.1:PORT/``), joining
  separate processes through ``python -m can_remote`` where the kernel has no SocketCAN.
"""
from __future__ import annotations

import os

import can

from sea_daemon.config import BusConfig
from sea_daemon.errors import ConfigError

from .errors import DeviceMismatch

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
        return can.Bus(interface="remote", channel=channel, bitrate=cfg.bitrate,
                       receive_own_messages=receive_own_messages)
    except DeviceMismatch:
        raise
    except (can.CanError, OSError, ValueError) as e:
        raise DeviceMismatch(None, f"{iface} bus {channel!r}", f"cannot open: {e}") from None
