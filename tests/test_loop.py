"""The fixed-rate loop and its fault policy, with test doubles for hardware and estimator."""
import types

import numpy as np
import pytest

from sea_daemon.hw.interface import HardwareInterface
from sea_daemon.core.log import log_columns
from sea_daemon.runtime.loop import FixedRateLoop
from sea_daemon.errors import Fault
from sea_daemon.runtime.safety import SafetySupervisor
from sea_daemon.errors import EstimatorFault, HardwareError, fault_of


class HeartbeatLost(HardwareError):
    fault = Fault.HEARTBEAT_LOST


class FakeHW(HardwareInterface):
    def __init__(self, fail_at=None, exc=HeartbeatLost("drive heartbeat missing for 120 ms")):
        self.n, self.period = 1, 0.01
        self.k = 0
        self.fail_at, self.exc = fail_at, exc
        self.writes = []
        self.safe_stops = []

    def read(self):
        k = self.k
        self.k += 1
        if self.fail_at is not None and k >= self.fail_at:
            raise self.exc
        return types.SimpleNamespace(t=k * 0.01, q=np.array([0.1]), theta_m=np.array([0.09]))

    def write(self, tau):
        self.writes.append((self.k - 1, float(tau[0])))

    def safe_stop(self):
        self.safe_stops.append(self.k - 1)

    def start(self, initial_torque=None):
        pass

    def stop(self):
        pass


class ConstEstimator:
    def __init__(self, nan_at=None):
        self.k = 0
        self.nan_at = nan_at

    def reset(self, q=None, theta_m=None, tau_m=None):
        pass

    def update(self, q, theta_m, tau_m, dt=None):
        self.k += 1
        if self.nan_at is not None and self.k > self.nan_at:
            raise EstimatorFault("state became non-finite")
        return types.SimpleNamespace(tau_h_act_hat=np.array([0.5]), tau_h_act_bound=np.array([0.2]),
                                     tau_h_act_sigma=np.array([0.1]), valid=True)


class Push:
    def update(self, t, q, theta_m, est):
        return np.array([1.5])


class ListLog:
    def __init__(self):
        self.rows = []

    def append(self, row):
        self.rows.append(row.copy())
        return True

    def fault(self):
        return None


def make(hw, est, **kw):
    return FixedRateLoop(hw, est, Push(), n=1, period=0.01, log=ListLog(), realtime=False, **kw)


def test_hardware_fault_zeroes_torque_in_the_same_cycle_and_latches():
    hw = FakeHW(fail_at=30)
    loop = make(hw, ConstEstimator())
    loop.run(60)
    assert loop.supervisor.latched == Fault.HEARTBEAT_LOST and loop.supervisor.latched_cycle == 30
    assert hw.safe_stops == [30]
    writes = dict(hw.writes)
    assert all(writes[k] == 1.5 for k in range(30))
    assert all(writes[k] == 0.0 for k in range(30, 60))       # zero from the faulty cycle on
    assert "reset needed" in loop.supervisor.status_line()


def test_estimator_fault_never_publishes_nan_and_reset_is_explicit():
    hw = FakeHW()
    loop = make(hw, ConstEstimator(nan_at=10))
    loop.run(20)
    rows = np.array(loop.log.rows)
    cols = log_columns(1)
    valid = rows[:, cols.index("valid")]
    assert np.all(np.isfinite(rows))
    assert valid[:10].all() and not valid[10:].any()
    assert loop.supervisor.latched == Fault.ESTIMATOR_NONFINITE
    loop.estimator.nan_at = None
    loop.run(5)  # still latched: the cause went away, but nobody reset
    assert loop.supervisor.latched == Fault.ESTIMATOR_NONFINITE
    loop.request_reset()
    loop.stats = type(loop.stats)()
    loop.run(3)
    assert loop.supervisor.ok and dict(hw.writes)[hw.k - 1] == 1.5


def test_overrun_streak_trips():
    t = [0.0]

    def clock():
        return t[0]

    def slow_hw_read_clock():
        t[0] += 0.02   # every cycle takes two periods

    hw = FakeHW()
    orig = hw.read

    def read():
        slow_hw_read_clock()
        return orig()

    hw.read = read
    loop = FixedRateLoop(hw, ConstEstimator(), Push(), n=1, period=0.01, clock=clock, sleep=lambda s: None,
                         supervisor=SafetySupervisor(overrun_streak=5))
    st = loop.run(10)
    assert st.overruns == 10
    assert loop.supervisor.latched == Fault.OVERRUN_STREAK
    assert loop.supervisor.latched_cycle == 4            # the fifth overrun cycle: 0..4
    assert hw.safe_stops == [4]


