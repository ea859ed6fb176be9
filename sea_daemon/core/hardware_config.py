"""The hardware sections of the model configuration (``hardware``, ``hardware.bus``) as validated,
frozen dataclasses: sensors, actuator and the CAN bus the drivers talk to.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np

from sea_daemon.core import validate
from sea_daemon.core.effects import MAX_ABS
from sea_daemon.errors import ConfigError, InputError


def _node_ids(source: str, key: str, v: Any, n: int) -> tuple[int, ...]:
    """CANopen node id(s): an integer (one joint) or a list of n integers, each 1..127."""
    vals = [v] if not isinstance(v, (list, tuple)) else list(v)
    if len(vals) != n or any(isinstance(x, bool) or not isinstance(x, int) or not 1 <= x <= 127 for x in vals):
        raise ConfigError(source, key, f"must be {'an integer' if n == 1 else f'a list of {n} integers'} "
                                       f"in 1..127 (CANopen node id), got {v!r}")
    return tuple(vals)


def _allowed(positive=False, non_negative=False, lo=None, hi=None) -> str:
    """The range :func:`~sea_daemon.core.validate.num` checks with these arguments, as text."""
    if lo is not None and hi is not None:
        return f"in [{lo}, {hi}]"
    if lo is not None or hi is not None:
        return f">= {lo}" if lo is not None else f"<= {hi}"
    return "> 0" if positive else ">= 0" if non_negative else f"within ±{MAX_ABS:g}"


def per_joint(source: str, key: str, v: Any, n: int, **check) -> float | tuple[float, ...]:
    """A setting of every joint (a number) or of each joint (a list of n numbers), each checked as
    :func:`~sea_daemon.core.validate.num` checks it with ``check`` (``positive=True``,
    ``non_negative=True``, ``lo=``/``hi=``): a float, or a tuple of n (a list of one for one
    joint: its float).  Anything else: one :class:`ConfigError` naming ``key``, the value and
    the allowed range (and the joint whose value is out of it)."""
    allowed = _allowed(**check)
    shape = f"a number {allowed}" + (f" or a list of {n} such numbers (one per joint)" if n > 1 else "")
    vals = list(v) if isinstance(v, (list, tuple)) else None
    if vals is not None and len(vals) != n:
        raise ConfigError(source, key, f"must be {shape}, got {v!r}")
    out = []
    for j, x in enumerate([v] if vals is None else vals):
        try:
            out.append(validate.num(source, key, x, **check))
        except ConfigError:
            where = f" (joint {j + 1}: {x!r})" if vals is not None and n > 1 else ""
            raise ConfigError(source, key, f"must be {shape}, got {v!r}{where}") from None
    return out[0] if vals is None or n == 1 else tuple(out)


def joint_values(v: float | tuple[float, ...], n: int) -> np.ndarray:
    """A :func:`per_joint` value as an array of the n joints' values."""
    return np.array(np.broadcast_to(np.asarray(v, dtype=float), (n,)))


def _channels(source: str, key: str, v: Any, n: int) -> tuple[str, tuple[str, ...]]:
    """``hardware.bus.channel``: one name (every joint on that bus) or a list of n names, the bus
    of each joint (joints of one name share it); (the first joint's, the list or ())."""
    if isinstance(v, (list, tuple)):
        if len(v) != n or any(not isinstance(c, str) or not c for c in v):
            raise ConfigError(source, key, f"must be a non-empty string or a list of {n} (one per joint), "
                                           f"got {v!r}")
        return v[0], (tuple(v) if len(set(v)) > 1 else ())
    if not isinstance(v, str) or not v:
        raise ConfigError(source, key, f"must be a non-empty string, got {v!r}")
    return v, ()


