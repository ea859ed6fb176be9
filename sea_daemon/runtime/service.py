"""The estimation service: what ``sea-daemon run`` and ``sea-daemon calibrate`` run around the fixed-rate loop.

The hardware comes as a :class:`~sea_daemon.runtime.rig.Rig` (:func:`~sea_daemon.runtime.rig.make_rig`),
the controller from :mod:`sea_daemon.runtime.controller`.

* :class:`StateFile` — ``sea-daemon.pid`` (JSON) in the state directory, for ``sea-daemon reset``
  and ``sea-daemon watch`` (it names the publication socket).
* :func:`serve` — the compiled kernels loaded (:func:`sea_daemon.core.jit.warm_up`), log writer,
  the bound worker (:mod:`.bound_worker`, ``estimator.bound_in``), real-time set-up
  (:func:`sea_daemon.runtime.realtime.try_realtime`: SCHED_FIFO, locked memory), signals
  (SIGTERM/SIGINT stop, SIGUSR1 reset), hardware start, READY=1, the loop (WATCHDOG=1 each cycle, latched or not, STATUS= once a second), STOPPING=1, clean stop
  and log close.
"""
from __future__ import annotations

import json
import os
import signal
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable

from sea_daemon.errors import InputError, shown
from sea_daemon.io.owned import check_owned
from sea_daemon.runtime.affinity import keep_off, pin_thread
from sea_daemon.runtime.bound_worker import BoundWorker, why_not
from sea_daemon.runtime.logwriter import LogWriter
from sea_daemon.core.log import DaemonLogLayout
from sea_daemon.core.estimators.validity import reason_counts
from sea_daemon.runtime.loop import Controller, FixedRateLoop
from sea_daemon.runtime.notify import Notifier
from sea_daemon.runtime.realtime import freeze_heap, try_realtime
from sea_daemon.runtime.safety import SafetySupervisor
from sea_daemon.io.files import atomic_write_bytes

if TYPE_CHECKING:                     # a Rig's module loads the scenario and simulator modules
    from sea_daemon.core.estimators.base import Estimator
    from sea_daemon.runtime.rig import Rig

PID_FILE = "sea-daemon.pid"
#: the bound worker's SCHED_FIFO priority: this far below the loop's (``rt_priority``)
WORKER_PRIORITY_BELOW = 20
LOCK_FILE = "sea-daemon.lock"
#: s the log writer's process may take to open its sinks (its start and the libraries' imports)
_SINKS_OPEN_S = 60.0


# ---------------------------------------------------------------------------- state file
def process_start_time(pid: int) -> int:
    """The start time of process ``pid`` (clock ticks since boot, /proc/PID/stat field 22): with
    the pid it names one process for the life of the system (a pid is reused, the pair is not).
    OSError when there is no such process."""
    stat = Path(f"/proc/{pid}/stat").read_bytes()
    return int(stat[stat.rindex(b")") + 2:].split()[19])      # fields after "pid (comm)": 3..


def lock_dir() -> Path:
    """Where the per-bus locks live: ``$SEA_DAEMON_LOCK_DIR``, else ``/run/sea-daemon`` (systemd's
    RuntimeDirectory) when it exists, else ``/run/lock`` when writable, else the temp directory."""
    env = os.environ.get("SEA_DAEMON_LOCK_DIR")
    if env:
        return Path(env)
    for d in ("/run/sea-daemon", "/run/lock"):
        if os.path.isdir(d) and (d == "/run/sea-daemon" or os.access(d, os.W_OK)):
            return Path(d)
    import tempfile
    return Path(tempfile.gettempdir())


def bus_lock_path(interface: str, channel: str) -> Path:
    """The lock file of one CAN bus (interface + channel) in :func:`lock_dir`."""
    import hashlib
    import re
    key = f"{interface}:{channel}"
    safe = re.sub(r"[^A-Za-z0-9._-]+", "_", key)[:60]
    return lock_dir() / f"sea-daemon-bus-{safe}-{hashlib.sha1(key.encode()).hexdigest()[:8]}.lock"