def test_fault_mapping_by_exception_type():
    assert fault_of(HeartbeatLost("x")) == Fault.HEARTBEAT_LOST
    assert fault_of(EstimatorFault("P is not positive definite", fault=Fault.COVARIANCE_NOT_PD)) == Fault.COVARIANCE_NOT_PD
    assert fault_of(RuntimeError("?")) == Fault.INTERNAL


def test_fault_is_carried_by_the_exception_not_its_name():
    """Every exception of the hierarchy carries its Fault; the class name plays no part."""
    from sea_daemon.core.estimators.health import CovarianceNotPD
    from sea_daemon.errors import InputError, RunFault
    from sea_daemon.hw.errors import BusOff, DriveFault, PdoTimeout

    class SendTimeoutHeartbeatError(Exception):      # a foreign exception whatever its name says
        pass

    assert fault_of(EstimatorFault("state became non-finite")) == Fault.ESTIMATOR_NONFINITE
    assert fault_of(CovarianceNotPD("P")) == Fault.COVARIANCE_NOT_PD
    assert fault_of(HardwareError("?")) == Fault.DEVICE_FAULT
    assert fault_of(PdoTimeout(1, 0x181, 3, 0.01)) == Fault.TPDO_MISSING
    assert fault_of(BusOff("x")) == Fault.BUS_OFF
    assert fault_of(DriveFault(1, 0x08, "FAULT")) == Fault.DEVICE_FAULT
    assert fault_of(InputError("x")) == fault_of(RunFault("x")) == Fault.INTERNAL
    assert fault_of(SendTimeoutHeartbeatError()) == Fault.INTERNAL
    # a wrapping estimator fault passes the wrapped one's on
    assert EstimatorFault("log.csv: sample 3", fault=CovarianceNotPD("P").fault).fault == Fault.COVARIANCE_NOT_PD


class TorqueRecorder(ConstEstimator):
    def __init__(self):
        super().__init__()
        self.taus = []

    def update(self, q, theta_m, tau_m, dt=None):
        self.taus.append(float(tau_m[0]))
        return super().update(q, theta_m, tau_m)


class Ramp:
    def update(self, t, q, theta_m, est):
        return np.array([round(t * 100) + 1.0])      # cycle k commands k + 1


@pytest.mark.parametrize("delay", [0, 1])
def test_estimator_and_log_get_the_torque_acting_over_the_cycle(delay):
    """Row k / update k carry the torque over [t_k, t_k+1]: this cycle's command with an
    asynchronous RPDO (delay 0), the previous one with a synchronous RPDO (delay 1)."""
    hw = FakeHW()
    hw.actuation_delay = delay
    est = TorqueRecorder()
    loop = FixedRateLoop(hw, est, Ramp(), n=1, period=0.01, log=ListLog(), realtime=False,
                         initial_torque=np.array([-7.0]))
    loop.run(5)
    expect = [1.0, 2.0, 3.0, 4.0, 5.0] if delay == 0 else [-7.0, 1.0, 2.0, 3.0, 4.0]
    assert est.taus == expect
    rows = np.array(loop.log.rows)
    assert list(rows[:, log_columns(1).index("tau_m")]) == expect
    assert [w for _, w in hw.writes] == [1.0, 2.0, 3.0, 4.0, 5.0]


def test_missed_deadlines_are_skipped_not_caught_up():
    t = [0.0]
    hw = FakeHW()
    orig = hw.read

    def read():
        if hw.k == 3:
            t[0] += 0.035          # one cycle takes 3.5 periods
        return orig()

    hw.read = read
    sleeps = []

    def sleep(s):
        sleeps.append(s)
        t[0] += s

    loop = FixedRateLoop(hw, ConstEstimator(), Push(), n=1, period=0.01, clock=lambda: t[0], sleep=sleep,
                         supervisor=SafetySupervisor(overrun_streak=5))
    st = loop.run(8)
    assert st.overruns == 1 and st.skipped == 2 and loop.supervisor.ok   # ends at 65 ms: 50, 60 ms missed
    # after the overrun the loop sleeps again to the re-phased deadlines: no burst of zero-length cycles
    assert len(sleeps) == 7 and all(s > 0 for s in sleeps)


class CountingNotifier:
    def __init__(self):
        self.watchdogs = 0
        self.statuses = []

    def watchdog(self):
        self.watchdogs += 1

    def status(self, text):
        self.statuses.append(text)