@dataclass(frozen=True)
class BusConfig:
    """The CAN bus and the CANopen devices on it (``sea_daemon.hw``).

    Angles and speeds are joint side [rad, rad/s]; ``rated_torque`` is the drive's 0x6076 on the
    MOTOR side in mN m (every drive's, or a tuple of each joint's drive), so one per mille of
    0x6071/0x6077 is ``rated_torque/1e6 * gear_ratio`` N m on the joint side.  ``rated_torque``,
    ``max_joint_speed`` and ``stuck_motion`` are every joint's (a float) or each joint's (a tuple
    of n): :meth:`rated_torques`, :meth:`max_joint_speeds` and :meth:`stuck_motions` give the n
    joints' values.
    """

    interface: str = "virtual"            # virtual | socketcan | remote
    channel: str = "sea-daemon"           # virtual: any name; socketcan: can0/vcan0; remote: ws://host:port/
    #                                       (the first joint's bus when joint_channel names several)
    bitrate: int = 1000000                # [bit/s]
    drive_node: tuple[int, ...] = (1,)    # CiA 402 drive node id per joint
    encoder_node: tuple[int, ...] = (2,)  # CiA 406 load encoder node id per joint
    heartbeat_ms: int = 50                # producer heartbeat time written to 0x1017 of every node
    heartbeat_timeout_ms: int = 200       # consumer: a node is lost after this long without heartbeat
    pdo_timeout_ms: float = 8.0           # wait for a cycle's TPDOs after SYNC [ms]
    # the missed-cycle tolerance (missed_cycles()): cycles in a row without a sample (a missing TPDO, or
    # a stall of the loop: no SYNC, no new command) that are survived.  As a count (max_missed_cycles)
    # or as a duration (max_missed_ms: the longest time from one sample and command to the next,
    # (missed + 1) periods); neither: MAX_MISSED_MS
    max_missed_cycles: int | None = None
    max_missed_ms: float | None = None
    # the drive's RPDO deadline monitoring (CiA 301 RPDO event timer 0x1400:5, EMCY 0x8250, reaction
    # 0x6007): the longest a drive holds a torque command without a new RPDO [ms]; None: derived from
    # the tolerance (rpdo_timeout_s()); 0: off
    rpdo_timeout_ms: int | None = None
    rated_torque: float | tuple[float, ...] = 100.0   # expected 0x6076, motor side [mN m] (per joint: a tuple)
    q_offset: tuple[float, ...] = (0.0,)        # load encoder zero: q = angle(counts) - q_offset [rad]
    theta_m_offset: tuple[float, ...] = (0.0,)  # motor encoder zero, joint side [rad]
    # encoder jump: |dq| > max_joint_speed*dt + 2 quanta [rad/s] (every joint's, or a tuple of each joint's)
    max_joint_speed: float | tuple[float, ...] = 20.0
    stuck_cycles: int = 20                # encoder stuck: same count this many cycles ...
    # ... while the other encoder of the joint moved this far [rad] (every joint's, or each joint's)
    stuck_motion: float | tuple[float, ...] = 0.05
    sync_rpdo: bool = False               # false: the drive actuates the torque RPDO on reception (type 255);
    #                                       true: at the next SYNC (type 1, one cycle more delay)
    sdo_timeout_ms: int = 300             # start-up: wait this long for each SDO answer (one retry)
    master_node: int = 127                # the daemon's own node id: its heartbeat, watched by the drives
    #                                       (0x1016, heartbeat_timeout_ms; reaction 0x6007 = quick stop)
    publish: bool = True                  # the daemon's node sends its TPDOs every cycle (estimate, bound,
    #                                       status; configs/eds/sea_daemon.eds, docs/can.md); joints <= 3
    joint_channel: tuple[str, ...] = ()   # the bus of each joint (YAML: channel as a list of n names;
    #                                       joints of one name share its bus); (): every joint on channel

    KEYS = ["interface", "channel", "bitrate", "drive_node", "encoder_node", "heartbeat_ms",
            "heartbeat_timeout_ms", "pdo_timeout_ms", "max_missed_cycles", "max_missed_ms", "rpdo_timeout_ms",
            "rated_torque", "q_offset",
            "theta_m_offset", "max_joint_speed", "stuck_cycles", "stuck_motion", "sync_rpdo", "sdo_timeout_ms",
            "master_node", "publish"]
    #: joints the daemon's node publishes: joint 1 on TPDO1, joint 2 on TPDO3, joint 3 on TPDO4 (TPDO2: status)
    PUBLISH_JOINTS = 3
    INTERFACES = ("virtual", "socketcan", "remote", "ipc")
    #: the missed-cycle tolerance when the configuration sets none [ms]: one period of the 100 Hz
    #: daemon, the slowest rate of the shipped configurations (docs/daemon.md "Missed cycles")
    MAX_MISSED_MS = 10.0

    @classmethod
    def default(cls, n: int) -> "BusConfig":
        return cls.from_dict({}, n, "<default>")

    @classmethod
    def from_dict(cls, d: Mapping, n: int, source: str) -> "BusConfig":
        validate.check_keys(source, "hardware.bus.", d, cls.KEYS, [])
        k = "hardware.bus."
        iface = d.get("interface", "virtual")
        if iface not in cls.INTERFACES:
            raise ConfigError(source, k + "interface", f"must be one of {', '.join(cls.INTERFACES)}, got {iface!r}")
        channel, joint_channel = _channels(source, k + "channel", d.get("channel", "sea-daemon"), n)
        for c in joint_channel or (channel,):
            if iface == "remote" and not c.startswith(("ws://", "wss://")):
                raise ConfigError(source, k + "channel", f"remote bus needs ws://HOST:PORT/, got {c!r}")
        ints = {}
        for key, lo, hi, default in (("bitrate", 10000, 1000000, 1000000), ("heartbeat_ms", 1, 65535, 50),
                                     ("heartbeat_timeout_ms", 1, 600000, 200), ("max_missed_cycles", 0, 1000, None),
                                     ("rpdo_timeout_ms", 0, 65535, None),
                                     ("stuck_cycles", 2, 100000, 20), ("sdo_timeout_ms", 10, 60000, 300),
                                     ("master_node", 1, 127, 127)):
            v = d.get(key, default)
            if v is None and default is None:
                ints[key] = None                 # not set: derived (missed_cycles(), rpdo_timeout_s())
                continue
            if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
                raise ConfigError(source, k + key, f"must be an integer in {lo}..{hi}, got {v!r}")
            ints[key] = v
        missed_ms = d.get("max_missed_ms")
        if missed_ms is not None:
            if ints["max_missed_cycles"] is not None:
                raise ConfigError(source, k + "max_missed_ms", f"give max_missed_ms or max_missed_cycles, not both "
                                                               f"(got {missed_ms!r} and {ints['max_missed_cycles']!r})")
            missed_ms = validate.num(source, k + "max_missed_ms", missed_ms, lo=0.0, hi=60000.0)
        if ints["heartbeat_timeout_ms"] <= ints["heartbeat_ms"]:
            raise ConfigError(source, k + "heartbeat_timeout_ms",
                              f"must be > heartbeat_ms ({ints['heartbeat_ms']}), got {ints['heartbeat_timeout_ms']}")
        # default: joint i has drive 2i+1 and load encoder 2i+2
        drive = _node_ids(source, k + "drive_node", d.get("drive_node", [2 * i + 1 for i in range(n)]), n)
        enc = _node_ids(source, k + "encoder_node", d.get("encoder_node", [2 * i + 2 for i in range(n)]), n)
        if len(set(drive) | set(enc) | {ints["master_node"]}) != 2 * n + 1:
            raise ConfigError(source, k + "encoder_node", f"node ids must all differ, got drives {list(drive)}, "
                                                          f"encoders {list(enc)}, master {ints['master_node']}")
        sync_rpdo = d.get("sync_rpdo", False)
        if not isinstance(sync_rpdo, bool):
            raise ConfigError(source, k + "sync_rpdo", f"must be true or false, got {sync_rpdo!r}")
        publish = d.get("publish", n <= cls.PUBLISH_JOINTS)
        if not isinstance(publish, bool):
            raise ConfigError(source, k + "publish", f"must be true or false, got {publish!r}")
        if publish and n > cls.PUBLISH_JOINTS:
            raise ConfigError(source, k + "publish",
                              f"the daemon's node publishes joints 1..{cls.PUBLISH_JOINTS} (TPDO1, TPDO3, TPDO4), "
                              f"the model has {n}; allowed: false (the local interface carries every joint)")
        return cls(
            interface=iface, channel=channel, joint_channel=joint_channel, drive_node=drive, encoder_node=enc, **ints, sync_rpdo=sync_rpdo,
            publish=publish, max_missed_ms=missed_ms,
            pdo_timeout_ms=validate.num(source, k + "pdo_timeout_ms", d.get("pdo_timeout_ms", 8.0), lo=0.1, hi=10000.0),
            rated_torque=per_joint(source, k + "rated_torque", d.get("rated_torque", 100.0), n, positive=True),
            q_offset=tuple(float(x) for x in validate.vector(source, k + "q_offset", d.get("q_offset", 0.0), n)),
            theta_m_offset=tuple(float(x) for x in validate.vector(source, k + "theta_m_offset", d.get("theta_m_offset", 0.0), n)),
            max_joint_speed=per_joint(source, k + "max_joint_speed", d.get("max_joint_speed", 20.0), n, positive=True),
            stuck_motion=per_joint(source, k + "stuck_motion", d.get("stuck_motion", 0.05), n, positive=True),
        )

    def missed_cycles(self, period: float) -> int:
        """The missed-cycle tolerance at the loop period ``period`` [s]: the cycles in a row without
        a sample (a missing TPDO, or a stall of the loop) that are survived.  ``max_missed_cycles``
        as set; else the most with (missed + 1) periods <= ``max_missed_ms`` (default
        :data:`MAX_MISSED_MS`): 0 at 100 Hz, 1 at 200 Hz, 9 at 1 kHz."""
        if self.max_missed_cycles is not None:
            return self.max_missed_cycles
        ms = self.MAX_MISSED_MS if self.max_missed_ms is None else self.max_missed_ms
        return max(0, int(math.floor(ms / 1e3 / period + 1e-9)) - 1)

    def longest_rpdo_gap(self, period: float) -> float:
        """The longest time [s] between two of the daemon's RPDOs (its torque commands) in a run
        that keeps every cycle the tolerance allows: the cycle before a stall writes its RPDO after
        its start, the cycle after it up to ``missed_cycles`` + 1 periods later, after waiting up to
        ``pdo_timeout_ms`` for its TPDOs, plus the work of both cycles before the write (a period
        each at most)."""
        return (self.missed_cycles(period) + 1) * period + self.pdo_timeout_ms / 1e3 + 2 * period

    def rpdo_timeout_s(self, period: float) -> float:
        """The drives' RPDO deadline [s] (0x1400:5, whole ms; 0: off) at the loop period
        ``period``: ``rpdo_timeout_ms`` as set, else :meth:`longest_rpdo_gap` rounded up to a
        whole ms — the tightest that a run keeping its tolerance never trips.  A set value
        shorter than that gap: :class:`~sea_daemon.errors.InputError`, one line (the drive would
        stop a run the loop is told to keep)."""
        ms = math.ceil(self.longest_rpdo_gap(period) * 1e3 - 1e-9)     # the gap in whole ms, rounded up
        if self.rpdo_timeout_ms is None:
            if ms > 65535:
                raise InputError(f"hardware.bus.max_missed_ms / max_missed_cycles: the tolerance at {1 / period:g} Hz "
                                 f"({self.missed_cycles(period)} missed cycles) needs a drive RPDO deadline of {ms} ms, "
                                 f"more than 0x1400:5 holds (65535 ms); allowed: a shorter tolerance, or "
                                 f"hardware.bus.rpdo_timeout_ms: 0 (off)")
            return ms / 1e3
        if 0 < self.rpdo_timeout_ms < ms:
            raise InputError(f"hardware.bus.rpdo_timeout_ms: must be 0 (off) or >= {ms} ms "
                             f"(the longest gap between two torque commands the missed-cycle tolerance allows at "
                             f"{1 / period:g} Hz: {self.missed_cycles(period)} missed cycles), "
                             f"got {self.rpdo_timeout_ms}")
        return self.rpdo_timeout_ms / 1e3

    def rated_torques(self, n: int) -> np.ndarray:
        """Each of the n joints' drive ``rated_torque`` (0x6076), motor side [mN m]."""
        return joint_values(self.rated_torque, n)

    def max_joint_speeds(self, n: int) -> np.ndarray:
        """Each of the n joints' ``max_joint_speed`` [rad/s]."""
        return joint_values(self.max_joint_speed, n)

    def stuck_motions(self, n: int) -> np.ndarray:
        """Each of the n joints' ``stuck_motion`` [rad]."""
        return joint_values(self.stuck_motion, n)

    def channels(self) -> tuple[str, ...]:
        """The bus channel of each joint (``len(drive_node)`` of them)."""
        return self.joint_channel or (self.channel,) * len(self.drive_node)

    def buses(self) -> list[tuple[str, tuple[int, ...]]]:
        """The buses in the order of their first joint: (channel, the joints on it, 0-based)."""
        out: dict[str, list[int]] = {}
        for j, c in enumerate(self.channels()):
            out.setdefault(c, []).append(j)
        return [(c, tuple(js)) for c, js in out.items()]

    def for_joints(self, joints, channel: str) -> "BusConfig":
        """The configuration of one bus: ``channel`` with the devices of ``joints`` (0-based)."""
        pick = lambda v: tuple(v[j] for j in joints)  # noqa: E731
        each = lambda v: pick(v) if isinstance(v, tuple) else v  # noqa: E731  (a per_joint value)
        return dataclasses.replace(self, channel=channel, joint_channel=(), drive_node=pick(self.drive_node),
                                   encoder_node=pick(self.encoder_node), q_offset=pick(self.q_offset),
                                   theta_m_offset=pick(self.theta_m_offset), rated_torque=each(self.rated_torque),
                                   max_joint_speed=each(self.max_joint_speed), stuck_motion=each(self.stuck_motion))

    def with_channel(self, text: str) -> "BusConfig":
        """``--channel``: one name (every joint on it) or a comma-separated name per joint."""
        channel, joint_channel = _channels("--channel", "", text.split(",") if "," in text else text,
                                           len(self.drive_node))
        return dataclasses.replace(self, channel=channel, joint_channel=joint_channel)

    def to_dict(self) -> dict:
        out = dataclasses.asdict(self)
        joint_channel = out.pop("joint_channel")
        if joint_channel:
            out["channel"] = list(joint_channel)
        for key in ("drive_node", "encoder_node", "q_offset", "theta_m_offset"):
            v = list(out[key])
            out[key] = v[0] if len(v) == 1 else v
        for key in ("rated_torque", "max_joint_speed", "stuck_motion"):
            if isinstance(out[key], tuple):
                out[key] = list(out[key])
        for key in ("max_missed_cycles", "max_missed_ms", "rpdo_timeout_ms"):
            if out[key] is None:
                del out[key]                    # not set: derived
        return out


