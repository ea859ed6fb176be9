"""The Theorem-1 bound in a worker process: the loop's estimator step runs the filter only.

:class:`BoundWorker` is a :class:`~sea_daemon.core.estimators.record.BoundConsumer` attached to
the loop's AKF (:meth:`~sea_daemon.core.estimators.akf.AKF.attach`): the AKF hands it every
reset's and step's :class:`~sea_daemon.core.estimators.record.StepRecord` instead of running its
bound component (:class:`~sea_daemon.core.estimators.base.Bound`, e.g.
:class:`~sea_daemon.core.bounds.akf_bound.AKFTheoremBound`), and takes ρ and the validity from
it.  A forked process (:mod:`.bound_serve`) holds a copy of the AKF with its bound and computes,
sample by sample and in order (the set of means needs every sample), exactly what the loop's own
step would have computed: :meth:`~sea_daemon.core.estimators.akf.AKF.finish_step` on the
record — the bound's step, then the start-up gate.  Same objects, same compiled kernels, same
inputs: the same ρ_k to the bit.

Per cycle, on the loop's side (no pickling, no lock, never blocking, nothing allocated but
integers):

* :meth:`BoundWorker.take` copies the step's record — x̂_{k−1}, P_{k−1}, u, dt, ẑ_{k−1}, A_k,
  F_k, Γ_μ, K_k, P_k, μ, ∂μ/∂z, the box of the start-up gate — and the loop's cycle into the next
  slot of a ring in shared memory (:mod:`.bound_slots`);
* :meth:`BoundWorker.flush`, called by the loop at the end of the cycle (after its log row),
  publishes the slots written: it writes the number of samples handed over (the head, an int64)
  to the worker's pipe, which also wakes the worker: the worker computes while the loop sleeps,
  not beside the loop's own work.  In real-time pace on a CPU with total store order (``period``
  given, counts through shared memory) the head is a store into shared memory instead, with the
  loop's clock at that moment, and the worker polls it on its own timer in phase with the loop
  (it wakes one period after the newest head was published, a little later, and again a
  fraction of a period later while none came): the loop's cycle makes no system call and wakes
  no other CPU for it (a write that wakes a process on another CPU cost the loop ≈ 18 µs a
  cycle on a 2-vCPU virtual machine);
* :meth:`BoundWorker.take` also reads, without waiting, the newest count of samples finished
  that the worker wrote to the loop's pipe, and fills the estimate with the result of that
  sample (cycle, ρ, valid): ``tau_h_act_bound`` = that sample's ρ, :attr:`bound_cycle` = the
  loop cycle of that sample (the log's ``bound_cycle``), ``valid`` = its gate and the age
  (cycle − bound_cycle) at most ``max_age`` cycles.  An older bound (worker behind, or none
  yet) is not published: the estimate is not valid in that cycle, counted in :attr:`stale`.

Memory order.  Python has no fences, and a weakly ordered CPU (aarch64) may make stores and
loads to shared memory visible out of program order, so every count that orders the ring goes
through a pipe, never through shared memory: a pipe's write and read are system calls that take
the pipe's lock, so what a process wrote before a write is visible to the process that has read
those bytes.  The worker computes a slot only once it has read a head beyond it from its pipe,
so the slot's inputs are visible to it.  It writes the sample's count to the loop's pipe after
the sample's result, so the loop reads a result only once it is complete.  The loop reuses a
slot only once a count beyond it came back, so the worker has finished reading its inputs, and
the worker writes its result slot again only for a sample the loop publishes after it has read
the result.  The counts are cumulative int64s (:mod:`sea_daemon.runtime.counts`): a reader takes
the newest complete one and keeps the bytes of one split across two reads.  The rest of the header is read without that order:
the worker's CPU time and scheduling (statistics), and its own count of samples done, stored
after each count written to the pipe — the loop reads its pipe only in a cycle where that count
is ahead of the last one the pipe gave it (no system call in a cycle with nothing new); seen
late it delays the read, seen early the read finds nothing yet.  On a CPU with total store order
(x86-64: stores become visible in program order, loads are not reordered with loads or with later
stores) that count in shared memory is itself enough — stored after the sample's result and
after the worker read the slot's inputs — and the loop reads it instead of the pipe
(``counts="auto"`` picks it there, :func:`counts_path`; one system call less per cycle).  The
heads go through the worker's pipe on every CPU: its write is what wakes the worker.

A ring full (the worker a whole ring of samples behind, as far as the counts that came back
say) breaks the set recursion: the bound is unavailable until the estimator's next reset
(:attr:`broken`).  That, and a worker that died, is what :meth:`fault` reports — the loop latches
it as BOUND_LOST (docs/safety.md), as a log writer that died latches LOG_FAILED.  A bound that
diverged in the worker (EstimatorFault in its step) raises the same EstimatorFault out of the
loop's estimator step when its result arrives, as the in-loop bound raises it in its own step.

Neither side ever blocks on a pipe.  The loop writes its heads non-blocking; a head that finds
the worker's pipe full (8192 heads unread in a pipe of 64 KiB: the worker stopped reading) is
written at the next flush, a later head replacing it.  The worker writes its counts non-blocking
too; a count that does not fit in the loop's pipe (the loop not reading) is written later, when
the pipe has room or after the next sample, the newest count replacing it; meanwhile the loop
sees fewer free slots, never a wrong result.  With heads polled the loop writes the worker's pipe
only to stop it (and closes it), and the worker waits on the pipe with the poll's timeout.  The worker exits when :meth:`close` asks (a head
of −1, after the samples before it), when the writing end of its pipe closes, when the reading
end of the loop's pipe closes, or when the parent dies (PR_SET_PDEATHSIG, and its parent id
checked every second).  With ``rt_priority`` it runs SCHED_FIFO at that priority (below the
loop's: the loop preempts it, and a machine busy with other work does not starve it of the CPU
it needs, ≈ 0.1 ms per sample) with its memory locked where permitted
(:func:`sea_daemon.runtime.realtime.lock_memory`), else SCHED_OTHER; what applied is in
:meth:`BoundWorker.stats`.  A worker behind gives its priority up until it has caught up
(:mod:`.bound_serve`; ``rt_yields`` in the stats).
"""
from __future__ import annotations

