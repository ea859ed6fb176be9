"""The log writer's ring is ordered by counts through pipes, never by counts in shared memory
(runtime/logwriter.py, Memory order): what the writer writes, and when the loop reuses a slot."""
from __future__ import annotations

import fcntl
import os
import struct
import termios
import time

import numpy as np

from sea_daemon.runtime import logwriter as lw
from sea_daemon.runtime.logwriter import LogWriter

COLS = ["t", "q", "theta_m", "tau_m"]


def _row(i: int) -> np.ndarray:
    return np.array([float(i), i + 0.25, -i - 0.5, 2.0 * i])      # exact in the log's 10 digits


def _wait(cond, timeout=30.0, loop: LogWriter | None = None) -> bool:
    """Until ``cond()``; ``loop``: call its fault() meanwhile, as the loop does every cycle (it
    writes a head that is due)."""
    deadline = time.monotonic() + timeout
    while not cond():
        if time.monotonic() > deadline:
            return False
        if loop is not None:
            assert loop.fault() is None
        time.sleep(0.005)
    return True


def _store_unpublished(w: LogWriter, i: int) -> bytes:
    """Row i into its slot and the head into shared memory, as append() does, but not to the
    pipe; the head's 8 bytes are returned."""
    w._data[i % w.capacity] = _row(i)
    w.appended = i + 1
    w._hdr[lw._HEAD] = i + 1
    return struct.pack("=q", i + 1)


def _check_rows(path, n):
    """Rows 0 … n−1, each once, in order, whole (the file's text, not read_log: these are no angles)."""
    lines = path.read_text().splitlines()
    assert lines[0] == ",".join(COLS) and len(lines) == n + 1
    got = np.array([[float(v) for v in line.split(",")] for line in lines[1:]]).reshape(n, len(COLS))
    assert np.array_equal(got, np.array([_row(i) for i in range(n)]).reshape(n, len(COLS)))


def test_a_row_whose_head_is_only_in_shared_memory_is_not_written_until_the_pipe_ends(tmp_path):
    w = LogWriter(tmp_path / "x.csv", COLS, capacity=64, flush_interval=0.04)   # polls every 10 ms
    for i in range(3):
        assert w.append(_row(i))
    assert _wait(lambda: w.rows_written == 3, loop=w)
    _store_unpublished(w, 3)
    time.sleep(0.3)                                   # 30 polls
    assert w.rows_written == 3                        # the head in shared memory alone is not trusted
    fin = w.close()                                   # the end of the pipe: every store of the loop is visible
    assert fin["rows_written"] == 4 and fin["rows_lost"] == 0 and fin["error"] is None
    _check_rows(tmp_path / "x.csv", 4)


def test_a_head_split_across_two_writes_is_completed(tmp_path):
    w = LogWriter(tmp_path / "x.csv", COLS, capacity=64, flush_interval=0.04)
    for i in range(2):
        assert w.append(_row(i))
    assert _wait(lambda: w.rows_written == 2, loop=w)
    b = _store_unpublished(w, 2)
    assert os.write(w._heads_w, b[:4]) == 4
    time.sleep(0.3)
    assert w.rows_written == 2                        # half a head is no head
    assert os.write(w._heads_w, b[4:]) == 4
    assert _wait(lambda: w.rows_written == 3)         # completed by the next read
    assert w.append(_row(3))
    fin = w.close()
    assert fin["rows_written"] == 4 and fin["error"] is None
    _check_rows(tmp_path / "x.csv", 4)


def _in_pipe(fd: int) -> int:
    buf = bytearray(4)
    fcntl.ioctl(fd, termios.FIONREAD, buf)
    return int.from_bytes(buf, "little")


def test_a_full_tail_pipe_blocks_neither_side_and_the_newest_tail_comes_later(tmp_path):
    w = LogWriter(tmp_path / "x.csv", COLS, capacity=1 << 14, flush_interval=0.004)   # polls every 1 ms
    fcntl.fcntl(w._tails_r, fcntl.F_SETPIPE_SZ, 4096)          # 512 tails
    w._read_at = 1 << 62                                       # the loop does not read the tails
    i = 0
    deadline = time.monotonic() + 60
    while _in_pipe(w._tails_r) < 4096:                         # one tail per poll that found rows
        assert time.monotonic() < deadline
        assert w.append(_row(i))
        i += 1
        time.sleep(0.0005)
    for _ in range(500):                                       # the writer goes on with a full pipe
        assert w.append(_row(i))
        i += 1
    assert _wait(lambda: w.rows_written == i, loop=w)
    assert w._tail == 0                                        # nothing read yet
    assert _wait(lambda: w._tails.newest(w._tail) == i)   # the newest tail, once there is room
    fin = w.close()
    assert fin["rows_written"] == i and fin["error"] is None
    _check_rows(tmp_path / "x.csv", i)


