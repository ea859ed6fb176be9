"""``python -m benchmarks.rt_budget``: what the kernel's budget for real-time tasks does to a
periodic real-time task when another real-time task keeps their CPU busy.

Two processes pinned to one CPU (``--cpu``, default the last): a SCHED_FIFO 60 process busy for
``--duty`` of every 1 ms (1.0: without pause, as a bound worker whose step costs more than the
period) and a SCHED_FIFO 70 process that wakes every 1 ms (as the device model answering SYNC)
and records every gap between two wake-ups longer than ``--gap-ms``.  The kernel gives
real-time tasks ``sched_rt_runtime_us`` of every ``sched_rt_period_us`` of a CPU; past it every
real-time task on that CPU, the higher priority too, is stopped for the rest of the period.
Printed: the budget, the wake-ups, each long gap (when, how long) and the load average.

The busy process keeps that CPU for ``--seconds`` (default 3): run it on a machine you may
disturb.  Needs SCHED_FIFO (root or CAP_SYS_NICE); without it, exit 2 with the reason.
"""
from __future__ import annotations

import os
import sys
import time

from sea_daemon.errors import InputError


def _budget() -> str:
    try:
        with open("/proc/sys/kernel/sched_rt_runtime_us") as f:
            rt = f.read().strip()
        with open("/proc/sys/kernel/sched_rt_period_us") as f:
            per = f.read().strip()
    except OSError:
        return "unknown (no /proc/sys/kernel/sched_rt_*)"
    return f"{rt} us of every {per} us of a CPU"


def _busy(cpu: int, duty: float, seconds: float) -> None:
    """The SCHED_FIFO 60 process: busy for ``duty`` ms of every 1 ms, then exits."""
    os.sched_setaffinity(0, {cpu})
    os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(60))
    end = time.monotonic() + seconds
    busy = duty * 1e-3
    while True:
        t0 = time.monotonic()
        if t0 > end:
            os._exit(0)
        while time.monotonic() - t0 < busy:
            pass
        if duty < 1.0:
            time.sleep(1e-3 - busy)


NAME = "rt_budget"
HELP = ("what the kernel's budget for real-time tasks does to a periodic SCHED_FIFO task when another "
        "keeps their CPU busy")


def add_arguments(p) -> None:
    p.add_argument("--duty", type=float, default=1.0, help="share of every 1 ms the busy process computes (0..1)")
    p.add_argument("--seconds", type=float, default=3.0, help="how long (default 3 s)")
    p.add_argument("--cpu", type=int, default=(os.cpu_count() or 1) - 1, help="the CPU both run on (default the last)")
    p.add_argument("--gap-ms", type=float, default=3.0, help="gaps between wake-ups longer than this are listed")


def run(a) -> int:
    cpus = sorted(os.sched_getaffinity(0))
    if not 0.0 <= a.duty <= 1.0:
        raise InputError(f"--duty must be in 0..1, got {a.duty}")
    if not 0.0 < a.seconds <= 60.0:
        raise InputError(f"--seconds must be in (0, 60], got {a.seconds}")
    if a.cpu not in cpus:
        raise InputError(f"--cpu must be one of {cpus}, got {a.cpu}")
    if not a.gap_ms > 1.0:
        raise InputError(f"--gap-ms must be > 1, got {a.gap_ms}")
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(70))
    except (OSError, AttributeError) as e:
        raise InputError(f"SCHED_FIFO not permitted here ({e}): needs root or CAP_SYS_NICE") from None
    os.sched_setaffinity(0, {a.cpu})
    pid = os.fork()
    if pid == 0:
        _busy(a.cpu, a.duty, a.seconds)
    start = last = time.monotonic()
    gaps, n = [], 0
    while last - start < a.seconds:
        time.sleep(1e-3)
        now = time.monotonic()
        if now - last > a.gap_ms * 1e-3:
            gaps.append((now - start, (now - last) * 1e3))
        last = now
        n += 1
    os.waitpid(pid, 0)
    os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    print(f"kernel budget for real-time tasks: {_budget()}")
    print(f"CPU {a.cpu}: a SCHED_FIFO 60 process busy {a.duty * 1e3:.0f} us of every 1000 us; a SCHED_FIFO 70 process "
          f"woke {n} times in {a.seconds:g} s (every 1 ms asked)")
    print(f"gaps > {a.gap_ms:g} ms between its wake-ups: " + (", ".join(f"{g:.1f} ms at {t:.2f} s" for t, g in gaps)
                                                             or "none"))
    print("load average " + " ".join(f"{v:.2f}" for v in os.getloadavg()) + " (1/5/15 min)")
    return 0


if __name__ == "__main__":
    from benchmarks._cli import main
    sys.exit(main(sys.modules[__name__]))
