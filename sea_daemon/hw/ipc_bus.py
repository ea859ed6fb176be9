"""``ipc``: a python-can bus between processes of one machine over UNIX datagram sockets.

For a kernel without SocketCAN (no ``vcan``): the daemon and the device model in separate
processes on one broadcast bus, each frame one ``sendto`` per other member and one ``recv``
— a single hop, no relay process (python-can-remote's websocket server is a relay: every frame
crosses two websocket hops and the server's event loop, ~0.5–1 ms per round trip on the 2-core
test machine).  It keeps python-can's :class:`can.BusABC` interface, so canopen, the driver
and the device model run on it unchanged, as they do on ``socketcan`` (the production path).

* The channel is a directory (``/dev/shm/sea-can/<channel>``, or the channel itself when it is
  an absolute path); every open bus binds one socket file in it.  A member learns the others
  from the directory, re-read when the channel's membership count changes: an 8-byte counter in
  the file ``.members`` of the directory, mapped into every member's memory and incremented
  (under ``flock``) by whoever joins, leaves or sets its filters — a send reads it from memory,
  no system call; a member that sees it move lists the directory under the shared ``flock``,
  which orders the changes on any CPU.  A member increments it before it sends anything, so a
  member that answers a frame of a newcomer (its boot-up, say) has seen the newcomer's
  increment (the send and the receive between them order it).  The last member to leave
  removes the file.  Every member
  sends each frame to each of the others — what a CAN bus does: every node sees every frame but
  its own (``receive_own_messages`` adds one's own).
* A member sends to each other one on a socket connected to it (made at its first frame, closed
  when it leaves): no look-up of its path per frame.
* A frame is 24 bytes: arbitration id, flags (extended, remote, error frame), DLC, 8 data
  bytes, the sender's ``time.time()``.  Classic CAN only (no FD).
* Sends never block: a member whose receive queue is full (not reading; a UNIX datagram socket
  queues ``net.unix.max_dgram_qlen`` datagrams, 10 by default) loses the frame, counted in
  :attr:`IpcBus.overruns` — a CAN controller overrun at that node; a member that has gone
  (socket refused or removed) is dropped from the list.
* ``set_filters`` is published next to the member's socket (``<socket>.filter``): senders skip
  a member for the ids it does not accept (the hardware acceptance filter of a CAN controller),
  so a handle read once a cycle — the driver's TPDO handle — only queues its TPDOs.

Registered as the python-can interface ``sea-ipc`` (entry point ``can.interface`` in
``pyproject.toml``); :func:`sea_daemon.hw.bus.make_bus` opens it for ``hardware.bus.interface: ipc``.
"""
from __future__ import annotations

import errno
import fcntl
import itertools
import mmap
import os
import select
import socket
import struct
import time

import can
import numpy as np

from sea_daemon.errors import InputError, shown
from sea_daemon.io.owned import check_owned, make_private_dir, trusted_uids

BASE_DIR = "/dev/shm/sea-can" if os.path.isdir("/dev/shm") else "/tmp/sea-can"
_FRAME = struct.Struct("<IBB2x8sd")          # id, flags, dlc, data, timestamp: 24 bytes
_TS = struct.Struct("<d")                    # the timestamp, at byte 16 of a frame
_EXT, _RTR, _ERR = 1, 2, 4
FILTER_SUFFIX = ".filter"
_counter = itertools.count()


MEMBERS_FILE = ".members"                   # the channel's membership count (see the module docstring)


def _is_member(name: str) -> bool:
    """Whether a file of the channel directory is a member's socket (not the count, a filter or
    a filter being written)."""
    return not name.startswith(".") and not name.endswith((FILTER_SUFFIX, ".tmp"))