def test_every_row_of_a_long_run_through_a_small_ring_is_written_once_in_order(tmp_path):
    w = LogWriter(tmp_path / "x.csv", COLS, capacity=64, flush_interval=0.02)
    n = 30000
    full = 0
    for i in range(n):
        row = _row(i)
        while not w.append(row):                   # the ring is full (by the tails read): wait
            full += 1
            time.sleep(0.0002)
    fin = w.close()
    assert full > 0                                # the ring did fill and wrap round
    assert fin["rows_written"] == n and fin["rows_appended"] == n
    assert fin["rows_dropped"] == full and fin["rows_lost"] == full and "is full" in fin["error"]
    _check_rows(tmp_path / "x.csv", n)


def test_a_process_forked_from_the_loop_does_not_keep_the_writer_running(tmp_path):
    w = LogWriter(tmp_path / "x.csv", COLS, capacity=64, flush_interval=0.04)
    pid = os.fork()
    if pid == 0:                                   # holds copies of the loop's ends, unless closed at fork
        time.sleep(20)
        os._exit(0)
    try:
        for i in range(10):
            assert w.append(_row(i))
        t0 = time.monotonic()
        fin = w.close(timeout=10)
        assert time.monotonic() - t0 < 5 and w._proc.exitcode == 0
        assert fin["rows_written"] == 10 and fin["error"] is None
    finally:
        os.kill(pid, 9)
        os.waitpid(pid, 0)
    _check_rows(tmp_path / "x.csv", 10)


_CHILD = """
import os, signal, sys, time
import numpy as np
sys.path.insert(0, {tests!r})
from test_logwriter_ring import COLS, _row, _store_unpublished
from sea_daemon.runtime.logwriter import LogWriter
if __name__ == "__main__":
    w = LogWriter(sys.argv[1], COLS, capacity=256, flush_interval=0.5)
    for i in range(100):
        assert w.append(_row(i))
    _store_unpublished(w, 100)           # its head in shared memory only
    print(w._proc.pid, flush=True)
    if sys.argv[2] == "kill":
        os.kill(os.getpid(), signal.SIGKILL)
    # else: the interpreter exits without close()
"""


def _child(tmp_path, how):
    import subprocess
    import sys
    from _paths import repo_root
    path = tmp_path / "x.csv"
    code = _CHILD.format(tests=str(repo_root() / "tests"))
    p = subprocess.run([sys.executable, "-c", code, str(path), how], capture_output=True, text=True, timeout=60,
                       cwd=repo_root(), env={"PYTHONPATH": str(repo_root()), "PATH": "/usr/bin:/bin"})
    writer = int(p.stdout.split()[0])
    assert _wait(lambda: not os.path.exists(f"/proc/{writer}") or "State:\tZ" in open(f"/proc/{writer}/status").read())
    return path, p


def test_the_loop_killed_its_last_rows_are_written_once_the_pipe_has_ended(tmp_path):
    path, p = _child(tmp_path, "kill")
    assert p.returncode == -9
    _check_rows(path, 101)


def test_a_loop_that_exits_without_close_has_every_row_written_and_exits(tmp_path):
    path, p = _child(tmp_path, "exit")               # without the end of the pipe at exit: no exit at all
    assert p.returncode == 0
    _check_rows(path, 101)


def test_heads_go_to_the_pipe_every_so_many_rows_or_once_due_and_every_row_arrives(tmp_path):
    """A head per 32 rows (a quarter of a smaller ring) or once its time is due, not one per row;
    a loop that stops appending has its last rows written through fault()."""
    w = LogWriter(tmp_path / "x.csv", COLS, capacity=1024, flush_interval=0.4)    # heads due after 0.05 s
    assert w._pub_rows == 32 and w._pub_s == 0.05
    for i in range(40):
        assert w.append(_row(i))
    assert w._published == 33                        # the first row's head (due at once), then 32 rows on
    assert _wait(lambda: w.rows_written == 33)
    time.sleep(0.3)
    assert w.rows_written == 33                       # rows 34-40: no head in the pipe yet, no fault() call
    assert _wait(lambda: w.rows_written == 40, loop=w)
    fin = w.close()
    assert fin["rows_written"] == 40 and fin["error"] is None
    _check_rows(tmp_path / "x.csv", 40)
