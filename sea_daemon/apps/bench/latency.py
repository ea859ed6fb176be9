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

import os
import time
from typing import Callable

import numpy as np

from sea_daemon.apps.bench import machine, summarize
from sea_daemon.apps.bench._gpakf_cases import CALIBRATED, register as register_gpakf_cases
from sea_daemon.core.estimators import make_estimator
from sea_daemon.core.linalg import discretize
from sea_daemon.core.log import MeasuredLog
from sea_daemon.core.model import SEAModel
from sea_daemon.errors import InputError
from sea_daemon.io.configfile import default_config_path, load_config
from sea_daemon.io.logcsv import read_log


#: label -> builder(cfg, dt, log) -> Estimator
CASES: dict[str, Callable] = {
    "akf": lambda cfg, dt, log: make_estimator("akf", cfg, dt=dt, bound=False),
    "spring": lambda cfg, dt, log: make_estimator("spring", cfg, dt=dt),
}


def register(label: str, builder: Callable) -> None:
    """Add a timed case (e.g. ``gp-akf-1e4``)."""
    CASES[label] = builder


def synthetic_log(cfg, seconds: float = 20.0, seed: int = 0) -> MeasuredLog:
    """Nominal-model log for timing (not for accuracy figures): a two-sine motor torque with
    random phases and a sine human torque through :func:`model_log`."""
    n, dt = cfg.joints, cfg.dt
    t = np.arange(int(seconds / dt) + 1) * dt
    ph = np.random.default_rng(seed).uniform(0, 2 * np.pi, size=(2, n))
    tau_m = 1.5 * np.sin(2 * np.pi * 0.5 * t[:, None] + ph[0]) + 0.5 * np.sin(2 * np.pi * 1.3 * t[:, None] + ph[1])
    tau_h = 1.0 * np.sin(2 * np.pi * 0.3 * t[:, None]) * np.ones(n)
    return model_log(cfg, t, tau_m, tau_h)


def model_log(cfg, t, tau_m, tau_h, path: str = "<synthetic>") -> MeasuredLog:
    """Log of ``cfg``'s model (declared effects included) driven by ``tau_m`` with the human
    torque ``tau_h`` (both (N, n) at the times ``t``, spaced ``cfg.dt``), integrated by the model's own
    local-linearisation step; encoders truncated to their counts (``hardware.encoder_bits``):
    2π/2^bits on the load side, 2π/(2^bits · gear_ratio) joint side for the motor encoder."""
    m = SEAModel.from_config(cfg)
    n, N = m.n, len(t)
    res, res_m = cfg.hardware.encoder_resolution(cfg.joints)
    x = np.zeros(5 * n)
    q, th = np.zeros((N, n)), np.zeros((N, n))
    for k in range(N):
        q[k] = np.floor((x[:n] + x[n:2 * n]) / res) * res
        th[k] = np.floor(x[:n] / res_m) * res_m
        x[4 * n:] = tau_h[k]
        _, dx = discretize(m.F_nom(x, tau_m[k]), m.f_nom(x, tau_m[k]), cfg.dt)
        x = x + dx
    return MeasuredLog(t=t, q=q, theta_m=th, tau_m=tau_m, tau_h_act=tau_h, path=path)


