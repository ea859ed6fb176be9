"""The Theorem-1 bound in a worker process (runtime/bound_worker.py): the same ρ_k per sample as
in the loop, the log's bound_cycle, a killed worker (BOUND_LOST, the loop goes on), no orphan."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
import types
from dataclasses import replace

import numpy as np
import pytest

from sea_daemon.errors import Fault
from sea_daemon.io.configfile import default_config_path, load_config, repo_root
from sea_daemon.runtime.bound_worker import BoundWorker
from sea_daemon.runtime.loop import FixedRateLoop, log_columns
from test_loop import ListLog

COLS = log_columns(1)
T = np.arange(0, 800) * 0.01
Q, TH, U = 0.3 * np.sin(2 * T), 0.29 * np.sin(2 * T), np.cos(3 * T)
TRAIN = 200


@pytest.fixture(scope="module")
def cfg():
    c = load_config(default_config_path())
    return replace(c, learning=replace(c.learning, max_points=40))


def _estimator(cfg):
    """A GP-AKF with a small GP learned on the first samples, learning frozen, the Theorem-1 bound."""
    from sea_daemon.core.bounds.akf_bound import theorem_bound
    from sea_daemon.core.estimators.gpakf import GPAKF
    est = GPAKF(cfg)
    est.reset([0.0], [0.0], [0.0])
    for k in range(1, TRAIN):
        est.update([Q[k]], [TH[k]], [U[k]])
    est.learning = False
    est.bound = theorem_bound(est)
    est.reset()
    return est


class _HW:
    actuation_delay = 0

    def __init__(self, pause=0.0):
        self.k, self.pause = TRAIN, pause

    def read(self):
        if self.pause:
            time.sleep(self.pause)
        k = self.k
        self.k += 1
        return types.SimpleNamespace(t=k * 0.01, q=Q[k:k + 1].copy(), theta_m=TH[k:k + 1].copy())

    def write(self, tau):
        pass

    def actuated(self, cmd):
        return U[self.k - 1:self.k].copy()

    def safe_stop(self):
        pass


class _Zero:
    def update(self, t, q, theta_m, est):
        return np.zeros(1)


def _run(cfg, cycles, worker=False, pause=0.0, kill_at=None, **kw):
    est = _estimator(cfg)
    log = ListLog()
    link = BoundWorker(est, capacity=1024, **kw).start() if worker else None
    hw = _HW(pause)
    if kill_at is not None:
        read = hw.read

        def read_and_kill():
            if hw.k - TRAIN == kill_at:
                os.kill(link.pid, signal.SIGKILL)
                time.sleep(0.3)                      # the loop sees a dead worker within 0.2 s
            return read()
        hw.read = read_and_kill
    loop = FixedRateLoop(hw, est, _Zero(), n=1, period=0.01, log=log, realtime=False, bound_link=link)
    loop.run(cycles)
    stats = link.close() if link is not None else None
    return np.array(log.rows), loop, stats, link


def test_worker_bound_equals_the_in_loop_bound_sample_by_sample(cfg):
    a, _, _, _ = _run(cfg, 400)
    # a lock-step loop outruns the worker: a large max age, so that every finished bound is published
    b, _, st, _ = _run(cfg, 400, worker=True, pause=0.002, max_age=10 ** 6)
    iv, ic, ib, ih = (COLS.index(c) for c in ("valid", "bound_cycle", "tau_h_act_bound", "tau_h_act_hat"))
    assert st["where"] == "worker" and not st["broken"] and st["fault"] is None
    # the filter is the loop's in both: the same estimates
    both = (a[:, iv] > 0) & (b[:, iv] > 0)
    assert both.sum() > 300 and np.array_equal(a[both, ih], b[both, ih])
    # in-loop: each row's bound is its own sample's
    assert np.array_equal(a[a[:, iv] > 0, ic], a[a[:, iv] > 0, COLS.index("cycle")])
    assert np.all(a[a[:, iv] == 0, ic] == -1)
    # worker: the row says which sample its bound belongs to; aligned on it, the same ρ_k to the bit
    sel = b[:, iv] > 0
    k_b = b[sel, ic].astype(int)
    assert np.all(k_b <= b[sel, COLS.index("cycle")]) and np.unique(k_b).size > 300
    assert np.array_equal(b[sel, ib], a[k_b, ib])
    # and the start-up gate, run where ρ_k is computed, says what the loop's own says of each sample
    assert np.all(a[k_b, iv] == 1) and k_b.min() >= int(np.argmax(a[:, iv] > 0))


def test_a_killed_worker_latches_BOUND_LOST_and_the_loop_goes_on(cfg):
    rows, loop, st, link = _run(cfg, 200, worker=True, pause=0.002, kill_at=120, max_age=50)
    sup = loop.supervisor
    assert len(rows) == 200 and loop.stats.cycles == 200          # the loop ran every cycle
    assert sup.latched == Fault.BOUND_LOST and "exited" in sup.latched_detail
    iv = COLS.index("valid")
    assert rows[100, iv] == 1 and not rows[125:, iv].any()         # no estimate published without its bound
    assert np.all(rows[125:, COLS.index("bound_cycle")] == -1)
    assert st["fault"] is not None


def test_stale_bound_is_not_published(cfg):
    # max age 0: the newest finished bound is always at least the previous cycle's → never published
    rows, loop, st, _ = _run(cfg, 120, worker=True, max_age=0)
    assert not rows[:, COLS.index("valid")].any() and st["stale"] == st["steps"] > 0
    assert loop.supervisor.ok


def test_the_daemon_log_has_the_bound_cycle_column(tmp_path, cfg):
    from sea_daemon.io.logcsv import read_log
    from sea_daemon.runtime.logwriter import LogWriter
    est = _estimator(cfg)
    log = LogWriter(tmp_path / "run.csv", COLS)
    link = BoundWorker(est, max_age=10 ** 6).start()
    try:
        FixedRateLoop(_HW(0.002), est, _Zero(), n=1, period=0.01, log=log, realtime=False, bound_link=link).run(150)
    finally:
        link.close()
        log.close()
    got = read_log(tmp_path / "run.csv", n=1)
    bc, cyc, valid = got.extra["bound_cycle"], got.extra["cycle"], got.extra["valid"]
    assert valid.any() and np.all((bc[valid > 0] >= 0) & (bc[valid > 0] <= cyc[valid > 0]))
    assert np.all(bc[valid == 0] == -1)


_ORPHAN = """
import os, sys, numpy as np
sys.path.insert(0, {root!r}); sys.path.insert(0, {tests!r})
from test_bound_worker import _estimator, load_config, default_config_path, replace
from sea_daemon.runtime.bound_worker import BoundWorker
c = load_config(default_config_path()); c = replace(c, learning=replace(c.learning, max_points=40))
w = BoundWorker(_estimator(c)).start()
print(w.pid, flush=True)
os._exit(0)          # the parent dies without stopping its worker
"""


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(") ")[-1][0] != "Z"
    except FileNotFoundError:
        return False


def test_no_worker_outlives_its_parent_or_the_session(cfg):
    root = str(repo_root())
    out = subprocess.run([sys.executable, "-c", _ORPHAN.format(root=root, tests=str(repo_root() / "tests"))],
                         capture_output=True, text=True, timeout=300, env=dict(os.environ, PYTHONPATH=root))
    pid = int(out.stdout.split()[0])
    end = time.monotonic() + 5
    while _alive(pid) and time.monotonic() < end:
        time.sleep(0.05)
    assert not _alive(pid)
    # closed by its owner: gone, and the AKF has its own bound back
    est = _estimator(cfg)
    bound = est.bound
    w = BoundWorker(est).start()
    assert est.bound is w and _alive(w.pid)
    w.close()
    assert not _alive(w.pid) and est.bound is bound
