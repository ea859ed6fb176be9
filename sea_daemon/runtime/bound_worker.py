"""The Theorem-1 bound in a worker process: the loop's estimator step runs the filter only.

:class:`BoundWorker` takes the bound component (:class:`~sea_daemon.core.estimators.base.Bound`,
e.g. :class:`~sea_daemon.core.bounds.akf_bound.AKFTheoremBound`) off the loop's AKF and puts
itself in its place (``deferred``: the AKF hands every step's inputs on and takes ρ and the
validity from it).  A forked process holds a copy of the AKF with the original bound and
computes, sample by sample and in order (the set of means needs every sample), exactly what the
loop's own step would have computed: the bound's step, then the start-up gate
(:meth:`~sea_daemon.core.estimators.akf.AKF.gate`).  Same objects, same compiled kernels, same
inputs: the same ρ_k to the bit.

Per cycle, on the loop's side (no pickling, no lock, never blocking, nothing allocated but
integers):

* :meth:`BoundWorker.step` copies the step's inputs — the AKF's step buffer (F_k, K_k, Γ_μ, P_k,
  μ, ∂μ/∂z, … of step k), ẑ_{k−1}, x̂_{k−1}, P_{k−1}, the input u, dt, the box of the start-up
  gate and the loop's cycle — into the next slot of a ring in shared memory;
* :meth:`BoundWorker.flush`, called by the loop at the end of the cycle (after its log row),
  publishes the slots written: it writes the number of samples handed over (the head, an int64)
  to the worker's pipe, which also wakes the worker: the worker computes while the loop sleeps,
  not beside the loop's own work;
* :meth:`BoundWorker.step` also reads, without waiting, the newest count of samples finished
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
sees fewer free slots, never a wrong result.  The worker exits when :meth:`close` asks (a head
of −1, after the samples before it), when the writing end of its pipe closes, when the reading
end of the loop's pipe closes, or when the parent dies (PR_SET_PDEATHSIG, and its parent id
checked every second).  With ``rt_priority`` it runs SCHED_FIFO at that priority (below the
loop's: the loop preempts it, and a machine busy with other work does not starve it of the CPU
it needs, ≈ 0.1 ms per sample) with its memory locked where permitted
(:func:`sea_daemon.runtime.realtime.lock_memory`), else SCHED_OTHER; what applied is in
:meth:`BoundWorker.stats`.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import multiprocessing as mp
import os
import platform
import select
import signal
import time
from multiprocessing import shared_memory

import numpy as np

from sea_daemon.errors import EstimatorFault
from sea_daemon.runtime.counts import CountReader, close_fds, write_count
from sea_daemon.runtime.realtime import lock_memory

# int64 header slots, read without order (module docstring): the worker's count of samples done
# (the loop's hint to read its pipe), its SCHED_FIFO priority (0 SCHED_OTHER, −1 not known yet),
# its memory locked (1) or not (0)
_DONE, _SCHED, _LOCKED, _NHDR = 0, 1, 2, 8
#: how long :meth:`BoundWorker.start` waits for the worker to be set up (a dead or slow one is
#: left to the loop's checks: BOUND_LOST, stale bounds)
_START_WAIT_S = 30.0
# float64 header slots (after the int64 ones): the worker's CPU time [s]: in bound steps, whole process
_F_STEPS, _F_PROC, _NFHDR = 0, 1, 4
# input slot: kind, cycle, k, dt, ready, gate_starts, epoch, then the arrays
_KIND, _CYC, _K, _DT, _READY, _GATES, _EPOCH, _NIN = 0, 1, 2, 3, 4, 5, 6, 8
STEP, RESET = 1.0, 2.0
# result slot: seq, cycle, k, valid, status, epoch, cpu, then ρ (n)
_RSEQ, _RCYC, _RK, _RVALID, _RSTATUS, _REPOCH, _RCPU, _NRES = 0, 1, 2, 3, 4, 5, 6, 8
OK, FAILED, NO_BOUND = 0.0, 1.0, 2.0
# the head that asks the worker to stop (after the samples published before it)
STOP = -1


def akf_of(estimator):
    """The AKF inside ``estimator`` (through wrappers such as the assist's InnovationGuard that
    keep it as ``.estimator``), or None."""
    obj = estimator
    for _ in range(8):
        if obj is None or hasattr(obj, "_buf"):
            return obj
        obj = vars(obj).get("estimator") if hasattr(obj, "__dict__") else None
    return None


def why_not(estimator) -> str | None:
    """None when the estimator's bound can run in a worker, else why not (one line)."""
    akf = akf_of(estimator)
    if akf is None or getattr(akf, "bound", None) is None:
        return "the estimator publishes no Theorem-1 bound"
    if getattr(akf.bound, "deferred", False):
        return "the bound already runs elsewhere"
    if getattr(akf, "learning", False):
        return "the GP learns in the loop (the worker's copy would not follow it)"
    return None


