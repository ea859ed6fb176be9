"""The Theorem-1 bound in a worker process (runtime/bound_worker.py): the same ρ_k per sample as
in the loop, the log's bound_cycle, a killed worker (BOUND_LOST, the loop goes on), no orphan."""
from __future__ import annotations

import os
import signal
import struct
import subprocess
import sys
import time
import types
from dataclasses import replace

import numpy as np
import pytest

from sea_daemon.errors import Fault
from sea_daemon.io.configfile import default_config_path, load_config
from _paths import repo_root
from sea_daemon.core.estimators.record import RESET, StepRecord
from sea_daemon.runtime import bound_slots as bs
from sea_daemon.runtime import bound_worker as bw
from sea_daemon.runtime.bound_worker import BoundWorker
from sea_daemon.runtime.counts import CountReader
from sea_daemon.core.log import log_columns
from sea_daemon.runtime.loop import FixedRateLoop
from test_loop import ListLog

COLS = log_columns(1)
T = np.arange(0, 800) * 0.01
Q, TH, U = 0.3 * np.sin(2 * T), 0.29 * np.sin(2 * T), np.cos(3 * T)
TRAIN = 200


@pytest.fixture(scope="module")
def cfg():
    c = load_config(default_config_path())
    # θ_m's R a tenth of the paper's (std 0.07 rad, not 0.2: the set of means stays off the angle
    # caps) and the bound's usefulness limit raised (these synthetic signals' ρ_k ≈ 14 N m): the
    # estimates are valid, and the worker's rows are compared with the loop's
    R = np.array(c.estimator.R, dtype=float)
    R[0, 0] *= 0.1
    return replace(c, learning=replace(c.learning, max_points=40),
                   estimator=replace(c.estimator, R=R, bound_limit=1e3))


def _estimator(cfg):
    """A GP-AKF with a small GP learned on the first samples, learning frozen, the Theorem-1 bound."""
    from sea_daemon.core.bounds.akf_bound import theorem_bound
    from sea_daemon.core.estimators.gpakf import GPAKF
    est = GPAKF(cfg)
    est.reset([0.0], [0.0], [0.0])
    for k in range(1, TRAIN):
        est.update([Q[k]], [TH[k]], [U[k]])
    est.learning = False
    est.bound = theorem_bound(est)
    est.reset()
    return est


class _HW:
    actuation_delay = 0

    def __init__(self, pause=0.0, caught_up=None):
        self.k, self.pause, self.caught_up = TRAIN, pause, caught_up

    def read(self):
        if self.pause:
            time.sleep(self.pause)
        if self.caught_up is not None:
            # the worker has finished every sample the loop gave it (however slowly a loaded host
            # runs it; a generous deadline): each cycle's newest bound is at most a cycle old
            end = time.monotonic() + 60
            while not self.caught_up() and time.monotonic() < end:
                time.sleep(0.0005)
        k = self.k
        self.k += 1
        return types.SimpleNamespace(t=k * 0.01, q=Q[k:k + 1].copy(), theta_m=TH[k:k + 1].copy())

    def write(self, tau):
        pass

    def actuated(self, cmd):
        return U[self.k - 1:self.k].copy()

    def safe_stop(self):
        pass


class _Zero:
    def update(self, t, q, theta_m, est):
        return np.zeros(1)


def _run(cfg, cycles, worker=False, pause=0.0, kill_at=None, **kw):
    est = _estimator(cfg)
    log = ListLog()
    link = BoundWorker(est, capacity=1024, **kw).start() if worker else None
    hw = _HW(pause, (lambda: not link._proc.is_alive() or link._hdr[bs.H_DONE] >= link._head) if worker else None)
    if kill_at is not None:
        read = hw.read

        def read_and_kill():
            if hw.k - TRAIN == kill_at:
                os.kill(link.pid, signal.SIGKILL)
                link._proc.join(60)                  # dead, however long a loaded host takes to end it
                time.sleep(0.25)                     # the loop looks whether the worker lives every 0.2 s
            return read()
        hw.read = read_and_kill
    loop = FixedRateLoop(hw, est, _Zero(), n=1, period=0.01, log=log, realtime=False, bound_link=link)
    loop.run(cycles)
    stats = link.close() if link is not None else None
    return np.array(log.rows), loop, stats, link


