"""Measured-log writer that never blocks the fixed-rate loop and accounts for every row.

The loop copies each row (a preallocated float64 vector) into a ring buffer in shared
memory — one slice assignment and one integer store, no allocation, no I/O, no lock.  A
separate *process* (so CSV formatting never competes for the loop's GIL) drains the ring and
writes measured-log CSV (docs/interfaces.md §1) with one ``write`` per batch of whole lines,
rotates to a new numbered file (each with its header) when a file exceeds ``rotate_bytes``, and
on close drains everything and fsyncs.  If the loop's process dies, the writer notices and
drains what is in the ring before exiting.

Nothing is lost silently:

* the first file and its header are written by the constructor, so a log that cannot be
  created (missing or read-only directory, full disk) is an :class:`~sea_daemon.errors.InputError`
  before the loop starts;
* a write that fails later (disk full, I/O error, file size limit) is cut back to the last
  whole line (no torn row), recorded (``errno``), and from then on the writer discards the
  rows it drains, counting them (``rows_lost``);
* a writer that died (killed, crashed) is seen by :meth:`LogWriter.fault` within 0.2 s;
* a full ring drops the row and counts it (``dropped``).

:meth:`LogWriter.fault` (called by the loop every cycle; an integer read, the process checked
every 0.2 s) returns one line naming what failed once any of these happened — the loop latches
it as the LOG_FAILED fault (docs/safety.md) — and :meth:`LogWriter.close` reports
``rows_lost`` = rows offered by the loop − rows written.
"""
from __future__ import annotations

import multiprocessing as mp
import os
import time
from multiprocessing import shared_memory
from pathlib import Path

import numpy as np

from sea_daemon.errors import InputError, shown

# header slots (int64) of the shared block
_HEAD, _TAIL, _STOP, _WRITTEN, _FILES, _ERRNO, _LOST, _NHDR = 0, 1, 2, 3, 4, 5, 6, 8
_UNKNOWN = -1                        # _ERRNO of a failure that was not an OSError


def segment_path(path: Path, index: int) -> Path:
    """``run.csv`` for the first segment, then ``run.part001.csv``, ``run.part002.csv`` …"""
    return path if index == 0 else path.with_name(f"{path.stem}.part{index:03d}{path.suffix}")


class _PartialWrite(OSError):
    """A write that failed after ``done`` bytes of its data had reached the file."""

    def __init__(self, err: OSError, done: int):
        super().__init__(err.errno, err.strerror)
        self.done = done


def _write_all(fd: int, data: bytes) -> None:
    """Write all of ``data``; _PartialWrite (with the bytes written) when the file refuses more."""
    view = memoryview(data)
    done = 0
    while done < len(data):
        try:
            done += os.write(fd, view[done:])
        except OSError as e:
            raise _PartialWrite(e, done) from None


