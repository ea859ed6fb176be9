"""One service instance per bus and state directory, and `sea-daemon reset` signals only a
process it proves to be the daemon (issue 15, item 3)."""
from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
import time

import pytest

from sea_daemon.apps.cli import main
from _paths import repo_root
from sea_daemon.runtime.service import StateFile, process_start_time

ROOT = repo_root()
CFG = str(ROOT / "configs" / "exo_1dof_sim.yaml")
PASSIVE = str(ROOT / "configs" / "scenarios" / "passive.yaml")

# a stand-in daemon: claims the state directory as `run` does, writes the pid file, reports SIGUSR1
DAEMON = textwrap.dedent("""
    import signal, sys, time
    from sea_daemon.runtime.service import StateFile
    got = []
    signal.signal(signal.SIGUSR1, lambda *_: got.append(1))
    with StateFile(sys.argv[1]).claim() as st:
        st.write(command="run")
        print("ready", flush=True)
        while not got:
            time.sleep(0.01)
        print("reset received", flush=True)
""")


def _cli(capsys, *argv):
    code = main([str(a) for a in argv])
    _, err = capsys.readouterr()
    return code, err


@pytest.fixture
def daemon(tmp_path):
    p = subprocess.Popen([sys.executable, "-c", DAEMON, str(tmp_path)], stdout=subprocess.PIPE, text=True,
                         env=dict(os.environ, PYTHONPATH=str(ROOT)))
    assert p.stdout.readline().strip() == "ready"
    yield p
    if p.poll() is None:
        p.kill()
    p.wait(10)


@pytest.fixture
def bystander():
    """An unrelated long-running process (the `tail -f` of the issue)."""
    p = subprocess.Popen(["sleep", "300"])
    yield p
    p.kill()
    p.wait(10)


def test_a_second_instance_on_the_same_state_directory_is_refused(tmp_path, daemon, capsys):
    before = (tmp_path / "sea-daemon.pid").read_text()
    code, err = _cli(capsys, "run", "--config", CFG, "--model", tmp_path / "m.npz", "--sim", PASSIVE,
                     "--log-dir", tmp_path, "--cycles", 5)
    assert code == 2 and "another sea-daemon" in err and "state directory" in err, err
    assert f"pid {daemon.pid}" in err
    assert (tmp_path / "sea-daemon.pid").read_text() == before          # the running one's pid file is intact
    assert not list(tmp_path.glob("run-*.csv"))
    code, err = _cli(capsys, "calibrate", "--config", CFG, "--sim", PASSIVE, "--out", tmp_path / "m.npz",
                     "--log-dir", tmp_path, "--cycles", 5, "--no-progress")
    assert code == 2 and "another sea-daemon" in err
    # reset still finds and signals the first one
    assert _cli(capsys, "reset", "--log-dir", tmp_path)[0] == 0
    assert daemon.stdout.readline().strip() == "reset received"


def test_a_second_instance_on_the_same_bus_is_refused(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("SEA_DAEMON_LOCK_DIR", str(tmp_path))
    (tmp_path / "a").mkdir()
    with StateFile(tmp_path / "a").claim(("socketcan", "can7")):
        code, err = _cli(capsys, "run", "--config", CFG, "--model", tmp_path / "m.npz", "--bus", "socketcan",
                         "--channel", "can7", "--log-dir", tmp_path / "b", "--cycles", 5)
    assert code == 2 and "another sea-daemon" in err and "bus socketcan can7" in err, err
    assert not (tmp_path / "b" / "sea-daemon.pid").exists()


def test_the_locks_are_released_when_the_instance_ends(tmp_path, monkeypatch):
    monkeypatch.setenv("SEA_DAEMON_LOCK_DIR", str(tmp_path))
    for _ in range(2):
        with StateFile(tmp_path).claim(("socketcan", "can7")):
            pass


def test_reset_refuses_a_planted_pid_file_and_signals_nothing(tmp_path, bystander, capsys):
    (tmp_path / "sea-daemon.pid").write_text(json.dumps(
        {"pid": bystander.pid, "start_time": process_start_time(bystander.pid), "command": "run"}))
    code, err = _cli(capsys, "reset", "--state-dir", tmp_path)
    assert code == 2 and "no running sea-daemon" in err
    time.sleep(0.2)
    assert bystander.poll() is None                       # still running: not signalled


def test_reset_refuses_a_pid_that_does_not_hold_the_daemons_lock(tmp_path, daemon, bystander, capsys):
    # a daemon holds the directory, but the pid file names another process
    (tmp_path / "sea-daemon.pid").write_text(json.dumps(
        {"pid": bystander.pid, "start_time": process_start_time(bystander.pid), "command": "run"}))
    code, err = _cli(capsys, "reset", "--state-dir", tmp_path)
    assert code == 2 and "is not the daemon" in err, err
    time.sleep(0.2)
    assert bystander.poll() is None and daemon.poll() is None


def test_reset_refuses_a_reused_pid(tmp_path, daemon, capsys):
    info = json.loads((tmp_path / "sea-daemon.pid").read_text())
    info["start_time"] += 1                                # the recorded process was another one
    (tmp_path / "sea-daemon.pid").write_text(json.dumps(info))
    code, err = _cli(capsys, "reset", "--state-dir", tmp_path)
    assert code == 2 and "another process" in err
