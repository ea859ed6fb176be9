"""Real-time set-up of a process, best effort: SCHED_FIFO and locked memory.

* :func:`try_realtime` — SCHED_FIFO for the calling thread (threads started later inherit it)
  and :func:`lock_memory`; the daemon's loop and the device model's process call it.
* :func:`lock_memory` — ``mlockall(MCL_CURRENT | MCL_FUTURE)`` where the limit cannot bite:
  RLIMIT_MEMLOCK unlimited (the systemd unit's ``LimitMEMLOCK=infinity``) or the process holds
  CAP_IPC_LOCK (mlock(2): a privileged process locks without limit).  Every page mapped now is
  faulted in, every later mapping at its creation: the real-time path takes no page fault.  With
  a finite limit and no capability MCL_FUTURE would make later allocations fail, so it is skipped
  (the buffers the loop fills per cycle are resident all the same: :mod:`sea_daemon.core.buffers`).
  The bound worker, a forked process (locks are not inherited), calls it for itself.

Both never raise; they return what applied, for the READY status line and the JSON summaries.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import gc
import os

#: CAP_IPC_LOCK's bit in /proc/PID/status ``CapEff`` (linux/capability.h)
CAP_IPC_LOCK = 14
MCL_CURRENT, MCL_FUTURE = 1, 2


def freeze_heap() -> None:
    """Collect once, then move every object that exists now out of the garbage collector's
    reach (``gc.freeze``): a collection during a real-time loop then walks only what the loop
    created since.  A process holding the estimator's and the plant's code has ~1.5e5 objects,
    and a full collection over them takes tens of ms -- longer than the missed-cycle tolerance
    at 1 kHz.  Call it after setting up, before serving."""
    gc.collect()
    gc.freeze()


def has_cap_ipc_lock(status_path: str = "/proc/self/status") -> bool:
    """Whether this process's effective capabilities hold CAP_IPC_LOCK (False where unknown)."""
    try:
        with open(status_path) as f:
            for line in f:
                if line.startswith("CapEff:"):
                    return bool(int(line.split()[1], 16) >> CAP_IPC_LOCK & 1)
    except (OSError, ValueError, IndexError):
        pass
    return False


def lock_memory() -> str:
    """``mlockall(MCL_CURRENT | MCL_FUTURE)`` when RLIMIT_MEMLOCK is unlimited or the process holds
    CAP_IPC_LOCK; what applied: ``locked``, ``locked (CAP_IPC_LOCK: …)`` or ``skipped (why)``."""
    try:
        import resource
        soft, _ = resource.getrlimit(resource.RLIMIT_MEMLOCK)
        why = ""
        if soft != resource.RLIM_INFINITY:
            if not has_cap_ipc_lock():
                return f"skipped (RLIMIT_MEMLOCK {soft} bytes, not unlimited, and no CAP_IPC_LOCK)"
            why = f" (CAP_IPC_LOCK: RLIMIT_MEMLOCK {soft} bytes does not apply)"
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        if libc.mlockall(MCL_CURRENT | MCL_FUTURE) == 0:
            return "locked" + why
        return f"skipped ({os.strerror(ctypes.get_errno())})"
    except Exception as e:  # noqa: BLE001 - best effort by design
        return f"skipped ({type(e).__name__})"


def try_realtime(priority: int = 80) -> dict[str, str]:
    """SCHED_FIFO ``priority`` for this thread (threads started later inherit it) and
    :func:`lock_memory`.  Returns what applied, e.g. ``{"sched": "fifo 80", "mlockall": "locked"}``."""
    out = {}
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
        out["sched"] = f"fifo {priority}"
    except (OSError, AttributeError) as e:
        out["sched"] = f"other (SCHED_FIFO not permitted: {getattr(e, 'strerror', e)})"
    out["mlockall"] = lock_memory()
    return out
