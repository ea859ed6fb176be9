"""Read what a running sea-daemon publishes: the estimate τ̂_h,act, its bound ρ_k, validity and faults.

Two publications, the same fields (docs/interfaces.md §6):

* **on the machine** — a UNIX datagram socket (default ``STATE_DIR/sea-daemon.sock``): every
  cycle one datagram with the cycle, the sample time, the fault, the validity and per joint the
  angle, the motor torque, τ̂_h,act, ρ_k, σ and the assistance.  :class:`Subscriber` subscribes
  (and renews the subscription while it reads), :func:`decode` reads one datagram;
* **on the CAN bus** — the TPDOs of the daemon's own node (``hardware.bus.master_node``, 127):
  :func:`decode_tpdo` reads one frame's data (``configs/eds/sea_daemon.eds``, docs/can.md).

A bound of ``+inf`` means "not valid": the start-up before the filter runs, a latched fault,
no estimator.  NaN is never published.

This module imports only the standard library and :mod:`sea_daemon.errors` — a client on the
exoskeleton's computer does not load the daemon (no numpy, no numba, no CAN stack)::

    from sea_daemon.client import Subscriber
    with Subscriber("/var/lib/sea-daemon/sea-daemon.sock") as sub:
        for s in sub.samples(timeout=1.0):
            print(s.cycle, s.tau_h_act_hat[0], s.tau_h_act_bound[0], s.valid[0], s.fault_name)
"""
from __future__ import annotations

import math
import os
import socket
import stat
import struct
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

from sea_daemon.errors import Fault, InputError

__all__ = ["Sample", "Subscriber", "daemon_uid", "sender_uid", "decode", "encode_into", "record_size", "decode_tpdo", "tpdo_cob_ids", "tpdo_cycles",
           "SOCKET_NAME", "FLAG_FAULT", "FLAG_ASSIST_ON", "FLAG_ASSIST_ENGAGED", "FLAG_ESTIMATOR",
           "FLAG_ASSIST_DRY_RUN", "FLAG_ASSIST_ENGAGED_JOINT", "engaged_joints",
           "TPDO_JOINT", "TPDO_STATUS"]

#: the daemon's socket in its state directory
SOCKET_NAME = "sea-daemon.sock"
MAGIC = b"SEAd"
VERSION = 1
#: header: magic, version, joints, cycle, t [s], t_mono [s], fault, flags, valid bits
HEADER = struct.Struct("<4sHHQddHHI")
#: per joint: q [rad], tau_m [N m], tau_h_act_hat, tau_h_act_bound, tau_h_act_sigma, tau_assist [N m]
JOINT = struct.Struct("<dddddd")
MAX_JOINTS = 16

# bits of Sample.flags (and of TPDO2 byte 7)
FLAG_FAULT = 1 << 0            # a fault is latched (zero torque)
FLAG_ASSIST_ON = 1 << 1        # the assist controller runs
FLAG_ASSIST_ENGAGED = 1 << 2   # it commands assistance (τ_assist ≠ 0 on some joint)
FLAG_ESTIMATOR = 1 << 3        # an estimator runs
FLAG_ASSIST_DRY_RUN = 1 << 4   # dry run: τ_assist computed and published, not commanded
#: it commands assistance on joint 1, 2, 3 (bits 5, 6, 7; set for models of 2 or 3 joints, beside
#: FLAG_ASSIST_ENGAGED: with one joint that bit alone says it, and a one-joint frame is as before)
FLAG_ASSIST_ENGAGED_JOINT = (1 << 5, 1 << 6, 1 << 7)

# subscription requests (client -> daemon)
SUBSCRIBE = struct.Struct("<4sHH")
SUB_MAGIC, UNSUB_MAGIC = b"SEAs", b"SEAu"
#: a subscription lapses after this long without renewal [s]; clients renew every RENEW_S
LEASE_S = 5.0
RENEW_S = 1.0

