"""The single fault policy of the daemon.

Policy (docs/safety.md says the same in prose):

* Any fault — a TPDO missing for k cycles, heartbeat timeout, EMCY, an encoder jump or a
  stuck encoder, bus-off or a failed send, NaN/inf or a covariance that lost positive
  definiteness in the estimator, NIS divergence, a streak of loop overruns, a stall of the loop
  longer than the missed-cycle tolerance — **latches**.
* In the same cycle the loop commands zero torque (and asks the drive for quick stop), the
  estimate is flagged invalid (``valid = 0`` in the log, NaN is never published), the cause
  is recorded with its cycle and monotonic time, and systemd is told with ``STATUS=``.
* A latched fault is cleared only by an explicit operator action (``sea-daemon reset`` or a
  restart), never silently, even if the cause goes away.

The supervisor is allocation-free on the hot path: :meth:`trip` stores codes in a
preallocated ring; the text of a fault is built only when it is reported.
"""
from __future__ import annotations

import numpy as np

from sea_daemon.errors import Fault

_NONE = Fault.NONE          # read every cycle (an enum member's look-up costs ≈ 0.2 µs)


class SafetySupervisor:
    """Latches the first fault, remembers the later ones, resets only on request."""

    def __init__(self, history: int = 256, overrun_streak: int = 5, loop_stall: bool = True):
        self.overrun_streak_limit = int(overrun_streak)
        #: False: the loop's stalls beyond the missed-cycle tolerance do not latch LOOP_STALL (timing
        #: faults off, ``--overrun-streak 0``: a run whose timing is not under test on a shared machine)
        self.loop_stall = bool(loop_stall)
        self._codes = np.zeros(history, dtype=np.int16)
        self._cycles = np.zeros(history, dtype=np.int64)
        self._times = np.zeros(history, dtype=np.float64)
        self._n = 0
        self.latched = Fault.NONE
        self.latched_cycle = -1
        self.latched_time = float("nan")
        self.latched_detail = ""
        self._streak = 0
        self.trips = 0

    @classmethod
    def with_streak(cls, overrun_streak: int) -> "SafetySupervisor":
        """The supervisor of ``--overrun-streak``: that many overruns in a row latch
        OVERRUN_STREAK; 0 turns the timing faults off (neither it nor LOOP_STALL latches)."""
        return cls(overrun_streak=overrun_streak or 2 ** 62, loop_stall=overrun_streak != 0)

    @property
    def ok(self) -> bool:
        return self.latched == _NONE

    def trip(self, code: Fault, cycle: int, t: float, detail: str = "") -> bool:
        """Record a fault; returns True when it is the one that latched now."""
        i = self._n % self._codes.shape[0]
        self._codes[i] = int(code)
        self._cycles[i] = cycle
        self._times[i] = t
        self._n += 1
        self.trips += 1
        if self.latched == Fault.NONE:
            self.latched = Fault(code)
            self.latched_cycle = cycle
            self.latched_time = t
            self.latched_detail = detail
            return True
        return False

    def overrun(self, overran: bool, cycle: int, t: float) -> bool:
        """Count consecutive overruns; a streak of ``overrun_streak`` trips the fault."""
        self._streak = self._streak + 1 if overran else 0
        if self._streak >= self.overrun_streak_limit:
            return self.trip(Fault.OVERRUN_STREAK, cycle, t, f"{self._streak} consecutive overruns")
        return False

    def reset(self) -> Fault:
        """Explicit operator action: clear the latched fault; returns what was cleared."""
        was = self.latched
        self.latched = Fault.NONE
        self.latched_cycle = -1
        self.latched_time = float("nan")
        self.latched_detail = ""
        self._streak = 0
        return was

    def history(self) -> list[tuple[int, float, str]]:
        """(cycle, time, fault name) of the remembered trips, oldest first."""
        n = min(self._n, self._codes.shape[0])
        start = self._n - n
        out = []
        for k in range(start, self._n):
            i = k % self._codes.shape[0]
            out.append((int(self._cycles[i]), float(self._times[i]), Fault(int(self._codes[i])).name))
        return out

    def status_line(self) -> str:
        if self.ok:
            return "ok"
        return (f"FAULT {self.latched.name} at cycle {self.latched_cycle}"
                + (f": {self.latched_detail}" if self.latched_detail else "")
                + "; torque zero; reset needed (sea-daemon reset or restart)")
