"""CPU placement (runtime.affinity): ``--cpus`` checked with one line and exit 2, the loop's
thread pinned by the service once the hardware has started, the bound worker pinned to its own,
the device model's threads to theirs."""
from __future__ import annotations

import os
import subprocess
import sys

import pytest

from sea_daemon.errors import InputError
from sea_daemon.runtime.affinity import allowed_cpus, parse_cpus, pin_thread
from tests._paths import repo_root

LAST = allowed_cpus()[-1]


@pytest.fixture
def keep_affinity():
    """The test's thread gets its CPUs back whatever the test pinned it to."""
    mask = os.sched_getaffinity(0)
    yield
    os.sched_setaffinity(0, mask)


def test_parse_cpus_takes_one_cpu_per_part_that_this_process_may_use():
    assert parse_cpus(None, "--cpus", ("loop", "worker")) is None
    assert parse_cpus(f"{LAST}", "--cpus", ("loop", "worker")) == (LAST,)
    assert parse_cpus(f"0, {LAST}", "--cpus", ("loop", "worker")) == (0, LAST)
    bad = LAST + 1
    with pytest.raises(InputError, match=rf"^--cpus 0,{bad}: the worker's CPU {bad} is not one this process may "
                                         r"run on \(allowed: 0"):
        parse_cpus(f"0,{bad}", "--cpus", ("loop", "worker"))
    for text in ("x", "0,1,0", "-1", "0;1", "1.5"):
        with pytest.raises(InputError, match=r"^--cpus .*: allowed LOOP\[,WORKER\], each a CPU number in 0"):
            parse_cpus(text, "--cpus", ("loop", "worker"))


def test_pin_thread_pins_the_calling_thread(keep_affinity):
    assert pin_thread(None) == "not pinned"
    assert pin_thread(LAST) == f"CPU {LAST}" and os.sched_getaffinity(0) == {LAST}


@pytest.mark.skipif(len(allowed_cpus()) < 2, reason="one CPU: nothing to keep off the loop's")
def test_the_service_pins_the_loop_and_the_bound_worker(tmp_path, keep_affinity, monkeypatch):
    """serve(cpus=(loop, worker)): every cycle runs on the loop's CPU, the worker on its own, the
    log writer's process on the CPUs other than the loop's."""
    import sea_daemon.runtime.service as svc
    made = []

    class Recording(svc.LogWriter):
        def __init__(self, *a, **k):
            super().__init__(*a, **k)
            made.append(self)
    monkeypatch.setattr(svc, "LogWriter", Recording)
    others = frozenset(allowed_cpus()) - {LAST}
    from sea_daemon.io.configfile import default_config_path, load_config
    from sea_daemon.runtime.rig import make_rig
    from sea_daemon.runtime.controller import ZeroTorque
    from sea_daemon.core.estimators import make_estimator
    cfg = load_config(default_config_path())
    scen = str(repo_root() / "configs" / "scenarios" / "passive.yaml")
    rig = make_rig(cfg, sim=scen, phase="estimation")
    seen, worker_cpus, writer_cpus = [], [], []
    est = make_estimator("akf", cfg, bound=True)

    def progress(k, e):
        seen.append(frozenset(os.sched_getaffinity(0)))
        link = getattr(est, "consumer", None)
        if link is not None and k == 5:
            worker_cpus.append(frozenset(os.sched_getaffinity(link.pid)))
            writer_cpus.append(frozenset(os.sched_getaffinity(made[0].writer_pid)))
    res = svc.serve(rig, est, ZeroTorque(cfg.joints), cfg.joints, cfg.dt, tmp_path / "run.csv", cycles=30,
                realtime=True, rt_priority=0, progress=progress, bound_in="worker", cpus=(LAST, 0))
    assert res.realtime["cpu"] == f"CPU {LAST}"
    assert seen and set(seen) == {frozenset({LAST})}
    assert worker_cpus == [frozenset({0})] and res.extra["bound"]["cpu"] == "CPU 0"
    assert writer_cpus == [others]


@pytest.mark.parametrize("argv, line", [
    (["bench", "loop", "--cpus", "0,1,0,1", "--cycles", "100"], "--cpus 0,1,0,1: allowed LOOP[,WORKER[,DEVICE_MODEL]]"),
    (["bench", "loop", "--cpus", "0,0,0", "--cycles", "100"], "a device model's CPU needs --bus ipc or remote"),
    (["device-model", "--cpu", "4096"], "--cpu 4096: the device model's CPU 4096 is not one this process may run on"),
])
def test_a_bad_cpu_option_is_one_line_and_exit_2(argv, line):
    out = subprocess.run([sys.executable, "-m", "sea_daemon", *argv], capture_output=True, text=True, timeout=120,
                         env=dict(os.environ, PYTHONPATH=str(repo_root())))
    assert out.returncode == 2 and line in out.stderr and len(out.stderr.strip().splitlines()) == 1, out.stderr