# ---------------------------------------------------------------------------- CAN (TPDOs)
#: TPDO with τ̂_h,act and ρ_k of one joint: <REAL32 τ̂, REAL32 ρ>, little-endian
TPDO_JOINT = struct.Struct("<ff")
#: TPDO2 (status): <UNSIGNED32 cycle, UNSIGNED16 fault, UNSIGNED8 valid bits, UNSIGNED8 flags>
TPDO_STATUS = struct.Struct("<IHBB")
#: function codes: joint 1 on TPDO1, status on TPDO2, joints 2 and 3 on TPDO3 and TPDO4
JOINT_FUNCTIONS = (0x180, 0x380, 0x480)
STATUS_FUNCTION = 0x280


def tpdo_cob_ids(node: int = 127, joints: int = 1) -> dict[str, int]:
    """COB-IDs of the daemon node's TPDOs: ``{"joint1": 0x1FF, "status": 0x2FF, ...}`` for node 127."""
    if not 1 <= node <= 127:
        raise InputError(f"node {node!r}: allowed 1..127 (CANopen node id)")
    if not 1 <= joints <= len(JOINT_FUNCTIONS):
        raise InputError(f"joints {joints!r}: the daemon's node publishes 1..{len(JOINT_FUNCTIONS)}")
    out = {f"joint{j + 1}": JOINT_FUNCTIONS[j] + node for j in range(joints)}
    out["status"] = STATUS_FUNCTION + node
    return out


def decode_tpdo(cob_id: int, data: bytes, node: int = 127) -> dict:
    """One TPDO of the daemon's node as a dict: ``{"joint": j, "tau_h_act_hat": …, "tau_h_act_bound": …}``
    (joint 1-based) or ``{"cycle": …, "fault": …, "fault_name": …, "valid": [...], "flags": …,
    "engaged": [joint 1, 2, 3]}`` (:func:`engaged_joints`)."""
    f = cob_id - node
    if f in JOINT_FUNCTIONS:
        if len(data) != TPDO_JOINT.size:
            raise InputError(f"TPDO 0x{cob_id:03X}: {len(data)} bytes, expected {TPDO_JOINT.size}")
        hat, bound = TPDO_JOINT.unpack(bytes(data))
        return {"joint": JOINT_FUNCTIONS.index(f) + 1, "tau_h_act_hat": hat, "tau_h_act_bound": bound,
                "valid": math.isfinite(bound)}
    if f == STATUS_FUNCTION:
        if len(data) != TPDO_STATUS.size:
            raise InputError(f"TPDO 0x{cob_id:03X}: {len(data)} bytes, expected {TPDO_STATUS.size}")
        cycle, fault, valid, flags = TPDO_STATUS.unpack(bytes(data))
        return {"cycle": cycle, "fault": fault, "fault_name": _fault_name(fault),
                "valid": [bool(valid >> j & 1) for j in range(8)], "flags": flags, "engaged": engaged_joints(flags)}
    raise InputError(f"COB-ID 0x{cob_id:03X} is no TPDO of node {node} (allowed: "
                     + ", ".join(f"0x{c + node:03X}" for c in JOINT_FUNCTIONS + (STATUS_FUNCTION,)) + ")")