@pytest.mark.parametrize("counts", ["pipe", "memory"])
def test_worker_bound_equals_the_in_loop_bound_sample_by_sample(cfg, counts):
    if counts == "memory" and bw.counts_path() != "memory":
        pytest.skip("counts through shared memory only on a CPU with total store order (x86-64)")
    a, _, _, _ = _run(cfg, 400)
    # a lock-step loop outruns the worker: a large max age, so that every finished bound is published
    b, _, st, _ = _run(cfg, 400, worker=True, pause=0.002, max_age=10 ** 6, counts=counts)
    iv, ic, ib, ih = (COLS.index(c) for c in ("valid", "bound_cycle", "tau_h_act_bound", "tau_h_act_hat"))
    assert st["where"] == "worker" and st["counts"] == counts and not st["broken"] and st["fault"] is None
    # the filter is the loop's in both: the same estimates
    both = (a[:, iv] > 0) & (b[:, iv] > 0)
    assert both.sum() > 300 and np.array_equal(a[both, ih], b[both, ih])
    # in-loop: each row's bound is its own sample's
    assert np.array_equal(a[a[:, iv] > 0, ic], a[a[:, iv] > 0, COLS.index("cycle")])
    assert np.all(a[a[:, iv] == 0, ic] == -1)
    # worker: the row says which sample its bound belongs to; aligned on it, the same ρ_k to the bit
    sel = b[:, iv] > 0
    k_b = b[sel, ic].astype(int)
    assert np.all(k_b <= b[sel, COLS.index("cycle")]) and np.unique(k_b).size > 300
    assert np.array_equal(b[sel, ib], a[k_b, ib])
    # and the start-up gate, run where ρ_k is computed, says what the loop's own says of each sample
    assert np.all(a[k_b, iv] == 1) and k_b.min() >= int(np.argmax(a[:, iv] > 0))


def test_with_heads_polled_the_loop_wakes_no_worker_and_every_bound_is_the_in_loop_one(cfg):
    # real-time pace on a CPU with total store order: the worker polls the heads in shared memory
    # in phase with the loop (its period), and the loop's cycle writes nothing to the worker's pipe
    if bw.counts_path() != "memory":
        pytest.skip("heads polled in shared memory only on a CPU with total store order (x86-64)")
    sent = []
    real_send = BoundWorker._send

    def send(self, head):
        sent.append(head)
        return real_send(self, head)
    a, _, _, _ = _run(cfg, 300)
    BoundWorker._send = send
    try:
        b, _, st, link = _run(cfg, 300, worker=True, pause=0.002, max_age=10 ** 6, period=0.002)
    finally:
        BoundWorker._send = real_send
    assert link.heads_via == "memory" and st["heads"] == "memory" and st["samples_done"] == st["steps"] + 1
    assert sent == [bs.STOP]                            # the stop only: no head through the pipe
    iv, ic, ib = (COLS.index(c) for c in ("valid", "bound_cycle", "tau_h_act_bound"))
    sel = b[:, iv] > 0
    k_b = b[sel, ic].astype(int)
    assert np.unique(k_b).size > 200 and np.array_equal(b[sel, ib], a[k_b, ib])
    # a loop without a fixed pace (no period) keeps the heads in the pipe
    assert BoundWorker(_estimator(cfg)).heads_via == "pipe"


def test_a_killed_worker_latches_BOUND_LOST_and_the_loop_goes_on(cfg):
    rows, loop, st, link = _run(cfg, 200, worker=True, pause=0.002, kill_at=120, max_age=50)
    sup = loop.supervisor
    assert len(rows) == 200 and loop.stats.cycles == 200          # the loop ran every cycle
    assert sup.latched == Fault.BOUND_LOST and "exited" in sup.latched_detail
    iv = COLS.index("valid")
    assert rows[100, iv] == 1 and not rows[125:, iv].any()         # no estimate published without its bound
    assert np.all(rows[125:, COLS.index("bound_cycle")] == -1)
    assert st["fault"] is not None


def test_stale_bound_is_not_published(cfg):
    # max age 0: the newest finished bound is always at least the previous cycle's → never published
    rows, loop, st, _ = _run(cfg, 120, worker=True, max_age=0)
    assert not rows[:, COLS.index("valid")].any() and st["stale"] == st["steps"] > 0
    assert loop.supervisor.ok


