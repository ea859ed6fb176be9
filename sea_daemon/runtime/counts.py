"""Cumulative int64 counts through a pipe: how two processes order what they share in memory.

Python has no memory fences, and a weakly ordered CPU (aarch64) may make stores and loads to
shared memory visible to another process out of program order.  A pipe's write and read are
system calls that take the pipe's lock, so what a process stored before it wrote a count is
visible to the process that has read that count.  The bound worker and the log writer order
their rings this way: each side acts only on counts it has read from a pipe.

The counts are cumulative (a newer one replaces an older one), so a writer whose count does not
fit (the pipe full: the reader behind) writes its newest count later, and a reader keeps the
newest it has read.  :func:`write_count` writes one count without blocking; :class:`CountReader`
reads counts in whatever pieces the reads return.
"""
from __future__ import annotations

import os
import struct

import numpy as np

INT64 = struct.Struct("=q")


def write_count(fd: int, buf: bytearray, value: int) -> bool:
    """Write ``value`` as 8 bytes (``buf``: 8 bytes made once) to a non-blocking pipe: True when
    it went, False when the pipe is full (the reader behind: write the newest count later;
    ≤ PIPE_BUF, so all 8 bytes go or none).  Any other OSError — the reading end closed —
    is raised."""
    INT64.pack_into(buf, 0, value)
    try:
        os.write(fd, buf)
    except BlockingIOError:
        return False
    return True


class CountReader:
    """The int64 counts a pipe carries, read in whatever pieces the reads return.

    :meth:`read` makes one read into a buffer made once (up to ``values`` counts); the bytes of a
    count split across two reads are kept and completed by the next read.  After it,
    :meth:`value` (i) is its i-th complete count, valid until the next read.  :meth:`newest`
    reads until the pipe is empty.
    """

    def __init__(self, fd: int, values: int = 512):
        self.fd = fd
        self._buf = bytearray(8 * (values + 1))
        self._i64 = np.frombuffer(self._buf, dtype=np.int64)
        mv = memoryview(self._buf)
        # one target list per number of bytes kept (0..7): readv into the buffer after them
        self._into = [[mv[c:c + 8 * values]] for c in range(8)]
        self._kept = 0                       # bytes of an incomplete count, at the buffer's start
        self._move = 0                       # > 0: they are still at this offset (after whole counts)
        self.eof = False

    def read(self) -> int:
        """One read: the number of complete counts it made (0: none, or only part of one).
        Raises BlockingIOError on a non-blocking pipe with nothing to read; sets :attr:`eof`
        when the writing end is closed."""
        c = self._kept
        a = self._move
        if a:                                # the incomplete count to the buffer's start (rare)
            self._buf[:c] = self._buf[a:a + c]
            self._move = 0
        got = os.readv(self.fd, self._into[c])
        if got == 0:
            self.eof = True
            return 0
        total = c + got
        whole = total & ~7
        self._kept = kept = total - whole
        if kept and whole:
            self._move = whole
        return whole >> 3

    def value(self, i: int) -> int:
        return self._i64.item(i)

    def newest(self, known: int) -> int:
        """Read a non-blocking pipe until it is empty (or at its end: :attr:`eof`); the newest
        complete count read, or ``known`` when none came.  Other read errors are raised."""
        while True:
            try:
                got = self.read()
            except BlockingIOError:
                return known
            if got:
                known = self.value(got - 1)
            elif self.eof:
                return known


def close_fds(obj, names) -> None:
    """Close the descriptors held in ``obj``'s attributes ``names`` (each set to −1 first, so
    that a second call closes nothing)."""
    for name in names:
        fd = getattr(obj, name, -1)
        if fd >= 0:
            setattr(obj, name, -1)
            try:
                os.close(fd)
            except OSError:
                pass