def engaged_joints(flags: int, joints: int | None = None) -> list[bool] | None:
    """Whether the assistance is engaged on each joint, from the flags (TPDO2 byte 7 or
    :attr:`Sample.flags`).

    Without ``joints``: joints 1, 2, 3 — bits 5–7 when the daemon set any (a model of 2 or 3
    joints), else :data:`FLAG_ASSIST_ENGAGED` for joint 1 (a one-joint model sets that bit alone).
    With ``joints`` (the model's joints, e.g. :attr:`Sample.joints`): one entry per joint; a model
    of more than 3 joints has no bit per joint, only :data:`FLAG_ASSIST_ENGAGED` ("engaged on some
    joint"): None while it is set (the flags do not say which joint; :attr:`Sample.engaged` does,
    from τ_assist), all False while it is not."""
    if joints is not None and (isinstance(joints, bool) or not isinstance(joints, int) or not 1 <= joints <= MAX_JOINTS):
        raise InputError(f"joints {joints!r}: allowed 1..{MAX_JOINTS}")
    if joints is not None and joints > len(FLAG_ASSIST_ENGAGED_JOINT):
        return None if flags & FLAG_ASSIST_ENGAGED else [False] * joints
    if joints == 1:
        return [bool(flags & FLAG_ASSIST_ENGAGED)]
    if flags & (FLAG_ASSIST_ENGAGED_JOINT[0] | FLAG_ASSIST_ENGAGED_JOINT[1] | FLAG_ASSIST_ENGAGED_JOINT[2]):
        out = [bool(flags & b) for b in FLAG_ASSIST_ENGAGED_JOINT]
    else:
        out = [bool(flags & FLAG_ASSIST_ENGAGED), False, False]
    return out if joints is None else out[:joints]


def tpdo_cycles(frames, node: int = 127) -> dict[int, tuple[dict, dict]]:
    """``(cob_id, data)`` frames of the daemon's node, in the order received, grouped per cycle:
    ``{cycle: (joint-1 TPDO1 dict, TPDO2 status dict)}`` — TPDO2 closes the frames of its cycle."""
    out: dict[int, tuple[dict, dict]] = {}
    pending = None
    for cob, data in frames:
        d = decode_tpdo(cob, data, node)
        if d.get("joint") == 1:
            pending = d
        elif "cycle" in d and pending is not None:
            out[d["cycle"]] = (pending, d)
            pending = None
    return out


# ---------------------------------------------------------------------------- local datagrams
def record_size(n: int) -> int:
    """Bytes of one datagram for ``n`` joints."""
    return HEADER.size + n * JOINT.size


def _fault_name(code: int) -> str:
    try:
        return Fault(code).name
    except ValueError:
        return f"FAULT_{code}"


@dataclass(frozen=True)
class Sample:
    """One cycle as the daemon published it (SI units, joint side; tuples of one value per joint)."""

    cycle: int
    t: float                        # [s] sample time of the hardware (k · period since start)
    t_mono: float                   # [s] the daemon's CLOCK_MONOTONIC when it published
    fault: int                      # latched fault code (sea_daemon.errors.Fault), 0 none
    flags: int                      # FLAG_* bits
    valid: tuple[bool, ...]
    q: tuple[float, ...]            # [rad]
    tau_m: tuple[float, ...]        # [N m] the motor torque acting over [t, t + period]
    tau_h_act_hat: tuple[float, ...]    # [N m] τ̂_h,act
    tau_h_act_bound: tuple[float, ...]  # [N m] ρ_k; +inf while not valid
    tau_h_act_sigma: tuple[float, ...]  # [N m]
    tau_assist: tuple[float, ...]   # [N m] the assistance in tau_m (0 without the assist controller)

    @property
    def joints(self) -> int:
        return len(self.q)

    @property
    def fault_name(self) -> str:
        return _fault_name(self.fault)

    @property
    def faulted(self) -> bool:
        return bool(self.flags & FLAG_FAULT)

    @property
    def engaged(self) -> tuple[bool, ...]:
        """Per joint: the assistance is engaged (τ_assist ≠ 0; it is 0 while a fault is latched)."""
        return tuple(t != 0.0 for t in self.tau_assist)


def encode_into(buf, n: int, cycle: int, t: float, t_mono: float, fault: int, flags: int, valid_mask: int,
                joints) -> None:
    """Write one datagram into ``buf`` (bytearray of :func:`record_size`); ``joints``: n rows of
    (q, tau_m, hat, bound, sigma, tau_assist).  The daemon's publisher packs its own arrays in place."""
    HEADER.pack_into(buf, 0, MAGIC, VERSION, n, cycle, t, t_mono, fault, flags, valid_mask)
    for j, row in enumerate(joints):
        JOINT.pack_into(buf, HEADER.size + j * JOINT.size, *row)


