"""The estimation service: what ``sea-daemon run`` and ``sea-daemon calibrate`` run around the fixed-rate loop.

The hardware comes as a :class:`~sea_daemon.runtime.rig.Rig` (:func:`~sea_daemon.runtime.rig.make_rig`),
the controller from :mod:`sea_daemon.runtime.controller`.

* :func:`try_realtime` — best-effort SCHED_FIFO and ``mlockall``, skipped when not permitted.
* :class:`StateFile` — ``sea-daemon.pid`` (JSON) in the state directory, for ``sea-daemon reset``.
* :func:`serve` — the compiled kernels loaded (:func:`sea_daemon.core.jit.warm_up`), log writer,
  real-time set-up, signals (SIGTERM/SIGINT stop, SIGUSR1 reset), hardware start, READY=1, the
  loop (WATCHDOG=1 each cycle, latched or not, STATUS= once a second), STOPPING=1, clean stop
  and log close.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import gc
import json
import os
import signal
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable

from sea_daemon.errors import InputError
from sea_daemon.runtime.logwriter import LogWriter
from sea_daemon.runtime.loop import Controller, FixedRateLoop, log_columns
from sea_daemon.runtime.notify import Notifier
from sea_daemon.runtime.safety import SafetySupervisor

if TYPE_CHECKING:                     # a Rig's module loads the scenario and simulator modules
    from sea_daemon.core.estimators.base import Estimator
    from sea_daemon.runtime.rig import Rig

PID_FILE = "sea-daemon.pid"


# ---------------------------------------------------------------------------- real time
def try_realtime(priority: int = 80) -> dict[str, str]:
    """SCHED_FIFO for this thread (threads started later inherit it) and mlockall, when permitted.

    ``mlockall(MCL_CURRENT | MCL_FUTURE)`` is tried only when RLIMIT_MEMLOCK is unlimited (with a
    finite limit MCL_FUTURE would make later allocations fail).  Returns what applied, e.g.
    ``{"sched": "fifo 80", "mlockall": "skipped (EPERM)"}``; never raises.
    """
    out = {}
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
        out["sched"] = f"fifo {priority}"
    except (OSError, AttributeError) as e:
        out["sched"] = f"other (SCHED_FIFO not permitted: {getattr(e, 'strerror', e)})"
    try:
        import resource
        soft, _ = resource.getrlimit(resource.RLIMIT_MEMLOCK)
        if soft != resource.RLIM_INFINITY:
            out["mlockall"] = f"skipped (RLIMIT_MEMLOCK {soft} bytes, not unlimited)"
        else:
            libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
            if libc.mlockall(3) == 0:                         # MCL_CURRENT | MCL_FUTURE
                out["mlockall"] = "locked"
            else:
                out["mlockall"] = f"skipped ({os.strerror(ctypes.get_errno())})"
    except Exception as e:  # noqa: BLE001 - best effort by design
        out["mlockall"] = f"skipped ({type(e).__name__})"
    return out


# ---------------------------------------------------------------------------- state file
class StateFile:
    """``<dir>/sea-daemon.pid``: JSON {pid, started, command, log}; removed on a clean exit."""

    def __init__(self, directory: str | Path):
        self.path = Path(directory) / PID_FILE

    def write(self, **info) -> None:
        from sea_daemon.io.files import atomic_write_bytes
        atomic_write_bytes(self.path, json.dumps({"pid": os.getpid(), "started": time.time(), **info}).encode())

    def remove(self) -> None:
        try:
            info = json.loads(self.path.read_text())
            if info.get("pid") == os.getpid():
                self.path.unlink()
        except (OSError, ValueError):
            pass

    def running_pid(self) -> int:
        """The pid of the daemon that wrote the file, if it still runs; InputError otherwise."""
        try:
            info = json.loads(self.path.read_text())
            pid = int(info["pid"])
        except FileNotFoundError:
            raise InputError(f"no running sea-daemon: {self.path} does not exist "
                             "(give the --log-dir / --state-dir the daemon was started with)") from None
        except (OSError, ValueError, KeyError, TypeError) as e:
            raise InputError(f"{self.path}: unreadable state file ({e})") from None
        try:
            cmd = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:
            raise InputError(f"no running sea-daemon: pid {pid} of {self.path} has exited (stale state file)") from None
        if "sea-daemon" not in cmd and "sea_daemon" not in cmd:
            raise InputError(f"no running sea-daemon: pid {pid} of {self.path} is another program (stale state file)")
        return pid


# ---------------------------------------------------------------------------- the service
@dataclass
class ServeResult:
    stats: Any
    supervisor: SafetySupervisor
    log: dict
    realtime: dict
    wall_s: float
    stopped_by_signal: bool = False
    extra: dict = field(default_factory=dict)


def serve(rig: Rig, estimator: Estimator, controller: Controller, n: int, period: float, log_path: Path, *,
          cycles: int | None = None, realtime: bool = True, notifier: Notifier | None = None,
          state: StateFile | None = None, progress: Callable[[int, Any], None] | None = None,
          rt_priority: int | None = 80, record_periods: bool = False, label: str = "run",
          supervisor: SafetySupervisor | None = None) -> ServeResult:
    """Run ``estimator`` + ``controller`` on ``rig`` until ``cycles`` or a stop signal."""
    # compile (or load) the numba kernels now: nothing compiles while the drives watch our heartbeat
    from sea_daemon.core.jit import warm_up        # numba: imported here, not by `sea-daemon reset`
    warm_up()
    notifier = notifier or Notifier()
    log = LogWriter(log_path, log_columns(n))           # before SCHED_FIFO: the writer stays SCHED_OTHER
    rt = try_realtime(rt_priority) if (realtime and rt_priority) else {"sched": "other (not asked)",
                                                                       "mlockall": "skipped (not asked)"}
    loop = None
    next_status = [0.0]
    rt_text = f"sched {rt['sched']}; mlockall {rt['mlockall']}"
    stopped = {"signal": False}

    def on_cycle(k, meas, est, tau):
        now = time.monotonic()
        if now >= next_status[0]:                        # STATUS= once a second (wall clock)
            next_status[0] = now + 1.0
            st = loop.stats
            notifier.status(f"{label}: {k} cycles, {st.overruns} overruns, {st.skipped} skipped, "
                            f"log drops {log.dropped}, {loop.supervisor.status_line()}")
        if progress is not None:
            progress(k, est)

    def on_stop(signum, frame):
        stopped["signal"] = True
        if loop is not None:
            loop.request_stop()

    def on_reset(signum, frame):
        if loop is not None:
            loop.request_reset()

    old = {s: signal.getsignal(s) for s in (signal.SIGTERM, signal.SIGINT, signal.SIGUSR1)}
    t_wall = time.monotonic()
    started = False
    try:
        loop = FixedRateLoop(rig.hw, estimator, controller, n=n, period=period, log=log, notifier=notifier,
                             realtime=realtime, record_periods=record_periods, on_cycle=on_cycle,
                             initial_torque=rig.initial_torque, supervisor=supervisor)
        signal.signal(signal.SIGTERM, on_stop)
        signal.signal(signal.SIGINT, on_stop)
        signal.signal(signal.SIGUSR1, on_reset)
        if state is not None:
            state.write(command=label, log=str(log_path), hardware=rig.description)
        rig.start()
        started = True
        # the drives watch our heartbeat from read(): the loop starts right away
        notifier.ready(f"{label}: {rig.description}; {rt_text}")
        t_wall = time.monotonic()
        # what exists now is never garbage: out of the collector's reach, so that a collection in
        # the loop only walks what the loop's cycles create (short pauses, no full-heap sweeps)
        gc.collect()
        gc.freeze()
        stats = loop.run(cycles)
    finally:
        notifier.stopping()
        try:
            rig.stop()
        finally:
            final = log.close()
            if not started and final["rows_written"] == 0:     # the hardware never came up: no empty log
                for f in final["files"]:
                    Path(f).unlink(missing_ok=True)
            if state is not None:
                state.remove()
            for s, h in old.items():
                signal.signal(s, h)
    sup = loop.supervisor
    notifier.status(f"{label}: stopped after {stats.cycles} cycles, {stats.overruns} overruns, "
                    f"{sup.status_line()}")
    return ServeResult(stats, sup, final, rt, time.monotonic() - t_wall, stopped["signal"])
