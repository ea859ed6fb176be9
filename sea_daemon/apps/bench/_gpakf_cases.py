"""GP-AKF cases of ``sea-daemon bench latency``: one step with online learning at N points.

The timed call is :meth:`GPAKF.update` with learning on: differentiator, GP prediction
(mean, Jacobian, variance; alg:torqueresidualAKF lines 4-6), the filter step (Alg. 2 lines
7-11), the training pair of the sample (eq:loadsidewmotor) and the LoG-GP ``update``,
including its hyperparameter slices (one phase every few updates, ``hyper_every``).

Before timing, the per-joint LoG-GP is pre-filled with N points (10³ … 10⁶) in the region
the timed log visits: the log's own training pairs (causal kinematics, eq:loadsidewmotor),
cycled with a small jitter (2 % of each input's spread) so that every point is new.  The
tree is unbounded (``max_leaves=None``) so it really holds N points; the pre-fill runs with
the hyperparameter slices off (it is set-up, not measured) and they are switched on for the
timed steps.  Pre-fill time is printed (about 50-100 µs per point on the 2-core bench machine).

``gp-akf-calibrated``: the step the daemon runs on a calibrated model (``fit``, ``calibrate
--fit``; :class:`~sea_daemon.core.estimators.calibrated.CalibratedGPAKF`): the residual GP
behind the variance weighting, learning off (the calibration trains the GP offline), and the
coverage flag.  Its GP holds the log's training pairs (one leaf's worth is what a calibration
keeps per region), with the calibration's own hyperparameter fit on them.

``gp-akf-frozen`` and ``gp-akf-bound``: the daemon's GP-AKF with the LoG-GPs it learned online
over one pass of the log, frozen (learning off), without and with its Theorem-1 bound ρ_k
(:mod:`~sea_daemon.core.bounds.akf_bound`, the compiled step where it applies, a URDF model's
included); the bound's own cost per step is the difference of the two.
"""
from __future__ import annotations

import dataclasses
import time

import numpy as np

from sea_daemon.apps.calibration.residual_gp import fit_gp_hyper
from sea_daemon.core.estimators import make_estimator
from sea_daemon.core.estimators.calibrated import make_calibrated
from sea_daemon.core.excitation import Coverage, WorkingRange
from sea_daemon.core.learning import ResidualGP, training_pairs_from_log
from sea_daemon.core.model import SEAModel

#: default pre-fill sizes
SIZES = (1_000, 10_000, 100_000, 1_000_000)


def label(n_points: int) -> str:
    return f"gp-akf-1e{int(round(np.log10(n_points)))}" if n_points in SIZES else f"gp-akf-{n_points}"


def prefilled_gpakf(cfg, dt, log, n_points: int, seed: int = 0, verbose: bool = True,
                    hyper_every: int | None = None):
    """A learning GP-AKF whose LoG-GP already holds ``n_points`` points near ``log``'s inputs."""
    model = SEAModel.from_config(cfg)
    Z, F = training_pairs_from_log(model, log, kinematics=cfg.kinematics, causal=True)
    rng = np.random.default_rng(seed)
    spread = Z.std(axis=0) + 1e-9
    extra = {} if hyper_every is None else {"hyper_every": int(hyper_every)}
    gp = ResidualGP(cfg.joints, cfg.learning, max_leaves=None, hyperopt=False, **extra)
    t0 = time.perf_counter()
    N = Z.shape[0]
    for k in range(int(n_points)):
        i = k % N
        z = Z[i] + 0.02 * spread * rng.standard_normal(Z.shape[1])
        for j, g in enumerate(gp.gps):
            g.update(z, F[i, j])
    fill_s = time.perf_counter() - t0
    for g in gp.gps:
        g.hyperopt = cfg.learning.hyperopt
    est = make_estimator("gp-akf", cfg, dt=dt, residual=gp, learning=True, bound=False)
    g0 = gp.gps[0]
    # leaves a prediction merges (LoG-GP overlaps), over the log's inputs
    route = float(np.mean([len(g0.route(z)) for z in Z[::10]]))
    if verbose:
        print(f"{label(n_points):>12s}: pre-filled {g0.n_points} points per joint in {fill_s:.1f} s "
              f"({fill_s / max(n_points, 1) * 1e6:.0f} us/point): {g0.n_leaves} leaves, depth {g0.depth}, "
              f"{g0.memory_bytes() / 1e6:.0f} MB, {route:.2f} leaves per prediction; hyperparameter slices "
              f"{'on, one phase every ' + str(g0.hyper_every) + ' updates' if g0.hyperopt else 'off'}",
              flush=True)
    return est