def test_the_daemon_log_has_the_bound_cycle_column(tmp_path, cfg):
    from sea_daemon.io.logcsv import read_log
    from sea_daemon.runtime.logwriter import LogWriter
    est = _estimator(cfg)
    log = LogWriter(tmp_path / "run.csv", COLS)
    link = BoundWorker(est, max_age=10 ** 6).start()
    try:
        # each cycle waits until the worker has caught up (a loaded host may take seconds to start it)
        hw = _HW(0.002, lambda: not link._proc.is_alive() or link._hdr[bs.H_DONE] >= link._head)
        FixedRateLoop(hw, est, _Zero(), n=1, period=0.01, log=log, realtime=False, bound_link=link).run(150)
    finally:
        link.close()
        log.close()
    got = read_log(tmp_path / "run.csv", n=1)
    bc, cyc, valid = got.extra["bound_cycle"], got.extra["cycle"], got.extra["valid"]
    assert valid.any() and np.all((bc[valid > 0] >= 0) & (bc[valid > 0] <= cyc[valid > 0]))
    assert np.all(bc[valid == 0] == -1)


_ORPHAN = """
import os, sys, numpy as np
sys.path.insert(0, {root!r}); sys.path.insert(0, {tests!r})
from test_bound_worker import _estimator, load_config, default_config_path, replace
from sea_daemon.core.estimators.record import RESET, StepRecord
from sea_daemon.runtime import bound_slots as bs
from sea_daemon.runtime import bound_worker as bw
from sea_daemon.runtime.bound_worker import BoundWorker
c = load_config(default_config_path()); c = replace(c, learning=replace(c.learning, max_points=40))
w = BoundWorker(_estimator(c)).start()
print(w.pid, flush=True)
os._exit(0)          # the parent dies without stopping its worker
"""


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(") ")[-1][0] != "Z"
    except FileNotFoundError:
        return False


def test_no_worker_outlives_its_parent_or_the_session(cfg):
    root = str(repo_root())
    out = subprocess.run([sys.executable, "-c", _ORPHAN.format(root=root, tests=str(repo_root() / "tests"))],
                         capture_output=True, text=True, timeout=300, env=dict(os.environ, PYTHONPATH=root))
    pid = int(out.stdout.split()[0])
    end = time.monotonic() + 5
    while _alive(pid) and time.monotonic() < end:
        time.sleep(0.05)
    assert not _alive(pid)
    # closed by its owner: gone, and the AKF computes its own bound again
    est = _estimator(cfg)
    bound = est.bound
    w = BoundWorker(est).start()
    assert est.consumer is w and est.bound is bound and _alive(w.pid)
    w.close()
    assert not _alive(w.pid) and est.consumer is None and est.bound is bound


# ---------------------------------------------------------------- the pipes' framing and order

def _i64(v: int) -> bytes:
    return struct.pack("=q", v)


def test_a_count_split_across_two_reads_is_completed_by_the_second():
    r, w = os.pipe()
    os.set_blocking(r, False)
    try:
        rd = CountReader(r, values=4)
        with pytest.raises(BlockingIOError):
            rd.read()                                        # nothing written yet
        os.write(w, _i64(1234)[:3])
        assert rd.read() == 0                                # 3 bytes: no count yet
        os.write(w, _i64(1234)[3:] + _i64(-1) + _i64(987654321)[:2])
        assert rd.read() == 2 and (rd.value(0), rd.value(1)) == (1234, -1)
        os.write(w, _i64(987654321)[2:] + _i64(5))
        assert rd.read() == 2 and (rd.value(0), rd.value(1)) == (987654321, 5)
        # more than the buffer holds (4 counts): the rest at the next read, nothing lost
        os.write(w, b"".join(_i64(v) for v in range(10, 16)))
        assert rd.read() == 4 and [rd.value(i) for i in range(4)] == [10, 11, 12, 13]
        assert rd.read() == 2 and [rd.value(i) for i in range(2)] == [14, 15]
        os.close(w)
        w = -1
        assert rd.read() == 0 and rd.eof
    finally:
        os.close(r)
        if w >= 0:
            os.close(w)


