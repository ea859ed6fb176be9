"""``sea-daemon bench record``: the measured log through the faults that threaten the record.

Rounds of three service-level attacks, each checked on the log it leaves:

* **device model stopped** — the service (:func:`~sea_daemon.runtime.service.serve`, the
  daemon's loop and log writer) runs ``--cycles`` lock-step cycles against the device model on
  a virtual bus; at a seeded random cycle the device model stops (its nodes fall silent: no
  PDO, no heartbeat).  Checked: a row for every cycle (cycle column 0..N−1, time increasing,
  none lost), ``fault`` ≠ 0 from the latch to the end, ``valid`` 0 and the torque 0 there,
  placeholder rows (``measured`` 0) for the cycles without a sample, the latch reported by
  STATUS=, the exit status the command would give (1).
* **disk full** — the same service with its log directory on a tmpfs of a seeded size that
  fills after 25–75 % of the run (mounted when this process may mount; otherwise the writer's
  RLIMIT_FSIZE is set to that size, and writes fail with EFBIG instead of ENOSPC).  Checked:
  LOG_FAILED latched and reported by STATUS=, ``rows_lost`` = cycles − rows written, the file
  holds exactly the rows written, whole lines only, the exit status 1.
* **service killed and restarted** — ``sea-daemon calibrate`` (device model, lock-step) in a
  subprocess is killed with SIGKILL once its log has rows, then started again on the same log
  and state directory (what systemd's Restart= does).  Checked: the killed run's log is whole
  lines with contiguous cycles from 0 (its writer drains the ring after the loop's process
  died); the restarted run gets the lock (the dead one's flock went with it) and exits 0, with
  a row for every cycle and no pid file left.

Per attack: rounds, cycles, rows, rows lost (all accounted for), checks passed.
"""
from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from sea_daemon.core.log import DaemonColumns
from sea_daemon.apps.bench import add_choice_argument, add_json_argument, choose, json_output, machine
from sea_daemon.core.estimators import make_estimator
from sea_daemon.io.configfile import load_config, data_root
from sea_daemon.runtime import service
from sea_daemon.runtime.controller import ScenarioController
from sea_daemon.io.scenario import load_scenario
from sea_daemon.runtime.rig import make_rig
from sea_daemon.io.logcsv import read_log
from sea_daemon.errors import Fault
from sea_daemon.errors import InputError

DESCRIPTION = __doc__
ATTACKS = ("device_model_stopped", "disk_full", "restart")
ROW_BYTES = 150                 # about one row of the daemon's log, one joint


class _Status:
    """A notifier that keeps the STATUS= lines (what systemd would show)."""

    def __init__(self):
        self.lines: list[str] = []

    def ready(self, text: str = "") -> None:
        pass

    def status(self, text: str) -> None:
        self.lines.append(text)

    def watchdog(self) -> None:
        pass

    def stopping(self) -> None:
        pass


def serve_with_action(log_dir: Path, cycles: int, at: int, action, writer_hook=None, after=None):
    """The service against the device model for ``cycles`` cycles; ``action(rig)`` in cycle ``at``,
    then ``after(rig)`` in every later cycle (e.g. to wait for the log writer)."""

    root = data_root()
    cfg = load_config(root / "configs" / "exo_1dof_sim.yaml")
    scen = root / "configs" / "scenarios" / "passive.yaml"
    rig = make_rig(cfg, device_model=str(scen), phase="estimation")
    ctl = ScenarioController(load_scenario(scen), cfg, rig.hold_torque, delay=rig.hw.actuation_delay)
    done = []

    def progress(k, est):
        if k == at and not done:
            done.append(k)
            action(rig)
        elif done and after is not None:
            after(rig)

    note = _Status()
    real = service.LogWriter

    def writer(*a, **kw):
        w = real(*a, **kw)
        if writer_hook is not None:
            writer_hook(w)
        return w
    service.LogWriter = writer
    try:
        res = service.serve(rig, make_estimator("akf", cfg), ctl, cfg.joints, cfg.dt, log_dir / "run.csv",
                            cycles=cycles, realtime=False, notifier=note, progress=progress, rt_priority=None)
    finally:
        service.LogWriter = real
    return res, log_dir / "run.csv", note


def _exit_status(res) -> int:
    """What ``sea-daemon run`` returns for this result (run.py)."""
    return 1 if (not res.supervisor.ok or res.log["error"]) else 0


def _lines_whole(path: Path) -> bool:
    data = path.read_bytes()
    return data.endswith(b"\n")


