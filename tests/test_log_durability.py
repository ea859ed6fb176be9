"""Nothing lost: the measured log survives the loop's process dying (SIGKILL), and a
SIGTERM'd loop closes it cleanly with every row."""
from __future__ import annotations

import signal
import subprocess
import sys
import textwrap
import time

import numpy as np

from _paths import repo_root
from sea_daemon.io.logcsv import read_log

CHILD = textwrap.dedent("""
    import os, signal, sys, time
    import numpy as np
    from sea_daemon.runtime.logwriter import LogWriter
    path, n, how = sys.argv[1], int(sys.argv[2]), sys.argv[3]
    w = LogWriter(path, ["t", "q", "theta_m", "tau_m"], capacity=1 << 14, flush_interval=0.5)
    stop = []
    signal.signal(signal.SIGTERM, lambda *_: stop.append(1))
    row = np.zeros(4)
    for i in range(n):
        row[0] = i * 0.001; row[1] = 0.1; row[2] = 0.1; row[3] = 0.0
        while not w.append(row):
            time.sleep(0.001)
    print(w._proc.pid, flush=True)
    if how == "kill":
        os.kill(os.getpid(), signal.SIGKILL)        # the loop dies: no close, no flush
    while not stop:
        time.sleep(0.01)
    print(w.close()["rows_written"], flush=True)   # SIGTERM: clean close
""")


def _run(tmp_path, how, n=20000):
    path = tmp_path / "run.csv"
    p = subprocess.Popen([sys.executable, "-c", CHILD, str(path), str(n), how], stdout=subprocess.PIPE,
                         text=True, cwd=repo_root(), env={"PYTHONPATH": str(repo_root()), "PATH": "/usr/bin:/bin"})
    writer_pid = int(p.stdout.readline())
    if how == "term":
        p.send_signal(signal.SIGTERM)
    p.wait(60)
    deadline = time.monotonic() + 30                 # the orphaned writer drains and exits
    while time.monotonic() < deadline:
        try:
            with open(f"/proc/{writer_pid}/status") as fh:
                if "State:\tZ" in fh.read():
                    break
        except FileNotFoundError:
            break
        time.sleep(0.05)
    return path, p


def test_rows_survive_the_loop_being_killed(tmp_path):
    path, p = _run(tmp_path, "kill")
    assert p.returncode == -signal.SIGKILL
    log = read_log(path)
    assert len(log) == 20000 and np.allclose(log.t, np.arange(20000) * 0.001, rtol=1e-9, atol=0)


def test_sigterm_closes_the_log_with_every_row(tmp_path):
    path, p = _run(tmp_path, "term")
    assert p.returncode == 0 and int(p.stdout.read().strip()) == 20000
    assert len(read_log(path)) == 20000