def _open_segment(path: Path, header: bytes) -> int:
    """A new segment file with its header, as an O_APPEND descriptor; a failed header write
    removes the file again."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_APPEND, 0o644)
    try:
        _write_all(fd, header)
    except OSError:
        os.close(fd)
        try:
            os.unlink(path)
        except OSError:
            pass
        raise
    return fd


def _writer_main(shm_name, capacity, ncols, path, columns, rotate_bytes, fmt, parent_pid, poll):
    try:
        # the writer must never compete with the loop: back to SCHED_OTHER when it inherited
        # SCHED_FIFO (systemd's CPUSchedulingPolicy=fifo applies to the whole service)
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    except (OSError, AttributeError):
        pass
    shm = shared_memory.SharedMemory(name=shm_name)
    hdr = np.ndarray((_NHDR,), dtype=np.int64, buffer=shm.buf)
    data = None
    fd = -1
    try:
        data = np.ndarray((capacity, ncols), dtype=np.float64, buffer=shm.buf, offset=_NHDR * 8)
        float(data.sum())        # map every page of the ring now (steady memory from the start)
        path = Path(path)
        header = (",".join(columns) + "\n").encode()
        seg = 0
        failed = False
        try:
            fd = os.open(segment_path(path, seg), os.O_WRONLY | os.O_APPEND)  # created with its header
            good = os.fstat(fd).st_size              # bytes of whole lines in the current file
        except OSError as e:
            failed = True
            hdr[_ERRNO] = e.errno or _UNKNOWN
        line_fmt = ",".join([fmt] * ncols) + "\n"
        while True:
            head = int(hdr[_HEAD])
            tail = int(hdr[_TAIL])
            if head > tail:
                n = min(head - tail, capacity, 1024)
                idx = np.arange(tail, tail + n) % capacity
                block = data[idx]                    # a copy: the ring slots are free again
                hdr[_TAIL] = tail + n
                if failed:
                    hdr[_LOST] += n
                    continue
                text = b""
                try:
                    if rotate_bytes and good >= rotate_bytes:   # rotate before writing: no empty files
                        os.fsync(fd)
                        os.close(fd)
                        fd = -1
                        seg += 1
                        fd = _open_segment(segment_path(path, seg), header)
                        good = len(header)
                        hdr[_FILES] = seg + 1
                    text = "".join(line_fmt % tuple(r) for r in block).encode()
                    _write_all(fd, text)
                    good += len(text)
                    hdr[_WRITTEN] += n
                except OSError as e:
                    # disk full, I/O error, file size limit: keep the whole lines that reached the
                    # file, cut the torn one, record the cause, account for the rows from here on
                    failed = True
                    hdr[_ERRNO] = e.errno or _UNKNOWN
                    kept = 0
                    if isinstance(e, _PartialWrite) and e.done:
                        cut = text.rfind(b"\n", 0, e.done) + 1
                        kept = text.count(b"\n", 0, cut)
                        good += cut
                        hdr[_WRITTEN] += kept
                    hdr[_LOST] += n - kept
                    if fd >= 0:
                        try:
                            os.ftruncate(fd, good)
                        except OSError:
                            pass
                continue
            if hdr[_STOP] or os.getppid() != parent_pid:
                if int(hdr[_HEAD]) == int(hdr[_TAIL]):
                    break
                continue
            time.sleep(poll)
        if fd >= 0:
            try:
                os.fsync(fd)
            except OSError as e:
                if not failed:
                    hdr[_ERRNO] = e.errno or _UNKNOWN
    except BaseException:
        if hdr[_ERRNO] == 0:
            hdr[_ERRNO] = _UNKNOWN
        raise
    finally:
        if fd >= 0:
            try:
                os.close(fd)
            except OSError:
                pass
        del hdr, data
        shm.close()


class LogWriter:
    """Bounded, non-blocking, loss-counting CSV log writer (see module docstring).

    ``flush_interval``: the longest a row waits in the ring before the writer writes it
    (the writer polls the ring at least this often; its writes go straight to the file).
    """

    def __init__(self, path: str | Path, columns: list[str], capacity: int = 1 << 16,
                 flush_interval: float = 0.5, rotate_bytes: int = 256 << 20, fmt: str = "%.10g"):
        if flush_interval > 1.0:
            raise ValueError(f"flush_interval {flush_interval} s: must be <= 1 s (logs are flushed at least once a second)")
        self.path = Path(path)
        self.columns = list(columns)
        self.capacity = int(capacity)
        self.ncols = len(self.columns)
        self._closed = True                      # until the writer runs
        # the first file and its header now: a log that cannot be written stops the start-up
        try:
            os.close(_open_segment(self.path, (",".join(self.columns) + "\n").encode()))
        except OSError as e:
            raise InputError(f"log {shown(self.path)}: cannot write: {e.strerror or e}") from None
        self._shm = shared_memory.SharedMemory(create=True, size=_NHDR * 8 + self.capacity * self.ncols * 8)
        self._hdr = np.ndarray((_NHDR,), dtype=np.int64, buffer=self._shm.buf)
        self._hdr[:] = 0
        self._hdr[_FILES] = 1
        self._data = np.ndarray((self.capacity, self.ncols), dtype=np.float64, buffer=self._shm.buf, offset=_NHDR * 8)
        self._data[:] = 0.0      # pre-fault the ring: the loop never takes a page fault on it
        self.dropped = 0
        self.appended = 0
        self._fault: str | None = None
        self._next_alive = 0.0
        ctx = mp.get_context("spawn")
        self._proc = ctx.Process(target=_writer_main, name="sea-daemon-logwriter", daemon=False,
                                 args=(self._shm.name, self.capacity, self.ncols, str(self.path), self.columns,
                                       rotate_bytes, fmt, os.getpid(), min(0.02, flush_interval / 4)))
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

    def fault(self) -> str | None:
        """None while every row offered can still reach the file; else one line saying what
        failed (the same string on every later call).  Real-time safe: an integer read, and
        every 0.2 s whether the writer process still runs."""
        if self._fault is not None:
            return self._fault
        if self._closed:
            return self._final["error"]
        err = int(self._hdr[_ERRNO])
        if err:
            why = os.strerror(err) if err > 0 else "the writer failed"
        elif self.dropped:
            why = f"the ring of {self.capacity} rows is full (the writer does not keep up)"
        else:
            now = time.monotonic()
            if now < self._next_alive:
                return None
            self._next_alive = now + 0.2
            if self._proc.is_alive():
                return None
            why = f"the writer process exited (exit code {self._proc.exitcode})"
        self._fault = (f"log {shown(self.path)}: {why}; rows written {self.rows_written}, "
                       "later rows are lost")
        return self._fault

    @property
    def rows_written(self) -> int:
        return self._final["rows_written"] if self._closed else int(self._hdr[_WRITTEN])

    @property
    def files(self) -> list[Path]:
        if self._closed:
            return [Path(f) for f in self._final["files"]]
        return [segment_path(self.path, i) for i in range(int(self._hdr[_FILES]))]

    def close(self, timeout: float = 30.0) -> dict:
        """Drain, fsync and stop the writer; returns counts.  Safe to call twice.

        ``rows_lost`` = rows the loop offered (appended + dropped) − rows written; ``error``:
        what failed (:meth:`fault`), None when nothing did."""
        if not self._closed:
            self._hdr[_STOP] = 1
            self._proc.join(timeout)
            if self._proc.is_alive():
                self._proc.terminate()
                self._proc.join(5)
            written = self.rows_written
            files = self.files
            err = self._fault
            if err is None and (self._hdr[_ERRNO] or self.dropped or self._proc.exitcode):
                self._next_alive = 0.0
                err = self.fault() or (f"log {shown(self.path)}: the writer process exited "
                                       f"(exit code {self._proc.exitcode})")
            lost = self.appended + self.dropped - written
            if err is None and lost:
                err = f"log {shown(self.path)}: the writer stopped with {lost} rows not written"
            self._final = {"rows_appended": self.appended, "rows_written": written,
                           "rows_dropped": self.dropped, "rows_lost": lost, "error": err,
                           "files": [str(f) for f in files]}
            self._closed = True
            del self._hdr, self._data
            self._shm.close()
            self._shm.unlink()
        return self._final

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
