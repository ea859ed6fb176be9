"""Measured-log writer that never blocks the fixed-rate loop and accounts for every row.

The loop copies each row (a preallocated float64 vector) into a ring buffer in shared
memory and publishes it — one slice assignment, two integer stores and, every 32 rows or
50 ms, one non-blocking write of 8 bytes; no allocation, no lock, never waiting.  A separate *process* (so CSV formatting
never competes for the loop's GIL) drains the ring and writes measured-log CSV
(docs/interfaces.md §1) with one ``write`` per batch of whole lines, rotates to a new numbered
file (each with its header) when a file exceeds ``rotate_bytes``, and on close drains
everything and fsyncs.  If the loop's process dies, the writer drains what is in the ring
before exiting.

Memory order.  Python has no fences, and a weakly ordered CPU (aarch64) may make stores and
loads to shared memory visible to the other process out of program order, so the counts that
order the ring go through pipes (:mod:`sea_daemon.runtime.counts`): what a process stored before
it wrote a count is visible to the process that has read the count.

* loop → writer: after copying rows, the loop writes its head (rows appended, a cumulative
  int64) to the heads pipe — every 32 rows (a quarter of a smaller ring) or once 50 ms (a
  quarter of ``flush_interval`` if less) have passed since the last head, in :meth:`append` or
  in :meth:`LogWriter.fault`, which the loop calls every cycle: a row reaches the writer within
  that time, and a system call in every cycle would lengthen the loop's slowest cycles (its
  p99 by ≈ 25 µs at 1 kHz).  The writer copies only rows up to the newest head it has read from
  that pipe, which it drains without waiting at each poll.  It polls on a timer and never waits
  on the pipe, so the loop's write never wakes it (a write that wakes a waiting reader costs
  the loop about twice as much).  A head that finds the pipe full (8192 heads unread: the writer
  stopped reading) is written again by a later call, a later head replacing it.
* writer → loop: after copying rows out of the ring, the writer writes its tail (rows copied)
  to the tails pipe, without waiting; one that does not fit is written later, the newest
  replacing it.  The loop reuses a slot only once a tail beyond it came through that pipe, so
  the writer's loads of the slot are complete.  The loop reads the pipe every 256 rows and when
  the tail it knows says the ring is full; a row is dropped (``dropped``) only when the ring is
  full by the newest tail in the pipe.
* the end: :meth:`LogWriter.close` closes the loop's end of the heads pipe, and so does the
  kernel when the loop's process dies (after every store of that process).  The writer reads
  the pipe's end only after those stores, so it may then trust the head the loop also stores in
  shared memory with each row: it writes every row up to it and exits.  Processes forked from
  the loop's close their copies of the loop's ends.  Should another process still hold one, the
  writer stops 2 s after the loop's process is gone, with the rows whose heads it had read.

The rest of the shared header (rows written and lost, files, errno) is the writer's report,
read by the loop without order: seen late, a fault is reported a cycle later.

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

Other outputs (``sinks``: the LSL stream and the MCAP recording, :mod:`sea_daemon.runtime.sinks`)
are fed by the writer process with every block of rows it copies out of the ring, after the
tail went back and before the CSV's lines are written; the ring's rows then go on past the
CSV's columns (``sink_columns``) with what only they carry.  A sink that fails stops alone (its
state and the first failure's text in the shared header); the CSV log is not affected.
"""
from __future__ import annotations

import atexit
import multiprocessing as mp
import os
import time
import weakref
# multiprocessing.util registers its exit handler (which waits for the writer process) as it is
# imported: before this module's own (atexit runs last in, first out), so that ours, run first,
# ends the heads pipe that handler waits on
from multiprocessing import reduction, util  # noqa: F401
from pathlib import Path

import numpy as np

from sea_daemon.errors import InputError, shown
from sea_daemon.io.logcsv import csv_header, csv_rows
from sea_daemon.runtime.counts import CountReader, close_fds, write_count
from sea_daemon.runtime.shared_block import SharedBlock
from sea_daemon.runtime.sinks import MAX_SINKS, MSG_BYTES, SinkBoard, SinkSet, wait_open

