"""``sea-daemon bench latency``: compute time per estimator step.

Times ``estimator.update()`` (one sample: differentiator, prediction with one matrix
exponential, Joseph update) with ``time.perf_counter`` over a log, after a warm-up, and
prints median, p99, p99.9 and max with the number of runs and the machine.

The workload is ``--log`` when given, else a synthetic log: the nominal model of
``--config`` driven by a two-sine motor torque and a sine human torque, integrated by the
model's own local-linearisation step, encoders quantised to ``hardware.encoder_bits``.

Extension point: :data:`CASES` maps a label to ``builder(cfg, dt, log) -> estimator``;
``register()`` adds one (the GP-AKF at 10^3 … 10^6 training points registers its cases
here; ``--estimators`` selects by label).
"""
from __future__ import annotations

import time
from typing import Callable

import numpy as np

from . import machine, summarize
from ..config import default_config_path, load_config
from ..estimators import AKF, SpringTorqueEstimator
from ..logio import MeasuredLog, read_log
from ..model import SEAModel, discretize

NAME = "latency"
HELP = "time per estimator step (median, p99, p99.9) on a simulated or given log"

#: label -> builder(cfg, dt, log) -> Estimator
CASES: dict[str, Callable] = {
    "akf": lambda cfg, dt, log: AKF(cfg, dt=dt),
    "spring": lambda cfg, dt, log: SpringTorqueEstimator(cfg, dt=dt),
}


def register(label: str, builder: Callable) -> None:
    """Add a timed case (e.g. ``gp-akf-1e4``)."""
    CASES[label] = builder


def synthetic_log(cfg, seconds: float = 20.0, seed: int = 0) -> MeasuredLog:
    """Nominal-model log for timing (not for accuracy figures)."""
    m = SEAModel.from_config(cfg)
    n, dt = m.n, cfg.dt
    N = int(seconds / dt) + 1
    t = np.arange(N) * dt
    rng = np.random.default_rng(seed)
    ph = rng.uniform(0, 2 * np.pi, size=(2, n))
    tau_m = 1.5 * np.sin(2 * np.pi * 0.5 * t[:, None] + ph[0]) + 0.5 * np.sin(2 * np.pi * 1.3 * t[:, None] + ph[1])
    tau_h = 1.0 * np.sin(2 * np.pi * 0.3 * t[:, None])
    x = np.zeros(5 * n)
    q = np.zeros((N, n))
    th = np.zeros((N, n))
    res = 2 * np.pi / 2 ** cfg.hardware.encoder_bits
    for k in range(N):
        q[k] = np.round((x[:n] + x[n:2 * n]) / res) * res
        th[k] = np.round(x[:n] / res) * res
        x[4 * n:] = tau_h[k]
        dx, _ = discretize(m.F_nom(x, tau_m[k]), m.f_nom(x, tau_m[k]), dt)
        x = x + dx
    return MeasuredLog(t=t, q=q, theta_m=th, tau_m=tau_m, tau_h_act=tau_h, path="<synthetic>")


def time_steps(est, log: MeasuredLog, warmup: int = 50) -> np.ndarray:
    """Seconds per ``update`` call over the log (first ``warmup`` steps not recorded)."""
    est.reset(log.q[0], log.theta_m[0], log.tau_m[0])
    clock = time.perf_counter
    out = np.empty(len(log) - 1)
    for k in range(1, len(log)):
        q, th, u, dt = log.q[k], log.theta_m[k], log.tau_m[k], log.t[k] - log.t[k - 1]
        t0 = clock()
        est.update(q, th, u, dt)
        out[k - 1] = clock() - t0
    return out[warmup:]


def add_arguments(p) -> None:
    p.add_argument("--config", default=str(default_config_path()), help="model configuration")
    p.add_argument("--log", default=None, help="measured log to replay (default: synthetic)")
    p.add_argument("--seconds", type=float, default=30.0, help="length of the synthetic log [s]")
    p.add_argument("--repeat", type=int, default=3, help="passes over the log per estimator")
    p.add_argument("--estimators", default="akf,spring",
                   help=f"comma-separated labels (known: {', '.join(CASES)})")


def run(args) -> int:
    from ..errors import InputError
    cfg = load_config(args.config)
    labels = [s.strip() for s in args.estimators.split(",") if s.strip()]
    unknown = [s for s in labels if s not in CASES]
    if unknown:
        raise InputError(f"--estimators: unknown {', '.join(unknown)}; allowed: {', '.join(CASES)}")
    if args.repeat < 1:
        raise InputError(f"--repeat must be >= 1, got {args.repeat}")
    log = read_log(args.log, n=cfg.joints, min_rows=100) if args.log else synthetic_log(cfg, args.seconds)
    import os
    print(f"machine: {machine()}; load average {os.getloadavg()[0]:.2f} at start")
    print(f"data: {log.path}, {len(log)} samples at {1 / log.dt:.0f} Hz, {cfg.joints} joint(s), "
          f"config {args.config}; {args.repeat} pass(es), 50 warm-up steps dropped per pass")
    for label in labels:
        est = CASES[label](cfg, log.dt, log)
        times = np.concatenate([time_steps(est, log) for _ in range(args.repeat)])
        print(f"{label:>10s}: per step {summarize(times)}")
    return 0
