"""Memory on the real-time path: buffers resident before the loop writes them, the loop's per-cycle
records without page faults, and when the service locks its memory (docs/daemon.md, "Memory")."""
from __future__ import annotations

import ctypes
import mmap
import resource
from pathlib import Path

import numpy as np
import pytest

from sea_daemon.core.buffers import PAGE, make_resident, resident_zeros
from sea_daemon.runtime import realtime
from sea_daemon.runtime.loop import Series


def minor_faults() -> int:
    return resource.getrusage(resource.RUSAGE_THREAD).ru_minflt


def write_every_page(a: np.ndarray) -> int:
    """This thread's minor page faults while one value per page of ``a`` is written."""
    step = max(1, PAGE // a.itemsize)
    f0 = minor_faults()
    a.reshape(-1)[::step] = 1.0
    return minor_faults() - f0


def fresh_array(nbytes: int) -> np.ndarray:
    """float64 on an anonymous mapping of its own: no page mapped yet (as calloc's large blocks).
    Transparent huge pages are declined for it, so the first write of each 4 KiB page faults
    (with them one fault may map the whole 4 MiB and the control would say nothing)."""
    m = mmap.mmap(-1, nbytes)
    if hasattr(mmap, "MADV_NOHUGEPAGE"):
        m.madvise(mmap.MADV_NOHUGEPAGE)
    return np.frombuffer(m, dtype=np.float64)


def resident_share(a: np.ndarray) -> float:
    """The share of ``a``'s pages (the host's page size) mapped in memory now (mincore(2))."""
    libc = ctypes.CDLL(None, use_errno=True)
    page = mmap.PAGESIZE
    start = a.ctypes.data - a.ctypes.data % page
    length = a.ctypes.data + a.nbytes - start
    n = -(-length // page)
    vec = (ctypes.c_ubyte * n)()
    if libc.mincore(ctypes.c_void_p(start), ctypes.c_size_t(length), vec) != 0:
        raise OSError(ctypes.get_errno(), "mincore")
    return sum(v & 1 for v in vec) / n


def test_a_resident_buffer_takes_no_page_fault_where_a_fresh_one_does():
    # an earlier test in this process may have locked its memory (a run's mlockall with
    # MCL_FUTURE maps every new page at once): the control needs the kernel's default
    ctypes.CDLL(None).munlockall()
    nbytes = 4 << 20
    # the control, whatever the host's page size and huge-page policy: a fresh mapping has no
    # page in memory and its first writes fault (one fault may map many pages: at least one)
    fresh = fresh_array(nbytes)
    assert resident_share(fresh) == 0.0
    assert write_every_page(fresh) >= 1
    a = make_resident(fresh_array(nbytes))
    assert resident_share(a) == 1.0                        # every page mapped before the first write
    assert write_every_page(a) == 0
    z = resident_zeros((3, 1000))
    assert z.shape == (3, 1000) and not z.any()
    data = np.arange(3 * PAGE, dtype=np.float64)           # values are kept
    assert np.array_equal(make_resident(data.copy()), data)
    with pytest.raises(ValueError, match="C-contiguous"):
        make_resident(np.zeros((64, 64))[:, ::2])


def test_the_loops_series_records_a_run_without_page_faults():
    """LoopStats' per-cycle records (bench loop): reserved for the run, appended without a fault;
    longer than reserved, they grow and keep every value."""
    s = Series()
    s.reserve(200_000)
    f0 = minor_faults()
    for k in range(200_000):
        s.append(k * 0.5)
    series_faults = minor_faults() - f0
    lst = []                                   # the control: a list of floats grows page by page
    f0 = minor_faults()
    for k in range(200_000):
        lst.append(k * 0.5)
    list_faults = minor_faults() - f0
    # the interpreter's own allocator may map a page or two meanwhile; the list ~1 per 100 appends
    assert series_faults <= 10 and list_faults >= 100, (series_faults, list_faults)
    assert len(s) == 200_000 and np.array_equal(np.asarray(s), np.arange(200_000) * 0.5)
    small = Series(4)
    for k in range(10):
        small.append(float(k))
    assert np.array_equal(np.asarray(small, dtype=float), np.arange(10.0))
    np.array(small)[0] = 99.0                                  # np.array copies, np.asarray views
    assert np.asarray(small)[0] == 0.0


def _status(tmp_path, capeff: int):
    p = tmp_path / "status"
    p.write_text(f"Name:\tpython\nCapInh:\t0000000000000000\nCapEff:\t{capeff:016x}\n")
    return str(p)


def test_cap_ipc_lock_is_read_from_the_effective_set(tmp_path):
    assert realtime.has_cap_ipc_lock(_status(tmp_path, 1 << 14))
    assert not realtime.has_cap_ipc_lock(_status(tmp_path, 0x1FFFEFFBFFF))   # all but bit 14
    assert not realtime.has_cap_ipc_lock(str(tmp_path / "missing"))


class FakeLibc:
    def __init__(self, rc=0):
        self.calls, self.rc = [], rc

    def mlockall(self, flags):
        self.calls.append(flags)
        return self.rc


@pytest.mark.parametrize("limit,cap,locks", [("inf", False, True), (8 << 20, True, True), (8 << 20, False, False)])
def test_memory_is_locked_where_the_limit_cannot_bite(monkeypatch, limit, cap, locks):
    """mlockall(MCL_CURRENT | MCL_FUTURE) with RLIMIT_MEMLOCK unlimited or with CAP_IPC_LOCK;
    with a finite limit and no capability it is skipped (MCL_FUTURE would fail later allocations)."""
    libc = FakeLibc()
    soft = resource.RLIM_INFINITY if limit == "inf" else limit
    monkeypatch.setattr(resource, "getrlimit", lambda which: (soft, soft))
    monkeypatch.setattr(realtime, "has_cap_ipc_lock", lambda: cap)
    monkeypatch.setattr(realtime.ctypes, "CDLL", lambda *a, **k: libc)
    got = realtime.lock_memory()
    if locks:
        assert libc.calls == [realtime.MCL_CURRENT | realtime.MCL_FUTURE] and got.startswith("locked")
        assert ("CAP_IPC_LOCK" in got) == (limit != "inf")
    else:
        assert libc.calls == [] and got.startswith("skipped") and "no CAP_IPC_LOCK" in got
    monkeypatch.setattr(realtime, "has_cap_ipc_lock", lambda: True)
    monkeypatch.setattr(realtime.ctypes, "CDLL", lambda *a, **k: FakeLibc(rc=-1))
    assert realtime.lock_memory().startswith("skipped")                     # the call refused: said so


def test_try_realtime_reports_what_applied(monkeypatch):
    monkeypatch.setattr(realtime.os, "sched_setscheduler", lambda *a: (_ for _ in ()).throw(PermissionError(1, "no")))
    monkeypatch.setattr(realtime, "lock_memory", lambda: "skipped (test)")
    monkeypatch.setattr(realtime, "no_huge_pages", lambda: "on (test)")
    out = realtime.try_realtime(80)
    assert out == {"sched": "other (SCHED_FIFO not permitted: no)", "mlockall": "skipped (test)",
                   "huge_pages": "on (test)"}


def _thp_enabled(code: str) -> str:
    """/proc/self/status ``THP_enabled`` of a fresh interpreter after ``code``."""
    import subprocess
    import sys
    out = subprocess.run([sys.executable, "-c", code + "\nprint([l.split()[1] for l in open('/proc/self/status') "
                          "if l.startswith('THP_enabled:')])"], capture_output=True, text=True, check=True,
                         cwd=str(Path(__file__).resolve().parents[1]))
    return out.stdout.strip()


@pytest.mark.skipif("THP_enabled:\t1" not in Path("/proc/self/status").read_text(),
                    reason="the kernel does not report THP_enabled, or this process has them off already")
def test_a_locked_process_has_no_transparent_huge_pages():
    # khugepaged collapsing a process's pages holds a CPU ~5 ms without preemption (PREEMPT_NONE):
    # the real-time processes (the loop's, the device model's, the bound worker's, each through
    # lock_memory) turn transparent huge pages off for themselves, whether the lock applies or not
    # the flag is inherited (another test of this run may have set it here): each interpreter
    # clears it first
    on = ("import ctypes, ctypes.util; "
          "ctypes.CDLL(ctypes.util.find_library('c') or 'libc.so.6').prctl(41, 0, 0, 0, 0)\n")
    assert _thp_enabled(on) == "['1']"
    assert _thp_enabled(on + "from sea_daemon.runtime.realtime import lock_memory; lock_memory()") == "['0']"


def test_huge_page_state_reads_the_mode_and_the_collapses(tmp_path):
    # bench loop prints the machine's mode and the collapses during its run (any process's)
    (tmp_path / "khugepaged").mkdir()
    (tmp_path / "enabled").write_text("always [madvise] never\n")
    (tmp_path / "khugepaged" / "pages_collapsed").write_text("3142\n")
    assert realtime.huge_page_state(str(tmp_path)) == {"mode": "madvise", "collapsed": 3142}
    assert realtime.huge_page_state(str(tmp_path / "missing")) is None