def _layout(d: int, m: int, n: int, nbuf: int) -> dict:
    """Offsets of the input slot's arrays."""
    o = _NIN
    out = {}
    for name, size in (("u", n), ("z", 3 * n), ("x", d), ("P", d * d), ("b0", d), ("buf", nbuf)):
        out[name] = (o, o + size)
        o += size
    out["width"] = o
    return out


def _pdeathsig() -> None:
    """Linux: SIGKILL this process when its parent thread exits (best effort)."""
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        libc.prctl(1, int(signal.SIGKILL), 0, 0, 0)          # PR_SET_PDEATHSIG
    except Exception:  # noqa: BLE001 - other kernels: the parent id check below remains
        pass


def _worker_main(akf, shm_name: str, cap: int, width: int, rwidth: int, lay: dict, record: int,
                 heads: int, counts: int, loop_ends: tuple, parent_pid: int, rt_priority: int,
                 via_pipe: bool = True) -> None:
    _pdeathsig()
    for fd in loop_ends:                           # the loop's ends: EOF on ``heads`` once the parent is gone
        try:
            os.close(fd)
        except OSError:
            pass
    sched = 0
    try:
        if rt_priority > 0:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(rt_priority))
            sched = rt_priority
        else:
            os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    except (OSError, AttributeError):
        try:
            os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
        except (OSError, AttributeError):
            pass
    if os.getppid() != parent_pid:
        return
    # a forked process inherits no memory locks: its own, in real-time pace
    locked = rt_priority > 0 and lock_memory().startswith("locked")
    shm = shared_memory.SharedMemory(name=shm_name)
    hdr = fhdr = ring = res = cpu_rec = None
    try:
        hdr = np.ndarray((_NHDR,), dtype=np.int64, buffer=shm.buf)
        hdr[_SCHED] = sched
        hdr[_LOCKED] = 1 if locked else 0
        fhdr = np.ndarray((_NFHDR,), dtype=np.float64, buffer=shm.buf, offset=_NHDR * 8)
        o = (_NHDR + _NFHDR) * 8
        ring = np.ndarray((cap, width), dtype=np.float64, buffer=shm.buf, offset=o)
        o += cap * width * 8
        res = np.ndarray((cap, rwidth), dtype=np.float64, buffer=shm.buf, offset=o)
        o += cap * rwidth * 8
        cpu_rec = np.ndarray((max(record, 1),), dtype=np.float64, buffer=shm.buf, offset=o)
        _serve(akf, hdr, fhdr, ring, res, cpu_rec, record, lay, heads, counts, parent_pid, via_pipe)
    finally:
        del hdr, fhdr, ring, res, cpu_rec
        shm.close()


