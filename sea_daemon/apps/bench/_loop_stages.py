"""``bench loop --stages``: the loop thread's CPU time per stage of the cycle (read, controller,
write, estimator and its bound, publication), each stage's method wrapped on its object."""
from __future__ import annotations

import time

import numpy as np

from sea_daemon.runtime.loop import Series


class Stages:
    """Thread CPU time of each stage of the cycle: the stage's method on its object replaced by a
    wrapper that reads the thread's CPU clock around the call (an instance attribute: the class
    and other instances are untouched); the times go into resident buffers for ``calls`` calls
    (:class:`~sea_daemon.runtime.loop.Series`: no page fault added to the cycle)."""

    def __init__(self, calls: int = 1024):
        self.times: dict[str, Series] = {}
        self.calls = calls

    def wrap(self, label: str, obj, name: str) -> None:
        if obj is None or not hasattr(obj, name):
            return
        f = getattr(obj, name)
        acc = self.times.setdefault(label, Series(self.calls))
        clock = time.thread_time

        def timed(*a, **k):
            c0 = clock()
            try:
                return f(*a, **k)
            finally:
                acc.append(clock() - c0)
        setattr(obj, name, timed)

    def summary(self, skip: int) -> dict:
        """Median / p99 [µs] per stage over the calls after the first ``skip``."""
        out = {}
        for label, v in self.times.items():
            v = np.asarray(v, dtype=float)[skip:]
            if v.size:
                out[label] = {"median": float(np.median(v) * 1e6), "p99": float(np.percentile(v, 99) * 1e6),
                              "calls": int(v.size)}
        return out


def stage_timers(n_cycles: int, rig, controller, estimator, publisher, in_worker: bool) -> Stages:
    stages = Stages(n_cycles + 10)
    for label, obj, name in (("read", rig.hw, "read"), ("controller", controller, "update"),
                             ("write", rig.hw, "write"), ("actuated", rig.hw, "actuated"),
                             ("estimator (with its bound)" if not in_worker else
                              "estimator (filter, bound handed to the worker)", estimator, "update"),
                             ("bound", None if in_worker else getattr(estimator, "bound", None), "step"),
                             ("publication", publisher, "publish")):
        stages.wrap(label, obj, name)
    return stages