# header slots (int64) of the shared block, read without order (module docstring): the loop's
# head (read by the writer only after the loop's end of the heads pipe closed), the writer's
# counts of rows written and lost, files and errno; then the sinks' board (runtime/sinks.py):
# two slots a sink, the first failure's text
_HEAD, _WRITTEN, _FILES, _ERRNO, _LOST = 0, 1, 2, 3, 4
_BOARD = 8
_MSG = _BOARD + 2 * MAX_SINKS
_NHDR = _MSG + MSG_BYTES // 8
_UNKNOWN = -1                        # _ERRNO of a failure that was not an OSError
_TAIL_EVERY = 256                    # the loop reads the writer's tails every this many rows
_PUBLISH_ROWS = 32                   # the loop writes its head to the pipe every this many rows …
_PUBLISH_S = 0.05                    # … or after this long [s] (at most a quarter of flush_interval)
_ORPHAN_WAIT = 2.0                   # s the writer waits for the heads pipe's end after the loop's process is gone


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


def _drain_heads(heads: CountReader, head: int) -> int:
    """The newest head in the loop's pipe (``head`` when none came)."""
    try:
        return heads.newest(head)
    except OSError:                          # not a pipe any more: as at its end
        heads.eof = True
        return head


def _send_tail(fd: int, out: bytearray, tail: int) -> bool:
    """Write the tail to the loop's pipe without waiting; True when it must be written again
    later (the pipe full: the loop not reading), False when it went or no one reads it."""
    try:
        return not write_count(fd, out, tail)
    except OSError:                          # the loop's end closed: no one reads tails
        return False


def _leave_realtime() -> None:
    """The writer must never compete with the loop: back to SCHED_OTHER when it inherited
    SCHED_FIFO (systemd's CPUSchedulingPolicy=fifo applies to the whole service)."""
    try:
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    except (OSError, AttributeError):
        pass