import multiprocessing as mp
import os
import platform
import time

import numpy as np

from sea_daemon.core.estimators.akf import AKF
from sea_daemon.core.estimators.record import RESET as KIND_RESET
from sea_daemon.core.estimators.validity import BOUND_STALE, STARTUP
from sea_daemon.errors import EstimatorFault
from sea_daemon.runtime import bound_slots as bs
from sea_daemon.runtime.affinity import pin_pid
from sea_daemon.runtime.bound_serve import worker_main
from sea_daemon.runtime.shared_block import SharedBlock
from sea_daemon.runtime.bound_slots import FAILED, OK, STOP
from sea_daemon.runtime.counts import CountReader, close_fds, write_count

#: how long :meth:`BoundWorker.start` waits for the worker to be set up (a dead or slow one is
#: left to the loop's checks: BOUND_LOST, stale bounds)
START_WAIT_S = 30.0


def akf_of(estimator) -> AKF | None:
    """The AKF inside ``estimator`` (through wrappers such as the assist's InnovationGuard that
    keep it as ``.estimator``), or None."""
    obj = estimator
    for _ in range(8):
        if obj is None or isinstance(obj, AKF):
            return obj
        obj = vars(obj).get("estimator") if hasattr(obj, "__dict__") else None
    return None


def why_not(estimator) -> str | None:
    """None when the estimator's bound can run in a worker, else why not (one line)."""
    akf = akf_of(estimator)
    if akf is None or akf.bound is None:
        return "the estimator publishes no Theorem-1 bound"
    if akf.consumer is not None:
        return "the bound already runs elsewhere"
    if getattr(akf, "learning", False):
        return "the GP learns in the loop (the worker's copy would not follow it)"
    return None


#: CPUs whose stores become visible to other cores in program order and whose loads are not
#: reordered with other loads or with later stores (total store order)
TSO_MACHINES = frozenset({"x86_64", "amd64", "i386", "i686", "x86"})


