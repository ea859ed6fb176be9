"""CPU placement (affinity) of the real-time parts: the loop's thread, the bound worker's process
and, on a test bench, the device model's process.

The loop, the bound worker and a device model in its own process are SCHED_FIFO tasks.  Left to
the kernel, a task woken on a CPU whose current task has a lower priority preempts it there: the
device model answering a SYNC may land on the CPU of the worker, the worker on the loop's, and
each switch leaves the caches of the task that comes back cold.  ``--cpus LOOP[,WORKER]`` keeps
the loop alone on one CPU and the worker on another (docs/daemon.md "CPU placement"): the loop
process's other threads (the CAN drivers') and the log writer's process go to the CPUs other than
the loop's (:func:`keep_off`).  Not pinned by default.

:func:`parse_cpus` checks the option (each CPU one this process may run on: exit 2 with one line
otherwise); :func:`pin_thread` pins the calling thread (its threads started later inherit it),
:func:`pin_pid` another process (the worker, after it started), :func:`keep_off` moves this
process's other threads and a few processes off a CPU.
"""
from __future__ import annotations

import os
import threading

from sea_daemon.errors import InputError


def allowed_cpus() -> list[int]:
    """The CPUs this process may run on (``sched_getaffinity``; its cgroup's and taskset's limits)."""
    return sorted(os.sched_getaffinity(0))


def _ranges(cpus: list[int]) -> str:
    """``[0, 1, 2, 5]`` → ``"0-2, 5"``."""
    out, start = [], None
    for i, c in enumerate(cpus):
        if start is None:
            start = c
        if i + 1 == len(cpus) or cpus[i + 1] != c + 1:
            out.append(str(start) if start == c else f"{start}-{c}")
            start = None
    return ", ".join(out)


def parse_cpus(text: str | None, flag: str, names: tuple[str, ...]) -> tuple[int, ...] | None:
    """``text`` = ``"A[,B...]"``: one CPU per name of ``names`` at most (e.g. loop, worker), each one
    this process may run on; None for None or ``""``.  :class:`~sea_daemon.errors.InputError` (one
    line naming the value and the allowed range) otherwise."""
    if text is None or not str(text).strip():
        return None
    allowed = allowed_cpus()
    up = [n.upper().replace(" ", "_") for n in names]
    form = up[0] + "".join(f"[,{n}" for n in up[1:]) + "]" * (len(up) - 1)
    parts = [p.strip() for p in str(text).split(",")]
    if len(parts) > len(names) or not all(p.isdigit() for p in parts):
        raise InputError(f"{flag} {text}: allowed {form}, each a CPU number in {_ranges(allowed)}")
    cpus = tuple(int(p) for p in parts)
    for name, c in zip(names, cpus):
        if c not in allowed:
            raise InputError(f"{flag} {text}: the {name}'s CPU {c} is not one this process may run on "
                             f"(allowed: {_ranges(allowed)})")
    return cpus


def pin_thread(cpu: int | None) -> str:
    """Pin the calling thread to ``cpu`` (None: nothing); what applied, for the status line."""
    return pin_pid(0, cpu)                 # 0: the calling thread (sched_setaffinity)


def keep_off(cpu: int | None, pids=()) -> None:
    """Every thread of this process but the calling one, and the processes ``pids`` (their main
    threads), onto the CPUs allowed other than ``cpu`` (nothing for None, or with no other CPU)."""
    others = set(allowed_cpus()) - {cpu}
    if cpu is None or not others:
        return
    me = threading.get_native_id()
    try:
        tids = [int(t) for t in os.listdir("/proc/self/task")]
    except OSError:
        tids = []
    for tid in [t for t in tids if t != me] + [p for p in pids if p]:
        try:
            os.sched_setaffinity(tid, others)
        except OSError:
            pass                    # gone meanwhile, or not ours to move


def pin_pid(pid: int, cpu: int | None) -> str:
    """Pin the process (its main thread) ``pid`` — 0: the calling thread — to ``cpu`` (None:
    nothing); what applied."""
    if cpu is None:
        return "not pinned"
    try:
        os.sched_setaffinity(pid, {cpu})
    except OSError as e:
        return f"not pinned to CPU {cpu} ({e.strerror or e})"
    return f"CPU {cpu}"