def time_steps(est, log: MeasuredLog, warmup: int = 50, cpu: bool = False, kinds: list | None = None,
               idle_s: float = 0.0, spin: bool = False):
    """Seconds per ``update`` call over the log (first ``warmup`` steps not recorded).

    With ``cpu``: ``(wall, cpu)``, the second the CPU time of this thread per call
    (``time.thread_time_ns``), which excludes the time the scheduler gave to other processes
    -- on a shared machine the closer figure to what the step costs on an idle one.
    ``kinds``: a list that receives, per recorded step, what the step's LoG-GP did
    (:func:`step_kind`; GP-AKF only).  ``idle_s``: this thread sleeps that long before each
    step, as the loop does between its cycles (the step then finds the caches as another
    process left them); with ``spin`` it busy-waits that long instead (the thread keeps its
    CPU: what is left is what the time itself does to the caches).
    """
    est.reset(log.q[0], log.theta_m[0], log.tau_m[0])
    clock = time.perf_counter_ns
    tclock = time.thread_time_ns
    out = np.empty(len(log) - 1)
    cout = np.empty(len(log) - 1)
    g = est.gp.gps[0] if kinds is not None else None
    for k in range(1, len(log)):
        q, th, u, dt = log.q[k], log.theta_m[k], log.tau_m[k], log.t[k] - log.t[k - 1]
        before = _gp_counters(g) if g is not None else None
        if idle_s > 0.0:
            if spin:
                end = time.monotonic() + idle_s
                while time.monotonic() < end:
                    pass
            else:
                time.sleep(idle_s)
        c0 = tclock()
        t0 = clock()
        est.update(q, th, u, dt)
        t1 = clock()
        cout[k - 1] = tclock() - c0
        out[k - 1] = t1 - t0
        if g is not None and k > warmup:
            kinds.append(step_kind(before, _gp_counters(g)))
    if cpu:
        return out[warmup:] * 1e-9, cout[warmup:] * 1e-9
    return out[warmup:] * 1e-9


def _gp_counters(g) -> tuple:
    return g.n_leaves, g.n_evicted, g.n_hyper_steps, g.hyper_proposal is not None


def step_kind(before: tuple, after: tuple) -> str:
    """What the first joint's LoG-GP did in a step, from its counters before and after:
    'split', 'eviction', 'hyper phase 1' (LML gradient + Adam), 'hyper phase 2' (rebuild
    with the new values) or 'plain' (predict + one O(N̄²) append)."""
    if after[0] != before[0]:
        return "split"
    if after[1] != before[1]:
        return "eviction"
    if after[2] != before[2]:
        return "hyper phase 1"
    if before[3] and not after[3]:
        return "hyper phase 2"
    return "plain"


def add_arguments(p) -> None:
    p.add_argument("--config", default=str(default_config_path()), help="model configuration")
    p.add_argument("--log", default=None, help="measured log to replay (default: synthetic)")
    p.add_argument("--seconds", type=float, default=30.0, help="length of the synthetic log [s]")
    p.add_argument("--repeat", type=int, default=3, help="passes over the log per estimator")
    p.add_argument("--estimators", default="akf,spring,gp-akf",
                   help="comma-separated labels; 'gp-akf' = every gp-akf-1eK case up to --max-points and "
                        "gp-akf-calibrated (known: akf, spring, gp-akf-1e3 … gp-akf-1e6 with online learning, "
                        "gp-akf-calibrated: the calibrated model's step, learning off)")
    p.add_argument("--max-points", type=float, default=1e6,
                   help="largest LoG-GP pre-fill of the gp-akf cases (default 1e6; ~50-100 us per point)")
    p.add_argument("--hyper-every", type=int, default=None,
                   help="gp-akf cases: updates between two hyperparameter slices (default: the LoG-GP "
                        "default, 10; each slice is two O(N̄³) phases on consecutive updates)")
    p.add_argument("--idle-ms", type=float, default=0.0,
                   help="sleep this long before each step, as the loop does between cycles (9 at 100 Hz, "
                        "0.5 at 1 kHz; default 0: the steps back to back)")
    p.add_argument("--idle-spin", action="store_true",
                   help="busy-wait the --idle-ms instead of sleeping (the thread never gives up its CPU)")
    p.add_argument("--quick", action="store_true",
                   help="quick run: 10 s log, 1 pass, gp-akf up to 1e4 points")


def _register_gp_akf(max_points: float, hyper_every: int | None = None) -> list[str]:
    """The GP-AKF cases (:mod:`._gpakf_cases`)."""
    return register_gpakf_cases(register, int(max_points), hyper_every)