def decode(data: bytes) -> Sample:
    """One datagram → :class:`Sample`; InputError naming the problem for anything else."""
    if len(data) < HEADER.size:
        raise InputError(f"datagram of {len(data)} bytes: shorter than the header ({HEADER.size})")
    magic, version, n, cycle, t, t_mono, fault, flags, vmask = HEADER.unpack_from(data, 0)
    if magic != MAGIC:
        raise InputError(f"datagram magic {magic!r}: expected {MAGIC!r}")
    if version != VERSION:
        raise InputError(f"datagram version {version}: this client reads version {VERSION}")
    if not 1 <= n <= MAX_JOINTS or len(data) != record_size(n):
        raise InputError(f"datagram of {len(data)} bytes for {n} joint(s): expected {record_size(n)} "
                         f"(joints 1..{MAX_JOINTS})")
    cols = list(zip(*(JOINT.unpack_from(data, HEADER.size + j * JOINT.size) for j in range(n))))
    return Sample(cycle=cycle, t=t, t_mono=t_mono, fault=fault, flags=flags,
                  valid=tuple(bool(vmask >> j & 1) for j in range(n)), q=cols[0], tau_m=cols[1],
                  tau_h_act_hat=cols[2], tau_h_act_bound=cols[3], tau_h_act_sigma=cols[4], tau_assist=cols[5])


#: the kernel's credentials of a datagram's sender (SO_PASSCRED): pid, uid, gid
CREDS = struct.Struct("3i")


def sender_uid(ancdata) -> int | None:
    """The uid the kernel attached to a datagram (``recvmsg`` ancillary data of a socket with
    ``SO_PASSCRED``); None when there is none."""
    for level, kind, data in ancdata:
        if level == socket.SOL_SOCKET and kind == socket.SCM_CREDENTIALS and len(data) >= CREDS.size:
            return CREDS.unpack_from(data)[1]
    return None


def daemon_uid(path: str) -> int:
    """The owner of the daemon's socket ``path``, the only user whose datagrams a reader takes.

    InputError when ``path`` is no socket, or when its directory lets others replace it
    (writable by group or others without the sticky bit, or owned by a user who is neither the
    socket's owner nor root)."""
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise InputError(f"no sea-daemon publishes on {path} (it does not exist); "
                         "give the socket of a running daemon (STATE_DIR/sea-daemon.sock)") from None
    except OSError as e:
        raise InputError(f"socket {path}: cannot read: {e.strerror or e}") from None
    if not stat.S_ISSOCK(st.st_mode):
        raise InputError(f"{path}: is not a socket (give the daemon's STATE_DIR/sea-daemon.sock)")
    real = os.path.realpath(path)
    d = os.path.dirname(real) or "."
    dst = os.stat(d)
    if dst.st_uid not in (st.st_uid, 0) or (dst.st_mode & 0o022 and not dst.st_mode & stat.S_ISVTX):
        raise InputError(f"socket {path}: its directory {d} (owner uid {dst.st_uid}, mode "
                         f"{stat.S_IMODE(dst.st_mode):04o}) lets others replace it; allowed: owned by the "
                         "socket's owner or root and not writable by group or others")
    return st.st_uid


