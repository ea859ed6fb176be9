"""The bound worker's process (:mod:`.bound_worker`): set-up and the loop that computes the bound.

:func:`worker_main` runs in the forked process: it takes its scheduling (SCHED_FIFO at the
priority asked, else SCHED_OTHER) and locks its memory where permitted, maps the shared memory
(:mod:`.bound_slots`) and runs a :class:`Server`: every slot up to the newest head read from the
worker's pipe (or, heads polled, from shared memory: :meth:`Server.wait`), in order — the slot's :class:`~sea_daemon.core.estimators.record.StepRecord`
copied into a record of its own, :meth:`AKF.finish_step` on the worker's copy of the filter (the
bound's step or reset, the start-up gate), the result into the result slot — each sample's count
written to the loop's pipe after its result (or, with total store order, stored in shared
memory only); then it waits.  The memory order is :mod:`.bound_worker`'s docstring.

A worker at SCHED_FIFO that falls behind never waits, and the kernel's budget for real-time
tasks (``sched_rt_runtime_us``) would then stop every real-time task on its CPU, the loop's
included, for the rest of the period.  So the worker holds its real-time priority only while
it keeps up (:class:`Priority`): when a read of the heads finds more than
:data:`YIELD_BEHIND` samples published and not yet computed it goes SCHED_OTHER, and it takes
SCHED_FIFO again once a read finds it caught up (at most one sample waiting).  An overloaded
worker then shows as the loop's stale bounds and, a whole ring behind, as BOUND_LOST; the
real-time tasks keep their CPU.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import os
import select
import signal
import time

from sea_daemon.core.estimators.record import RESET as KIND_RESET
from sea_daemon.core.estimators.record import STEP as KIND_STEP
from sea_daemon.core.estimators.record import StepRecord
from sea_daemon.core.estimators.validity import STARTUP
from sea_daemon.errors import EstimatorFault
from sea_daemon.runtime import bound_slots as bs
from sea_daemon.runtime.counts import CountReader, write_count
from sea_daemon.runtime.realtime import freeze_heap, lock_memory


def _pdeathsig() -> None:
    """Linux: SIGKILL this process when its parent thread exits (best effort)."""
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        libc.prctl(1, int(signal.SIGKILL), 0, 0, 0)          # PR_SET_PDEATHSIG
    except Exception:  # noqa: BLE001 - other kernels: the parent id check below remains
        pass


def _schedule(rt_priority: int) -> int:
    """SCHED_FIFO at ``rt_priority`` (> 0) where permitted, else SCHED_OTHER: the priority taken (0: other)."""
    try:
        if rt_priority > 0:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(rt_priority))
            return rt_priority
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    except (OSError, AttributeError):
        try:
            os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
        except (OSError, AttributeError):
            pass
    return 0


#: samples published and not yet computed past which the worker gives up SCHED_FIFO: more than
#: the age of a bound the loop publishes (``bound_max_age``, 3 cycles), far less than the ring
YIELD_BEHIND = 8


class Priority:
    """The worker's SCHED_FIFO priority ``rt_priority`` (0: SCHED_OTHER from the start, nothing
    to give up), held only while it keeps up (module docstring); the state in ``hdr``
    (:data:`~.bound_slots.H_YIELDS`, :data:`~.bound_slots.H_YIELDED`, :data:`~.bound_slots.H_SCHED`)."""

    def __init__(self, rt_priority: int, hdr, behind: int = YIELD_BEHIND):
        self.rt = int(rt_priority)
        self.hdr = hdr
        self.behind = int(behind)
        self.yielded = False

    def update(self, backlog: int) -> None:
        """After a read of the heads: ``backlog`` samples published and not yet computed."""
        if self.yielded:
            if backlog <= 1:
                taken = _schedule(self.rt)
                self.yielded = False
                self.hdr[bs.H_YIELDED] = 0
                if not taken:              # no longer permitted: SCHED_OTHER from now on
                    self.rt = 0
                    self.hdr[bs.H_SCHED] = 0
        elif self.rt and backlog > self.behind:
            _schedule(0)
            self.yielded = True
            self.hdr[bs.H_YIELDED] = 1
            self.hdr[bs.H_YIELDS] += 1


def worker_main(akf, shm, cap: int, width: int, rwidth: int, lay: dict, record: int,
                heads: int, counts: int, loop_ends: tuple, parent_pid: int, rt_priority: int,
                via_pipe: bool = True, poll_period: float | None = None) -> None:
    """The worker process: ``akf`` its copy of the loop's filter (with the bound), the shared
    memory ``shm`` (a :class:`~sea_daemon.runtime.shared_block.SharedBlock` inherited from the
    loop's process) of ``cap`` slots, the pipes' ends ``heads`` (read) and ``counts``
    (write); ``loop_ends`` the loop's ends, closed here; ``poll_period``: the loop's period when
    the worker polls the heads in shared memory (None: they come through ``heads``)."""
    _pdeathsig()
    for fd in loop_ends:                           # the loop's ends: EOF on ``heads`` once the parent is gone
        try:
            os.close(fd)
        except OSError:
            pass
    sched = _schedule(rt_priority)
    if os.getppid() != parent_pid:
        return
    # a forked process inherits no memory locks: its own, in real-time pace
    locked = rt_priority > 0 and lock_memory().startswith("locked")
    views = None
    try:
        views = bs.map_shared(shm.buf, cap, width, rwidth, record)
        views.hdr[bs.H_SCHED] = sched
        views.hdr[bs.H_LOCKED] = 1 if locked else 0
        freeze_heap()          # the inherited heap out of the collector's reach (a full sweep: tens of ms)
        Server(akf, views, record, lay, heads, counts, parent_pid, via_pipe, sched, poll_period).serve()
    finally:
        del views
        shm.close()


class Server:
    """The worker's loop over the ring (module docstring)."""

    #: heads polled: the first poll comes this fraction of a period after the newest head's
    #: period is over, and while no head came the next ones after this fraction of a period,
    #: doubled each time up to :data:`POLL_MAX` periods (a head that comes after a pause — the
    #: loop's start, a reset — waits at most that long)
    POLL_LATE = 0.05
    POLL_AGAIN = 0.125
    POLL_MAX = 1.0

    def __init__(self, akf, views: bs.Shared, record: int, lay: dict, heads: int, counts: int, parent_pid: int,
                 via_pipe: bool = True, rt_priority: int = 0, poll_period: float | None = None):
        self.akf = akf
        self.e = akf.est
        self.views = views
        self.record = record
        self.counts = counts
        self.parent_pid = parent_pid
        self.via_pipe = via_pipe
        self.cap = views.ring.shape[0]
        # the slot's record is copied into one of the worker's own (the bound's compiled call
        # keeps its arrays from step to step)
        self.rec = StepRecord.zeros(akf.n, getattr(akf, "d", None))     # d: 5n, or 6n with τ̇_h,act
        self.slot_arrays = [bs.slot_arrays(views.ring[i], lay) for i in range(self.cap)]
        self.cpu_total = 0.0
        self.reader = CountReader(heads)
        self.out = bytearray(8)
        self.head = self.done = 0
        self.stop = self.unsent = False
        self.priority = Priority(rt_priority, views.hdr)
        self.poll_period = poll_period
        self.misses = 0                  # heads polled: polls in a row that found no new head

    def serve(self) -> None:
        """Every slot published, in order, then wait for more; return when asked to stop, when
        a pipe closes or the parent is gone."""
        hdr, fhdr = self.views.hdr, self.views.fhdr
        while True:
            if self.done < self.head:
                self.compute(self.done)
                self.done += 1
                self.unsent = True
            if self.unsent:
                if self.via_pipe:
                    # the count after the result: the loop reads the result once it has read the count
                    try:
                        self.unsent = not write_count(self.counts, self.out, self.done)   # full: later
                    except OSError:              # the loop's end closed: the parent is gone
                        return
                else:
                    self.unsent = False          # total store order: the store below is the count
                hdr[bs.H_DONE] = self.done       # after the write: the loop's hint to read the pipe (memory: the count)
            if self.done < self.head:
                continue
            fhdr[bs.F_PROC] = time.process_time()
            if self.stop or self.reader.eof or not self.wait():
                return
            self.priority.update(self.head - self.done)

    def compute(self, i: int) -> None:
        """Sample i: its record from the slot, the bound's step or reset and the gate on the
        worker's filter, the result into its result slot."""
        c0 = time.thread_time()
        s = self.views.ring[i % self.cap]
        r = self.views.res[i % self.cap]
        rec, e = self.rec, self.e
        for (_, view), (_, dst) in zip(self.slot_arrays[i % self.cap], rec.arrays()):
            dst[...] = view
        rec.kind = KIND_RESET if s[bs.I_KIND] == bs.RESET else KIND_STEP
        rec.k = e.k = int(s[bs.I_K])
        rec.dt = float(s[bs.I_DT])
        rec.ready = bool(s[bs.I_READY])
        rec.gate_starts = int(s[bs.I_GATES])
        valid = 0.0
        try:
            # the same end of a step (or reset) as the loop's AKF.step / GPAKF._frozen_update would run
            ok = self.akf.finish_step(e, rec)
        except EstimatorFault:
            status = bs.FAILED
        except Exception:  # noqa: BLE001 - a reset's failure: a failed step of the loop's estimator
            if rec.kind != KIND_RESET:
                raise
            status = bs.FAILED
        else:
            status = bs.NO_BOUND if rec.kind == KIND_RESET else bs.OK
            valid = 1.0 if (ok and rec.kind != KIND_RESET) else 0.0
        r[bs.R_SEQ] = i
        r[bs.R_CYC] = s[bs.I_CYC]
        r[bs.R_K] = s[bs.I_K]
        r[bs.R_VALID] = valid
        r[bs.R_REASON] = 0.0 if valid else (e.invalid_reason or STARTUP)
        r[bs.R_STATUS] = status
        r[bs.R_EPOCH] = s[bs.I_EPOCH]
        r[bs.N_RES:bs.N_RES + self.akf.n] = e.tau_h_act_bound
        spent = time.thread_time() - c0
        r[bs.R_CPU] = spent
        if self.record and i < self.record:
            self.views.cpu[i] = spent
        self.cpu_total += spent
        self.views.fhdr[bs.F_STEPS] = self.cpu_total

    def _poll_timeout(self) -> float:
        """Heads polled: how long to wait before looking at the head again — until a little after
        one period since the newest head was published (when the loop publishes the next one), or,
        that time past, a fraction of a period, doubled while no head comes."""
        p = self.poll_period
        due = self.views.fhdr.item(bs.F_FLUSH) + p * (1.0 + self.POLL_LATE) - time.monotonic()
        if due > 0.0 and self.misses == 0:
            return min(due, p * self.POLL_MAX)
        self.misses += 1
        return p * min(self.POLL_AGAIN * 2.0 ** min(self.misses - 1, 16), self.POLL_MAX)

    def wait(self) -> bool:
        """Wait up to a second for heads (or room for an unsent count); heads polled, wait on the
        pipe (which then carries only the stop) for :meth:`_poll_timeout` and look at the head in
        shared memory.  False when the worker should exit (the pipe unreadable, the parent gone)."""
        polled = self.poll_period is not None
        if polled:
            h = self.views.hdr.item(bs.H_HEAD)
            if h > self.head:                 # came while the last samples were computed
                self.head, self.misses = h, 0
                return True
        ready, _, _ = select.select([self.reader.fd], [self.counts] if self.unsent else [], [],
                                    self._poll_timeout() if polled else 1.0)
        if polled:
            # total store order: the slots' stores are visible before the head's (after the pipe:
            # the head stored before a stop written there is seen with it)
            h = self.views.hdr.item(bs.H_HEAD)
            if h > self.head:
                self.head, self.misses = h, 0
        if ready:
            try:
                got = self.reader.read()
            except OSError:
                return False
            for j in range(got):
                h = self.reader.value(j)
                if h == bs.STOP:
                    self.stop = True
                elif h > self.head:
                    self.head = h
        return os.getppid() == self.parent_pid
