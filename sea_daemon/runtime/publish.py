"""The estimate in use: published every cycle, right after the estimate, on the bus and on the machine.

:class:`Publisher` is the loop's publication step (:class:`~sea_daemon.runtime.loop.FixedRateLoop`
calls :meth:`Publisher.publish` once per cycle, after the estimate and the fault policy of that
cycle).  It fills preallocated buffers and hands them to

* :class:`sea_daemon.hw.canopen_publish.TpdoPublisher` — the TPDOs of the daemon's own node
  (``hardware.bus.master_node``; docs/can.md, ``configs/eds/sea_daemon.eds``);
* :class:`LocalPublisher` — datagrams on a UNIX socket (``STATE_DIR/sea-daemon.sock``) to every
  subscribed reader (:mod:`sea_daemon.client`, ``sea-daemon watch``).

Never blocking, never raising into the cycle: a reader whose socket buffer is full misses that
cycle's datagram (counted per reader), a reader that went away is dropped (counted), a CAN
frame that cannot be sent is counted.  No allocation of its own on the path: the datagram, the
frames and the value rows are preallocated and packed in place.
"""
from __future__ import annotations

import grp
import math
import os
import pwd
import select
import socket
import time
from pathlib import Path
from typing import Any

from sea_daemon.client import (CREDS, FLAG_ASSIST_DRY_RUN, FLAG_ASSIST_ENGAGED, FLAG_ASSIST_ENGAGED_JOINT, FLAG_ASSIST_ON,
                               FLAG_ESTIMATOR, FLAG_FAULT, HEADER, JOINT, LEASE_S, MAGIC, SUB_MAGIC, SUBSCRIBE,
                               UNSUB_MAGIC, VERSION, record_size)
from sea_daemon.errors import InputError
from sea_daemon.hw.canopen_publish import make_tpdo_publisher

INF = math.inf
FLT_MAX = 3.4028234663852886e38


def _real32(x: float, bound: bool) -> float:
    """A value REAL32 can carry: a bound beyond REAL32 is +inf (not valid), an estimate is clipped."""
    if x != x:                                         # NaN never leaves the daemon
        return INF if bound else 0.0
    if abs(x) > FLT_MAX:
        return INF if bound else math.copysign(FLT_MAX, x)
    return x


class ReaderPolicy:
    """Who may subscribe to the local publication: root, the daemon's own user, and the users and
    groups of ``hardware.local_readers`` — checked on the sender's credentials as the kernel
    reports them (``SO_PASSCRED``): its uid, its gid, or a uid among a listed group's members."""

    def __init__(self, uids=(), gids=()):
        self.uids = frozenset({0, os.geteuid(), *uids})
        self.gids = frozenset(gids)

    def allows(self, uid: int, gid: int) -> bool:
        return uid in self.uids or gid in self.gids

    @property
    def socket_mode(self) -> int:
        """The socket file's mode: only the daemon's user (0600) unless others are listed — a
        group (0660, the file's group), users (0666: the credentials are the gate then)."""
        others = self.uids - {0, os.geteuid()}
        return 0o666 if others else 0o660 if self.gids else 0o600

    @classmethod
    def from_config(cls, users=(), groups=()) -> "ReaderPolicy":
        """Names resolved on the host (at start, not per request); InputError for an unknown one."""
        key = "hardware.local_readers"
        uids, gids = set(), set()
        for u in users:
            try:
                uids.add(u if isinstance(u, int) else pwd.getpwnam(u).pw_uid)
            except KeyError:
                raise InputError(f"{key}.users: no user {u!r} on the host") from None
        for g in groups:
            try:
                entry = grp.getgrgid(g) if isinstance(g, int) else grp.getgrnam(g)
            except KeyError:
                if isinstance(g, int):
                    gids.add(g)
                    continue
                raise InputError(f"{key}.groups: no group {g!r} on the host") from None
            gids.add(entry.gr_gid)
            for member in entry.gr_mem:
                try:
                    uids.add(pwd.getpwnam(member).pw_uid)
                except KeyError:
                    pass
        return cls(uids, gids)