class _Flock:
    """An exclusive ``flock`` on a file, held until :meth:`release` or the process ends."""

    def __init__(self, path: Path, private: bool = False):
        self.path = path
        self.private = private                       # the state directory's: this user's or root's only
        self.fd: int | None = None

    def acquire(self, what: str) -> None:
        import fcntl
        # never through a symbolic link (a link planted in a shared lock directory would have
        # the lock's pid written over the file it points to)
        try:
            try:
                fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW, 0o644)
            except PermissionError:
                fd = os.open(self.path, os.O_RDONLY | os.O_NOFOLLOW)   # another user's lock file: flock still works
        except OSError as e:
            raise InputError(f"{what} lock {shown(self.path)}: cannot open: {e.strerror or e}") from None
        if self.private:
            try:
                check_owned(f"{what} lock", self.path, st=os.fstat(fd))
            except InputError:
                os.close(fd)
                raise
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            try:
                holder = os.pread(fd, 64, 0).decode(errors="replace").strip() or "?"
            except OSError:
                holder = "?"
            os.close(fd)
            raise InputError(f"another sea-daemon (pid {shown(holder, 20)}) runs on this {what}: it holds "
                             f"{shown(self.path)}; one instance per bus and state directory "
                             "(stop it first, or use `sea-daemon reset` to clear its fault)") from None
        try:
            os.ftruncate(fd, 0)
            os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        except OSError:
            pass                                     # read-only: the holder's pid is not recorded
        self.fd = fd

    def release(self) -> None:
        if self.fd is not None:
            os.close(self.fd)                        # closing the last descriptor drops the flock
            self.fd = None


