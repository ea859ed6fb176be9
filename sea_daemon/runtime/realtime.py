"""Real-time set-up of a process, best effort: SCHED_FIFO, locked memory, no transparent huge pages.

* :func:`try_realtime` — SCHED_FIFO for the calling thread (threads started later inherit it)
  and :func:`lock_memory`; the daemon's loop and the device model's process call it.
* :func:`lock_memory` — ``mlockall(MCL_CURRENT | MCL_FUTURE)`` where the limit cannot bite:
  RLIMIT_MEMLOCK unlimited (the systemd unit's ``LimitMEMLOCK=infinity``) or the process holds
  CAP_IPC_LOCK (mlock(2): a privileged process locks without limit).  Every page mapped now is
  faulted in, every later mapping at its creation: the real-time path takes no page fault.  With
  a finite limit and no capability MCL_FUTURE would make later allocations fail, so it is skipped
  (the buffers the loop fills per cycle are resident all the same: :mod:`sea_daemon.core.buffers`).
  The bound worker, a forked process (locks are not inherited), calls it for itself.
  It calls :func:`no_huge_pages` first, whether the lock applies or not.
* :func:`no_huge_pages` — ``prctl(PR_SET_THP_DISABLE)``: no transparent huge pages in this
  process (and the processes it starts).  numpy asks for huge pages (``MADV_HUGEPAGE``) on every
  array of 4 MiB or more, and the kernel's ``khugepaged`` then collapses such a region's small
  pages into a huge page in the background.  One collapse holds a CPU for about 5 ms without a
  preemption point on a kernel built without full preemption (``PREEMPT_NONE``, the default of
  many distributions and virtual machines): a SCHED_FIFO thread woken on that CPU waits for it —
  the loop 5 ms late, or the device model's answer to SYNC missing for 5 cycles at 1 kHz, several
  collapses in a row tens of ms.  With the flag set ``khugepaged`` leaves the process alone.  It
  cannot keep ``khugepaged`` off another process's memory; docs/daemon.md says how to turn it off
  for the machine.

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
#: prctl(2) option: no transparent huge pages for this process (linux/prctl.h)
PR_SET_THP_DISABLE = 41


def _libc():
    return ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)


def no_huge_pages() -> str:
    """``prctl(PR_SET_THP_DISABLE, 1)``: no transparent huge pages in this process and its
    children, so that ``khugepaged`` never collapses its pages while it runs (module docstring).
    What applied: ``off`` or ``on (why)``; never raises."""
    try:
        if _libc().prctl(PR_SET_THP_DISABLE, 1, 0, 0, 0) == 0:
            return "off"
        return f"on (prctl refused: {os.strerror(ctypes.get_errno())})"
    except Exception as e:  # noqa: BLE001 - best effort by design
        return f"on ({type(e).__name__})"


def freeze_heap() -> None:
    """Collect once, then move every object that exists now out of the garbage collector's
    reach (``gc.freeze``): a collection during a real-time loop then walks only what the loop
    created since.  A process holding the estimator's and the plant's code has ~1.5e5 objects,
    and a full collection over them takes tens of ms -- longer than the missed-cycle tolerance
    at 1 kHz.  Call it after setting up, before serving."""
    gc.collect()
    gc.freeze()


#: the machine's transparent huge page settings (sysfs)
THP_DIR = "/sys/kernel/mm/transparent_hugepage"


def huge_page_state(root: str = THP_DIR) -> dict | None:
    """The machine's transparent huge pages: ``mode`` (``always``, ``madvise`` or ``never``) and
    ``collapsed`` (huge pages ``khugepaged`` made so far, in any process); None where sysfs does
    not tell.  Two readings around a run give the collapses during it (:func:`no_huge_pages`)."""
    try:
        with open(os.path.join(root, "enabled")) as f:
            text = f.read()
        with open(os.path.join(root, "khugepaged", "pages_collapsed")) as f:
            collapsed = int(f.read())
    except (OSError, ValueError):
        return None
    mode = text[text.index("[") + 1:text.index("]")] if "[" in text and "]" in text else text.strip()
    return {"mode": mode, "collapsed": collapsed}


def _boot_log_preemption(kmsg: str) -> str | None:
    """A PREEMPT_DYNAMIC kernel's boot line ``Dynamic Preempt: MODE`` in the kernel's log
    (``/dev/kmsg``, read without waiting; None where it is not readable or no longer there)."""
    try:
        fd = os.open(kmsg, os.O_RDONLY | os.O_NONBLOCK)
    except OSError:
        return None
    try:
        for _ in range(100000):
            try:
                rec = os.read(fd, 8192)
            except BrokenPipeError:          # a record overwritten while read: go on
                continue
            except OSError:                  # EAGAIN: the end of the log
                return None
            i = rec.find(b"Dynamic Preempt: ")
            if i >= 0:
                return rec[i + 17:].split()[0].decode(errors="replace")
    finally:
        os.close(fd)
    return None


def kernel_preemption(version: str | None = None, debugfs: str = "/sys/kernel/debug/sched/preempt",
                      cmdline: str = "/proc/cmdline", kmsg: str = "/dev/kmsg") -> str:
    """The kernel's preemption model as far as the machine tells: ``PREEMPT_RT``; a
    PREEMPT_DYNAMIC kernel's mode (``none``, ``voluntary``, ``full``, ``lazy``) from debugfs, the
    ``preempt=`` boot parameter or the boot log; else the build's tag in ``uname -v`` (``version``).  With
    ``none`` or ``voluntary`` a real-time thread that wakes while another task runs kernel code
    on its CPU waits until that code reaches a preemption point (up to milliseconds)."""
    version = os.uname().version if version is None else version
    if "PREEMPT_RT" in version:
        return "PREEMPT_RT"
    try:
        with open(debugfs) as f:
            text = f.read()
        if "(" in text and ")" in text:
            return f"{text[text.index('(') + 1:text.index(')')]} (PREEMPT_DYNAMIC)"
    except OSError:
        pass
    try:
        with open(cmdline) as f:
            for arg in f.read().split():
                if arg.startswith("preempt="):
                    return f"{arg.split('=', 1)[1]} (preempt= on the kernel command line)"
    except OSError:
        pass
    if "PREEMPT_DYNAMIC" in version:
        mode = _boot_log_preemption(kmsg)
        return (f"{mode} (PREEMPT_DYNAMIC, the kernel's boot log)" if mode else
                "PREEMPT_DYNAMIC, its mode not readable here (the build's default)")
    words = version.split()
    return "full (PREEMPT)" if "PREEMPT" in words else ("voluntary" if "PREEMPT_VOLUNTARY" in words else
                                                        "none or voluntary (no PREEMPT in uname -v)")


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
    """:func:`no_huge_pages`, then ``mlockall(MCL_CURRENT | MCL_FUTURE)`` when RLIMIT_MEMLOCK is
    unlimited or the process holds CAP_IPC_LOCK; what applied to the lock: ``locked``,
    ``locked (CAP_IPC_LOCK: …)`` or ``skipped (why)``."""
    no_huge_pages()
    try:
        import resource
        soft, _ = resource.getrlimit(resource.RLIMIT_MEMLOCK)
        why = ""
        if soft != resource.RLIM_INFINITY:
            if not has_cap_ipc_lock():
                return f"skipped (RLIMIT_MEMLOCK {soft} bytes, not unlimited, and no CAP_IPC_LOCK)"
            why = f" (CAP_IPC_LOCK: RLIMIT_MEMLOCK {soft} bytes does not apply)"
        libc = _libc()
        if libc.mlockall(MCL_CURRENT | MCL_FUTURE) == 0:
            return "locked" + why
        return f"skipped ({os.strerror(ctypes.get_errno())})"
    except Exception as e:  # noqa: BLE001 - best effort by design
        return f"skipped ({type(e).__name__})"


def try_realtime(priority: int = 80) -> dict[str, str]:
    """SCHED_FIFO ``priority`` for this thread (threads started later inherit it) and
    :func:`lock_memory` (with :func:`no_huge_pages`).  Returns what applied, e.g.
    ``{"sched": "fifo 80", "mlockall": "locked", "huge_pages": "off"}``."""
    out = {}
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
        out["sched"] = f"fifo {priority}"
    except (OSError, AttributeError) as e:
        out["sched"] = f"other (SCHED_FIFO not permitted: {getattr(e, 'strerror', e)})"
    out["mlockall"] = lock_memory()
    out["huge_pages"] = no_huge_pages()
    return out
