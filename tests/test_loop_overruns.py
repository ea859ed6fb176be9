"""``bench loop``'s overrun anatomy: the loop's per-cycle records of how late each cycle started
and ended, and where the time of each overrun went (``apps/bench/_loop_overruns.py``)."""
import numpy as np
import pytest

from sea_daemon.apps.bench._loop_overruns import describe, overrun_anatomy
from sea_daemon.runtime.loop import FixedRateLoop
from tests.test_loop import ConstEstimator, FakeHW, ListLog, Push

PERIOD = 1e-3


def _cycles(n=50):
    """Normal cycles: start 30 us late, read 200, work 120, tail 30 us (ends 620 us before the
    next deadline), 300 us of CPU."""
    wake = np.full(n, 30e-6)
    read = np.full(n, 200e-6)
    compute = read + 120e-6
    tail = np.full(n, 30e-6)
    cpu = np.full(n, 300e-6)
    return wake, read, compute, tail, cpu


def _late(wake, compute, tail):
    return wake + compute + tail - PERIOD


def test_each_overrun_is_put_down_to_the_part_that_ran_long():
    wake, read, compute, tail, cpu = _cycles()
    read[10] += 900e-6                                   # the devices answered late
    compute[10] += 900e-6
    wake[20] += 1.5e-3                                   # the sleep returned late ...
    compute[30] += 800e-6                                # the cycle's own CPU
    cpu[30] += 780e-6
    compute[40] += 800e-6                                # off its CPU: wall without CPU
    tail[45] += 900e-6                                   # after the log row, off CPU
    wake[21] = _late(wake, compute, tail)[20]            # ... the next one started late: a run-on
    late = _late(wake, compute, tail)
    a = overrun_anatomy(late, wake, compute, read, cpu, PERIOD)
    causes = {r["cycle"]: r["cause"] for r in a["worst"]}
    assert causes == {10: "device answer", 20: "late wake-up", 21: "run-on", 30: "own CPU", 40: "off CPU",
                      45: "off CPU"}
    assert a["overruns"] == 6 and sum(a["by_cause"].values()) == 6
    assert a["median_us"] == pytest.approx({"start": 30.0, "read": 200.0, "work": 120.0, "tail": 30.0})
    r10 = next(r for r in a["worst"] if r["cycle"] == 10)
    assert abs(r10["read_us"] - 1100) < 1e-6 and abs(r10["late_us"] - (30 + 1220 + 30 - 1000)) < 1e-6
    text = "\n".join(describe(a))
    assert "1 device answer" in text and "2 off CPU" in text and "1 run-on" in text


def test_the_start_up_cycle_and_cycles_in_time_are_not_overruns():
    wake, read, compute, tail, cpu = _cycles()
    late = _late(wake, compute, tail)
    late[0] = 5e-3                                       # the first cycle: its start-up
    a = overrun_anatomy(late, wake, compute, read, cpu, PERIOD)
    assert a["overruns"] == 0 and a["worst"] == []
    assert describe(a) == ["overruns by cause: none"]


def test_the_loop_records_how_late_each_cycle_started_and_ended():
    """With record_periods in real-time pace: ``wake`` (start past its own deadline) and ``late``
    (end past the next deadline; > 0 exactly for the overruns counted)."""
    now = [0.0]
    read_ends = iter([0.0002, 0.0013, 0.0031, 0.0035])   # cycle 2 ends past 3 ms: an overrun

    class SlowHW(FakeHW):
        def read(self):
            now[0] = max(now[0], next(read_ends))
            return super().read()

    def sleep(s):
        now[0] += s

    loop = FixedRateLoop(SlowHW(), ConstEstimator(), Push(), n=1, period=PERIOD, log=ListLog(), clock=lambda: now[0],
                         sleep=sleep, realtime=True, record_periods=True)
    st = loop.run(4)
    assert np.asarray(st.wake) == pytest.approx([0.0, 0.0, 0.0, 0.0001], abs=1e-12)
    assert np.asarray(st.late) == pytest.approx([-0.0008, -0.0007, 0.0001, -0.0005], abs=1e-12)
    assert st.overruns == 1


def test_the_loop_records_no_start_or_end_unless_asked():
    loop = FixedRateLoop(FakeHW(), ConstEstimator(), Push(), n=1, period=PERIOD, log=ListLog(), realtime=False,
                         record_periods=True)
    st = loop.run(5)
    assert len(st.wake) == 0 and len(st.late) == 0 and len(st.cpu) == 5


def test_the_kernels_preemption_model_as_far_as_the_machine_tells(tmp_path):
    from sea_daemon.runtime.realtime import kernel_preemption
    none = str(tmp_path / "absent")
    debugfs = tmp_path / "preempt"
    debugfs.write_text("none voluntary (full) lazy\n")
    cmdline = tmp_path / "cmdline"
    cmdline.write_text("console=ttyS0 preempt=voluntary quiet\n")
    dyn = "#1 SMP PREEMPT_DYNAMIC @0"
    assert kernel_preemption("#1 SMP PREEMPT_RT @0", str(debugfs), str(cmdline), none) == "PREEMPT_RT"
    assert kernel_preemption(dyn, str(debugfs), str(cmdline), none) == "full (PREEMPT_DYNAMIC)"
    assert kernel_preemption(dyn, none, str(cmdline), none).startswith("voluntary (preempt=")
    assert kernel_preemption(dyn, none, none, none) == "PREEMPT_DYNAMIC, its mode not readable here (the build's default)"
    assert kernel_preemption("#1 SMP PREEMPT @0", none, none, none) == "full (PREEMPT)"
    assert kernel_preemption("#1 SMP @0", none, none, none).startswith("none or voluntary")


def test_a_long_read_is_split_by_the_device_models_slow_answers():
    """The device model's slow answers (its cycle = the daemon's + 1): late without more CPU (it
    waited for its CPU), late with its handler's CPU, or in time (the loop took the TPDOs late)."""
    wake, read, compute, tail, cpu = _cycles()
    for j in (10, 20, 30):
        read[j] += 900e-6
        compute[j] += 900e-6
    late = _late(wake, compute, tail)
    device = {"slow": {11: (1050e-6, 95e-6),          # cycle 10: answered late, its CPU as usual
                       21: (1040e-6, 900e-6)},        # cycle 20: its handler took the time
              "answer": 150e-6, "cpu": 90e-6}         # cycle 30: answered in time
    a = overrun_anatomy(late, wake, compute, read, cpu, PERIOD, device=device)
    causes = {r["cycle"]: r["cause"] for r in a["worst"]}
    assert causes == {10: "model ran late", 20: "model's CPU", 30: "answer taken late"}
    assert overrun_anatomy(late, wake, compute, read, cpu, PERIOD)["by_cause"]["device answer"] == 3