def counts_path(machine: str | None = None) -> str:
    """``memory`` on a CPU with total store order (:data:`TSO_MACHINES`, ``platform.machine()``),
    else ``pipe`` (module docstring, Memory order)."""
    m = (platform.machine() if machine is None else machine).lower()
    return "memory" if m in TSO_MACHINES else "pipe"


class BoundWorker:
    """The estimator's bound in a worker process (see module docstring).

    ``estimator``: the loop's estimator (an AKF / GP-AKF, possibly wrapped); its bound is taken
    off it by :meth:`start` and given back by :meth:`close`.  ``max_age``: the oldest bound
    published, in cycles behind the estimate.  ``capacity``: ring slots (samples the worker may
    be behind).  ``record``: keep the first ``record`` steps' bound age and the worker's CPU time
    per sample (for ``bench loop``; 0: none).  ``rt_priority``: the worker's SCHED_FIFO priority
    (0: SCHED_OTHER; SCHED_OTHER too where SCHED_FIFO is not permitted).  ``counts``: how the
    worker's counts of samples done reach the loop — ``pipe``, ``memory`` (shared memory only:
    correct on a CPU with total store order, x86-64), ``auto`` (:func:`counts_path`: memory on
    x86-64, the pipe on every other CPU).  ``cpu``: the CPU the worker is pinned to once started
    (:mod:`sea_daemon.runtime.affinity`; None: where the kernel puts it).  ``period``: the loop's
    period [s] when it runs in real-time pace: with counts through shared memory the worker then
    polls the heads there, in phase with the loop (module docstring; :attr:`heads_via`
    ``memory``), else they go through its pipe (``pipe``; a lock-step loop, whose cycles come at
    no fixed pace, always).
    """

    def __init__(self, estimator, max_age: int = 3, capacity: int = 1024, record: int = 0, rt_priority: int = 0,
                 counts: str = "auto", cpu: int | None = None, period: float | None = None):
        if counts not in ("auto", "pipe", "memory"):
            raise ValueError(f"bound worker: counts must be auto, pipe or memory, got {counts!r}")
        self.counts_via = counts_path() if counts == "auto" else counts
        if period is not None and not 0.0 < period <= 1.0:
            raise ValueError(f"bound worker: period must be in (0, 1] s, got {period!r}")
        # the heads polled by the worker in shared memory (total store order and a fixed pace), or
        # through its pipe
        self.poll_period = float(period) if (period is not None and self.counts_via == "memory") else None
        self.heads_via = "memory" if self.poll_period is not None else "pipe"
        why = why_not(estimator)
        if why is not None:
            raise ValueError(f"bound worker: {why}")
        akf = self.akf = akf_of(estimator)
        self.max_age = int(max_age)
        self.capacity = cap = int(capacity)
        self.record = int(record)
        self.rt_priority = int(rt_priority)
        self.cpu = cpu
        self.placed = "not pinned"               # where the worker runs (pin_pid)
        self.n = n = akf.n
        self._map_shared(akf, n, cap)
        self.ages = np.full(max(self.record, 1), -1, dtype=np.int64)   # per step (record): age, −1 none
        self.cycle = 0                           # the loop's cycle of the step being made (set by the loop)
        self.bound_cycle = -1                    # the cycle of the sample whose ρ is in the estimate
        self.valid = False
        self.stale = 0                           # steps with no bound within max_age
        self.steps = 0
        self.broken = False                      # the ring was full: no bound until the next reset
        self._head = 0                           # samples written into the ring
        self._published = 0                      # the newest head written to the worker's pipe
        self._done = 0                           # the newest count of samples done read from the loop's pipe
        self._seen = 0
        self._epoch = 0
        self._fault = None
        self._next_alive = 0.0
        self._newest_cycle = -1
        self._newest_valid = False
        self._newest_reason = STARTUP
        self.invalid_reason = STARTUP            # why the estimate of this cycle is not valid (0: it is)
        self._newest_epoch = -1
        self._rho = np.zeros(n)
        self._rho_in = np.zeros(n)
        self._final = None
        self.cpu_per_sample = np.array([])
        self._proc = None
        # the worker's pipe (heads, loop → worker) and the loop's (counts done, worker → loop);
        # the ends the loop writes and reads never block, nor does the worker's writing end
        self._heads_r, self._heads_w = os.pipe()
        self._counts_r, self._counts_w = os.pipe()
        for fd in (self._heads_w, self._counts_r, self._counts_w):
            os.set_blocking(fd, False)
        self._hbuf = bytearray(8)
        self._counts = CountReader(self._counts_r)
        self.started = False

    def _map_shared(self, akf: AKF, n: int, cap: int) -> None:
        """The shared memory (:mod:`.bound_slots`): slots laid out for the AKF's step record,
        every page touched now (no page fault in the loop), views of each slot's arrays."""
        self._lay, w = bs.layout(akf.record)
        self._width = w
        self._rwidth = rw = bs.N_RES + n
        self._shm = SharedBlock.create(bs.shared_size(cap, w, rw, self.record), "sea-daemon-bound")
        v = bs.map_shared(self._shm.buf, cap, w, rw, self.record)
        self._hdr, self._fhdr, self._ring, self._res, self._cpu_rec = v
        self._hdr[:] = 0
        self._hdr[bs.H_SCHED] = -1
        self._fhdr[:] = 0.0
        self._ring[:] = 0.0                      # pre-fault every page: no page fault in the loop
        self._res[:] = -1.0
        self._cpu_rec[:] = np.nan
        # per slot: the slot, views of its arrays and the flat view of them all (the loop writes into
        # them, nothing is made per cycle)
        self._slots = [(self._ring[i], bs.slot_arrays(self._ring[i], self._lay), self._ring[i, bs.N_IN:w])
                       for i in range(cap)]
        # the AKF's record arrays (fixed views of its own arrays) as flat views, copied into a slot's
        # in one call (np.concatenate); None where one is not C-contiguous (copied one by one)
        self._rec = akf.record
        flat = tuple(a.reshape(-1) for _, a in akf.record.arrays())
        same = all(f.size == 0 or np.shares_memory(f, a) for f, (_, a) in zip(flat, akf.record.arrays()))
        self._rec_flat = flat if same else None
        self._results = [(self._res[i], self._res[i, bs.N_RES:bs.N_RES + n]) for i in range(cap)]

    # ------------------------------------------------------------------ life

    def start(self, wait: bool = True) -> "BoundWorker":
        """Fork the worker (its AKF a copy of the loop's as it is now, with the bound) and attach
        to the loop's AKF in the bound's place (:meth:`AKF.attach`); with ``wait``, once the worker has its scheduling
        and memory (not from inside a running loop: locking may take a second or more)."""
        ctx = mp.get_context("fork")
        self._proc = ctx.Process(target=worker_main, name="sea-daemon-bound", daemon=True,
                                 args=(self.akf, self._shm, self.capacity, self._width, self._rwidth,
                                       self._lay, self.record, self._heads_r, self._counts_w,
                                       (self._heads_w, self._counts_r), os.getpid(), self.rt_priority,
                                       self.counts_via == "pipe", self.poll_period))
        self._proc.start()
        self.placed = pin_pid(self._proc.pid, self.cpu)
        self._close_fds("_heads_r", "_counts_w")          # the worker's ends
        # until the worker has its scheduling and its memory locked (faulting a few hundred MB in
        # on one core): then the loop's first cycles do not run beside that
        end = time.monotonic() + (START_WAIT_S if wait else 0.0)
        while self._hdr[bs.H_SCHED] < 0 and self._proc.is_alive() and time.monotonic() < end:
            time.sleep(0.005)
        self.akf.attach(self)
        self.started = True
        return self

    def close(self, timeout: float = 5.0) -> dict:
        """Stop the worker, detach from the AKF, which computes its bound in its step again (reset:
        its set of means did not follow the steps made meanwhile) and return :meth:`stats`.  Safe
        to call twice."""
        if self._final is not None:
            return self._final
        if not self.started:                     # never started: only the shared memory and pipes to free
            self._final = self.stats()
            self._release()
            return self._final
        self.flush()
        self._send(STOP)                         # after the samples published: they are computed first
        self._close_fds("_heads_w")              # and EOF, should the pipe be full
        self._proc.join(timeout)
        if self._proc.is_alive():
            self._proc.kill()
            self._proc.join(5)
        # the worker has exited (and was waited for): all it wrote is visible
        self.cpu_per_sample = np.array(self._cpu_rec[:min(self.record, int(self._hdr[bs.H_DONE]))])
        self._final = self.stats()
        self.started = False
        if self.akf.consumer is self:
            self.akf.detach()
            self.akf.reset()
        self._release()
        return self._final

    def _release(self) -> None:
        self._close_fds("_heads_r", "_heads_w", "_counts_r", "_counts_w")
        del self._hdr, self._fhdr, self._ring, self._res, self._cpu_rec, self._slots, self._results
        self._shm.close()

    def _close_fds(self, *names: str) -> None:
        close_fds(self, names)

    @property
    def pid(self) -> int | None:
        return None if self._proc is None else self._proc.pid

    # ------------------------------------------------------------------ the loop's side

    def _send(self, head: int) -> bool:
        """Write ``head`` to the worker's pipe (which wakes it); False if it did not go."""
        # False: pipe full (the worker not reading) or closed (the worker gone)
        try:
            return write_count(self._heads_w, self._hbuf, head)
        except OSError:
            return False

    def _slot(self):
        """The next free slot, or None when the ring is full (the chain is broken then): a slot
        is free once the worker's count of samples done, read from its pipe, is past it."""
        h = self._head
        if h - self._done >= self.capacity:
            self.broken = True
            return None
        return self._slots[h % self.capacity]

    def flush(self) -> None:
        """Publish the slots written since the last call and wake the worker (the loop calls it
        once per cycle, after the cycle's log row); with heads polled, store the head and the
        clock for the worker's next poll instead."""
        h = self._head
        if h == self._published:
            return
        if self.poll_period is not None:
            # total store order: the slot's stores are visible before the head's
            self._hdr[bs.H_HEAD] = h
            self._fhdr[bs.F_FLUSH] = time.monotonic()
            self._published = h
        elif self._send(h):                           # not sent: again at the next flush
            self._published = h

    def take(self, est, record) -> None:
        """The loop's AKF ended a reset or a step (:class:`~sea_daemon.core.estimators.record.BoundConsumer`):
        hand its record to the worker; after a step, fill ``est`` with the newest bound (module docstring)."""
        if record.kind == KIND_RESET:
            self._reset(est, record)
            return
        if not self.broken:
            slot = self._slot()
            if slot is not None:
                self._write(slot, bs.STEP, est, record)
        self._collect(est)

    def _reset(self, est, record) -> None:
        """The AKF was reset: a new chain of samples (results of the old one are not published)."""
        self._epoch += 1
        self.valid = False
        self.invalid_reason = STARTUP
        self.bound_cycle = -1
        self.broken = False
        slot = self._slot()
        if slot is not None:
            self._write(slot, bs.RESET, est, record)

    def _write(self, slot, kind: float, est, record) -> None:
        """The record into the slot, published at the next :meth:`flush`."""
        s, arrays, flat = slot
        # the scalars at I_KIND, I_CYC, I_K, I_DT, I_READY, I_GATES, I_EPOCH (0..6), one assignment
        s[:bs.I_EPOCH + 1] = (kind, self.cycle, est.k, record.dt, 1.0 if record.ready else 0.0,
                              record.gate_starts, self._epoch)
        if record is self._rec and self._rec_flat is not None:
            np.concatenate(self._rec_flat, out=flat)     # the arrays in layout order, one call
        else:
            for name, view in arrays:
                view[...] = getattr(record, name)
        self._head += 1

    def _collect(self, est) -> None:
        if self.counts_via == "memory":
            # total store order: the worker stored its count after the result (and after it read
            # the slot's inputs); loads are not reordered with loads
            d = self._hdr.item(bs.H_DONE)
            if d > self._done:
                self._done = d
        elif self._hdr.item(bs.H_DONE) > self._done:
            # the worker's own count, seen in shared memory, says that a newer count is in the
            # pipe (or soon will be): read it.  Only what came through the pipe is used; a count
            # seen late in shared memory delays the read, one seen early finds the pipe empty
            counts = self._counts
            try:
                got = counts.read()
            except OSError:                          # nothing yet (EAGAIN)
                got = 0
            if got:
                self._done = counts.value(got - 1)
        done = self._done
        if done > self._seen:
            self._seen = done
            # sample done − 1's result, complete: its count came through the pipe after it; and
            # not overwritten while read: that needs a sample the loop publishes after this
            r, rho = self._results[(done - 1) % self.capacity]
            head = r[:bs.N_RES].tolist()             # seq, cycle, k, valid, status, epoch, cpu, reason
            status, epoch, cyc, ok = head[bs.R_STATUS], head[bs.R_EPOCH], head[bs.R_CYC], head[bs.R_VALID] != 0.0
            reason = int(head[bs.R_REASON])
            self._rho_in[:] = rho
            if head[bs.R_SEQ] != done - 1:
                epoch = -1.0                         # not that sample's (the ring's order rules it out)
            if epoch == self._epoch:
                if status == FAILED:
                    self._newest_cycle = -1
                    raise EstimatorFault(f"Theorem-1 bound (worker), sample of cycle {int(cyc)}: the set of "
                                         f"means diverged")
                if status == OK:
                    self._newest_cycle = int(cyc)
                    self._newest_valid = ok
                    self._newest_reason = reason
                    self._rho[:] = self._rho_in
                else:
                    self._newest_cycle = -1
                self._newest_epoch = self._epoch
        i = self.steps
        self.steps = i + 1
        c = self._newest_cycle
        fresh = (c >= 0 and self._newest_epoch == self._epoch and not self.broken
                 and self.cycle - c <= self.max_age)
        if i < self.record:
            self.ages[i] = self.cycle - c if (c >= 0 and self._newest_epoch == self._epoch) else -1
        if fresh:
            est.tau_h_act_bound[:] = self._rho
            self.bound_cycle = c
            est.valid = self.valid = self._newest_valid
            est.invalid_reason = self.invalid_reason = self._newest_reason
        else:
            self.stale += 1
            self.bound_cycle = -1
            est.valid = self.valid = False
            est.invalid_reason = self.invalid_reason = BOUND_STALE

    def fault(self) -> str | None:
        """None while the bound can come; else one line saying why not (a dead worker: the same
        string from then on).  Real-time safe: a flag, and every 0.2 s whether the worker lives."""
        if self._fault is not None:
            return self._fault
        if self.broken:
            return (f"bound worker {self._head - self._done} samples behind (its ring of "
                    f"{self.capacity} is full): the Theorem-1 bound is unavailable until the estimator's reset")
        now = time.monotonic()
        if now < self._next_alive:
            return None
        self._next_alive = now + 0.2
        if self._proc is not None and self._proc.is_alive():
            return None
        self._fault = (f"bound worker exited (exit code {self._proc.exitcode if self._proc else None}): the "
                       "Theorem-1 bound is unavailable")
        return self._fault

    def stats(self) -> dict:
        """Counts and the worker's CPU time (bound steps, whole process) [s]."""
        if self._final is not None:
            return self._final
        done = int(self._hdr[bs.H_DONE])
        sched = int(self._hdr[bs.H_SCHED])
        return {"where": "worker", "pid": self.pid, "max_age": self.max_age, "capacity": self.capacity,
                "counts": self.counts_via, "heads": self.heads_via,
                "sched": "not started" if sched < 0 else (f"fifo {sched}" if sched else "other"), "cpu": self.placed,
                "memory_locked": bool(self._hdr[bs.H_LOCKED]), "rt_yields": int(self._hdr[bs.H_YIELDS]),
                "steps": self.steps, "samples_done": done, "stale": self.stale, "broken": self.broken,
                "worker_cpu_steps_s": float(self._fhdr[bs.F_STEPS]), "worker_cpu_process_s": float(self._fhdr[bs.F_PROC]),
                "fault": self._fault}