def _hand(link: BoundWorker, est, cycle: int) -> None:
    """The loop's estimator step with a bound worker: the sample of ``cycle`` handed over, the
    newest result collected into ``est``."""
    rec = StepRecord.zeros(link.akf.n)
    rec.dt = 0.01
    link.cycle = cycle
    link.take(est, rec)


def _result(link: BoundWorker, i: int, cycle: int, rho: float, status=bs.OK, epoch: int = 0) -> None:
    """Sample i's result in shared memory, as the worker writes it."""
    r = link._res[i % link.capacity]
    r[bs.R_SEQ], r[bs.R_CYC], r[bs.R_K], r[bs.R_VALID] = i, cycle, i, 1.0
    r[bs.R_STATUS], r[bs.R_EPOCH] = status, epoch
    r[bs.N_RES:] = rho
    link._hdr[bs.H_DONE] = i + 1


def test_the_loop_takes_a_result_only_once_its_count_came_through_the_pipe(cfg):
    # the test plays the worker (not started): results and counts written by hand
    link = BoundWorker(_estimator(cfg), max_age=10, counts="pipe")
    try:
        e = types.SimpleNamespace(tau_h_act_bound=np.zeros(1), k=0)
        _hand(link, e, 7)                                    # sample 0
        _result(link, 0, 7, 1.25)                            # complete in shared memory, no count sent
        link.cycle = 8
        link._collect(e)
        assert link.bound_cycle == -1 and not link.valid and e.tau_h_act_bound[0] == 0.0
        os.write(link._counts_w, _i64(1)[:5])                # the count, split across two writes
        link._collect(e)
        assert link.bound_cycle == -1 and not link.valid and e.tau_h_act_bound[0] == 0.0
        os.write(link._counts_w, _i64(1)[5:])
        link._collect(e)
        assert link.bound_cycle == 7 and link.valid and e.tau_h_act_bound[0] == 1.25
        assert link.stale == 3 and link.steps == 4
    finally:
        link.close()


def test_with_counts_in_shared_memory_the_loop_takes_a_result_once_the_count_is_stored(cfg):
    # x86-64 (total store order): the worker's count of samples done is the header's, no pipe
    assert bw.counts_path("x86_64") == "memory" and bw.counts_path("aarch64") == "pipe"
    assert bw.counts_path("armv7l") == "pipe" and bw.counts_path("riscv64") == "pipe"
    with pytest.raises(ValueError, match="auto, pipe or memory"):
        BoundWorker(_estimator(cfg), counts="fence")
    link = BoundWorker(_estimator(cfg), max_age=10, counts="memory")   # not started: the test is the worker
    try:
        e = types.SimpleNamespace(tau_h_act_bound=np.zeros(1), k=0)
        _hand(link, e, 7)                                    # sample 0
        _result(link, 0, 7, 1.25)                            # complete, its count not stored yet
        link._hdr[bs.H_DONE] = 0
        link.cycle = 8
        link._collect(e)
        assert link.bound_cycle == -1 and not link.valid and e.tau_h_act_bound[0] == 0.0
        link._hdr[bs.H_DONE] = 1                              # the worker's store after the result, no pipe
        link._collect(e)
        assert link.bound_cycle == 7 and link.valid and e.tau_h_act_bound[0] == 1.25
        assert link.stats()["counts"] == "memory"
    finally:
        link.close()


def test_a_full_ring_breaks_the_bound_until_the_reset_and_the_old_chain_is_never_published(cfg):
    link = BoundWorker(_estimator(cfg), max_age=10, capacity=4, counts="pipe")   # not started: the test is the worker
    try:
        e = types.SimpleNamespace(tau_h_act_bound=np.zeros(1), k=0)
        for c in range(4):
            _hand(link, e, c)                                # samples 0..3: the ring's 4 slots
        assert not link.broken
        _hand(link, e, 4)                                    # no count came back: no free slot
        assert link.broken and "full" in link.fault() and link._head == 4
        for i in range(3):
            _result(link, i, i, 1.0 + i)
        os.write(link._counts_w, _i64(1) + _i64(2) + _i64(3))
        link.cycle = 5
        link._collect(e)
        assert link._done == 3 and link.bound_cycle == -1   # broken: nothing published
        rec = StepRecord.zeros(1)
        rec.kind = RESET
        link.take(e, rec)                                    # a new chain: sample 4 its reset
        assert not link.broken and link._head == 5
        _result(link, 3, 3, 4.0)                             # the old chain's last sample, after the reset
        os.write(link._counts_w, _i64(4))
        _hand(link, e, 6)                                    # sample 5
        assert link._done == 4 and link.bound_cycle == -1 and e.tau_h_act_bound[0] == 0.0
        _result(link, 4, 5, 0.0, status=bs.NO_BOUND, epoch=1)
        _result(link, 5, 6, 2.5, epoch=1)
        os.write(link._counts_w, _i64(5) + _i64(6))
        link.cycle = 7
        link._collect(e)
        assert link.bound_cycle == 6 and link.valid and e.tau_h_act_bound[0] == 2.5
    finally:
        link.close()