class StateFile:
    """The daemon's claim on its state directory and its bus, and what ``sea-daemon reset`` reads.

    * ``<dir>/sea-daemon.lock`` — an exclusive ``flock`` held for the process's life
      (:meth:`claim`); a second instance with the same state directory is refused, and so is
      one on the same bus (the lock of :func:`bus_lock_path`), before it touches the drives.
    * ``<dir>/sea-daemon.pid`` — JSON {pid, start_time, started, command, log, ...}; removed on a
      clean exit.  ``start_time`` is the process's start time from /proc (a reused pid has another).

    :meth:`running_pid` proves the identity of the process it returns: the lock is held, the
    pid's start time is the recorded one, and that process has the lock file open.
    """

    def __init__(self, directory: str | Path):
        self.path = Path(directory) / PID_FILE
        self.lock_path = Path(directory) / LOCK_FILE
        self._locks: list[_Flock] = []

    def claim(self, bus: tuple[str, str] | list[tuple[str, str]] | None = None) -> "StateFile":
        """Take the state directory's lock and, with ``bus`` = (interface, channel) or a list of
        them (a bus per joint), each bus's; InputError naming the holder when another instance
        has any.  Returns self (a context manager that releases them)."""
        buses = [bus] if isinstance(bus, tuple) else list(bus or [])
        try:
            for path, what in [(self.lock_path, "state directory")] + [
                    (bus_lock_path(*b), f"bus {b[0]} {b[1]}") for b in buses]:
                lk = _Flock(path, private=path == self.lock_path)
                lk.acquire(what)
                self._locks.append(lk)
        except BaseException:
            self.release()
            raise
        return self

    def release(self) -> None:
        for lk in reversed(self._locks):
            lk.release()
        self._locks.clear()

    def __enter__(self) -> "StateFile":
        return self

    def __exit__(self, *exc) -> None:
        self.release()

    def write(self, **info) -> None:
        atomic_write_bytes(self.path, json.dumps({"pid": os.getpid(), "start_time": process_start_time(os.getpid()),
                                                  "started": time.time(), "lock": str(self.lock_path),
                                                  **info}).encode())

    def remove(self) -> None:
        try:
            info = json.loads(self.path.read_text())
            if info.get("pid") == os.getpid():
                self.path.unlink()
        except (OSError, ValueError):
            pass

    def running_pid(self) -> int:
        """The pid of the daemon that holds this state directory, proven (class docstring);
        InputError otherwise."""
        return self._proven()[0]

    def _proven(self) -> tuple[int, int | None]:
        """(pid, pidfd or None): the daemon's pid and, where the system has them, a pidfd opened
        before the checks, so that the signal goes to the process that was checked."""
        import fcntl
        try:
            info = json.loads(self.path.read_text())
            pid, start = int(info["pid"]), int(info["start_time"])
        except FileNotFoundError:
            raise InputError(f"no running sea-daemon: {shown(self.path)} does not exist "
                             "(give the --log-dir / --state-dir the daemon was started with)") from None
        except (OSError, ValueError, KeyError, TypeError) as e:
            raise InputError(f"{shown(self.path)}: unreadable state file ({shown(e)})") from None
        stale = f"no running sea-daemon: pid {pid} of {shown(self.path)}"
        try:
            lock_fd = os.open(self.lock_path, os.O_RDONLY)
        except OSError:
            raise InputError(f"{stale} holds no lock ({shown(self.lock_path)} is missing; stale state file)") from None
        try:
            try:
                fcntl.flock(lock_fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
            except BlockingIOError:
                pass                                  # held: a daemon runs here
            else:
                raise InputError(f"{stale}: nobody holds {shown(self.lock_path)} (stale state file)")
            lock_id = os.fstat(lock_fd)
        finally:
            os.close(lock_fd)
        pidfd = None
        if hasattr(os, "pidfd_open"):
            try:
                pidfd = os.pidfd_open(pid)
            except ProcessLookupError:
                raise InputError(f"{stale} has exited (stale state file)") from None
            except OSError:
                pidfd = None
        try:
            try:
                if process_start_time(pid) != start:
                    raise InputError(f"{stale}: that pid now belongs to another process (stale state file)")
            except OSError:
                raise InputError(f"{stale} has exited (stale state file)") from None
            if not _holds_file(pid, lock_id):
                raise InputError(f"{stale} does not hold {shown(self.lock_path)}: it is not the daemon "
                                 "(a planted or stale state file); nothing signalled")
        except BaseException:
            if pidfd is not None:
                os.close(pidfd)
            raise
        return pid, pidfd

    def signal(self, signum: int) -> int:
        """Send ``signum`` to the proven daemon (:meth:`running_pid`); returns its pid."""
        pid, pidfd = self._proven()
        try:
            if pidfd is not None and hasattr(signal, "pidfd_send_signal"):
                signal.pidfd_send_signal(pidfd, signum)
            else:
                os.kill(pid, signum)
        except ProcessLookupError:
            raise InputError(f"no running sea-daemon: pid {pid} has exited") from None
        except PermissionError:
            raise InputError(f"not permitted to signal sea-daemon pid {pid} (run as its user or root)") from None
        finally:
            if pidfd is not None:
                os.close(pidfd)
        return pid


def _holds_file(pid: int, st: os.stat_result) -> bool:
    """Whether process ``pid`` has the file ``st`` (device, inode) open; InputError when its
    descriptors cannot be inspected (another user's process)."""
    d = f"/proc/{pid}/fd"
    try:
        names = os.listdir(d)
    except PermissionError:
        raise InputError(f"cannot prove that pid {pid} is the daemon: not permitted to inspect {d} "
                         "(run as its user or root)") from None
    except OSError:
        return False
    for name in names:
        try:
            s = os.stat(os.path.join(d, name))
        except OSError:
            continue
        if s.st_dev == st.st_dev and s.st_ino == st.st_ino:
            return True
    return False


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
          supervisor: SafetySupervisor | None = None, publisher=None, bound_in: str = "auto",
          bound_max_age: int = 3, bound_record: int = 0, sinks=(), sinks_wait: float = 0.0,
          cpus: tuple[int, ...] | None = None) -> ServeResult:
    """Run ``estimator`` + ``controller`` on ``rig`` until ``cycles`` or a stop signal.

    ``bound_in`` (``estimator.bound_in``): where the estimator's Theorem-1 bound is computed —
    ``worker`` (:class:`~sea_daemon.runtime.bound_worker.BoundWorker`, started here and stopped
    with the service; ρ at most ``bound_max_age`` cycles old), ``loop`` (in the estimator's step),
    ``auto`` (the worker when ``realtime``, the loop in lock-step); in real-time pace the worker
    runs SCHED_FIFO :data:`WORKER_PRIORITY_BELOW` below ``rt_priority``.  An estimator without a bound,
    or one that learns, keeps it in the loop.  ``bound_record``: the worker keeps the first
    that many steps' bound age and CPU time (``bench loop``).  ``extra["bound"]`` says where it ran.

    ``publisher``: the loop's publication step (:func:`sea_daemon.runtime.publish.make_publisher`),
    closed (its socket removed) when the service stops; its counts go into ``extra["publish"]``.

    ``sinks``: the log writer's other outputs (:mod:`sea_daemon.runtime.sinks`: the LSL outlet,
    the MCAP recording), fed by its process with every row; the loop starts once they are open
    (and an LSL outlet has waited its ``wait_s`` for an inlet; ``sinks_wait``: that longest wait),
    what they did is ``log["sinks"]``.

    ``cpus``: (loop[, worker]) CPUs the loop's thread (once the hardware has started its threads,
    which go with the log writer's process to the other CPUs) and the bound worker are pinned to
    (:mod:`sea_daemon.runtime.affinity`; None: not pinned); ``realtime["cpu"]`` says what applied."""
    # compile (or load) the numba kernels now: nothing compiles while the drives watch our heartbeat
    # local import: numba's kernels load only where a daemon runs, not for `sea-daemon reset`
    from sea_daemon.core.jit import warm_up
    warm_up()
    notifier = notifier or Notifier()
    if bound_in not in ("auto", "worker", "loop"):
        raise ValueError(f"bound_in must be auto, worker or loop, got {bound_in!r}")
    layout = DaemonLogLayout.of(n)
    # before SCHED_FIFO: the writer stays SCHED_OTHER
    log = LogWriter(log_path, list(layout.columns), sink_columns=layout.sink_columns if sinks else (), sinks=sinks)
    try:
        log.wait_sinks(sinks_wait + _SINKS_OPEN_S)
        link, where = _bound_link(estimator, bound_in, realtime, rt_priority, bound_max_age, bound_record,
                                  cpus[1] if cpus and len(cpus) > 1 else None, period)
    except BaseException:
        log.close()
        raise
    rt = try_realtime(rt_priority) if (realtime and rt_priority) else {"sched": "other (not asked)",
                                                                       "mlockall": "skipped (not asked)"}
    status = _StatusLine(label, notifier, log, progress)
    signals = _Signals()
    t_wall = time.monotonic()
    started = False
    try:
        loop = status.loop = signals.loop = FixedRateLoop(
            rig.hw, estimator, controller, n=n, period=period, log=log, notifier=notifier, realtime=realtime,
            record_periods=record_periods, on_cycle=status, initial_torque=rig.initial_torque,
            supervisor=supervisor, publisher=publisher, bound_link=link)
        signals.install()
        if state is not None:
            sock = getattr(getattr(publisher, "local", None), "path", None)
            state.write(command=label, log=str(log_path), hardware=rig.description,
                        socket=None if sock is None else str(sock))
        rig.start()
        started = True
        # after the hardware's threads started: they and the log writer off the loop's CPU
        rt["cpu"] = _place_loop(cpus, log, link)
        # the drives watch our heartbeat from read(): the loop starts right away
        notifier.ready(f"{label}: {rig.description}; sched {rt['sched']}; mlockall {rt['mlockall']}; loop {rt['cpu']}")
        t_wall = time.monotonic()
        # what exists now is never garbage: a collection in the loop walks only what its cycles create
        freeze_heap()
        stats = loop.run(cycles)
    finally:
        notifier.stopping()
        try:
            rig.stop()
        finally:
            final, where = _shut_down(log, link, where, started, state, publisher, signals)
    return _result(loop, stats, final, rt, time.monotonic() - t_wall, signals.stopped, publisher, where, link,
                   label, notifier)