class Subscriber:
    """Receives the daemon's datagrams on a socket of its own (Linux abstract address).

    ``path``: the daemon's socket (``STATE_DIR/sea-daemon.sock``, or the ``--socket`` it was
    started with).  The subscription is sent at construction and renewed every second from
    :meth:`receive`; a reader that stops reading is dropped by the daemon after 5 s.  Datagrams
    the reader was too slow for are dropped by the daemon (counted there): gaps in
    :attr:`Sample.cycle` show them, :attr:`missed` counts them here.

    Only the daemon's datagrams are taken, as the kernel vouches: the reader's socket is
    connected to the daemon's (the kernel refuses datagrams of any other socket), and every
    datagram's sender, as the kernel reports it (``SO_PASSCRED``), must be the owner of the
    daemon's socket (:func:`daemon_uid`, or ``uid``).  A datagram of anyone else, or one that is
    no sample, is dropped and counted in :attr:`rejected`.
    """

    def __init__(self, path: str | os.PathLike, *, buffer_bytes: int = 1 << 20, uid: int | None = None):
        self.path = str(path)
        if len(os.fsencode(self.path)) >= 108:
            raise InputError(f"socket path {self.path!r}: {len(os.fsencode(self.path))} bytes, a UNIX socket "
                             "path allows at most 107")
        self._fixed_uid = uid
        self.uid = uid if uid is not None else daemon_uid(self.path)
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        try:
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, buffer_bytes)
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_PASSCRED, 1)
            self.sock.bind("")                       # autobind: an abstract address of our own
        except OSError:
            self.sock.close()
            raise
        self._buf = bytearray(record_size(MAX_JOINTS) + 64)
        self._anc = socket.CMSG_SPACE(CREDS.size)
        self._next_renew = 0.0
        self.received = 0
        self.missed = 0
        self.rejected = 0                             # datagrams dropped: not the daemon's, or no sample
        self._last_cycle: int | None = None
        try:
            self.subscribe()
        except BaseException:
            self.sock.close()
            raise

    def subscribe(self) -> None:
        """(Re)new the subscription: connect to the daemon's socket (again: a restarted daemon
        has a new one) and send the request; InputError when no daemon listens at :attr:`path`."""
        try:
            if self._fixed_uid is None:
                self.uid = daemon_uid(self.path)
            self.sock.connect(self.path)
            self.sock.send(SUBSCRIBE.pack(SUB_MAGIC, VERSION, 0))
        except (FileNotFoundError, ConnectionRefusedError) as e:
            raise InputError(f"no sea-daemon publishes on {self.path} ({e.strerror or e}); "
                             "give the socket of a running daemon (STATE_DIR/sea-daemon.sock)") from None
        except PermissionError as e:
            raise InputError(f"socket {self.path}: {e.strerror or e} (the daemon's hardware.local_readers "
                             "and the socket's permissions say who may read)") from None
        self._next_renew = time.monotonic() + RENEW_S

    def receive(self, timeout: float | None = 1.0) -> Sample | None:
        """The next sample, or None after ``timeout`` seconds without one."""
        now = time.monotonic()
        if now >= self._next_renew:
            try:
                self.subscribe()
            except InputError:
                self._next_renew = now + RENEW_S       # the daemon may be restarting: try again later
        self.sock.settimeout(timeout)
        while True:
            try:
                nbytes, anc, _, _ = self.sock.recvmsg_into([self._buf], self._anc)
            except (socket.timeout, BlockingIOError):
                return None
            except ConnectionError:                     # the daemon went away (reported once)
                continue
            if sender_uid(anc) != self.uid:
                self.rejected += 1                    # not the daemon: dropped, counted
                continue
            try:
                s = decode(bytes(self._buf[:nbytes]))
            except InputError:
                self.rejected += 1
                continue
            if self._last_cycle is not None and s.cycle > self._last_cycle + 1:
                self.missed += s.cycle - self._last_cycle - 1
            self._last_cycle = s.cycle
            self.received += 1
            return s

    def samples(self, timeout: float | None = 1.0) -> Iterator[Sample]:
        """Samples until ``timeout`` seconds pass without one."""
        while True:
            s = self.receive(timeout)
            if s is None:
                return
            yield s

    def close(self) -> None:
        try:
            self.sock.send(SUBSCRIBE.pack(UNSUB_MAGIC, VERSION, 0))
        except OSError:
            pass
        self.sock.close()

    def __enter__(self) -> "Subscriber":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def default_socket(state_dir: str | os.PathLike) -> Path:
    """The daemon's socket in its state directory."""
    return Path(state_dir) / SOCKET_NAME