class LocalPublisher:
    """Datagrams to subscribed readers on the UNIX socket ``path`` (see :mod:`sea_daemon.client`).

    A reader subscribes by sending a subscription datagram from its own (bound) socket and
    renews it at least every :data:`~sea_daemon.client.LEASE_S` seconds; at most ``max_readers``
    at a time (more are refused, counted in :attr:`refused`).  Only senders ``readers`` allows
    (:class:`ReaderPolicy`; default: root and the daemon's user) are subscribed, by the kernel's
    credentials of the request; others are counted in :attr:`foreign`.  A stale socket file (no
    daemon behind it) is replaced; a live one — another daemon publishing there — is an InputError.
    """

    def __init__(self, path: str | os.PathLike, n: int, *, max_readers: int = 8, mode: int | None = None,
                 readers: ReaderPolicy | None = None, clock=time.monotonic):
        self.path = Path(path)
        if len(os.fsencode(str(self.path))) >= 108:
            raise InputError(f"--socket {self.path}: {len(os.fsencode(str(self.path)))} bytes, a UNIX socket "
                             "path allows at most 107 (choose a shorter --state-dir or --socket)")
        self.n = n
        self.clock = clock
        self.max_readers = int(max_readers)
        self.policy = readers if readers is not None else ReaderPolicy()
        self._probe_stale()
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        try:
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_PASSCRED, 1)
            self.sock.bind(str(self.path))
            os.chmod(self.path, self.policy.socket_mode if mode is None else mode)
            self.sock.setblocking(False)
            self._rpoll = select.poll()               # a request waiting? (no exception per empty read)
            self._rpoll.register(self.sock.fileno(), select.POLLIN)
        except OSError as e:
            self.sock.close()
            raise InputError(f"--socket {self.path}: cannot bind: {e.strerror or e}") from None
        self.buf = bytearray(record_size(n))
        self._req = bytearray(64)
        self._anc = socket.CMSG_SPACE(CREDS.size)
        self.poll_s = 0.02                            # subscription requests are taken every 20 ms
        self._next_poll = 0.0
        self._readers: dict[Any, float] = {}          # address -> lease end (clock)
        self.sent = 0
        self.dropped = 0                              # datagrams a reader's full buffer refused
        self.gone = 0                                 # readers dropped because their socket went away
        self.refused = 0                              # subscriptions refused (too many readers)
        self.foreign = 0                              # requests of senders the policy does not allow
        self.errors = 0
        self._closed = False

    def _probe_stale(self) -> None:
        if not os.path.exists(self.path):
            return
        probe = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        try:
            probe.sendto(b"", str(self.path))        # a live socket takes it (and ignores it)
        except (ConnectionRefusedError, FileNotFoundError):
            try:
                os.unlink(self.path)                  # stale: nobody bound behind it
            except FileNotFoundError:
                pass
            return
        except OSError as e:
            raise InputError(f"--socket {self.path}: exists and cannot be probed ({e.strerror or e})") from None
        finally:
            probe.close()
        raise InputError(f"--socket {self.path}: another process publishes there (a sea-daemon running with "
                         "this --state-dir?); stop it or give another --socket")

    @property
    def readers(self) -> int:
        return len(self._readers)

    def poll(self, now: float) -> None:
        """Every :attr:`poll_s` at most: take the subscription requests waiting on the socket
        (at most 16) and expire lapsed leases."""
        if now < self._next_poll:
            return
        self._next_poll = now + self.poll_s
        sock = self.sock
        for _ in range(16 if self._rpoll.poll(0) else 0):
            try:
                nbytes, anc, _, addr = sock.recvmsg_into([self._req], self._anc)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:
                self.errors += 1
                break
            if nbytes != SUBSCRIBE.size or not addr:
                continue                              # not a request (a probe, junk, an unbound sender)
            if not self._allowed(anc):
                self.foreign += 1                     # a sender the policy does not allow: refused
                continue
            magic, version, _ = SUBSCRIBE.unpack_from(self._req, 0)
            if magic == SUB_MAGIC and version == VERSION:
                if addr in self._readers or len(self._readers) < self.max_readers:
                    self._readers[addr] = now + LEASE_S
                else:
                    self.refused += 1
            elif magic == UNSUB_MAGIC:
                self._readers.pop(addr, None)
        if self._readers:
            for addr in [a for a, end in self._readers.items() if end < now]:
                del self._readers[addr]

    def _allowed(self, anc) -> bool:
        for level, kind, data in anc:
            if level == socket.SOL_SOCKET and kind == socket.SCM_CREDENTIALS and len(data) >= CREDS.size:
                _, uid, gid = CREDS.unpack_from(data)
                return self.policy.allows(uid, gid)
        return False

    def send(self) -> None:
        """Send :attr:`buf` (packed by :class:`Publisher`) to every reader."""
        for addr in self._readers:
            try:
                self.sock.sendto(self.buf, addr)
                self.sent += 1
            except (BlockingIOError, InterruptedError):
                self.dropped += 1
            except (ConnectionRefusedError, FileNotFoundError, PermissionError):
                # gone, or connected to a former daemon's socket (it subscribes anew): expired at the next poll
                self._readers[addr] = -math.inf
                self.gone += 1
            except OSError:
                self.errors += 1

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        self.sock.close()
        try:
            os.unlink(self.path)
        except OSError:
            pass