@dataclass(frozen=True)
class LocalReaders:
    """``hardware.local_readers``: user names or uids, group names or gids."""

    users: tuple[str | int, ...] = ()
    groups: tuple[str | int, ...] = ()


def _keyed(source: str, key: str, v: Any, allowed: tuple[str, ...], example: str) -> None:
    """``key`` must be a mapping whose keys are among ``allowed``; ConfigError naming it otherwise."""
    if not isinstance(v, Mapping):
        raise ConfigError(source, key, f"must be a mapping like {example}, got {v!r}")
    for k in v:
        if k not in allowed:
            raise ConfigError(source, f"{key}.{k}", f"unknown key; allowed: {', '.join(allowed)}")


@dataclass(frozen=True)
class HardwareConfig:
    """The exoskeleton's sensors and actuator (Sec. V-A) and the CAN bus.

    ``gear_ratio``, ``torque_limit`` and ``torque_noise`` are every joint's (a number) or each
    joint's (a tuple of n, from a list in the YAML): :meth:`gear_ratios`, :meth:`torque_limits`
    and :meth:`torque_noises` give the n joints' values.
    """

    gear_ratio: float | tuple[float, ...] = 100.0     # motor turns per joint turn
    encoder_bits: int = 19           # both absolute encoders
    torque_limit: float | tuple[float, ...] = 10.0    # |τ_m| limit, joint side [N m]
    torque_noise: float | tuple[float, ...] = 0.02   # std of motor-torque noise, joint side [N m] (simulator)
    bus: BusConfig = field(default_factory=BusConfig)   # CAN bus and CANopen devices (sea_daemon.hw)
    # counts per revolution of the shaft each encoder reads, per joint: the load encoder on the
    # joint, the motor encoder on the motor shaft (before the gear).  () = 2^encoder_bits.
    encoder_counts_load: tuple[int, ...] = ()
    encoder_counts_motor: tuple[int, ...] = ()
    # who may subscribe to the local publication (the UNIX socket, docs/interfaces.md §6) besides
    # the daemon's own user and root
    local_readers: LocalReaders = field(default_factory=LocalReaders)

    KEYS = ["gear_ratio", "encoder_bits", "encoder_counts", "torque_limit", "torque_noise", "bus", "local_readers"]
    READER_KINDS = ("users", "groups")
    COUNT_SIDES = ("load", "motor")

    def gear_ratios(self, n: int) -> np.ndarray:
        """Each of the n joints' gear ratio (motor turns per joint turn)."""
        return joint_values(self.gear_ratio, n)

    def torque_limits(self, n: int) -> np.ndarray:
        """Each of the n joints' motor-torque limit, joint side [N m]."""
        return joint_values(self.torque_limit, n)

    def torque_noises(self, n: int) -> np.ndarray:
        """Each of the n joints' simulated motor-torque noise (standard deviation, joint side) [N m]."""
        return joint_values(self.torque_noise, n)

    @property
    def torque_limit_max(self) -> float:
        """The largest joint's motor-torque limit [N m] (a scale: every joint's torque is within it)."""
        return float(np.max(self.torque_limit))

    def encoder_counts(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """Counts per revolution of (the load encoder's joint, the motor encoder's shaft) per
        joint: ``encoder_counts``, else 2^``encoder_bits``."""
        def counts(c):
            return np.asarray(c if c else (2 ** self.encoder_bits,), dtype=np.int64) * np.ones(n, dtype=np.int64)
        return counts(self.encoder_counts_load), counts(self.encoder_counts_motor)

    def encoder_resolution(self, n: int = 1) -> tuple[np.ndarray, np.ndarray]:
        """Joint-side angle quanta (Δq, Δθ_m) [rad] per joint: 2π/counts for the load encoder,
        2π/(counts · gear_ratio) for the motor encoder (it turns gear_ratio times per joint turn).
        A side without ``encoder_counts`` has 2^``encoder_bits`` counts."""
        load, motor = self.encoder_counts(n)
        return 2 * np.pi / load.astype(float), 2 * np.pi / (motor.astype(float) * self.gear_ratios(n))

    @classmethod
    def from_dict(cls, d: Mapping, n: int, source: str) -> "HardwareConfig":
        validate.check_keys(source, "hardware.", d, cls.KEYS, [])
        out = {}
        if "gear_ratio" in d:
            out["gear_ratio"] = per_joint(source, "hardware.gear_ratio", d["gear_ratio"], n, positive=True)
        if "encoder_bits" in d:
            b = d["encoder_bits"]
            if isinstance(b, bool) or not isinstance(b, int) or not 8 <= b <= 32:
                raise ConfigError(source, "hardware.encoder_bits", f"must be an integer in 8..32, got {b!r}")
            out["encoder_bits"] = b
        if "encoder_counts" in d:
            out.update(cls._counts(source, d["encoder_counts"], n))
        if "torque_limit" in d:
            out["torque_limit"] = per_joint(source, "hardware.torque_limit", d["torque_limit"], n, positive=True)
        if "torque_noise" in d:
            out["torque_noise"] = per_joint(source, "hardware.torque_noise", d["torque_noise"], n, non_negative=True)
        out["bus"] = BusConfig.from_dict(d.get("bus") or {}, n, source)
        if "local_readers" in d:
            out.update(cls._readers(source, d["local_readers"]))
        return cls(**out)

    @classmethod
    def _readers(cls, source: str, v: Any) -> dict:
        """``hardware.local_readers``: {users: [name or uid, ...], groups: [name or gid, ...]}."""
        key = "hardware.local_readers"
        if v is None:
            return {}
        _keyed(source, key, v, cls.READER_KINDS, "{users: [therapist], groups: [sea-daemon]} (who may "
                                                 "subscribe besides the daemon's user and root)")
        out = {}
        for kind, names in v.items():
            vals = [] if names is None else list(names) if isinstance(names, (list, tuple)) else [names]
            for x in vals:
                ok_id = isinstance(x, int) and not isinstance(x, bool) and 0 <= x < 2 ** 32 - 1
                ok_name = isinstance(x, str) and 0 < len(x) <= 64 and ":" not in x and "\n" not in x
                if not (ok_id or ok_name):
                    raise ConfigError(source, f"{key}.{kind}", f"must be a list of {kind[:-1]} names or ids "
                                                               f"(0..4294967294), got {x!r}")
            out[kind] = tuple(vals)
        return {"local_readers": LocalReaders(**out)}

    @classmethod
    def _counts(cls, source: str, ec: Any, n: int) -> dict:
        """``hardware.encoder_counts``: {load: C, motor: C}, C an integer (every joint) or a list of n."""
        key = "hardware.encoder_counts"
        _keyed(source, key, ec, cls.COUNT_SIDES, "{load: 8000, motor: 2000} (counts per revolution of the "
                                                 "shaft each encoder reads)")
        out = {}
        for side, v in ec.items():
            vals = list(v) if isinstance(v, (list, tuple)) else [v]
            if len(vals) not in (1, n) or any(isinstance(x, bool) or not isinstance(x, int) or not 4 <= x <= 2 ** 32
                                              for x in vals):
                raise ConfigError(source, f"{key}.{side}", "must be an integer in 4..2^32 (counts per revolution)"
                                                           f"{'' if n == 1 else f' or a list of {n}'}, got {v!r}")
            out[f"encoder_counts_{side}"] = tuple(vals) * (n if len(vals) == 1 else 1)
        return out

    def to_dict(self) -> dict:
        out = {k: v for k, v in dataclasses.asdict(self).items()
               if k not in ("bus", "encoder_counts_load", "encoder_counts_motor", "local_readers")}
        for key in ("gear_ratio", "torque_limit", "torque_noise"):
            if isinstance(out[key], tuple):
                out[key] = list(out[key])
        counts = {}
        for side in self.COUNT_SIDES:
            c = getattr(self, f"encoder_counts_{side}")
            if c:
                counts[side] = c[0] if len(set(c)) == 1 else list(c)
        if counts:
            out["encoder_counts"] = counts
        out["bus"] = self.bus.to_dict()
        r = self.local_readers
        if r.users or r.groups:
            out["local_readers"] = {"users": list(r.users), "groups": list(r.groups)}
        return out