class _Members:
    """The membership count of a channel directory: ``.members``, 8 bytes, mapped shared.

    :meth:`count` reads it (no system call); :meth:`bump` increments it under an exclusive
    ``flock`` (a member joined, left or changed its filter), after the change.  A member that
    sees the count move lists the directory under the shared lock, so it sees every change
    counted (the lock, not the mapped memory, orders them on any CPU).  :meth:`open_locked`
    holds the lock while it makes sure the file it mapped is still the directory's (the last
    member to leave removes it under the same lock), and returns locked: the joiner binds its
    socket before it unlocks, so a member that leaves either sees the newcomer's socket or
    removed the file before the newcomer looked at it."""

    def __init__(self, fd: int, mm: mmap.mmap):
        self.fd, self._mm = fd, mm
        self._count = np.frombuffer(mm, dtype=np.int64, count=1)

    @classmethod
    def open_locked(cls, directory: str) -> "_Members":
        path = os.path.join(directory, MEMBERS_FILE)
        while True:
            private_channel_dir(directory)
            try:
                fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC | os.O_NOFOLLOW, 0o600)
            except OSError as e:
                raise InputError(f"ipc bus {shown(path)}: cannot open: {e.strerror or e}") from None
            try:
                fcntl.flock(fd, fcntl.LOCK_EX)
                st = os.fstat(fd)
                if st.st_uid not in trusted_uids():    # in a directory of ours: only ours or root's
                    check_owned("ipc bus count", path, st=st)
                if st.st_nlink == 0:                 # removed by the last leaver meanwhile: anew
                    os.close(fd)
                    continue
                if st.st_size < 8:
                    os.ftruncate(fd, 8)
                mm = mmap.mmap(fd, 8)
            except BaseException:
                os.close(fd)
                raise
            return cls(fd, mm)

    def count(self) -> int:
        return self._count.item(0)

    def linked(self) -> bool:
        """Whether the file is still the directory's (not removed with it)."""
        try:
            return os.fstat(self.fd).st_nlink > 0
        except OSError:
            return False

    def lock(self, shared: bool = False) -> None:
        fcntl.flock(self.fd, fcntl.LOCK_SH if shared else fcntl.LOCK_EX)

    def unlock(self) -> None:
        fcntl.flock(self.fd, fcntl.LOCK_UN)

    def bump(self, locked: bool = False) -> None:
        """Count one change (under the lock, taken here unless ``locked``)."""
        if not locked:
            self.lock()
        try:
            self._count[0] += 1
        finally:
            if not locked:
                self.unlock()

    def close(self) -> None:
        del self._count
        self._mm.close()
        os.close(self.fd)


def channel_dir(channel: str) -> str:
    """The directory of a channel (a name under :data:`BASE_DIR`, or an absolute path)."""
    channel = str(channel)
    if os.path.isabs(channel):
        return channel
    if not channel or "/" in channel or channel in (".", ".."):
        raise ValueError(f"ipc channel must be a name without '/' or an absolute path, got {channel!r}")
    return os.path.join(BASE_DIR, channel)


def private_channel_dir(directory: str) -> None:
    """Create the channel's directory (and :data:`BASE_DIR` for a named channel) with mode 0700
    where missing and refuse one another user owns or others may write (InputError): whoever
    owned it would own the bus."""
    if os.path.dirname(directory) == BASE_DIR:
        make_private_dir("ipc bus directory", BASE_DIR)
    make_private_dir("ipc bus channel", directory)


