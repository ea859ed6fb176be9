"""The measured log has a row for every cycle the loop ran, through and after any fault, and a
log that cannot be written is itself a fault (issue 15, item 1; docs/safety.md)."""
from __future__ import annotations

import resource
import time

import numpy as np
import pytest

from sea_daemon.hw.device_model import parse_fault
from sea_daemon.apps.bench.record import serve_with_action as _serve
from sea_daemon.errors import Fault, InputError
from sea_daemon.io.logcsv import read_log
from sea_daemon.runtime.logwriter import LogWriter


def _check_every_cycle(res, log_path, cycles):
    log = read_log(log_path, n=1)
    ex = log.extra
    assert len(log) == cycles == res.stats.cycles == res.log["rows_written"]
    assert res.log["rows_lost"] == 0 and res.log["error"] is None
    assert np.array_equal(ex["cycle"], np.arange(cycles))
    assert np.all(np.diff(log.t) > 0)
    return log, ex


def test_device_model_killed_mid_run_every_cycle_has_a_row(tmp_path):
    res, path, note = _serve(tmp_path, 300, 100, lambda rig: rig.device_model.stop())
    log, ex = _check_every_cycle(res, path, 300)
    f = ex["fault"]
    first = int(np.argmax(f != 0))
    assert 100 <= first <= 105 and np.all(f[first:] != 0)           # latched, and stays so
    assert np.all(ex["valid"][first:] == 0) and np.all(log.tau_m[first:] == 0)
    assert np.all(ex["measured"][first + 1:] == 0) and np.all(ex["measured"][:first] == 1)
    # placeholders: the last measured angles held, no NaN anywhere (read_log refuses NaN)
    assert np.all(log.q[first + 1:] == log.q[first])
    assert any("FAULT" in s for s in note.lines)


def test_encoder_jump_latches_and_the_log_goes_on(tmp_path):
    res, path, _ = _serve(tmp_path, 300, 100,
                          action=lambda rig: rig.device_model.schedule(parse_fault("jump:target=encoder,rad=0.5")))
    log, ex = _check_every_cycle(res, path, 300)
    assert res.supervisor.latched == Fault.ENCODER_JUMP
    first = int(np.argmax(ex["fault"] != 0))
    assert ex["fault"][first] == int(Fault.ENCODER_JUMP) and np.all(ex["fault"][first:] != 0)
    assert np.all(ex["valid"][first:] == 0)


def test_full_disk_during_a_run_latches_log_failed_and_counts_the_rows_lost(tmp_path):
    def fill_disk(rig):        # the writer's file may grow no further: writes fail (EFBIG)
        w = fill_disk.writer
        resource.prlimit(w._proc.pid, resource.RLIMIT_FSIZE, (w.path.stat().st_size + 4000, resource.RLIM_INFINITY))

    def keep(w):
        fill_disk.writer = w

    def caught_up(rig):        # the unpaced loop waits for the writer (a loaded host lags it): the
        w = fill_disk.writer   # failure then comes while the run goes on, not after its last cycle
        end = time.monotonic() + 60
        while w.fault() is None and w.rows_written < w.appended and time.monotonic() < end:
            time.sleep(0.002)

    res, path, note = _serve(tmp_path, 400, 50, fill_disk, writer_hook=keep, after=caught_up)
    assert res.supervisor.latched == Fault.LOG_FAILED
    assert "File too large" in res.supervisor.latched_detail
    fin = res.log
    assert fin["rows_lost"] > 0 and fin["rows_lost"] == 400 - fin["rows_written"]
    assert "File too large" in fin["error"]
    text = path.read_text()
    assert text.endswith("\n") and text.count("\n") == fin["rows_written"] + 1     # no torn line
    log = read_log(path, n=1)
    assert len(log) == fin["rows_written"]
    assert any("FAULT LOG_FAILED" in s for s in note.lines)
    assert any("rows lost" in s for s in note.lines)


def test_log_writer_that_dies_is_a_fault_and_its_rows_are_counted(tmp_path):
    w = LogWriter(tmp_path / "x.csv", ["t", "q", "theta_m", "tau_m"], capacity=64)
    row = np.zeros(4)
    for i in range(10):
        row[0] = i
        w.append(row)
    deadline = time.monotonic() + 30
    while w.rows_written < 10 and time.monotonic() < deadline:
        w.fault()                  # as the loop every cycle: writes the head when it is due
        time.sleep(0.01)
    w._proc.kill()
    w._proc.join(10)
    deadline = time.monotonic() + 5
    while w.fault() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    assert "writer process exited" in w.fault()
    for i in range(100):
        row[0] = 10 + i
        w.append(row)
    fin = w.close()
    assert fin["rows_written"] == 10 and fin["rows_lost"] == 100 and fin["rows_dropped"] == 100 - 64
    assert fin["error"]


def test_a_log_that_cannot_be_created_is_refused_before_the_start(tmp_path):
    with pytest.raises(InputError, match="cannot write"):
        LogWriter(tmp_path / "missing" / "x.csv", ["t"])