class _Drain:
    """The writer process's side of the ring (module docstring): the loop's heads in, the rows
    up to them out to the current segment file as whole lines, the tails back to the loop.

    ``hdr``, ``data``: the shared header and ring; ``failed``: a write failed (the rows drained
    from then on are counted lost); ``good``: bytes of whole lines in the current file."""

    def __init__(self, hdr: np.ndarray, data: np.ndarray, path: Path, header: bytes, rotate_bytes: int,
                 fmt: str, heads_fd: int, tails_fd: int, ncsv: int):
        self.hdr, self.data, self.capacity = hdr, data, data.shape[0]
        self.ncsv, self.sinks = ncsv, None     # the CSV's columns (the first ncsv of a row); the SinkSet
        self.path, self.header, self.rotate_bytes, self.fmt = path, header, rotate_bytes, fmt
        self.heads, self.tails_fd, self.out = CountReader(heads_fd), tails_fd, bytearray(8)
        self.head = self.tail = 0     # rows published (read from the loop's pipe), rows copied out
        self.unsent = False           # a tail not yet written to the loop's pipe (it was full)
        self.final = False            # every write end of the loop's pipe closed: its last head is known
        self.seg, self.fd, self.good, self.failed = 0, -1, 0, False
        try:
            self.fd = os.open(segment_path(path, 0), os.O_WRONLY | os.O_APPEND)  # created with its header
            self.good = os.fstat(self.fd).st_size
        except OSError as e:
            self.failed = True
            hdr[_ERRNO] = e.errno or _UNKNOWN

    def run(self, parent_pid: int, poll: float) -> None:
        """Drain until the loop's end of the heads pipe closed and every row up to its last head
        is out; a loop process gone with the end still open: stop :data:`_ORPHAN_WAIT` later."""
        orphan = 0.0                  # when the loop's process was first seen gone (0: not yet)
        while True:
            if not self.final:
                self._read_heads()
            if self.head > self.tail:
                self._drain_block()
                continue
            if self.final:
                return
            if self.unsent:
                self.unsent = _send_tail(self.tails_fd, self.out, self.tail)
            if os.getppid() != parent_pid:
                # the loop's process is gone but the pipe's end is still open (a process forked
                # from it holds it): the rows whose heads came through the pipe are written;
                # wait a while for the end to close, then stop
                now = time.monotonic()
                if not orphan:
                    orphan = now
                elif now - orphan > _ORPHAN_WAIT:
                    return
            # a timed poll, not a wait on the pipe: the loop's writes never wake this process
            time.sleep(poll)

    def _read_heads(self) -> None:
        self.head = _drain_heads(self.heads, self.head)
        if self.heads.eof:
            # the loop closed its end (close()) or its process is gone: the kernel closed the end
            # after every store of that process, and this read of the end came after, so the
            # head it stored last, and its rows, are visible
            self.final = True
            self.head = max(self.head, int(self.hdr[_HEAD]))

    def _drain_block(self) -> None:
        """Copy up to 1024 published rows out of the ring, hand the tail back, write them."""
        n = min(self.head - self.tail, self.capacity, 1024)
        idx = np.arange(self.tail, self.tail + n) % self.capacity
        block = self.data[idx]                   # a copy: the ring slots are free again
        self.tail += n
        # the tail after the copy: the loop reuses the slots once it has read it
        self.unsent = _send_tail(self.tails_fd, self.out, self.tail)
        if self.sinks is not None:
            self.sinks.write(block)
        if self.failed:
            self.hdr[_LOST] += n
            return
        text = b""
        try:
            if self.rotate_bytes and self.good >= self.rotate_bytes:   # rotate before writing: no empty files
                self._rotate()
            text = csv_rows(block[:, :self.ncsv], self.fmt)
            _write_all(self.fd, text)
            self.good += len(text)
            self.hdr[_WRITTEN] += n
        except OSError as e:
            self._write_failed(e, text, n)

    def _rotate(self) -> None:
        os.fsync(self.fd)
        os.close(self.fd)
        self.fd = -1
        self.seg += 1
        self.fd = _open_segment(segment_path(self.path, self.seg), self.header)
        self.good = len(self.header)
        self.hdr[_FILES] = self.seg + 1

    def _write_failed(self, e: OSError, text: bytes, n: int) -> None:
        """Disk full, I/O error, file size limit: keep the whole lines that reached the file, cut
        the torn one, record the cause, account for the rows from here on."""
        hdr = self.hdr
        self.failed = True
        hdr[_ERRNO] = e.errno or _UNKNOWN
        kept = 0
        if isinstance(e, _PartialWrite) and e.done:
            cut = text.rfind(b"\n", 0, e.done) + 1
            kept = text.count(b"\n", 0, cut)
            self.good += cut
            hdr[_WRITTEN] += kept
        hdr[_LOST] += n - kept
        if self.fd >= 0:
            try:
                os.ftruncate(self.fd, self.good)
            except OSError:
                pass

    def sync(self) -> None:
        """fsync the current file; a failure is the log's error unless one came before."""
        if self.fd >= 0:
            try:
                os.fsync(self.fd)
            except OSError as e:
                if not self.failed:
                    self.hdr[_ERRNO] = e.errno or _UNKNOWN

    def close(self) -> None:
        """Close the current file and drop the views of the shared block (a traceback that
        still holds this object must not keep the block from closing)."""
        if self.fd >= 0:
            try:
                os.close(self.fd)
            except OSError:
                pass
            self.fd = -1
        self.hdr = self.data = None


def _writer_main(shm_fd, shm_size, capacity, ncols, path, columns, rotate_bytes, fmt, parent_pid, poll,
                 heads_fd, tails_fd, sinks):
    """The writer process: drain the ring into the log's files (:class:`_Drain`) and the
    ``sinks`` (specs, :mod:`sea_daemon.runtime.sinks`) until the loop is done; any failure of
    the log leaves its errno (or :data:`_UNKNOWN`) in the shared header."""
    _leave_realtime()
    os.set_blocking(heads_fd, False)
    os.set_blocking(tails_fd, False)
    shm = SharedBlock.attach(shm_fd, shm_size)
    hdr = np.ndarray((_NHDR,), dtype=np.int64, buffer=shm.buf)
    data = drain = None
    try:
        data = np.ndarray((capacity, ncols), dtype=np.float64, buffer=shm.buf, offset=_NHDR * 8)
        float(data.sum())        # map every page of the ring now (steady memory from the start)
        drain = _Drain(hdr, data, Path(path), csv_header(columns), rotate_bytes, fmt, heads_fd, tails_fd,
                       len(columns))
        data = None
        if sinks:
            drain.sinks = SinkSet(sinks, _board(hdr, shm))
        drain.run(parent_pid, poll)
        drain.sync()
    except BaseException:
        if hdr[_ERRNO] == 0:
            hdr[_ERRNO] = _UNKNOWN
        raise
    finally:
        if drain is not None:
            if drain.sinks is not None:
                drain.sinks.close()
            drain.close()
        for f in (heads_fd, tails_fd):
            try:
                os.close(f)
            except OSError:
                pass
        del hdr, data, drain     # the views of the shared block go before it closes
        shm.close()