def _place_loop(cpus: tuple[int, ...] | None, log: LogWriter, link) -> str:
    """The calling thread (the loop's) pinned to ``cpus[0]``, the process's other threads, the log
    writer and a worker without a CPU of its own moved to the other CPUs; what applied."""
    loop = cpus[0] if cpus else None
    keep_off(loop, (log.writer_pid,) + ((link.pid,) if link is not None and link.cpu is None else ()))
    return pin_thread(loop)


def _bound_link(estimator, bound_in: str, realtime: bool, rt_priority: int | None, max_age: int, record: int,
                cpu: int | None = None, period: float | None = None):
    """The bound worker, when the estimator's bound runs in one (``serve``'s ``bound_in``), and
    where the bound runs: (worker or None, {"where": ..., "why_not_worker": ...})."""
    where = {"where": "loop"}
    if estimator is None or not (bound_in == "worker" or (bound_in == "auto" and realtime)):
        return None, where
    why = why_not(estimator)
    if why is not None:
        where["why_not_worker"] = why
        return None, where
    # forked before the hardware's threads start; in real-time pace SCHED_FIFO below the loop
    prio = max(1, rt_priority - WORKER_PRIORITY_BELOW) if (realtime and rt_priority) else 0
    # in real-time pace the worker polls the heads in phase with the loop where the CPU allows it
    # (BoundWorker's period): no wake-up of the worker from the loop's cycle
    return BoundWorker(estimator, max_age=max_age, record=record, rt_priority=prio, cpu=cpu,
                       period=period if realtime else None).start(), where


