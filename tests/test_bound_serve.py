"""The bound worker's loop (runtime/bound_serve.py) holds SCHED_FIFO only while it keeps up: a
worker more than YIELD_BEHIND samples behind goes SCHED_OTHER (so the kernel's budget for
real-time tasks never stops the loop's CPU for it) and takes SCHED_FIFO again once caught up.
The timing is simulated: each sample's cost is a number of loop periods, in which the fake
loop publishes that many heads; no clock is read."""
from __future__ import annotations

import os
import types

import numpy as np
import pytest

from sea_daemon.core.estimators.record import StepRecord
from sea_daemon.runtime import bound_serve
from sea_daemon.runtime import bound_slots as bs
from sea_daemon.runtime.counts import write_count

CAP = 256


class _Loop:
    """The loop's side: heads written to the worker's pipe as loop periods pass; the periods a
    sample costs, by sample, from ``cost``; ``last`` heads in all, then the stop."""

    def __init__(self, fd: int, cost, last: int):
        self.fd, self.cost, self.last = fd, cost, last
        self.published, self.owed, self.stopped = 0, 0.0, False
        self.buf = bytearray(8)

    def periods(self, n: float) -> None:
        self.owed += n
        while self.owed >= 1.0 and not self.stopped:
            self.owed -= 1.0
            if self.published < self.last:
                self.published += 1
                write_count(self.fd, self.buf, self.published)
            else:
                write_count(self.fd, self.buf, bs.STOP)
                self.stopped = True


class _AKF:
    """Stands in for the worker's copy of the filter: each sample "costs" its periods."""

    n = 1

    def __init__(self):
        self.est = types.SimpleNamespace(k=0, invalid_reason=0, tau_h_act_bound=np.zeros(1))
        self.samples = 0
        self.loop = None

    def finish_step(self, e, rec):
        self.loop.periods(self.loop.cost(self.samples))
        self.samples += 1
        return True


def _server(monkeypatch, cost, last: int, rt_priority: int = 60, permitted=lambda policy: True):
    """A Server on a fake loop; the scheduling changes asked, with the backlog at each."""
    rec = StepRecord.zeros(1)
    lay, w = bs.layout(rec)
    rw = bs.N_RES + 1
    views = bs.map_shared(bytearray(bs.shared_size(CAP, w, rw, 0)), CAP, w, rw, 0)
    views.hdr[bs.H_SCHED] = rt_priority
    heads_r, heads_w = os.pipe()
    counts_r, counts_w = os.pipe()
    akf = _AKF()
    akf.loop = _Loop(heads_w, cost, last)
    server = bound_serve.Server(akf, views, 0, lay, heads_r, counts_w, os.getppid(), via_pipe=False,
                                rt_priority=rt_priority)
    calls = []

    def setsched(pid, policy, param):
        calls.append((policy, param.sched_priority, server.head - server.done))
        if not permitted(policy):
            raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(os, "sched_setscheduler", setsched)
    wait = server.wait

    def wait_a_period():
        # the worker waits for the loop's next head: a period passes
        if akf.loop.published == server.head and not akf.loop.stopped:
            akf.loop.periods(1.0)
        return wait()

    server.wait = wait_a_period
    akf.loop.periods(1.0)
    fds = (heads_r, heads_w, counts_r, counts_w)
    return server, calls, views, fds


def _serve(monkeypatch, cost, last: int, **kw):
    """The worker's loop run to its stop on the fake loop: (server, scheduling calls, views)."""
    server, calls, views, fds = _server(monkeypatch, cost, last, **kw)
    try:
        server.serve()
    finally:
        for fd in fds:
            os.close(fd)
    return server, calls, views


def test_a_worker_behind_gives_up_sched_fifo_and_takes_it_again_once_caught_up(monkeypatch):
    # 2 periods a sample for the first 40 samples (always behind), then half a period
    server, calls, views = _serve(monkeypatch, lambda i: 2.0 if i < 40 else 0.5, last=400)
    assert server.done == server.head == 400 and server.stop
    assert calls == [(os.SCHED_OTHER, 0, 16), (os.SCHED_FIFO, 60, 1)]
    assert views.hdr[bs.H_YIELDS] == 1 and views.hdr[bs.H_YIELDED] == 0 and views.hdr[bs.H_SCHED] == 60


def test_a_worker_that_keeps_up_keeps_sched_fifo(monkeypatch):
    # 3 samples of 2 periods, then half a period: never more than YIELD_BEHIND behind
    server, calls, views = _serve(monkeypatch, lambda i: 2.0 if i < 3 else 0.5, last=100)
    assert server.done == 100
    assert calls == [] and views.hdr[bs.H_YIELDS] == 0


def test_a_worker_always_behind_stays_sched_other(monkeypatch):
    server, calls, views = _serve(monkeypatch, lambda i: 1.5, last=300)
    assert calls == [(os.SCHED_OTHER, 0, 9)]
    assert views.hdr[bs.H_YIELDS] == 1 and views.hdr[bs.H_YIELDED] == 1


def test_a_worker_not_permitted_sched_fifo_again_stays_sched_other(monkeypatch):
    server, calls, views = _serve(monkeypatch, lambda i: 2.0 if i < 40 else 0.5, last=400,
                                  permitted=lambda policy: policy != os.SCHED_FIFO)
    assert [c[:2] for c in calls] == [(os.SCHED_OTHER, 0), (os.SCHED_FIFO, 60), (os.SCHED_OTHER, 0)]
    assert views.hdr[bs.H_SCHED] == 0 and views.hdr[bs.H_YIELDED] == 0


@pytest.mark.parametrize("cost", [0.5, 3.0])
def test_a_worker_at_sched_other_never_changes_its_scheduling(monkeypatch, cost):
    server, calls, views = _serve(monkeypatch, lambda i: cost, last=200, rt_priority=0)
    assert server.done == 200 and calls == []