def test_watchdog_keeps_going_while_latched_so_systemd_never_clears_the_fault():
    hw = FakeHW(fail_at=5)
    nt = CountingNotifier()
    loop = make(hw, ConstEstimator(), notifier=nt)
    loop.run(20)
    assert loop.supervisor.latched == Fault.HEARTBEAT_LOST
    assert nt.watchdogs == 20                          # alive loop: every cycle, latched or not
    assert len(nt.statuses) == 1 and nt.statuses[0].startswith("FAULT HEARTBEAT_LOST")


def test_failed_operator_reset_stays_latched_and_loop_keeps_running():
    hw = FakeHW(fail_at=3)
    loop = make(hw, ConstEstimator())
    loop.run(6)
    assert loop.supervisor.latched == Fault.HEARTBEAT_LOST

    def reset_fault():
        raise HeartbeatLost("SDO timeout while re-enabling the drive")
    hw.reset_fault = reset_fault
    loop.request_reset()
    loop.run(4)                                         # no exception escapes the loop
    assert loop.supervisor.latched == Fault.HEARTBEAT_LOST
    assert "operator reset failed" in loop.supervisor.latched_detail
    assert all(tau == 0.0 for k, tau in hw.writes if k >= 3)


def test_a_row_in_every_cycle_through_failed_reads_and_time_keeps_increasing():
    """Reads that fail before the hardware's clock moves (an EMCY before the SYNC) get placeholder
    rows one period apart; the next sample continues after them (docs/interfaces.md §1)."""
    class StallingHW(FakeHW):
        def __init__(self):
            super().__init__()
            self.samples = 0

        def read(self):
            self.k += 1
            if 20 <= self.k - 1 < 25:
                raise HeartbeatLost("no heartbeat")
            self.samples += 1
            return types.SimpleNamespace(t=self.samples * 0.01, q=np.array([0.1 + 0.001 * self.k]),
                                         theta_m=np.array([0.09]))

    hw = StallingHW()
    loop = make(hw, ConstEstimator())
    loop.run(40)
    cols = log_columns(1)
    rows = np.array(loop.log.rows)
    col = {c: rows[:, cols.index(c)] for c in cols}
    assert len(rows) == 40 and np.array_equal(col["cycle"], np.arange(40)) and np.all(np.isfinite(rows))
    assert np.all(np.diff(col["t"]) > 0.005)                       # strictly increasing, by whole periods
    assert list(col["measured"][18:27]) == [1, 1, 0, 0, 0, 0, 0, 1, 1]
    assert np.all(col["q"][20:25] == col["q"][19])                 # the last measured angles held
    assert np.all(col["fault"][20:] == int(Fault.HEARTBEAT_LOST)) and not col["valid"][20:].any()
    assert np.all(col["tau_m"][20:] == 0.0)


def test_a_log_that_fails_latches_LOG_FAILED_once_and_again_after_a_reset():
    class FailingLog(ListLog):
        def fault(self):
            return "log x.csv: No space left on device" if len(self.rows) > 10 else None

    hw = FakeHW()
    loop = FixedRateLoop(hw, ConstEstimator(), Push(), n=1, period=0.01, log=FailingLog(), realtime=False)
    loop.run(20)
    sup = loop.supervisor
    assert sup.latched == Fault.LOG_FAILED and sup.latched_cycle == 10 and sup.trips == 1
    assert hw.safe_stops == [10] and all(tau == 0.0 for k, tau in hw.writes if k > 10)
    loop.request_reset()
    loop.run(3)
    assert sup.latched == Fault.LOG_FAILED and sup.trips == 2       # a dead log is not cleared by a reset