class _StatusLine:
    """The service's ``on_cycle``: STATUS= once a second (wall clock), and the caller's progress."""

    def __init__(self, label: str, notifier: Notifier, log: LogWriter, progress):
        self.label, self.notifier, self.log, self.progress = label, notifier, log, progress
        self.loop: FixedRateLoop | None = None
        self.next_status = 0.0

    def __call__(self, k, meas, est, tau) -> None:
        now = time.monotonic()
        if now >= self.next_status:
            self.next_status = now + 1.0
            st = self.loop.stats
            self.notifier.status(f"{self.label}: {k} cycles, {st.overruns} overruns, {st.skipped} skipped, "
                                 f"log rows written {self.log.rows_written}, {self.loop.supervisor.status_line()}")
        if self.progress is not None:
            self.progress(k, est)


class _Signals:
    """SIGTERM / SIGINT stop the loop, SIGUSR1 asks for the operator reset; :meth:`restore` puts
    the handlers found back."""

    def __init__(self):
        self.loop: FixedRateLoop | None = None
        self.stopped = False
        self.old = {s: signal.getsignal(s) for s in (signal.SIGTERM, signal.SIGINT, signal.SIGUSR1)}

    def install(self) -> None:
        signal.signal(signal.SIGTERM, self.on_stop)
        signal.signal(signal.SIGINT, self.on_stop)
        signal.signal(signal.SIGUSR1, self.on_reset)

    def on_stop(self, signum, frame) -> None:
        self.stopped = True
        if self.loop is not None:
            self.loop.request_stop()

    def on_reset(self, signum, frame) -> None:
        if self.loop is not None:
            self.loop.request_reset()

    def restore(self) -> None:
        for s, h in self.old.items():
            signal.signal(s, h)


def _shut_down(log: LogWriter, link, where: dict, started: bool, state, publisher, signals: _Signals):
    """After the hardware stopped: the log closed (no empty log when the hardware never came up),
    the worker, the state file, the publisher, the signal handlers; (the log's counts, where the
    bound ran)."""
    try:
        final = log.close()
        if link is not None:
            where = link.close()
        if not started and final["rows_written"] == 0:     # the hardware never came up: no empty log
            for f in final["files"]:
                Path(f).unlink(missing_ok=True)
        if state is not None:
            state.remove()
        if publisher is not None:
            publisher.close()
    finally:
        signals.restore()
    return final, where


def _result(loop: FixedRateLoop, stats, final: dict, rt: dict, wall_s: float, stopped: bool, publisher,
            where: dict, link, label: str, notifier: Notifier) -> ServeResult:
    sup = loop.supervisor
    lost = f"; log incomplete, {final['rows_lost']} rows lost: {final['error']}" if final["error"] else ""
    notifier.status(f"{label}: stopped after {stats.cycles} cycles, {stats.overruns} overruns, "
                    f"{sup.status_line()}{lost}")
    extra = {"publish": publisher.stats()} if publisher is not None else {}
    # how many cycles were valid, and why the others were not (docs/interfaces.md §3)
    extra["bound"] = {**where, "validity": reason_counts(stats.validity)}
    if link is not None:
        extra["bound_link"] = link
    return ServeResult(stats, sup, final, rt, wall_s, stopped, extra)