class Publisher:
    """The loop's publication step: one cycle's estimate to the bus and to local readers.

    ``tpdo``: a :class:`sea_daemon.hw.canopen_publish.TpdoPublisher` (or None); ``local``: a
    :class:`LocalPublisher` (or None); ``controller``: the loop's controller, read for its
    assistance (``tau_assist``, an :class:`~sea_daemon.runtime.controller.AssistController`);
    ``has_estimator``: whether the loop runs an estimator.
    """

    def __init__(self, n: int, period: float, *, tpdo=None, local: LocalPublisher | None = None,
                 controller=None, has_estimator: bool = True, clock=time.monotonic):
        self.n, self.period = int(n), float(period)
        self.tpdo, self.local = tpdo, local
        self.clock = clock
        self.assist = getattr(controller, "tau_assist", None)
        self.assist_on = self.assist is not None and getattr(controller, "gain", 0.0) > 0.0
        # a dry run: the assistance is computed and published, the motor does not get it
        self.dry_run = FLAG_ASSIST_DRY_RUN if (self.assist_on and getattr(controller, "dry_run", False)) else 0
        self.has_estimator = has_estimator
        # the flags a joint's assistance sets: "engaged", and with 2 or 3 joints the joint's own bit
        self._engaged_bits = [FLAG_ASSIST_ENGAGED | (FLAG_ASSIST_ENGAGED_JOINT[j] if 1 < self.n <= 3 else 0)
                              for j in range(self.n)]
        self.hat = [0.0] * self.n
        self.bound = [INF] * self.n
        self.published = 0
        self.errors = 0

    def publish(self, k: int, meas, est, tau, fault: int, q=None) -> None:
        """Cycle k: ``meas`` (None when the read failed), ``est`` (None when there is none or a
        fault latched), ``tau`` the torque acting over [t_k, t_k+1], ``fault`` the latched code,
        ``q`` the load angles the loop passed on in this cycle (a sample the hardware missed goes
        on extrapolated, not as the driver's held values; None: ``meas.q``)."""
        try:
            self._publish(k, meas, est, tau, int(fault), meas.q if q is None and meas is not None else q)
            self.published += 1
        except Exception:  # noqa: BLE001 - the publication never stops the cycle: counted
            self.errors += 1

    def _publish(self, k: int, meas, est, tau, fault: int, q) -> None:
        n = self.n
        ok = est is not None and bool(getattr(est, "valid", True)) and fault == 0
        hat, bound = self.hat, self.bound
        vmask = 0
        for j in range(n):
            if est is not None:
                hat[j] = _real32(float(est.tau_h_act_hat[j]), False)
            else:
                hat[j] = 0.0
            if ok:
                b = _real32(float(est.tau_h_act_bound[j]), True)
                bound[j] = b
                if b != INF:
                    vmask |= 1 << j
            else:
                bound[j] = INF
        engaged = 0
        if self.assist is not None and not fault:
            bits = self._engaged_bits
            for j in range(n):
                if self.assist[j] != 0.0:
                    engaged |= bits[j]
        flags = ((FLAG_FAULT if fault else 0) | (FLAG_ASSIST_ON if self.assist_on else 0)
                 | engaged | (FLAG_ESTIMATOR if self.has_estimator else 0) | self.dry_run)
        if self.tpdo is not None:
            self.tpdo.send(k, hat, bound, vmask, fault, flags)
        loc = self.local
        if loc is not None:
            now = self.clock()
            loc.poll(now)
            if loc.readers:
                buf = loc.buf
                t = meas.t if meas is not None else k * self.period
                HEADER.pack_into(buf, 0, MAGIC, VERSION, n, k, t, now, fault, flags, vmask)
                off = HEADER.size
                for j in range(n):
                    sig = float(est.tau_h_act_sigma[j]) if est is not None else 0.0
                    JOINT.pack_into(buf, off, float(q[j]) if q is not None else 0.0, float(tau[j]),
                                    hat[j], bound[j], sig if sig == sig else 0.0,
                                    float(self.assist[j]) if (self.assist is not None and not fault) else 0.0)
                    off += JOINT.size
                loc.send()

    def stats(self) -> dict:
        out = {"published": self.published, "errors": self.errors}
        if self.tpdo is not None:
            out["can"] = {"frames_sent": self.tpdo.sent, "bytes_sent": self.tpdo.sent_bytes,
                          "frames_dropped": self.tpdo.dropped}
        if self.local is not None:
            out["local"] = {"socket": str(self.local.path), "datagrams_sent": self.local.sent,
                            "dropped_full": self.local.dropped, "readers_gone": self.local.gone,
                            "refused": self.local.refused, "foreign_refused": self.local.foreign,
                            "errors": self.local.errors}
        return out

    def close(self) -> None:
        if self.local is not None:
            self.local.close()


def make_publisher(rig, cfg, controller, *, socket_path: str | os.PathLike | None, has_estimator: bool = True):
    """The publisher of a service run: the TPDOs when the hardware is a CANopen bus and
    ``hardware.bus.publish`` is on; the local socket when ``socket_path`` is given."""
    tpdo = None
    if cfg.hardware.bus.publish and hasattr(rig.hw, "network"):
        tpdo = make_tpdo_publisher(rig.hw, cfg.hardware.bus.master_node, cfg.joints)
    local = None
    if socket_path is not None:
        r = cfg.hardware.local_readers
        local = LocalPublisher(socket_path, cfg.joints, readers=ReaderPolicy.from_config(r.users, r.groups))
    if tpdo is None and local is None:
        return None
    return Publisher(cfg.joints, cfg.dt, tpdo=tpdo, local=local, controller=controller, has_estimator=has_estimator)
