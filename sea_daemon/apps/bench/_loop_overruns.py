"""``bench loop``: where the time of each overrun went, from the loop's per-cycle records.

An overrun is a cycle that ended after the next cycle's deadline (:class:`~sea_daemon.runtime.loop.FixedRateLoop`'s
pacing).  From the start of cycle j's period (its deadline) to its end, the time splits into

* **start**: how late the cycle started after its deadline (``LoopStats.wake``): a sleep that
  returned late (a late wake-up of the loop's thread), or the cycle before ran past it;
* **read**: ``hw.read()``, the SYNC to the cycle's TPDOs (the log's ``read``): mostly the wait
  for the devices' answer;
* **work**: the rest of the cycle up to its log row (controller, write, estimator, publication,
  the log's ``compute`` minus ``read``);
* **tail**: from the log row to the pacing (the caller's recorder, the bound worker's hand-over,
  the watchdog).

Each overrun is put down to the part furthest above that part's median over the run (the
normal cycle), and an overrun whose start was late because the cycle before overran is counted
as such (a run-on, not a cause of its own).  A **work** or **tail** overrun is split by the
loop thread's CPU time of the cycle (``LoopStats.cpu``): if the CPU time grew by at least half
the excess, the cycle's own work (CPU); else the thread was off its CPU (preempted, or held in
the kernel).  With the device model's slow answers (its ``answer_stats``' ``slow_answers``:
cycle, SYNC → last TPDO and its handler's CPU), a **device answer** is split: the model answered
late without more CPU (it waited for its CPU: **model ran late**), its handler took the time
(**model's CPU**), or it answered in time and the loop thread took the TPDOs late (**answer
taken late**).
"""
from __future__ import annotations

import numpy as np

PARTS = ("start", "read", "work", "tail")
CAUSES = {
    "run-on": "started late because the cycle before overran",
    "late wake-up": "the sleep before it returned late",
    "device answer": "hw.read() long (waiting for the devices' TPDOs)",
    "model ran late": "hw.read() long: the device model answered late without more CPU (it waited for its CPU)",
    "model's CPU": "hw.read() long: the device model's SYNC handler took more CPU",
    "answer taken late": "hw.read() long: the device model answered in time, the loop thread took the TPDOs late",
    "own CPU": "the cycle's own work took more CPU",
    "off CPU": "the loop thread was off its CPU during its work (preempted, or held in the kernel)",
}


def _part_times(late, wake, compute, read, period: float) -> np.ndarray:
    """(cycles, 4) start / read / work / tail [s] of each cycle (module docstring)."""
    total = period + late - wake                       # the cycle's wall time, start to pacing
    return np.column_stack([wake, read, compute - read, total - compute])


def _device_cause(j: int, excess: float, device: dict) -> str:
    """Which side of a long read of cycle j (``excess`` over the median read [s]): ``device``
    holds ``slow`` {device cycle: (answer, handler CPU) [s]} and the medians ``answer``, ``cpu``
    [s].  The daemon's cycle k is the device's cycle k + 1 (the start-up's priming SYNC is its
    first); a cycle or so either way is searched."""
    slow = device["slow"]
    for c in (j + 1, j, j + 2):
        if c in slow:
            answer, cpu = slow[c]
            return "model's CPU" if cpu - device["cpu"] >= 0.5 * (answer - device["answer"]) else "model ran late"
    return "answer taken late"


def overrun_anatomy(late, wake, compute, read, cpu, period: float, skip: int = 1, worst: int = 10,
                    device: dict | None = None) -> dict:
    """Where the time of each overrun went (module docstring).

    Arrays per cycle j (the same length): ``late`` at the end of cycle j past the next deadline,
    ``wake`` its start past its own deadline, ``compute`` start → log row, ``read`` the read's
    wall time, ``cpu`` the loop thread's CPU of the cycle — all [s]; the first ``skip`` cycles
    (the start-up) are left out; ``device`` (None: not split) the device model's slow answers
    (:func:`_device_cause`).  Returns the count per
    cause, the medians of the parts [µs] and the ``worst`` overruns (latest first), each with its
    parts [µs] and cause."""
    k = min(len(late), len(wake), len(compute), len(read), len(cpu))
    late, wake, compute, read, cpu = (np.asarray(a, dtype=float)[:k] for a in (late, wake, compute, read, cpu))
    parts = _part_times(late, wake, compute, read, period)
    normal = parts[skip:]
    med = np.median(normal, axis=0) if normal.size else np.zeros(len(PARTS))
    cpu_med = float(np.median(cpu[skip:])) if k > skip else 0.0
    counts = {c: 0 for c in CAUSES}
    rows = []
    for j in np.flatnonzero(late > 0):
        if j < skip:
            continue
        excess = parts[j] - med
        part = PARTS[int(np.argmax(excess))]
        if part == "start":
            cause = "run-on" if j > 0 and late[j - 1] > 0 else "late wake-up"
        elif part == "read":
            cause = "device answer" if device is None else _device_cause(int(j), excess[1], device)
        else:
            cause = "own CPU" if cpu[j] - cpu_med >= 0.5 * excess[PARTS.index(part)] else "off CPU"
        counts[cause] += 1
        rows.append({"cycle": int(j), "late_us": late[j] * 1e6, "cause": cause, "cpu_us": cpu[j] * 1e6,
                     **{f"{p}_us": float(parts[j, i] * 1e6) for i, p in enumerate(PARTS)}})
    rows.sort(key=lambda r: -r["late_us"])
    return {"overruns": len(rows), "by_cause": counts,
            "median_us": {p: float(med[i] * 1e6) for i, p in enumerate(PARTS)}, "cpu_median_us": cpu_med * 1e6,
            "worst": rows[:worst]}


def describe(anatomy: dict) -> list[str]:
    """The printed lines of :func:`overrun_anatomy`'s result."""
    if not anatomy["overruns"]:
        return ["overruns by cause: none"]
    med = anatomy["median_us"]
    lines = ["overruns by cause (the part of the cycle furthest above its median; medians "
             + ", ".join(f"{p} {med[p]:.0f}" for p in PARTS) + " us): "
             + "; ".join(f"{n} {cause} ({CAUSES[cause]})" for cause, n in anatomy["by_cause"].items() if n)]
    for r in anatomy["worst"][:5]:
        lines.append(f"  cycle {r['cycle']}: {r['late_us']:.0f} us late, {r['cause']}; start {r['start_us']:.0f}, "
                     f"read {r['read_us']:.0f}, work {r['work_us']:.0f}, tail {r['tail_us']:.0f} us, "
                     f"loop thread CPU {r['cpu_us']:.0f} us")
    return lines