def run(args) -> int:
    cfg = load_config(args.config)
    if args.quick:
        args.seconds, args.repeat, args.max_points = min(args.seconds, 10.0), 1, min(args.max_points, 1e4)
    if args.hyper_every is not None and args.hyper_every < 1:
        raise InputError(f"--hyper-every must be >= 1, got {args.hyper_every}")
    gp_labels = _register_gp_akf(args.max_points, args.hyper_every)
    labels = []
    # the calibrated case fits one joint's residual GP from the log's pairs (a model of several
    # joints gets its calibrated residual from `sea-daemon fit` / `calibrate`)
    one_joint = {CALIBRATED} if cfg.joints > 1 else set()
    for s in args.estimators.split(","):
        s = s.strip()
        if s == "gp-akf":
            labels += [g for g in gp_labels if g not in one_joint]
        elif s in one_joint:
            raise InputError(f"--estimators: {s} is for a one-joint model; {args.config} has {cfg.joints} joints "
                             f"(its GP-AKF cases: {', '.join(g for g in gp_labels if g not in one_joint)})")
        elif s:
            labels.append(s)
    unknown = [s for s in labels if s not in CASES]
    if unknown:
        raise InputError(f"--estimators: unknown {', '.join(unknown)}; allowed: {', '.join(CASES)}")
    if args.repeat < 1:
        raise InputError(f"--repeat must be >= 1, got {args.repeat}")
    if not 0.0 <= args.idle_ms <= 1000.0:
        raise InputError(f"--idle-ms must be in 0..1000, got {args.idle_ms}")
    log = read_log(args.log, n=cfg.joints, min_rows=100) if args.log else synthetic_log(cfg, args.seconds)
    print(f"machine: {machine()}; load average {os.getloadavg()[0]:.2f} at start")
    print("per step: wall-clock time (perf_counter); 'CPU time': thread CPU time of the same calls "
          "(thread_time), without the time other processes had the core")
    print(f"data: {log.path}, {len(log)} samples at {1 / log.dt:.0f} Hz, {cfg.joints} joint(s), "
          f"config {args.config}; {args.repeat} pass(es), 50 warm-up steps dropped per pass; "
          + (f"{args.idle_ms:g} ms {'busy-waiting' if args.idle_spin else 'asleep'} before each step"
             if args.idle_ms > 0 else "steps back to back"))
    if gp_labels:
        print("gp-akf-1eK: GP-AKF step WITH online learning (GP mean + Jacobian + variance, filter step, "
              "training pair, LoG-GP update incl. hyperparameter slices) with the LoG-GP pre-filled to "
              "1eK points; LoG-GP vs lgrt4gps on the same data: `python -m benchmarks.loggp`")
    for label in labels:
        est = CASES[label](cfg, log.dt, log)
        kinds = [] if hasattr(est, "gp") else None
        runs = [time_steps(est, log, cpu=True, kinds=kinds, idle_s=args.idle_ms * 1e-3, spin=args.idle_spin)
                for _ in range(args.repeat)]
        times = np.concatenate([r[0] for r in runs])
        cpu = np.concatenate([r[1] for r in runs])
        print(f"{label:>12s}: per step {summarize(times)}; load average {os.getloadavg()[0]:.2f}", flush=True)
        print(f"{'':>12s}  CPU time of the step {summarize(cpu)}", flush=True)
        if kinds:
            kinds = np.asarray(kinds)
            parts = []
            for kind in ("plain", "hyper phase 1", "hyper phase 2", "split", "eviction"):
                c = cpu[kinds == kind]
                if len(c):
                    parts.append(f"{kind} {len(c)}x median {np.median(c) * 1e6:.0f} max {c.max() * 1e6:.0f} us")
            print(f"{'':>12s}  CPU time by what the LoG-GP did: " + "; ".join(parts), flush=True)
    return 0