class IpcBus(can.BusABC):
    """One member of an ``ipc`` bus (see the module docstring)."""

    def __init__(self, channel: str = "sea", receive_own_messages: bool = False, rcvbuf: int = 1 << 20,
                 **kwargs):
        self.channel = str(channel)
        self.channel_info = f"ipc bus {self.channel}"
        self._dir = channel_dir(self.channel)
        private_channel_dir(self._dir)
        self._own = receive_own_messages
        self._pending: list[can.Message] = []
        self.overruns = 0                       # frames a full member queue lost (all members)
        self._rcvbuf = rcvbuf
        self._sock = self._socket()
        self.path = os.path.join(self._dir, f"{os.getpid()}-{next(_counter)}")
        self._rd = (self._sock,)
        self._poll = select.poll()                  # recv_frame(0): is a frame queued (no exception)
        self._poll.register(self._sock.fileno(), select.POLLIN)
        self._peers: list[tuple] = []
        self._seen = -1                             # the membership count the list was made at
        self._next_link_check = 0.0                 # when to check that .members is the directory's
        self._buf = bytearray(_FRAME.size)
        self._rbuf = bytearray(64)                  # recv_frame's receive buffer
        self._rview = memoryview(self._rbuf)
        self._pending_ts: float | None = None       # frame_timestamp() of a frame from _pending
        self._closed = False
        # ((id, mask), ...) of set_filters, None: all; the constructor's published as it joins (no
        # sender sees this member without its filter)
        self._accept: tuple | None = self._pairs(kwargs.get("can_filters"))
        self._accepts: dict[int, bool] = {}        # id -> whether _accept takes it (cache)
        self._dest: dict[int, tuple] = {}          # id -> the members a frame with it goes to (cache)
        self._conns: dict[str, socket.socket] = {}  # member -> a socket connected to it (send())
        try:
            self._members = self._join(self._sock.bind)
        except BaseException:
            self._sock.close()
            raise
        super().__init__(channel=self.channel, **kwargs)
        self._refresh()

    # ------------------------------------------------------------------ members
    def _socket(self) -> socket.socket:
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, self._rcvbuf)
        except OSError:
            pass
        return sock

    def _join(self, bind) -> _Members:
        """Under the channel's lock: remove a stale file at this member's path, ``bind(path)``,
        publish its filter (if set) and count the change.  Returns the channel's count, unlocked."""
        members = _Members.open_locked(self._dir)
        try:
            try:
                os.unlink(self.path)
            except FileNotFoundError:
                pass
            bind(self.path)
            if self._accept is not None:
                self._publish_filter()
            members.bump(locked=True)
        except BaseException:
            members.unlock()
            members.close()
            raise
        members.unlock()
        return members

    def _refresh(self) -> None:
        """Re-read the members and their filters when the channel's membership count moved (a
        read of shared memory per send); every 0.25 s also whether the count's file is still
        the directory's (a directory removed and made again: joined anew)."""
        m = self._members
        now = time.monotonic()
        if now >= self._next_link_check:
            self._next_link_check = now + 0.25
            if not m.linked():
                self._rejoin()
                m = self._members
        if m.count() == self._seen:
            return
        me = os.path.basename(self.path)
        peers = []
        m.lock(shared=True)                        # every change counted is in the directory
        try:
            c = m.count()
            try:
                names = set(os.listdir(self._dir))
            except OSError:
                names = set()
            for f in sorted(names):
                if f == me or not _is_member(f):
                    continue
                acc = None
                if f + FILTER_SUFFIX in names:
                    try:
                        with open(os.path.join(self._dir, f + FILTER_SUFFIX)) as fh:
                            acc = tuple(tuple(int(v, 16) for v in item.split(":")) for item in fh.read().split())
                    except (OSError, ValueError):
                        acc = None
                peers.append((os.path.join(self._dir, f), acc))
        finally:
            m.unlock()
        self._seen = c
        self._peers = peers
        self._dest = {}
        for peer in [p for p in self._conns if p not in {q for q, _ in peers}]:
            self._disconnect(peer)                 # a member that left: its connection closed

    def _rejoin(self) -> None:
        """The channel's directory went (removed under the members): make it again, bind anew."""
        members = self._join(self._rebind)
        self._members, old = members, self._members
        old.close()
        self._seen = -1

    def _rebind(self, path: str) -> None:
        """A new socket bound to ``path`` under this handle's descriptor: whoever polls its
        fileno() (the driver's one poll for its handles) keeps polling the right socket."""
        sock = self._socket()
        try:
            sock.bind(path)
            os.dup2(sock.fileno(), self._sock.fileno())
        finally:
            sock.close()

    def _gone(self, peer: str, stale: bool) -> None:
        self._disconnect(peer)
        self._peers = [p for p in self._peers if p[0] != peer]
        self._dest = {}
        if stale:                                  # nobody bound to it any more: remove the files
            for f in (peer, peer + FILTER_SUFFIX):
                try:
                    os.unlink(f)
                except OSError:
                    pass
            self._members.bump()

    # ------------------------------------------------------------------ BusABC
    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if self._closed:
            raise can.CanOperationError("ipc bus is shut down")
        flags = (_EXT if msg.is_extended_id else 0) | (_RTR if msg.is_remote_frame else 0) | \
            (_ERR if msg.is_error_frame else 0)
        dlc = msg.dlc
        if dlc > 8:
            raise can.CanOperationError(f"ipc bus: classic CAN only, DLC {dlc} > 8")
        data = msg.data
        if len(data) != dlc:
            data = bytes(data[:dlc])
        can_id = msg.arbitration_id
        if self._members._count.item(0) != self._seen or time.monotonic() >= self._next_link_check:
            self._refresh()                        # (its checks, without a call when nothing is due)
        # the members that take this id (their published filters; error frames pass every filter)
        key = -1 if flags & _ERR else can_id
        dest = self._dest.get(key)
        if dest is None:
            dest = tuple(peer for peer, acc in self._peers
                         if key < 0 or acc is None or any(can_id & m == i & m for i, m in acc))
            if len(self._dest) < 4096:             # bounded: extended ids are many
                self._dest[key] = dest
        if not dest and not self._own:
            return                                 # nobody takes it: nothing to send
        buf = self._buf
        _FRAME.pack_into(buf, 0, can_id, flags, dlc, data, time.time())
        conns = self._conns
        for peer in dest:
            conn = conns.get(peer)
            if conn is None:
                conn = self._connect(peer)
            if conn is None:
                self._send_to_path(buf, peer)      # not connectable now: by its path, which says why
                continue
            try:
                conn.send(buf, socket.MSG_DONTWAIT)
            except BlockingIOError:
                self.overruns += 1                 # that member is not reading: its frame is lost
            except OSError:
                # the socket connected to has gone: once more by its path, which tells whether
                # the member has gone too (refused, removed) or bound anew (sent)
                self._disconnect(peer)
                self._send_to_path(buf, peer)
        if self._own:
            self._pending.append(self._decode(bytes(buf)))

    def _connect(self, peer: str):
        """A socket connected to ``peer`` (a send without the path's lookup), or None when it
        cannot be connected now (the frame goes by the path, which reports why)."""
        conn = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        try:
            conn.connect(peer)
        except OSError:
            conn.close()
            return None
        self._conns[peer] = conn
        return conn

    def _disconnect(self, peer: str) -> None:
        conn = self._conns.pop(peer, None)
        if conn is not None:
            conn.close()

    def _send_to_path(self, buf, peer: str) -> None:
        try:
            self._sock.sendto(buf, socket.MSG_DONTWAIT, peer)
        except BlockingIOError:
            self.overruns += 1
        except OSError as e:
            self._send_failed(peer, e)

    def _send_failed(self, peer: str, e: OSError) -> None:
        """A send by ``peer``'s path failed: a member gone is dropped (its files removed when no
        socket is bound to them), anything else is the bus's error."""
        if isinstance(e, (ConnectionRefusedError, FileNotFoundError)):
            self._gone(peer, isinstance(e, ConnectionRefusedError))
        elif e.errno in (errno.ENOTSOCK, errno.ECONNREFUSED, errno.ENOENT):
            self._gone(peer, True)
        else:
            raise can.CanOperationError(f"ipc bus {self.channel}: send failed: {e}") from None

    @staticmethod
    def _decode(raw: bytes) -> can.Message:
        can_id, flags, dlc, data, ts = _FRAME.unpack(raw)
        return can.Message(timestamp=ts, arbitration_id=can_id, is_extended_id=bool(flags & _EXT),
                           is_remote_frame=bool(flags & _RTR), is_error_frame=bool(flags & _ERR), dlc=dlc,
                           data=data[:dlc], channel=None, check=False)

    @staticmethod
    def _pairs(filters) -> tuple | None:
        """python-can's ``can_filters`` as ((id, mask), ...); None (accept all) for none."""
        return tuple((int(f["can_id"]), int(f["can_mask"])) for f in filters) if filters else None

    def _apply_filters(self, filters) -> None:
        """python-can's accept filters, checked on the raw id before a frame is decoded (error
        frames always pass, as on SocketCAN)."""
        self._accept = self._pairs(filters)
        self._accepts = {}
        # published next to the socket: the senders skip this member for other ids (a member's
        # queue holds max_dgram_qlen datagrams, 10 by default: a handle read only once a cycle
        # must not fill with frames it drops anyway)
        self._publish_filter()
        self._members.bump()

    def _publish_filter(self) -> None:
        path = self.path + FILTER_SUFFIX
        try:
            if self._accept is None:
                os.unlink(path)
            else:
                with open(path + ".tmp", "w") as fh:
                    fh.write(" ".join(f"{i:x}:{m:x}" for i, m in self._accept))
                os.replace(path + ".tmp", path)
        except OSError:
            pass

    def _recv_internal(self, timeout: float | None):
        if self._pending:
            return self._pending.pop(0), False
        if self._closed:
            return None, False
        end = None if timeout is None else time.monotonic() + timeout
        acc = self._accept
        while True:
            try:
                raw = self._sock.recv(64, socket.MSG_DONTWAIT)
            except BlockingIOError:
                left = None if end is None else end - time.monotonic()
                if left is not None and left <= 0.0:
                    return None, True
                # select: a timeout in µs (poll's is in ms, too coarse inside a 1 ms period)
                if not select.select(self._rd, (), (), left)[0]:
                    return None, True
                continue
            except OSError:
                return None, False
            if len(raw) != _FRAME.size:
                continue
            if acc is not None and not raw[4] & _ERR:
                can_id = raw[0] | raw[1] << 8 | raw[2] << 16 | raw[3] << 24
                if not any(can_id & m == i & m for i, m in acc):
                    continue                     # another frame: the queue is read on (no time check)
            return self._decode(raw), True

    def recv_frame(self, timeout: float, ready: bool = False):
        """The cycle's receive path (:class:`sea_daemon.hw.canopen_rx.TpdoWindow`): the next frame
        this member accepts as ``(arbitration id, data)`` — ``data`` a view of a receive buffer
        that the next call overwrites — or None after ``timeout`` seconds (0: only what is
        queued).  The same frames as :meth:`recv`, without building a :class:`can.Message`.
        ``ready``: a frame is probably queued (the rest of a burst): read before waiting or
        polling (one system call when it is there; a read that finds none then waits as
        without it)."""
        if self._pending:
            msg = self._pending.pop(0)
            self._pending_ts = msg.timestamp
            return msg.arbitration_id, msg.data
        self._pending_ts = None
        if self._closed:
            return None
        sock, buf, acc = self._sock, self._rbuf, self._accept
        end = None
        if not ready and timeout <= 0.0 and not self._poll.poll(0):
            return None                      # nothing queued (a poll, not an exception per empty read)
        while True:
            if timeout > 0.0 and not ready:
                # wait first: after a SYNC the answer is not there yet (no exception per frame)
                if end is None:
                    end = time.monotonic() + timeout
                    left = timeout
                else:
                    left = end - time.monotonic()
                    if left <= 0.0:
                        return None
                if not select.select(self._rd, (), (), left)[0]:
                    return None
            try:
                nb = sock.recv_into(buf, 64, socket.MSG_DONTWAIT)
            except BlockingIOError:
                if ready:
                    ready = False            # not there after all: wait (or poll) as without the hint
                    if timeout <= 0.0:
                        return None
                    continue
                if timeout > 0.0:
                    continue
                return None
            except OSError:
                return None
            if nb != _FRAME.size:
                continue
            can_id = buf[0] | buf[1] << 8 | buf[2] << 16 | buf[3] << 24
            if acc is not None and not buf[4] & _ERR:
                ok = self._accepts.get(can_id)
                if ok is None:
                    ok = any(can_id & m == i & m for i, m in acc)
                    if len(self._accepts) < 4096:
                        self._accepts[can_id] = ok
                if not ok:
                    continue                 # another frame: the queue is read on
            return can_id, self._rview[8:8 + buf[5]]

    def frame_timestamp(self) -> float:
        """The sender's ``time.time()`` of the frame :meth:`recv_frame` returned last."""
        if self._pending_ts is not None:
            return self._pending_ts
        return _TS.unpack_from(self._rbuf, 16)[0]

    def fileno(self) -> int:
        return self._sock.fileno()

    def shutdown(self) -> None:
        if self._closed:
            return
        self._closed = True
        for peer in list(self._conns):
            self._disconnect(peer)
        try:
            self._sock.close()
        except OSError:
            pass
        try:
            self._leave()
        finally:
            super().shutdown()

    def _leave(self) -> None:
        """Leave the channel under its lock; the last member removes the count's file."""
        m = getattr(self, "_members", None)        # None: never joined (the constructor failed)
        if m is None:
            return
        m.lock()
        try:
            for f in (self.path, self.path + FILTER_SUFFIX):
                try:
                    os.unlink(f)
                except OSError:
                    pass
            m.bump(locked=True)
            try:
                left = [f for f in os.listdir(self._dir) if _is_member(f)]
            except OSError:
                left = None
            if left == []:
                try:
                    os.unlink(os.path.join(self._dir, MEMBERS_FILE))
                except OSError:
                    pass
        finally:
            m.unlock()
            m.close()

    @staticmethod
    def _detect_available_configs():
        return []
