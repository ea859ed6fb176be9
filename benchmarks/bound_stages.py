"""``python -m benchmarks.bound_stages``: the Theorem-1 bound's cost per sample, stage by stage —
what the bound worker computes for every sample.

The GP-AKF of ``--config`` (default the two-joint arm, ``configs/exo_2dof.yaml``) at ``--rate``
learns its LoG-GPs online over a synthetic log of ``--seconds`` (``sea-daemon bench latency``'s,
:func:`sea_daemon.apps.bench.latency.synthetic_log`), is frozen and runs again over the log with
its bound.  Each public call of the bound's step is wrapped with the thread's CPU clock: the
whole step (``AKFTheoremBound.step``), the Gaussian part, a URDF model's rigid-body box
(``RigidBox.at``: M(q̂) and the box; in it ``RigidBox.box``, the batched ABA
``RigidBody.forward_columns``, the ABA derivatives) and the compiled step
(``bound_core.bound_step``: GP stage, prior and update of the set of means).  Printed: the
median and p99 of each over the run (the caches as the filter's own step leaves them), then the
last sample's compiled step and rigid box called ``--repeat`` times in a row (hot caches), and
the machine's load average.  CPU time, not wall time: valid on a shared host, but a busy host
makes the CPU time of the same work larger too (shared caches, hyperthreads).
"""
from __future__ import annotations

import dataclasses
import os
import time

import numpy as np

from sea_daemon.apps.bench._gpakf_cases import frozen_gpakf
from sea_daemon.apps.bench.latency import synthetic_log
from sea_daemon.core.bounds import bound_core
from sea_daemon.core.bounds.akf_bound import AKFTheoremBound
from sea_daemon.core.bounds.gaussian_part import GaussianPart
from sea_daemon.core.bounds.rigid_box import RigidBox
from sea_daemon.core.model import SEAModel
from sea_daemon.core.rigid import RigidBody
from sea_daemon.errors import InputError
from sea_daemon.io.configfile import data_root, load_config

NAME = "bound_stages"
HELP = "the Theorem-1 bound's CPU time per sample, stage by stage (the bound worker's work)"


WHOLE, GAUSS, RIGID = "bound step (whole)", "  Gaussian part", "  rigid body: M(q) and its box"
MASS, BOX = "    M(q), M^-1", "    box over W.C"
ABA, ABAD = "      ABA at its points (one call)", "      ABA derivatives (the filter's too)"
CORE = "  compiled step (GP, set of means)"
#: the printed order
ORDER = (WHOLE, GAUSS, RIGID, MASS, BOX, ABA, ABAD, CORE)


def add_arguments(p) -> None:
    p.add_argument("--config", default=str(data_root() / "configs" / "exo_2dof.yaml"), help="model configuration")
    p.add_argument("--rate", type=float, default=1000.0, help="sample rate [Hz] (default 1000)")
    p.add_argument("--seconds", type=float, default=3.0, help="length of the synthetic log [s] (default 3)")
    p.add_argument("--repeat", type=int, default=2000, help="hot calls of the last sample's stages (default 2000)")


class _Timed:
    """CPU time of every call of the wrapped callables, by label (restored by :meth:`restore`)."""

    def __init__(self):
        self.t: dict[str, list[int]] = {}
        self._undo = []

    def wrap(self, owner, attr: str, label: str) -> None:
        fn = getattr(owner, attr)
        t = self.t.setdefault(label, [])
        clock = time.thread_time_ns

        def timed(*a, **k):
            c0 = clock()
            try:
                return fn(*a, **k)
            finally:
                t.append(clock() - c0)
        setattr(owner, attr, timed)
        self._undo.append((owner, attr, fn))

    def restore(self) -> None:
        for owner, attr, fn in reversed(self._undo):
            setattr(owner, attr, fn)
        self._undo.clear()


def _hot(fn, repeat: int) -> float:
    """Hot cost [µs]: the mean CPU time of ``repeat`` calls in a row, after 20 unmeasured ones."""
    for _ in range(20):
        fn()
    c0 = time.thread_time_ns()
    for _ in range(repeat):
        fn()
    return (time.thread_time_ns() - c0) / repeat / 1e3


def run(args) -> int:
    if not 10.0 <= args.rate <= 10000.0:
        raise InputError(f"--rate must be in 10..10000 Hz, got {args.rate}")
    if not 0.5 <= args.seconds <= 60.0:
        raise InputError(f"--seconds must be in 0.5..60, got {args.seconds}")
    if not 1 <= args.repeat <= 10 ** 6:
        raise InputError(f"--repeat must be in 1..1000000, got {args.repeat}")
    cfg = dataclasses.replace(load_config(args.config), rate_hz=float(args.rate))
    log = synthetic_log(cfg, args.seconds)
    est = frozen_gpakf(cfg, log.dt, log, True, verbose=False)
    timed = _Timed()
    last = {}
    timed.wrap(AKFTheoremBound, "step", WHOLE)
    timed.wrap(GaussianPart, "step", GAUSS)
    timed.wrap(RigidBox, "at", RIGID)
    timed.wrap(SEAModel, "at", MASS)
    timed.wrap(RigidBody, "forward_columns", ABA)
    timed.wrap(RigidBody, "forward_derivatives", ABAD)
    bs = bound_core.bound_step

    def grab(*a):
        last["step"] = a
        return bs(*a)
    bound_core.bound_step = grab
    timed.wrap(bound_core, "bound_step", CORE)
    box_orig = RigidBox.box

    def grab_box(self, *a):
        last["box"] = (self, a)
        return box_orig(self, *a)
    try:
        RigidBox.box = grab_box
        timed.wrap(RigidBox, "box", BOX)
        est.reset(log.q[0], log.theta_m[0], log.tau_m[0])
        for k in range(1, len(log)):
            est.update(log.q[k], log.theta_m[k], log.tau_m[k], log.t[k] - log.t[k - 1])
    finally:
        timed.restore()
        RigidBox.box = box_orig
        bound_core.bound_step = bs
    print(f"{args.config}: {cfg.joints} joint(s) at {args.rate:g} Hz, {len(log)} samples; CPU time per sample "
          f"(thread clock), median / p99 over the run after its first 100 samples:")
    for label in ORDER:
        v = np.asarray(timed.t.get(label, [])[100:], dtype=float) / 1e3
        if v.size:
            print(f"  {label:40s} {np.median(v):7.1f} / {np.percentile(v, 99):7.1f} us  ({v.size} calls)")
    if "step" in last:
        print(f"the last sample's calls, {args.repeat} times in a row (hot caches), mean CPU time:")
        print(f"  {CORE.strip():40s} {_hot(lambda: bs(*last['step']), args.repeat):7.1f} us")
    if "box" in last:
        rb, a = last["box"]
        print(f"  {'rigid body: ' + BOX.strip():40s} {_hot(lambda: box_orig(rb, *a), args.repeat):7.1f} us")
    print("load average " + " ".join(f"{x:.2f}" for x in os.getloadavg()) + " (1/5/15 min)")
    return 0


if __name__ == "__main__":
    import sys

    from benchmarks._cli import main
    sys.exit(main(sys.modules[__name__]))