def attack_device_model_stopped(tmp: Path, cycles: int, rng) -> dict:
    at = int(rng.integers(cycles // 4, 3 * cycles // 4))
    res, path, note = serve_with_action(tmp, cycles, at, lambda rig: rig.device_model.stop())
    log = read_log(path, n=1)
    ex = DaemonColumns.of(log)
    f = ex.fault != 0
    first = int(np.argmax(f)) if f.any() else -1
    checks = {
        "every_cycle": len(log) == cycles == res.stats.cycles and np.array_equal(ex.cycle, np.arange(cycles))
        and bool(np.all(np.diff(log.t) > 0)),
        "none_lost": res.log["rows_lost"] == 0 and res.log["error"] is None,
        "latched_after_stop": at <= first <= at + 5 and bool(f[first:].all()),
        "invalid_and_zero_torque_latched": not ex.valid[f].any() and bool(np.all(log.tau_m[f] == 0)),
        "placeholders_without_sample": bool(np.all(ex.measured[first + 1:] == 0)),
        "status_reported": any("FAULT" in s for s in note.lines),
        "exit_status_1": _exit_status(res) == 1,
    }
    return {"cycles": cycles, "rows": len(log), "rows_lost": res.log["rows_lost"], "at": at,
            "latched": res.supervisor.latched.name, "latched_cycle": first,
            "placeholder_rows": int(np.count_nonzero(ex.measured == 0)), "checks": checks}


@contextlib.contextmanager
def _small_disk(base: Path, size: int):
    """A directory of ``size`` bytes: a tmpfs when this process may mount one, else None."""
    d = base / "tmpfs"
    d.mkdir()
    mounted = False
    if os.geteuid() == 0:
        r = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(d)],
                           capture_output=True, text=True)
        mounted = r.returncode == 0
    try:
        yield d, mounted
    finally:
        if mounted:
            subprocess.run(["umount", "-l", str(d)], capture_output=True)


