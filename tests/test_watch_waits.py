"""``sea-daemon watch`` started before the daemon waits for it, says so, and shows the run when
it starts; ``--timeout`` bounds the wait (exit 2, one refusal line); Ctrl-C ends it with exit 0."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

from _cli import run as cli
from _paths import repo_root
from sea_daemon.apps.cli import main

ROOT = repo_root()
CFG = str(ROOT / "configs" / "exo_1dof_sim.yaml")
PASSIVE = str(ROOT / "configs" / "scenarios" / "passive.yaml")
ENV = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))


def short_dir(tmp_path: Path) -> Path:
    """A state directory whose socket path fits a UNIX socket (107 bytes)."""
    if len(os.fsencode(str(tmp_path / "sea-daemon.sock"))) < 100:
        return tmp_path
    return Path(tempfile.mkdtemp(prefix="sea-"))


def wait_for(cond, timeout: float, what: str, proc=None) -> None:
    """Until ``cond()`` holds; fails after ``timeout`` seconds (generous: a loaded machine)."""
    deadline = time.monotonic() + timeout
    while not cond():
        assert proc is None or proc.poll() is None, f"{what}: the process ended ({proc.returncode})"
        assert time.monotonic() < deadline, f"{what}: not within {timeout} s"
        time.sleep(0.1)


def test_watch_without_a_daemon_waits_until_its_timeout_then_exit_2(tmp_path, capsys):
    code, out, err = cli(["watch", "--state-dir", tmp_path, "--timeout", "0.5", "--plain"], capsys)
    lines = err.strip().splitlines()
    assert code == 2 and "Traceback" not in err
    assert lines[0].startswith(f"sea-daemon watch: waiting for a daemon in {tmp_path}")
    assert len(lines) == 2 and lines[1].startswith(f"sea-daemon watch: error: no sea-daemon publishes in {tmp_path} "
                                                  "within --timeout 0.5 s")


@pytest.mark.parametrize("bad", ["-1", "nan", "inf"])
def test_watch_timeout_out_of_range_refused(tmp_path, capsys, bad):
    from _cli import refused
    code, out, err = cli(["watch", "--state-dir", tmp_path, "--timeout", bad], capsys)
    refused(code, err, r"--timeout .*allowed")


@pytest.mark.slow
def test_watch_started_before_run_shows_the_run_and_ctrl_c_exits_0(tmp_path):
    d = short_dir(tmp_path)
    cal = tmp_path / "cal"
    cal.mkdir()
    assert main(["calibrate", "--config", CFG, "--scenario", PASSIVE, "--device-model", PASSIVE,
                 "--out", str(cal / "m.npz"), "--log-dir", str(cal), "--cycles", "300", "--no-progress",
                 "--socket", "none"]) == 0
    out_path, err_path = tmp_path / "watch.out", tmp_path / "watch.err"
    with open(out_path, "w") as out, open(err_path, "w") as err:
        watch = subprocess.Popen([sys.executable, "-m", "sea_daemon", "watch", "--state-dir", str(d), "--plain",
                                  "--refresh", "0.2"], stdout=out, stderr=err, env=ENV,
                                 # as at a terminal: a suite started in the background (nohup, &)
                                 # passes SIGINT on ignored, and Python then keeps it ignored
                                 preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        # the watcher is up and says it waits (it would have exit 2 before any daemon without waiting)
        wait_for(lambda: "waiting for a daemon" in err_path.read_text(), 60, "watch's waiting message", watch)
        time.sleep(5.0)
        assert watch.poll() is None, err_path.read_text()
        # a short run in real-time pace (10 s at 100 Hz): the watcher finds it whenever it starts;
        # no SCHED_FIFO and no overrun fault for a test on a shared machine (timing is not under test)
        assert main(["run", "--config", CFG, "--model", str(cal / "m.npz"), "--device-model", PASSIVE,
                     "--log-dir", str(d), "--cycles", "1000", "--pace", "realtime", "--rt-priority", "0",
                     "--overrun-streak", "0"]) == 0
        wait_for(lambda: "cycle " in out_path.read_text(), 60, "watch's first sample", watch)
        watch.send_signal(signal.SIGINT)                                   # Ctrl-C of the person watching
        assert watch.wait(60) == 0, err_path.read_text()
    finally:
        if watch.poll() is None:
            watch.kill()
            watch.wait()
    err = err_path.read_text()
    assert f"waiting for a daemon in {d}" in err and "Traceback" not in err, err
    assert "a daemon publishes on" in err
    shown = [ln.split() for ln in out_path.read_text().splitlines() if ln.startswith("cycle ")]
    assert shown and all(0 <= int(x[1]) < 1000 for x in shown)              # the run's cycles
    assert shown[-1][5] == "NONE" and int(shown[-1][1]) > 0