def _serve(akf, hdr, fhdr, ring, res, cpu_rec, record, lay, heads, counts, parent_pid, via_pipe=True) -> None:
    """The worker's loop: every slot up to the newest head read from ``heads``, in order, each
    one's count written to ``counts`` after its result (``via_pipe``), else stored in shared
    memory only (module docstring); then wait."""
    bound = akf.bound
    e = akf.est
    d, n = akf.d, akf.n
    cap = ring.shape[0]
    sl = {k: slice(*v) for k, v in lay.items() if k != "width"}
    gates = -1
    clock = time.thread_time
    cpu_total = 0.0
    reader = CountReader(heads)
    out = bytearray(8)
    head = done = 0
    stop = unsent = False
    while True:
        if done < head:
            c0 = clock()
            s = ring[done % cap]
            r = res[done % cap]
            kind = s[_KIND]
            akf._buf[:] = s[sl["buf"]]
            e.k = int(s[_K])
            status = OK
            valid = 0.0
            if kind == RESET:
                # AKF.reset: the filter restarted (from a sample when ready); the bound's reset
                akf._ready = bool(s[_READY])
                akf.converged, akf.converged_at = False, -1
                try:
                    bound.reset(e)
                except Exception:  # noqa: BLE001 - reported as a failed step of the loop's estimator
                    status = FAILED
                else:
                    status = NO_BOUND
            else:
                akf.z[:] = s[sl["z"]]
                g = int(s[_GATES])
                if g != gates:
                    # the loop's AKF started its gate (_start_gate) since the last step: its box b₀, Φ = I
                    gates = g
                    akf._b0[:] = s[sl["b0"]]
                    akf._Phi[:] = 0.0
                    np.fill_diagonal(akf._Phi, 1.0)
                    akf.converged, akf.converged_at = False, -1
                x_prev = s[sl["x"]]
                P_prev = s[sl["P"]].reshape(d, d)
                try:
                    # the same step as the loop's AKF.step / GPAKF._frozen_update would run
                    bound.step(e, x_prev, P_prev, s[sl["u"]], float(s[_DT]))
                    valid = 1.0 if akf.gate(e) else 0.0
                except EstimatorFault:
                    status = FAILED
            r[_RSEQ] = done
            r[_RCYC] = s[_CYC]
            r[_RK] = s[_K]
            r[_RVALID] = valid
            r[_RSTATUS] = status
            r[_REPOCH] = s[_EPOCH]
            r[_NRES:_NRES + n] = e.tau_h_act_bound
            spent = clock() - c0
            r[_RCPU] = spent
            if record and done < record:
                cpu_rec[done] = spent
            cpu_total += spent
            fhdr[_F_STEPS] = cpu_total
            done += 1
            unsent = True
        if unsent:
            if via_pipe:
                # the count after the result: the loop reads the result once it has read the count
                try:
                    unsent = not write_count(counts, out, done)   # full: the newest count later
                except OSError:                  # the loop's end closed: the parent is gone
                    return
            else:
                unsent = False                   # total store order: the store below is the count
            hdr[_DONE] = done                    # after the write: the loop's hint to read the pipe (memory: the count)
        if done < head:
            continue
        fhdr[_F_PROC] = time.process_time()
        if stop or reader.eof:
            return
        ready, writable, _ = select.select([heads], [counts] if unsent else [], [], 1.0)
        if ready:
            try:
                got = reader.read()
            except OSError:
                return
            for i in range(got):
                h = reader.value(i)
                if h == STOP:
                    stop = True
                elif h > head:
                    head = h
        if os.getppid() != parent_pid:
            return


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
    x86-64, the pipe on every other CPU).
    """

    deferred = True

    def __init__(self, estimator, max_age: int = 3, capacity: int = 1024, record: int = 0, rt_priority: int = 0,
                 counts: str = "auto"):
        if counts not in ("auto", "pipe", "memory"):
            raise ValueError(f"bound worker: counts must be auto, pipe or memory, got {counts!r}")
        self.counts_via = counts_path() if counts == "auto" else counts
        why = why_not(estimator)
        if why is not None:
            raise ValueError(f"bound worker: {why}")
        akf = self.akf = akf_of(estimator)
        self.bound = akf.bound
        self.max_age = int(max_age)
        self.capacity = cap = int(capacity)
        self.record = int(record)
        self.rt_priority = int(rt_priority)
        d, m, n = akf.d, akf.m, akf.n
        self.n = n
        self._lay = lay = _layout(d, m, n, akf._buf.size)
        self._width = w = lay["width"]
        self._rwidth = rw = _NRES + n
        size = (_NHDR + _NFHDR) * 8 + cap * (w + rw) * 8 + max(self.record, 1) * 8
        self._shm = shared_memory.SharedMemory(create=True, size=size)
        buf = self._shm.buf
        self._hdr = np.ndarray((_NHDR,), dtype=np.int64, buffer=buf)
        self._hdr[:] = 0
        self._hdr[_SCHED] = -1
        self._fhdr = np.ndarray((_NFHDR,), dtype=np.float64, buffer=buf, offset=_NHDR * 8)
        self._fhdr[:] = 0.0
        o = (_NHDR + _NFHDR) * 8
        self._ring = np.ndarray((cap, w), dtype=np.float64, buffer=buf, offset=o)
        o += cap * w * 8
        self._res = np.ndarray((cap, rw), dtype=np.float64, buffer=buf, offset=o)
        o += cap * rw * 8
        self._cpu_rec = np.ndarray((max(self.record, 1),), dtype=np.float64, buffer=buf, offset=o)
        self._ring[:] = 0.0                      # pre-fault every page: no page fault in the loop
        self._res[:] = -1.0
        self._cpu_rec[:] = np.nan
        # per slot: views of its arrays (the loop writes into them, nothing is made per cycle)
        self._slots = []
        for i in range(cap):
            s = self._ring[i]
            v = {k: s[a:b] for k, (a, b) in ((k, lay[k]) for k in ("u", "z", "x", "b0", "buf"))}
            a, b = lay["P"]
            v["P"] = s[a:b].reshape(d, d)
            self._slots.append((s, v["u"], v["z"], v["x"], v["P"], v["b0"], v["buf"]))
        self._results = [(self._res[i], self._res[i, _NRES:_NRES + n]) for i in range(cap)]
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

    # ------------------------------------------------------------------ life

    def start(self, wait: bool = True) -> "BoundWorker":
        """Fork the worker (its AKF a copy of the loop's as it is now, with the bound) and take
        the bound's place in the loop's AKF; with ``wait``, once the worker has its scheduling
        and memory (not from inside a running loop: locking may take a second or more)."""
        ctx = mp.get_context("fork")
        self._proc = ctx.Process(target=_worker_main, name="sea-daemon-bound", daemon=True,
                                 args=(self.akf, self._shm.name, self.capacity, self._width, self._rwidth,
                                       self._lay, self.record, self._heads_r, self._counts_w,
                                       (self._heads_w, self._counts_r), os.getpid(), self.rt_priority,
                                       self.counts_via == "pipe"))
        self._proc.start()
        self._close_fds("_heads_r", "_counts_w")          # the worker's ends
        # until the worker has its scheduling and its memory locked (faulting a few hundred MB in
        # on one core): then the loop's first cycles do not run beside that
        end = time.monotonic() + (_START_WAIT_S if wait else 0.0)
        while self._hdr[_SCHED] < 0 and self._proc.is_alive() and time.monotonic() < end:
            time.sleep(0.005)
        self.akf.bound = self
        self.started = True
        return self

    def close(self, timeout: float = 5.0) -> dict:
        """Stop the worker, give the AKF its bound back (reset: its set of means did not follow
        the steps made meanwhile) and return :meth:`stats`.  Safe to call twice."""
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
        self.cpu_per_sample = np.array(self._cpu_rec[:min(self.record, int(self._hdr[_DONE]))])
        self._final = self.stats()
        self.started = False
        if self.akf.bound is self:
            self.akf.bound = self.bound
            self.akf.reset()
        self._release()
        return self._final

    def _release(self) -> None:
        self._close_fds("_heads_r", "_heads_w", "_counts_r", "_counts_w")
        del self._hdr, self._fhdr, self._ring, self._res, self._cpu_rec, self._slots, self._results
        self._shm.close()
        self._shm.unlink()

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

    def _publish_slot(self) -> None:
        self._head += 1                          # written; published by flush()

    def flush(self) -> None:
        """Publish the slots written since the last call and wake the worker (the loop calls it
        once per cycle, after the cycle's log row)."""
        h = self._head
        if h != self._published and self._send(h):   # not sent: again at the next flush
            self._published = h

    def reset(self, est) -> None:
        """The AKF was reset: a new chain of samples (results of the old one are not published)."""
        self._epoch += 1
        self.valid = False
        self.bound_cycle = -1
        self.broken = False
        slot = self._slot()
        if slot is None:
            return
        s, _, _, _, _, _, buf = slot
        akf = self.akf
        s[_KIND] = RESET
        s[_CYC] = self.cycle
        s[_K] = est.k
        s[_READY] = 1.0 if akf._ready else 0.0
        s[_EPOCH] = self._epoch
        buf[:] = akf._buf
        self._publish_slot()

    def step(self, est, x_prev, P_prev, u, dt) -> None:
        """Hand step k's inputs to the worker; fill ``est`` with the newest bound (module docstring)."""
        if not self.broken:
            slot = self._slot()
            if slot is not None:
                s, su, sz, sx, sP, sb0, sbuf = slot
                akf = self.akf
                s[_KIND] = STEP
                s[_CYC] = self.cycle
                s[_K] = est.k
                s[_DT] = dt
                s[_GATES] = akf.gate_starts
                s[_EPOCH] = self._epoch
                su[:] = u
                sz[:] = akf.z
                sx[:] = x_prev
                sP[:] = P_prev
                sb0[:] = akf._b0
                sbuf[:] = akf._buf
                self._publish_slot()
        self._collect(est)

    def _collect(self, est) -> None:
        if self.counts_via == "memory":
            # total store order: the worker stored its count after the result (and after it read
            # the slot's inputs); loads are not reordered with loads
            d = self._hdr.item(_DONE)
            if d > self._done:
                self._done = d
        elif self._hdr.item(_DONE) > self._done:
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
            status, epoch, cyc, ok = r[_RSTATUS], r[_REPOCH], r[_RCYC], r[_RVALID] != 0.0
            self._rho_in[:] = rho
            if r[_RSEQ] != done - 1:
                epoch = -1.0                         # not that sample's (the ring's order rules it out)
            if epoch == self._epoch:
                if status == FAILED:
                    self._newest_cycle = -1
                    raise EstimatorFault(f"Theorem-1 bound (worker), sample of cycle {int(cyc)}: the set of "
                                         f"means diverged")
                if status == OK:
                    self._newest_cycle = int(cyc)
                    self._newest_valid = ok
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
            self.valid = self._newest_valid
        else:
            self.stale += 1
            self.bound_cycle = -1
            self.valid = False

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
        done = int(self._hdr[_DONE])
        sched = int(self._hdr[_SCHED])
        return {"where": "worker", "pid": self.pid, "max_age": self.max_age, "capacity": self.capacity,
                "counts": self.counts_via,
                "sched": "not started" if sched < 0 else (f"fifo {sched}" if sched else "other"),
                "memory_locked": bool(self._hdr[_LOCKED]),
                "steps": self.steps, "samples_done": done, "stale": self.stale, "broken": self.broken,
                "worker_cpu_steps_s": float(self._fhdr[_F_STEPS]), "worker_cpu_process_s": float(self._fhdr[_F_PROC]),
                "fault": self._fault}