CALIBRATED = "gp-akf-calibrated"


def calibrated_gpakf(cfg, dt, log, verbose: bool = True):
    """The calibrated GP-AKF (no learning) with a residual GP trained on ``log``'s pairs and a
    coverage map of them (see the module docstring)."""
    Z, F = training_pairs_from_log(SEAModel.from_config(cfg), log, kinematics=cfg.kinematics, causal=True)
    hyp = fit_gp_hyper(Z, F, 400, 0)
    lc = dataclasses.replace(cfg.learning, sigma_f=hyp["sigma_f"], lengthscales=tuple(hyp["lengthscales"]),
                             sigma_n=hyp["sigma_n"], hyperopt=False)
    cfg = dataclasses.replace(cfg, learning=lc, estimator=dataclasses.replace(cfg.estimator, gp_noise_in_Q=True))
    gp = ResidualGP.from_config(cfg)
    gp.train(Z, F)
    cov = Coverage(WorkingRange(float(Z[:, 0].min()), float(Z[:, 0].max()), float(np.abs(Z[:, 1]).max()),
                                float(np.abs(Z[:, 2]).max())))
    cov.add(Z)
    est = make_calibrated(cfg, gp, cov, dt=dt)
    if verbose:
        g0 = gp.gps[0]
        print(f"{CALIBRATED:>12s}: residual GP of {g0.n_points} points ({g0.n_leaves} leaves), learning off, "
              f"coverage flag on", flush=True)
    return est


FROZEN, BOUND = "gp-akf-frozen", "gp-akf-bound"


def frozen_gpakf(cfg, dt, log, bound: bool, verbose: bool = True):
    """A GP-AKF whose LoG-GPs learned online over one pass of ``log``, then frozen; with ``bound``
    its Theorem-1 bound (see the module docstring)."""
    learner = make_estimator("gp-akf", cfg, dt=dt, bound=False)
    learner.reset(log.q[0], log.theta_m[0], log.tau_m[0])
    for k in range(1, len(log)):
        learner.update(log.q[k], log.theta_m[k], log.tau_m[k], log.t[k] - log.t[k - 1])
    est = make_estimator("gp-akf", cfg, dt=dt, residual=learner.gp, learning=False, bound=bound)
    if verbose:
        g0 = learner.gp.gps[0]
        print(f"{BOUND if bound else FROZEN:>12s}: LoG-GP per joint learned online over the log "
              f"({g0.n_points} points, {g0.n_leaves} leaves), learning off, Theorem-1 bound "
              f"{'on' if bound else 'off'}", flush=True)
    return est


def register(register_fn, max_points: int = SIZES[-1], hyper_every: int | None = None) -> list[str]:
    """Register ``gp-akf-1eK`` cases up to ``max_points`` and ``gp-akf-calibrated`` with
    ``register_fn(label, builder)`` (``hyper_every``: updates between hyperparameter slices of
    the learning cases, default the LoG-GP's)."""
    labels = []
    for n in SIZES:
        if n > max_points:
            break
        register_fn(label(n), lambda cfg, dt, log, n=n: prefilled_gpakf(cfg, dt, log, n, hyper_every=hyper_every))
        labels.append(label(n))
    register_fn(CALIBRATED, lambda cfg, dt, log: calibrated_gpakf(cfg, dt, log))
    register_fn(FROZEN, lambda cfg, dt, log: frozen_gpakf(cfg, dt, log, False))
    register_fn(BOUND, lambda cfg, dt, log: frozen_gpakf(cfg, dt, log, True))
    return labels + [CALIBRATED, FROZEN, BOUND]
