"""The fixed-rate loop: read → control → estimate → publish → record → sleep to an absolute deadline (ros2_control).

The one cycle loop of the project: the daemon (:mod:`.service`), the offline simulator
(:mod:`.sim_runner`, lock-step over :class:`sea_daemon.hw.sim_hw.SimHardware`) and the
hardware-in-the-loop session (:mod:`.hil_session`, over :class:`sea_daemon.hw.canopen_hw.CanopenHardware`
and the device model) run it against a :class:`sea_daemon.hw.interface.HardwareInterface`.

One cycle k, each step a method of :class:`FixedRateLoop` (the estimator after the write, so
that it gets the torque that acts over [t_k, t_k+1] — see :mod:`sea_daemon.hw.interface`):

1. read (``_read``): ``hw.read()``, the measurement sampled at t_k (raises a HardwareError on a
   fault); a sample the hardware missed within its tolerance (``valid`` False: a TPDO that did
   not come, its values held) goes on to the controller, the estimator and the log as the
   constant-velocity extrapolation 2·x_{k−1} − x_{k−2} of the angles of the two cycles before
   (``measured`` 0 in its row; counted in ``stats.extrapolated``), not as the held angles
2. control (``_control``): ``controller.update()``, the torque command from the measurement and
   the last estimate, then ``hw.write(tau_m)``
3. estimate (``_estimate``): ``estimator.update()`` with the torque acting over [t_k, t_k+1]:
   ``hw.actuated()`` of the one written now with ``hw.actuation_delay`` 0 (asynchronous RPDO),
   of the previous cycle's with delay 1; raises EstimatorFault instead of emitting NaN.  With
   the bound worker (:mod:`sea_daemon.runtime.bound_worker`) the step runs the filter, and the
   estimate carries the newest ρ the worker finished, of the sample of cycle ``bound_cycle`` (logged)
4. fault policy: an exception of any step latches its ``fault`` (:func:`sea_daemon.errors.fault_of`;
   ``_failed``: ``hw.safe_stop()`` in the cycle it latches), and while a fault is latched the
   loop writes zero torque and has no estimate (``_hold_when_latched``)
5. publish (``_publish``): the estimate, its bound, validity and the latched fault to the bus
   and to local readers, with the angles the cycle passed on (a missed sample's extrapolation)
   (:mod:`sea_daemon.runtime.publish`; never blocks, never raises)
6. record (``_record``, ``_fill_row``, ``_keep_alive``): ``on_cycle`` (the caller's recorder)
   and one row into the off-loop log writer (row k's ``tau_m`` is that same torque, its columns
   :class:`sea_daemon.core.log.DaemonLogLayout`, docs/interfaces.md §1) — in **every** cycle,
   through and after a fault: a cycle whose read failed gets a placeholder row (``measured`` 0;
   the last measured angles held, the time one period on, no NaN), ``valid`` is the estimator's
   own flag (0 while it starts or converges, and whenever a fault is latched), ``fault`` the
   latched code; a log writer that cannot write latches LOG_FAILED; the cycle's sample to the
   bound worker; the watchdog from every cycle the loop runs (latched or not; the notifier
   sends WATCHDOG=1 to systemd at most every 1/40 of its watchdog period)
7. pace (``_pace``): sleep until ``t0 + (k+1)·period`` on the monotonic clock; a late wake-up is
   an overrun, and deadlines missed by a whole period or more are skipped (counted), not caught
   up in a burst; a stall of the loop that skipped more deadlines in a row than the hardware's
   missed-cycle tolerance (``hardware.bus.max_missed_ms`` / ``max_missed_cycles``: the cycles
   without a sample a missing TPDO may take) latches LOOP_STALL — one within it is survived, and so is a slow first
   cycle of a run (its start-up); lock-step runs (``realtime=False``) do not sleep

No allocation beyond what numpy's small ops do, no logging calls, no locks on the path: the
row vector and the cycle's state (:class:`CycleState`) are preallocated and overwritten, and
the log writer only copies the row.  Faults follow the single
policy of :mod:`sea_daemon.runtime.safety`.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Callable, Protocol

import numpy as np

from sea_daemon.hw.interface import HardwareInterface, Measurement
from sea_daemon.core.buffers import resident_zeros
from sea_daemon.core.log import DaemonLogLayout
from sea_daemon.core.estimators.validity import FAULT, NO_SAMPLE, REASONS, STARTUP, VALID
from sea_daemon.errors import Fault, fault_of
from sea_daemon.runtime.safety import SafetySupervisor

if TYPE_CHECKING:                     # the estimators load compiled kernels: not for a type
    from sea_daemon.core.estimators.base import Estimator


class Controller(Protocol):
    """What the loop asks for the torque command (e.g. :class:`sea_daemon.runtime.controller.ScenarioController`)."""

    def update(self, t: float, q: np.ndarray, theta_m: np.ndarray, estimate: Any) -> np.ndarray: ...


class Series:
    """float64 values appended one per cycle into a resident buffer (:mod:`sea_daemon.core.buffers`):
    no page is first written, and nothing allocated, in the cycle — a Python list of floats took
    a page fault about every 100 appends.  :meth:`reserve` before the loop; a run longer than
    reserved doubles the buffer (an allocation then, once).  ``np.asarray(series)``: the values."""

    def __init__(self, capacity: int = 1024):
        self._a = resident_zeros(max(1, int(capacity)))
        self.n = 0

    def reserve(self, capacity: int) -> None:
        if capacity > self._a.size:
            a = resident_zeros(int(capacity))
            a[:self.n] = self._a[:self.n]
            self._a = a

    def append(self, x: float) -> None:
        if self.n == self._a.size:
            self.reserve(2 * self.n)
        self._a[self.n] = x
        self.n += 1

    def __len__(self) -> int:
        return self.n

    def __array__(self, dtype=None, copy=None):
        v = self._a[:self.n]
        if dtype is not None:
            v = v.astype(dtype, copy=bool(copy))
        return v.copy() if copy and dtype is None else v


@dataclass
class LoopStats:
    cycles: int = 0
    overruns: int = 0
    max_late_s: float = 0.0
    periods: Series = field(default_factory=Series)   # filled only when record_periods=True
    # the loop thread's CPU time per cycle [s] (record_periods): from one cycle's end to the next's
    # (the pacing between them counted with the next cycle; one clock read per cycle)
    cpu: Series = field(default_factory=Series)
    # real-time pace with record_periods: how late cycle k started after its deadline [s] (a sleep
    # that returned late, or the cycle before ran past it), and at the end of cycle k how far past
    # the next cycle's deadline it was [s] (> 0: an overrun; < 0: the sleep that followed)
    wake: Series = field(default_factory=Series)
    late: Series = field(default_factory=Series)
    faults: int = 0
    skipped: int = 0                               # deadlines skipped after overruns >= 1 period
    extrapolated: int = 0                          # samples the hardware missed, extrapolated (run docstring)
    # cycles per Estimate.invalid_reason code (validity.REASONS: valid, or why not; reason_counts)
    validity: np.ndarray = field(default_factory=lambda: np.zeros(len(REASONS), dtype=np.int64))


class CycleState:
    """What one cycle has so far, overwritten in place by the next (no allocation per cycle):
    the steps of :meth:`FixedRateLoop.run` hand it on.

    ``meas``: the measurement (None when the read failed); ``q``, ``theta_m``: the angles the
    cycle passes on (a missed sample's extrapolation, not the held values); ``measured``: the
    row holds this cycle's sample; ``from_start``: cycle 0 is ``hw.start()``'s sample; ``est``,
    ``valid``: the estimate and the estimator's own validity flag (1.0 / 0.0); ``start``,
    ``t_read`` [s]: ``clock()`` at the start of the cycle and after the read."""

    __slots__ = ("k", "start", "t_read", "meas", "q", "theta_m", "measured", "from_start", "est", "valid")

    def __init__(self):
        self.k = 0
        self.start = self.t_read = 0.0
        self.meas = self.q = self.theta_m = self.est = None
        self.measured = self.from_start = False
        self.valid = 0.0


class FixedRateLoop:
    """read → control (update, write) → estimate → fault policy → publish → record → pace to an
    absolute deadline (module docstring; each a step of :meth:`run`).

    ``estimator``: None runs no estimation (the offline simulator).  ``initial_torque``: the
    torque in force when the loop starts (what ``hw.start()`` primed with); with
    ``hw.actuation_delay`` 1 it is the torque acting over the first interval.
    ``on_cycle(k, measurement, estimate, tau)``: called at the end of every cycle with the
    torque acting over [t_k, t_k+1] (``measurement`` None when the read failed, ``estimate``
    None when invalid); it may read :attr:`cycle_start` (``clock()`` when cycle k began).
    ``fail_fast``: a lock-step run (the simulator, the HIL session) raises the exception of the
    first fault out of :meth:`run`, after the fault policy's zero torque, instead of going on
    latched.  ``publisher``: the publication step (a :class:`sea_daemon.runtime.publish.Publisher`),
    called every cycle after the estimate with the estimate (None when invalid or faulted).
    ``bound_link``: the estimator's bound when it runs in a worker
    (:class:`sea_daemon.runtime.bound_worker.BoundWorker`): the loop tells it each cycle's index,
    hands it the cycle's sample at the end of the cycle (``flush``), logs the cycle of the sample
    whose ρ it published (``bound_cycle``) and latches BOUND_LOST when it reports a fault (the
    worker died or fell a whole ring behind).  ``stall_cycles``: the deadlines the loop may skip in
    a row before LOOP_STALL latches (None: the hardware's missed-cycle tolerance, its
    ``stall_cycles`` — ``hardware.bus.max_missed_ms`` / ``max_missed_cycles`` at the loop's
    period — where it has one, else no such fault).
    """

    def __init__(self, hw: HardwareInterface, estimator: Estimator | None, controller: Controller, n: int,
                 period: float, log=None, notifier=None, supervisor: SafetySupervisor | None = None,
                 clock: Callable[[], float] = time.monotonic, sleep: Callable[[float], None] = time.sleep,
                 cpu_clock: Callable[[], float] = time.thread_time,
                 realtime: bool = True, record_periods: bool = False,
                 on_cycle: Callable[[int, Any, Any, np.ndarray], None] | None = None,
                 initial_torque: np.ndarray | None = None, fail_fast: bool = False, publisher=None,
                 bound_link=None, stall_cycles: int | None = None):
        self.hw, self.estimator, self.controller = hw, estimator, controller
        self.n, self.period = n, float(period)
        self.log, self.notifier = log, notifier
        self.supervisor = supervisor or SafetySupervisor()
        self.clock, self.sleep = clock, sleep
        self.cpu_clock = cpu_clock
        self.realtime = realtime
        self.record_periods = record_periods
        self.on_cycle = on_cycle
        self.fail_fast = fail_fast
        self.publisher = publisher
        self.bound_link = bound_link
        self._bound_fault_seen = False
        if stall_cycles is None:
            stall_cycles = getattr(hw, "stall_cycles", None)
        self.stall_cycles = None if stall_cycles is None else int(stall_cycles)
        self.stats = LoopStats()
        #: the log row's columns, each quantity's index or slice (docs/interfaces.md §1)
        self.layout = DaemonLogLayout.of(n)
        self._row = np.zeros(self.layout.width)
        # what the log takes: the whole row for a writer with the sinks' columns, else the CSV's part
        self._log_row = self._row[:getattr(log, "ncols", len(self.layout.columns))]
        L = self.layout
        # the loop's columns valid … bound_cycle, consecutive in the row: written in one assignment
        self._loop_cols = slice(L.valid, L.bound_cycle + 1)
        assert (L.valid, L.fault, L.cycle, L.period, L.compute, L.read, L.measured, L.bound_cycle) == \
            tuple(range(L.valid, L.bound_cycle + 1)), "the loop's log columns are consecutive"
        self._assist = getattr(controller, "tau_assist", None)     # (n,) updated in place, or None
        self._zero = np.zeros(n)
        self._tau = np.zeros(n)                  # torque acting over [t_k, t_k+1] (row k's tau_m)
        self._act_prev = np.zeros(n) if initial_torque is None else np.array(initial_torque, dtype=float).reshape(n)
        self._delay = int(hw.actuation_delay)
        self._stop = False
        self._reset_requested = False
        self._t_row = -float("inf")              # the last row's time (rows strictly increasing)
        # the angles the last two cycles passed on (a sample the hardware missed is extrapolated
        # from them) and how many there are since the start, a failed read or a reset (≤ 2)
        self._q1, self._q2, self._th1, self._th2 = (np.zeros(n) for _ in range(4))
        self._qx, self._thx = np.zeros(n), np.zeros(n)
        self._passed = 0
        self._log_fault_seen = False
        self._cycle = CycleState()
        self._t0 = 0.0                           # the pacing origin: cycle k's deadline is t0 + k·period
        self._last_start = 0.0                   # clock() at the start of the cycle before
        self._cpu_end = 0.0                      # the thread's CPU clock at the end of the cycle before (record_periods)
        self.last_estimate = None
        self.cycle_start = 0.0

    def request_stop(self) -> None:          # signal-handler safe: sets a flag only
        self._stop = True

    def request_reset(self) -> None:         # operator action (sea-daemon reset → SIGUSR1)
        self._reset_requested = True

    # ------------------------------------------------------------------ the fault policy
    def _trip(self, code: Fault, cycle: int, t: float, detail: str) -> None:
        if self.supervisor.trip(code, cycle, t, detail):
            self._latched()

    def _latched(self) -> None:
        """A fault has just latched: zero torque / quick stop now, tell systemd."""
        self.stats.faults += 1
        try:
            self.hw.safe_stop()
        except Exception:  # noqa: BLE001 - the bus may be gone; zero torque is written below too
            pass
        if self.notifier is not None:
            self.notifier.status(self.supervisor.status_line())

    def _failed(self, e: BaseException, cycle: int, t: float) -> None:
        """An exception in the cycle: latch its fault (``e.fault``, zero torque now); re-raise it
        when ``fail_fast``."""
        self._trip(fault_of(e), cycle, t, f"{type(e).__name__}: {e}")
        if self.fail_fast:
            raise e

    def _operator_reset(self, k: int, start: float) -> None:
        """The operator's reset, asked for since the last cycle: clear the latch, reset the
        hardware and the estimator; a reset that fails leaves (or latches) the fault."""
        self._reset_requested = False
        self._passed = 0
        was = self.supervisor.reset()
        try:
            self.hw.reset_fault()
            if self.estimator is not None:
                self.estimator.reset()
        except Exception as e:  # noqa: BLE001 - a failed reset leaves the fault latched
            self._trip(fault_of(e) if was == Fault.NONE else was, k, start,
                       f"operator reset failed: {type(e).__name__}: {e}")
        else:
            if self.notifier is not None:
                self.notifier.status("fault reset by operator")

    def _hold_when_latched(self, c: CycleState) -> None:
        """While a fault is latched: zero torque in force and written, no estimate."""
        if self.supervisor.ok:
            return
        self._tau[:] = 0.0
        self._act_prev[:] = 0.0
        c.valid = 0.0
        c.est = None
        try:
            self.hw.write(self._zero)
        except Exception:  # noqa: BLE001 - the bus may be gone; safe_stop was already asked
            pass

    # ------------------------------------------------------------------ the cycle
    def run(self, cycles: int | None = None, start_sample: Measurement | None = None) -> LoopStats:
        """Run ``cycles`` cycles (None: until :meth:`request_stop`).

        ``start_sample``: the sample ``hw.start()`` took at t_0 (the CANopen driver's priming
        cycle); cycle 0 is then that sample, estimated and recorded with the initial torque
        (in force over [t_0, t_1]) and no command, and the reads start at t_1.
        """
        st = self.stats
        c = self._cycle
        k = 0
        if self.record_periods and cycles is not None:
            for series in (st.cpu, st.periods, st.wake, st.late):
                series.reserve(len(series) + cycles)
        # the pacing origin once the buffers are there (mapping them takes ms on a virtual machine)
        self._t0 = self._last_start = self.clock()
        if self.record_periods:
            # the thread's CPU clock is a system call (no vDSO): read once per cycle, and only
            # when recorded
            self._cpu_end = self.cpu_clock()
        while not self._stop and (cycles is None or k < cycles):
            link = self.bound_link                    # may be attached while the loop runs
            c.k = k
            c.start = start = self.clock()
            self.cycle_start = start
            if self.record_periods and self.realtime:
                st.wake.append(start - (self._t0 + k * self.period))
            if self._reset_requested:
                self._operator_reset(k, start)
            self._read(c, start_sample)
            start_sample = None
            self._control(c)
            self._estimate(c, link)
            self._hold_when_latched(c)
            self._publish(c)
            self._record(c, link)
            self._keep_alive(c, link)
            k += 1
            st.cycles = k
            self._pace(k)
        return st

    def _read(self, c: CycleState, start_sample: Measurement | None) -> None:
        """``hw.read()`` (or ``start_sample``), then the angles the cycle passes on: a sample the
        hardware missed goes on as the constant-velocity extrapolation (:meth:`_pass_on`)."""
        c.meas, c.est, c.valid = None, None, 0.0
        c.from_start = start_sample is not None
        if c.from_start:
            c.meas = start_sample
            self._tau[:] = self._act_prev          # the initial torque acts over [t_0, t_1]
        else:
            try:
                c.meas = self.hw.read()
            except Exception as e:  # noqa: BLE001 - every hardware fault latches
                self._failed(e, c.k, c.start)
        c.t_read = self.clock()
        c.measured = c.meas is not None
        if c.measured:
            self._pass_on(c)
        else:
            self._passed = 0

    def _pass_on(self, c: CycleState) -> None:
        meas = c.meas
        q, theta_m = meas.q, meas.theta_m
        if not getattr(meas, "valid", True):
            # the hardware missed this sample (a TPDO within its tolerance, the values held): a
            # held angle reads as a stop then a jump (to the PID's D term, the differentiator,
            # the filter's innovation); constant velocity from the two samples before it
            # instead: 2·x_{k−1} − x_{k−2} (held without them)
            c.measured = False
            if self._passed >= 2:
                q, theta_m = self._qx, self._thx
                np.multiply(self._q1, 2.0, out=q)
                q -= self._q2
                np.multiply(self._th1, 2.0, out=theta_m)
                theta_m -= self._th2
                self.stats.extrapolated += 1
        # the history: the buffers swap, the new sample copied in
        self._q1, self._q2 = self._q2, self._q1
        self._th1, self._th2 = self._th2, self._th1
        self._q1[:] = q
        self._th1[:] = theta_m
        if self._passed < 2:
            self._passed += 1
        c.q, c.theta_m = q, theta_m

    def _control(self, c: CycleState) -> None:
        """``controller.update()`` → ``hw.write()``; the torque acting over [t_k, t_k+1] into
        ``_tau`` (the one written now, or the previous cycle's with a synchronous RPDO)."""
        if c.meas is None or not self.supervisor.ok or c.from_start:
            return
        try:
            cmd = self.controller.update(c.meas.t, c.q, c.theta_m, self.last_estimate)
            self.hw.write(cmd)
            act = self.hw.actuated(cmd)
            if self._delay:
                # synchronous RPDO: the previous command acts over [t_k, t_k+1]
                self._tau[:] = self._act_prev
                self._act_prev[:] = act
            else:
                # actuated on reception: this command acts over [t_k, t_k+1]
                self._tau[:] = act
        except Exception as e:  # noqa: BLE001
            self._failed(e, c.k, c.start)

    def _estimate(self, c: CycleState, link) -> None:
        """``estimator.update()`` with the torque acting over [t_k, t_k+1]; ``valid`` is the
        estimator's own flag (0 at a (re)start and until the filter converged)."""
        if c.meas is None or not self.supervisor.ok or self.estimator is None:
            return
        if link is not None:
            link.cycle = c.k
        try:
            c.est = self.estimator.update(c.q, c.theta_m, self._tau)
            c.valid = 1.0 if c.est.valid else 0.0
        except Exception as e:  # noqa: BLE001
            self._failed(e, c.k, c.start)

    def _publish(self, c: CycleState) -> None:
        """The estimate (None when invalid or faulted), the torque, the latched fault and the
        angles the estimate was made from — a missed sample's extrapolation, not the held values."""
        self.last_estimate = c.est if c.valid else None
        if self.publisher is not None:
            self.publisher.publish(c.k, c.meas, self.last_estimate, self._tau, self.supervisor.latched,
                                   c.q if c.meas is not None else None)

    def _record(self, c: CycleState, link) -> None:
        """The caller's ``on_cycle``, then one row into the log writer — in every cycle; a log
        that cannot be written latches LOG_FAILED (once, again after a reset)."""
        if self.on_cycle is not None:
            self.on_cycle(c.k, c.meas, c.est, self._tau)
        if self.estimator is not None:
            # the cycle's validity, or why not (the run summary's counts)
            why = (VALID if c.valid else FAULT if not self.supervisor.ok else NO_SAMPLE if c.est is None
                   else getattr(c.est, "invalid_reason", STARTUP))
            self.stats.validity[why] += 1
        done = self.clock()
        if self.log is None:
            return
        self._fill_row(c, link, done)
        self.log.append(self._log_row)
        lost = self.log.fault()
        if lost is not None and (self.supervisor.ok or not self._log_fault_seen):
            self._log_fault_seen = True
            self._trip(Fault.LOG_FAILED, c.k, c.start, lost)

    def _fill_row(self, c: CycleState, link, done: float) -> None:
        """The cycle's log row (docs/interfaces.md §1) in the preallocated vector."""
        row, L = self._row, self.layout
        meas = c.meas
        t_row, period = self._t_row, self.period
        if meas is not None:
            # the hardware's time is whole periods; one that did not move on past a placeholder
            # row (a read that failed before its SYNC) continues from it
            t = meas.t
            t = float(t if t > t_row + 0.5 * period else t_row + period)
            row[L.q] = c.q
            row[L.theta_m] = c.theta_m
        else:
            # no sample: the last measured angles held (zero before the first), the time one period on
            t = t_row + period if c.k else 0.0
        row[L.t] = self._t_row = t
        row[L.tau_m] = self._tau
        est = c.est if c.valid else None
        if est is not None:
            row[L.tau_h_act_hat] = est.tau_h_act_hat
            row[L.tau_h_act_bound] = est.tau_h_act_bound
            row[L.tau_h_act_sigma] = est.tau_h_act_sigma
        else:
            row[L.estimate] = 0.0
        start = c.start
        # valid, fault, cycle, period, compute, read, measured, and the cycle of the sample the
        # published ρ belongs to (bound_cycle: the worker's bound lags)
        row[self._loop_cols] = (c.valid, float(self.supervisor.latched), c.k, start - self._last_start,
                                done - start, c.t_read - start, 1.0 if c.measured else 0.0,
                                -1.0 if est is None else (c.k if link is None else link.bound_cycle))
        # beyond the CSV's columns, for the log writer's sinks (the LSL stream, the MCAP file)
        row[L.cycle_start] = c.start
        if self._assist is not None and self.supervisor.ok:
            row[L.tau_assist] = self._assist
        else:
            row[L.tau_assist] = 0.0

    def _keep_alive(self, c: CycleState, link) -> None:
        """The cycle's sample to the bound worker (it computes while the loop sleeps; a worker
        that died or fell a whole ring behind: BOUND_LOST, once, again after a reset while it
        lasts), WATCHDOG=1, and the cycle's CPU time and period when recorded."""
        sup, k = self.supervisor, c.k
        if link is not None:
            link.flush()
            gone = link.fault()
            if gone is not None and (sup.ok or not self._bound_fault_seen):
                self._bound_fault_seen = True
                self._trip(Fault.BOUND_LOST, k, c.start, gone)
        # the loop is alive: WATCHDOG=1 even while a fault is latched, so systemd restarts
        # only a stuck loop and never clears a latched fault behind the operator's back
        if self.notifier is not None:
            self.notifier.watchdog()
        if self.record_periods:
            cpu = self.cpu_clock()
            self.stats.cpu.append(cpu - self._cpu_end)
            self._cpu_end = cpu
            if k > 0:
                self.stats.periods.append(c.start - self._last_start)
        self._last_start = c.start

    def _pace(self, k: int) -> None:
        """Sleep until ``t0 + k·period`` (k cycles done); a late wake-up is an overrun of cycle
        k − 1, deadlines missed by a whole period or more are skipped (re-phased), not caught up;
        more skipped in a row than ``stall_cycles``: LOOP_STALL."""
        if not self.realtime:
            return
        st, sup = self.stats, self.supervisor
        deadline = self._t0 + k * self.period
        now = self.clock()
        late = now - deadline
        if self.record_periods:
            st.late.append(late)
        if late > 0:
            st.overruns += 1
            st.max_late_s = max(st.max_late_s, late)
            if late >= self.period:
                # skip the deadlines already missed: re-phase instead of a catch-up burst
                skip = int(late // self.period)
                st.skipped += skip
                self._t0 += skip * self.period
                if self.stall_cycles is not None and skip > self.stall_cycles and k > 1 and sup.loop_stall:
                    # as many cycles without a SYNC, a sample or a new command as the stall
                    # lasted: beyond what a missing TPDO may take (the first cycle of a run, its
                    # start-up — the first calls into the estimator and the publisher — aside)
                    self._trip(Fault.LOOP_STALL, k - 1, now,
                               f"the loop stalled {late * 1e3:.1f} ms: {skip} cycles skipped in a row, "
                               f"{self.stall_cycles} tolerated (hardware.bus.max_missed_ms / max_missed_cycles)")
            if sup.overrun(True, k - 1, now):
                self._latched()
        else:
            sup.overrun(False, k - 1, now)
            self.sleep(-late)