def _board(hdr: np.ndarray, shm) -> SinkBoard:
    return SinkBoard(hdr[_BOARD:_MSG], shm.buf[_MSG * 8:_NHDR * 8])


class _PassFd:
    """A descriptor handed to the spawned writer process (passed to it as it starts)."""

    def __init__(self, fd: int):
        self.fd = fd

    def __reduce__(self):
        return _detach, (reduction.DupFd(self.fd),)


def _detach(dup) -> int:
    return dup.detach()


_LIVE: "weakref.WeakSet[LogWriter]" = weakref.WeakSet()


def _after_fork_in_child() -> None:
    # a process forked from the loop's (the bound worker) must not hold the loop's ends of the
    # pipes: the writer takes the end of the head pipe closing as the loop's process being gone
    for w in list(_LIVE):
        w.close_loop_ends()


def _at_exit() -> None:
    # a process that exits without close(): its writers drain every row and stop (multiprocessing
    # waits for them after this, its own exit handler having been registered before this one)
    for w in list(_LIVE):
        w.end_heads()


os.register_at_fork(after_in_child=_after_fork_in_child)
atexit.register(_at_exit)


class LogWriter:
    """Bounded, non-blocking, loss-counting CSV log writer (see module docstring).

    ``flush_interval``: the longest a row waits in the ring before the writer writes it
    (the writer polls the ring at least this often; its writes go straight to the file).
    ``sink_columns``: values of a row after the CSV's ``columns``, not written to the CSV (the
    loop's row: :class:`~sea_daemon.core.log.DaemonLogLayout`); ``sinks``: the specs of the
    other outputs the writer feeds with every row (:mod:`sea_daemon.runtime.sinks`;
    :meth:`wait_sinks`, ``sinks`` in :meth:`close`'s counts).
    """

    def __init__(self, path: str | Path, columns: list[str], capacity: int = 1 << 16,
                 flush_interval: float = 0.5, rotate_bytes: int = 256 << 20, fmt: str = "%.10g",
                 sink_columns=(), sinks=()):
        if flush_interval > 1.0:
            raise ValueError(f"flush_interval {flush_interval} s: must be <= 1 s (logs are flushed at least once a second)")
        self.path = Path(path)
        self.columns = list(columns)
        self.capacity = int(capacity)
        self.ncols = len(self.columns) + len(sink_columns)     # values a row appended has
        self.sinks = tuple(sinks)
        if len(self.sinks) > MAX_SINKS:
            raise ValueError(f"{len(self.sinks)} sinks: at most {MAX_SINKS}")
        self._closed = True                      # until the writer runs
        # the first file and its header now: a log that cannot be written stops the start-up
        try:
            os.close(_open_segment(self.path, csv_header(self.columns)))
        except OSError as e:
            raise InputError(f"log {shown(self.path)}: cannot write: {e.strerror or e}") from None
        self._shm = SharedBlock.create(_NHDR * 8 + self.capacity * self.ncols * 8, "sea-daemon-log")
        self._hdr = np.ndarray((_NHDR,), dtype=np.int64, buffer=self._shm.buf)
        self._hdr[:] = 0
        self._hdr[_FILES] = 1
        self._data = np.ndarray((self.capacity, self.ncols), dtype=np.float64, buffer=self._shm.buf, offset=_NHDR * 8)
        self._data[:] = 0.0      # pre-fault the ring: the loop never takes a page fault on it
        self.dropped = 0
        self.appended = 0
        self._tail = 0                           # rows the writer has copied out, as its pipe said
        self._read_at = _TAIL_EVERY              # the append that reads the writer's pipe next
        self._published = 0                      # the newest head written to the writer's pipe
        # heads go to the pipe every this many rows or seconds (module docstring)
        self._pub_rows = max(1, min(_PUBLISH_ROWS, self.capacity // 4))
        self._pub_s = min(_PUBLISH_S, flush_interval / 4)
        self._pub_due = 0.0                      # monotonic time from which the next head is due
        self._fault: str | None = None
        self._next_alive = 0.0
        # heads (loop → writer) and tails (writer → loop): the loop's ends never block
        self._heads_r, self._heads_w = os.pipe()
        self._tails_r, self._tails_w = os.pipe()
        for f in (self._heads_r, self._heads_w, self._tails_r, self._tails_w):
            os.set_blocking(f, False)
        self._hbuf = bytearray(8)
        self._tails = CountReader(self._tails_r)
        ctx = mp.get_context("spawn")
        self._proc = ctx.Process(target=_writer_main, name="sea-daemon-logwriter", daemon=False,
                                 args=(_PassFd(self._shm.fd), self._shm.size, self.capacity, self.ncols,
                                       str(self.path), self.columns,
                                       rotate_bytes, fmt, os.getpid(), min(0.02, flush_interval / 4),
                                       _PassFd(self._heads_r), _PassFd(self._tails_w), self.sinks))
        try:
            self._proc.start()
        finally:
            self._close_fds("_heads_r", "_tails_w")      # the writer's ends
        self._board = _board(self._hdr, self._shm)
        _LIVE.add(self)
        self._closed = False

    def wait_sinks(self, timeout: float) -> list[int]:
        """Wait until the writer has opened every sink (an LSL sink with ``wait_s``: and waited
        for a consumer) or ``timeout`` s passed; the sinks' states (:func:`~sea_daemon.runtime.sinks.wait_open`).
        InputError naming what failed when a sink could not open or the writer is gone."""
        try:
            return wait_open(self._board, len(self.sinks), self._proc, timeout)
        except InputError as e:
            raise InputError(f"log {shown(self.path)}: {e}") from None

    def _close_fds(self, *names: str) -> None:
        close_fds(self, names or ("_heads_w", "_tails_r"))

    def close_loop_ends(self) -> None:
        """Close this process's ends of the pipes, as a process forked from the loop's must (the
        writer takes the end of the heads pipe closing as the loop's process being gone)."""
        self._close_fds()

    def end_heads(self) -> None:
        """Close the heads pipe: the writer drains every row up to the last head and stops
        (what :meth:`close` does first; at the exit of a process that did not close)."""
        self._close_fds("_heads_w")

    @property
    def writer_pid(self) -> int | None:
        """The writer process's pid (read-only: for a benchmark that measures or limits it)."""
        return self._proc.pid

    def append(self, row: np.ndarray) -> bool:
        """Copy one row into the ring (real-time safe: a copy, two integer stores, and every
        so many rows one non-blocking write of 8 bytes).  False when the ring is full (counted)."""
        h = self.appended
        if h >= self._read_at or h - self._tail >= self.capacity:
            # the writer's newest tail: every _TAIL_EVERY rows, and when the ring looks full
            self._read_at = h + _TAIL_EVERY
            try:
                self._tail = self._tails.newest(self._tail)
            except OSError:
                pass
            if h - self._tail >= self.capacity:
                self.dropped += 1
                if h > self._published:
                    self._publish(h)     # what the writer may take to free the ring
                return False
        self._data[h % self.capacity] = row
        h += 1
        self.appended = h
        self._hdr[_HEAD] = h             # read by the writer only once the loop's end is closed
        if h - self._published >= self._pub_rows or time.monotonic() >= self._pub_due:
            self._publish(h)
        return True

    def _publish(self, h: int) -> None:
        """The head through the pipe, after its rows: the writer copies rows up to a head it
        read.  A pipe full (the writer not reading: 8192 heads unread) or closed (the writer
        gone: fault() reports it) leaves the head for a later call."""
        try:
            if not write_count(self._heads_w, self._hbuf, h):
                return
        except OSError:
            return
        self._published = h
        self._pub_due = time.monotonic() + self._pub_s

    def fault(self) -> str | None:
        """None while every row offered can still reach the file; else one line saying what
        failed (the same string on every later call).  Real-time safe: an integer read, the head
        written to the pipe when it is due, and every 0.2 s whether the writer process still
        runs."""
        if self._fault is not None:
            return self._fault
        if self._closed:
            return self._final["error"]
        if self.appended > self._published and time.monotonic() >= self._pub_due:
            self._publish(self.appended)     # the rows of a loop that appends no more reach the file
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
            _LIVE.discard(self)
            self.end_heads()                     # the writer drains up to the last head, then stops
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
                           "files": [str(f) for f in files], "sinks": self._board.report(self.sinks)}
            self._closed = True
            self._close_fds("_tails_r")
            self._board.release()
            del self._hdr, self._data, self._board
            self._shm.close()
        return self._final

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