def test_the_worker_computes_a_sample_only_once_its_head_came_whole_through_the_pipe(cfg):
    est = _estimator(cfg)
    link = BoundWorker(est, max_age=10 ** 6).start()
    e = types.SimpleNamespace(tau_h_act_bound=np.zeros(1))

    def done_after(seconds: float, until: int | None = None) -> int:
        """The count of samples done the loop has read after ``seconds`` (or once it is ``until``)."""
        end = time.monotonic() + seconds
        while time.monotonic() < end and link._done != until:
            link.cycle += 1
            link._collect(e)
            time.sleep(0.01)
        return link._done

    def updates(k0: int, k1: int) -> None:
        for k in range(k0, k1):
            link.cycle = k
            est.update([Q[k]], [TH[k]], [U[k]])

    try:
        updates(TRAIN, TRAIN + 40)                           # the filter's start: samples in the ring
        h = link._head
        assert h >= 3
        assert done_after(0.5) == 0                          # written, not published
        os.write(link._heads_w, _i64(h - 2)[:3])
        assert done_after(0.5) == 0                          # part of a head: nothing computed
        os.write(link._heads_w, _i64(h - 2)[3:] + _i64(h)[:6])
        assert done_after(20.0, until=h - 2) == h - 2        # the whole head, not the partial one after it
        assert done_after(0.5) == h - 2
        os.write(link._heads_w, _i64(h)[6:])
        assert done_after(20.0, until=h) == h
        assert link.bound_cycle >= 0 and link.stats()["samples_done"] == h
        st = link.close(timeout=10.0)                        # the stop through the same pipe
        assert st["fault"] is None and link._proc.exitcode == 0
    finally:
        link.close()


def test_a_full_count_pipe_blocks_neither_side_and_the_newest_count_comes_later(cfg):
    import fcntl
    est = _estimator(cfg)
    link = BoundWorker(est, max_age=10 ** 6, counts="pipe")
    fcntl.fcntl(link._counts_w, fcntl.F_SETPIPE_SZ, 4096)   # room for 512 counts
    link.start()
    e = types.SimpleNamespace(tau_h_act_bound=np.zeros(1))

    def batch() -> int:
        """The loop hands 560 samples over without reading the worker's counts; the worker's own
        count once it has computed them all."""
        for k in range(TRAIN, TRAIN + 560):
            link.cycle = k
            est.update([Q[k]], [TH[k]], [U[k]])
            if k == TRAIN:
                link._collect = lambda est: None             # the loop stops reading
        link.flush()
        end = time.monotonic() + 60
        while link._hdr[bs.H_DONE] < link._head and time.monotonic() < end:
            time.sleep(0.01)
        del link._collect
        return int(link._hdr[bs.H_DONE])

    try:
        h = batch()
        assert h == link._head > 512 and link._proc.is_alive()
        time.sleep(0.2)
        link._collect(e)                                     # 512 counts: the pipe's room
        assert link._done == 512
        end = time.monotonic() + 10                          # then the newest one, written later
        while link._done < h and time.monotonic() < end:
            time.sleep(0.01)
            link._collect(e)
        assert link._done == h
        est.reset()
        h = batch()                                          # full again, and the loop stops the worker
        assert h == link._head and link._done < h
        t0 = time.monotonic()
        st = link.close(timeout=10.0)
        assert link._proc.exitcode == 0 and time.monotonic() - t0 < 5 and st["samples_done"] == h
    finally:
        link.close()