def test_a_sample_the_hardware_missed_goes_on_extrapolated_not_held():
    """A sample the hardware missed within its tolerance (valid False, the driver's values held)
    reaches the controller, the estimator, the publication and the log as the constant-velocity extrapolation of
    the two samples before it (measured 0), not as the held angles; two misses in a row go on
    at that velocity."""

    class Ramp(FakeHW):
        missing = {5, 9, 10}

        def read(self):
            k = self.k
            self.k += 1
            held = k in self.missing
            j = max(m for m in range(k + 1) if m not in self.missing)      # the last sample received
            q = 0.1 + 0.01 * j + 0.001 * j * j
            return types.SimpleNamespace(t=k * 0.01, q=np.array([q]), theta_m=np.array([0.5 * q]), valid=not held)

    class Rec(ConstEstimator):
        def __init__(self):
            super().__init__()
            self.got = []

        def update(self, q, theta_m, tau_m, dt=None):
            self.got.append((float(q[0]), float(theta_m[0])))
            return super().update(q, theta_m, tau_m, dt)

    class RecCtl:
        def __init__(self):
            self.got = []

        def update(self, t, q, theta_m, est):
            self.got.append(float(q[0]))
            return np.array([1.0])

    class RecPub:
        def __init__(self):
            self.got = []

        def publish(self, k, meas, est, tau, fault, q=None):
            self.got.append(float(q[0]))

    est, ctl, pub = Rec(), RecCtl(), RecPub()
    loop = FixedRateLoop(Ramp(), est, ctl, n=1, period=0.01, log=ListLog(), realtime=False, publisher=pub)
    loop.run(14)
    x = [0.1 + 0.01 * j + 0.001 * j * j for j in range(14)]
    want = list(x)
    want[5] = 2 * x[4] - x[3]
    want[9] = 2 * x[8] - x[7]
    want[10] = 2 * want[9] - x[8]
    got_q = [g[0] for g in est.got]
    np.testing.assert_allclose(got_q, want, rtol=0, atol=1e-15)
    np.testing.assert_allclose([g[1] for g in est.got], 0.5 * np.array(want), rtol=0, atol=1e-15)
    np.testing.assert_allclose(ctl.got, want, rtol=0, atol=1e-15)
    np.testing.assert_allclose(pub.got, want, rtol=0, atol=1e-15)      # the local readers see them too
    rows = np.array(loop.log.rows)
    cols = log_columns(1)
    np.testing.assert_allclose(rows[:, cols.index("q")], want, rtol=0, atol=1e-15)
    assert [k for k in range(14) if rows[k, cols.index("measured")] == 0.0] == [5, 9, 10]
    assert loop.stats.extrapolated == 3
    # on this ramp (20 rad/s² at 100 Hz) the extrapolation is off by the second difference,
    # 0.002 rad, the held value by the step, 0.019 rad
    assert abs(want[5] - x[5]) == pytest.approx(0.002) and abs(x[4] - x[5]) == pytest.approx(0.019)


def test_without_two_samples_before_a_missed_one_goes_on_held():
    """No history (the first samples; after a failed read or a reset): nothing to extrapolate
    from, the held values go on as the hardware gave them (measured 0 all the same)."""

    class Hw(FakeHW):
        def read(self):
            k = self.k
            self.k += 1
            return types.SimpleNamespace(t=k * 0.01, q=np.array([0.1 + 0.01 * min(k, 1)]), theta_m=np.array([0.0]),
                                         valid=k != 1)

    est = ConstEstimator()
    got = []
    orig = est.update
    est.update = lambda q, th, tau, dt=None: (got.append(float(q[0])), orig(q, th, tau))[1]
    loop = FixedRateLoop(Hw(), est, Push(), n=1, period=0.01, log=ListLog(), realtime=False)
    loop.run(3)
    assert got == [0.1, 0.11, 0.11]
    assert loop.stats.extrapolated == 0
    assert [r[log_columns(1).index("measured")] for r in loop.log.rows] == [1.0, 0.0, 1.0]


def test_cycle_keeps_no_allocation():
    """The loop's steps hand the cycle on in preallocated state: cycles leave no allocated
    block behind (a per-cycle list, dict or array kept would grow the count with the cycles)."""
    import gc
    import sys

    class Log:
        def append(self, row):
            pass

        def fault(self):
            return None

    t = [0.0]

    def clock():
        t[0] += 1e-3
        return t[0]

    hw = FakeHW()
    hw.write = lambda tau: None
    loop = FixedRateLoop(hw, ConstEstimator(), Push(), n=1, period=0.01, log=Log(), clock=clock,
                         sleep=lambda s: None, cpu_clock=clock)
    loop.run(500)
    gc.collect()
    gc.disable()
    try:
        before = sys.getallocatedblocks()
        loop.run(10000)
        grown = sys.getallocatedblocks() - before
    finally:
        gc.enable()
    assert grown < 200, grown               # less than one block per 50 cycles: none per cycle


@pytest.mark.parametrize("record", [False, True])
def test_the_threads_cpu_clock_is_read_once_a_cycle_and_only_when_recorded(record):
    """The thread's CPU clock is a system call: none per cycle unless the CPU is recorded, then
    one, each cycle's CPU running from the end of the cycle before (the pacing included)."""
    reads = []

    def cpu_clock():
        reads.append(None)
        return 0.25 * len(reads) ** 2               # distinct steps: each cycle's share is known

    loop = make(FakeHW(), ConstEstimator(), cpu_clock=cpu_clock, record_periods=record)
    loop.run(5)
    if not record:
        assert reads == []
        return
    assert len(reads) == 6                          # the start, then one per cycle
    assert list(np.asarray(loop.stats.cpu)) == [0.25 * ((i + 1) ** 2 - i ** 2) for i in range(1, 6)]