def attack_disk_full(tmp: Path, cycles: int, rng) -> dict:
    import resource

    # fills after 25..75 % of the run (a row is about 150 bytes), in whole pages
    size = max(2, int(rng.uniform(0.25, 0.75) * cycles * ROW_BYTES) // 4096) * 4096
    with _small_disk(tmp, size) as (d, mounted):
        writers = []

        def limit(w):                    # no tmpfs: the writer's files may grow to the same size
            writers.append(w)
            if not mounted:
                resource.prlimit(w.writer_pid, resource.RLIMIT_FSIZE, (size, resource.RLIM_INFINITY))

        def caught_up(rig):              # the unpaced loop waits for the writer (a loaded host lags
            w = writers[-1]              # it): the disk fills while the run goes on, not after it
            end = time.monotonic() + 60
            while w.fault() is None and w.rows_written < w.appended and time.monotonic() < end:
                time.sleep(0.002)
        res, path, note = serve_with_action(d, cycles, 0, lambda rig: None, writer_hook=limit, after=caught_up)
        fin = res.log
        log = read_log(path, n=1) if fin["rows_written"] >= 2 else None
        rows_in_file = path.read_bytes().count(b"\n") - 1
        checks = {
            "log_failed_latched": res.supervisor.latched == Fault.LOG_FAILED,
            "rows_lost_accounted": fin["rows_lost"] == cycles - fin["rows_written"] > 0,
            "file_holds_rows_written": rows_in_file == fin["rows_written"]
            and (log is None or (len(log) == fin["rows_written"]
                                 and np.array_equal(DaemonColumns.of(log).cycle, np.arange(len(log))))),
            "whole_lines": _lines_whole(path),
            "status_reported": any("LOG_FAILED" in s for s in note.lines)
            and any("rows lost" in s for s in note.lines),
            "exit_status_1": _exit_status(res) == 1,
        }
        return {"cycles": cycles, "rows": fin["rows_written"], "rows_lost": fin["rows_lost"], "disk_bytes": size,
                "disk": "tmpfs" if mounted else "RLIMIT_FSIZE", "error": fin["error"], "checks": checks}


def attack_restart(tmp: Path, cycles: int, rng) -> dict:
    root = data_root()
    cfg = root / "configs" / "exo_1dof_sim.yaml"
    scen = root / "configs" / "scenarios" / "passive.yaml"
    logs = tmp / "logs"
    argv = [sys.executable, "-m", "sea_daemon", "calibrate", "--config", str(cfg), "--device-model", str(scen),
            "--scenario", str(scen), "--out", str(tmp / "model.npz"), "--log-dir", str(logs), "--no-progress"]
    env = dict(os.environ, PYTHONPATH=str(root) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    kill_after = int(rng.integers(50, 400))
    p = subprocess.Popen(argv + ["--cycles", str(10 * cycles)], env=env, stdout=subprocess.DEVNULL,
                         stderr=subprocess.PIPE, text=True)
    first_log = None
    t0 = time.monotonic()
    try:
        while time.monotonic() - t0 < 300 and p.poll() is None:
            found = sorted(logs.glob("calibration-*.csv")) if logs.exists() else []
            if found and found[0].stat().st_size > ROW_BYTES * kill_after:
                first_log = found[0]
                break
            time.sleep(0.02)
        p.send_signal(signal.SIGKILL)
    finally:
        p.wait(30)
    killed = p.returncode == -signal.SIGKILL and first_log is not None
    time.sleep(0.5)                        # the orphaned writer drains the ring and exits
    log1 = read_log(first_log, n=1) if first_log is not None else None
    r = subprocess.run(argv + ["--cycles", str(cycles)], env=env, capture_output=True, text=True, timeout=600)
    summary = json.loads(r.stdout.strip().splitlines()[-1]) if r.stdout.strip() else {}
    log2 = read_log(summary["log"], n=1) if summary.get("log") else None
    checks = {
        "killed_mid_run": killed,
        "killed_log_whole_and_contiguous": log1 is not None and _lines_whole(first_log)
        and np.array_equal(DaemonColumns.of(log1).cycle, np.arange(len(log1))),
        "restart_gets_the_lock": r.returncode == 0 and "another sea-daemon" not in r.stderr,
        "restarted_every_cycle": log2 is not None and len(log2) == cycles == summary.get("rows_written")
        and summary.get("rows_lost") == 0,
        "no_pid_file_left": not (logs / "sea-daemon.pid").exists(),
    }
    return {"cycles": cycles, "rows": (0 if log2 is None else len(log2)), "rows_lost": summary.get("rows_lost"),
            "killed_rows": 0 if log1 is None else len(log1), "checks": checks,
            "stderr": r.stderr.strip().splitlines()[-1:] if r.returncode else []}


def run_rounds(rounds: int, cycles: int, seed: int, attacks=ATTACKS, progress=None) -> dict:
    rng = np.random.default_rng(seed)
    fns = {"device_model_stopped": attack_device_model_stopped, "disk_full": attack_disk_full,
           "restart": attack_restart}
    out = {"rounds": rounds, "cycles": cycles, "seed": seed, "attacks": {a: [] for a in attacks}}
    for i in range(rounds):
        for a in attacks:
            with tempfile.TemporaryDirectory(prefix=f"sea-bench-record-{a}-") as d:
                t0 = time.monotonic()
                r = fns[a](Path(d), cycles, rng)
                r["wall_s"] = round(time.monotonic() - t0, 1)
                r["ok"] = all(bool(v) for v in r["checks"].values())
                out["attacks"][a].append(r)
                if progress:
                    progress(i, a, r)
    return out


def table(res: dict) -> str:
    lines = [f"{'attack':<22}{'rounds':>7}{'passed':>8}{'cycles':>9}{'rows':>9}{'rows lost':>11}  failed checks"]
    for a, rs in res["attacks"].items():
        failed = sorted({k for r in rs for k, v in r["checks"].items() if not v})
        lines.append(f"{a:<22}{len(rs):>7}{sum(r['ok'] for r in rs):>8}{sum(r['cycles'] for r in rs):>9}"
                     f"{sum(r['rows'] for r in rs):>9}{sum(r['rows_lost'] or 0 for r in rs):>11}  "
                     f"{', '.join(failed) or '-'}")
    return "\n".join(lines)


def add_arguments(p) -> None:
    p.add_argument("--rounds", type=int, default=5, help="rounds of every attack (default 5)")
    p.add_argument("--cycles", type=int, default=600, help="loop cycles of each service run (default 600)")
    p.add_argument("--seed", type=int, default=0, help="seed of the attack cycles and sizes")
    add_choice_argument(p, "--attacks", ATTACKS)
    add_json_argument(p, "every round's record")


def run(args) -> int:
    if args.rounds < 1 or args.cycles < 200:
        raise InputError(f"--rounds {args.rounds} (>= 1), --cycles {args.cycles} (>= 200)")
    attacks, save = choose(args.attacks, ATTACKS, "--attacks"), json_output(args)
    print(f"# sea-daemon bench record on {machine()}")
    print(f"# {args.rounds} rounds of {', '.join(attacks)}; {args.cycles} cycles a service run, lock-step, "
          f"device model on a virtual CAN bus, seed {args.seed}", flush=True)

    def progress(i, a, r):
        bad = [k for k, v in r["checks"].items() if not v]
        print(f"#   round {i + 1} {a}: {r['rows']} rows, {r['rows_lost']} lost, "
              f"{'ok' if r['ok'] else 'FAILED ' + ', '.join(bad)} ({r['wall_s']} s)", flush=True)
    res = run_rounds(args.rounds, args.cycles, args.seed, attacks, progress)
    print(table(res))
    save(res)
    return 0 if all(r["ok"] for rs in res["attacks"].values() for r in rs) else 1
