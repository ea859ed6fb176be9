"""Measured-log writer that never blocks the fixed-rate loop and loses nothing.

The loop copies each row (a preallocated float64 vector) into a ring buffer in shared
memory — one slice assignment and one integer store, no allocation, no I/O, no lock.  A
separate *process* (so CSV formatting never competes for the loop's GIL) drains the ring,
writes measured-log CSV (docs/interfaces.md §1), flushes at least every ``flush_interval`` seconds, rotates to a new
numbered file (each with its header) when a file exceeds ``rotate_bytes``, and on close
drains everything and fsyncs.  If the loop's process dies, the writer notices and drains
what is in the ring before exiting.  A full ring is counted (``dropped``), never silent.
"""
from __future__ import annotations

import multiprocessing as mp
import os
import time
from multiprocessing import shared_memory
from pathlib import Path

import numpy as np

# header slots (int64) of the shared block
_HEAD, _TAIL, _STOP, _WRITTEN, _FILES, _NHDR = 0, 1, 2, 3, 4, 8


def segment_path(path: Path, index: int) -> Path:
    """``run.csv`` for the first segment, then ``run.part001.csv``, ``run.part002.csv`` …"""
    return path if index == 0 else path.with_name(f"{path.stem}.part{index:03d}{path.suffix}")


def _writer_main(shm_name, capacity, ncols, path, columns, flush_interval, rotate_bytes, fmt, parent_pid):
    try:
        # the writer must never compete with the loop: back to SCHED_OTHER when it inherited
        # SCHED_FIFO (systemd's CPUSchedulingPolicy=fifo applies to the whole service)
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    except (OSError, AttributeError):
        pass
    shm = shared_memory.SharedMemory(name=shm_name)
    try:
        hdr = np.ndarray((_NHDR,), dtype=np.int64, buffer=shm.buf)
        data = np.ndarray((capacity, ncols), dtype=np.float64, buffer=shm.buf, offset=_NHDR * 8)
        float(data.sum())        # map every page of the ring now (steady memory from the start)
        path = Path(path)
        header = ",".join(columns) + "\n"
        seg = 0
        fh = open(segment_path(path, seg), "w", buffering=1 << 20)
        fh.write(header)
        last_flush = time.monotonic()
        line_fmt = ",".join([fmt] * ncols) + "\n"
        while True:
            head = int(hdr[_HEAD])
            tail = int(hdr[_TAIL])
            if head > tail:
                if rotate_bytes and fh.tell() >= rotate_bytes:   # rotate before writing: no empty files
                    fh.flush()
                    os.fsync(fh.fileno())
                    fh.close()
                    seg += 1
                    fh = open(segment_path(path, seg), "w", buffering=1 << 20)
                    fh.write(header)
                    hdr[_FILES] = seg + 1
                n = min(head - tail, capacity, 1024)
                idx = np.arange(tail, tail + n) % capacity
                block = data[idx]
                fh.write("".join(line_fmt % tuple(r) for r in block))
                hdr[_TAIL] = tail + n
                hdr[_WRITTEN] += n
                continue
            now = time.monotonic()
            if now - last_flush >= flush_interval:
                fh.flush()
                last_flush = now
            if hdr[_STOP] or os.getppid() != parent_pid:
                if int(hdr[_HEAD]) == int(hdr[_TAIL]):
                    break
                continue
            time.sleep(min(0.02, flush_interval / 4))
        fh.flush()
        os.fsync(fh.fileno())
        fh.close()
    finally:
        shm.close()


class LogWriter:
    """Bounded, non-blocking, loss-counting CSV log writer (see module docstring)."""

    def __init__(self, path: str | Path, columns: list[str], capacity: int = 1 << 16,
                 flush_interval: float = 0.5, rotate_bytes: int = 256 << 20, fmt: str = "%.10g"):
        if flush_interval > 1.0:
            raise ValueError(f"flush_interval {flush_interval} s: must be <= 1 s (logs are flushed at least once a second)")
        self.path = Path(path)
        self.columns = list(columns)
        self.capacity = int(capacity)
        self.ncols = len(self.columns)
        self._shm = shared_memory.SharedMemory(create=True, size=_NHDR * 8 + self.capacity * self.ncols * 8)
        self._hdr = np.ndarray((_NHDR,), dtype=np.int64, buffer=self._shm.buf)
        self._hdr[:] = 0
        self._hdr[_FILES] = 1
        self._data = np.ndarray((self.capacity, self.ncols), dtype=np.float64, buffer=self._shm.buf, offset=_NHDR * 8)
        self._data[:] = 0.0      # pre-fault the ring: the loop never takes a page fault on it
        self.dropped = 0
        self.appended = 0
        ctx = mp.get_context("spawn")
        self._proc = ctx.Process(target=_writer_main, name="sea-daemon-logwriter", daemon=False,
                                 args=(self._shm.name, self.capacity, self.ncols, str(self.path), self.columns,
                                       flush_interval, rotate_bytes, fmt, os.getpid()))
        self._proc.start()
        self._closed = False

    def append(self, row: np.ndarray) -> bool:
        """Copy one row into the ring (real-time safe).  False when the ring is full (counted)."""
        h = self.appended
        if h - int(self._hdr[_TAIL]) >= self.capacity:
            self.dropped += 1
            return False
        self._data[h % self.capacity] = row
        self.appended = h + 1
        self._hdr[_HEAD] = h + 1
        return True

    @property
    def rows_written(self) -> int:
        return int(self._hdr[_WRITTEN])

    @property
    def files(self) -> list[Path]:
        return [segment_path(self.path, i) for i in range(int(self._hdr[_FILES]))]

    def close(self, timeout: float = 30.0) -> dict:
        """Drain, fsync and stop the writer; returns counts.  Safe to call twice."""
        if not self._closed:
            self._hdr[_STOP] = 1
            self._proc.join(timeout)
            if self._proc.is_alive():
                self._proc.terminate()
                self._proc.join(5)
            written = self.rows_written
            files = self.files
            self._shm.close()
            self._shm.unlink()
            self._closed = True
            self._final = {"rows_appended": self.appended, "rows_written": written,
                           "rows_dropped": self.dropped, "files": [str(f) for f in files]}
        return self._final

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
