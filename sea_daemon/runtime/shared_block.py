"""Memory shared between the daemon's processes that no other process can open and no exit leaves behind.

A :class:`SharedBlock` is an anonymous file of the kernel (``memfd_create``): it has no name in
``/dev/shm`` — nobody else can open it, nobody can plant one under its name, and it is freed
with the last process that maps it or holds its descriptor, however that process ends (a
``SIGKILL`` included).  A child forked from the daemon inherits it; a spawned one is handed its
descriptor (:meth:`SharedBlock.attach`).  The log writer's ring (:mod:`.logwriter`) and the
bound worker's slots (:mod:`.bound_worker`) live in one each.
"""
from __future__ import annotations

import mmap
import os


class SharedBlock:
    """``size`` bytes of shared memory: :attr:`buf` (a memoryview), :attr:`fd` (its descriptor)."""

    def __init__(self, fd: int, size: int):
        self.fd, self.size = fd, int(size)
        self._mm = mmap.mmap(fd, self.size)
        self.buf: memoryview | None = memoryview(self._mm)

    @classmethod
    def create(cls, size: int, name: str) -> "SharedBlock":
        """A new block of ``size`` bytes (zeros); ``name`` shows in /proc/PID/fd (memfd:NAME) only."""
        fd = os.memfd_create(name, os.MFD_CLOEXEC)
        try:
            os.ftruncate(fd, int(size))
            return cls(fd, size)
        except BaseException:
            os.close(fd)
            raise

    @classmethod
    def attach(cls, fd: int, size: int) -> "SharedBlock":
        """The block whose descriptor ``fd`` this process was handed (it takes ``fd`` over)."""
        return cls(fd, size)

    def close(self) -> None:
        """Unmap and close this process's hold on the block (the views of :attr:`buf` must be
        gone); safe to call twice."""
        if self.buf is None:
            return
        self.buf.release()
        self.buf = None
        self._mm.close()
        os.close(self.fd)
