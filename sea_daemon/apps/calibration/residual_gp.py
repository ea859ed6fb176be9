"""The residual GP of the calibration (step 4 of :mod:`.pipeline`): its training pairs, its
hyperparameters and whether it is worth keeping.

The pairs z = [q, q̇, q̈] and the load side's leftover f of the augmented model come from the
zero-phase kinematics of diagnose (:func:`smooth_pairs`); the hyperparameters by maximum
likelihood with physics-first priors (:func:`fit_gp_hyper`); the GP is kept when blocked
cross-validation shows it predicts the leftover better than zero (:func:`gp_cross_validation`).
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from sea_daemon.analysis.diagnose.residuals import kinematics_from_log, residual_channels, stick_velocity, window_samples
from sea_daemon.core.config import LearningConfig, ModelConfig
from sea_daemon.core.gp.hyper import fit_hyperparameters
from sea_daemon.core.learning import ResidualGP
from sea_daemon.core.log import MeasuredLog
from sea_daemon.core.model import SEAModel


#: floors of the data spans the GP's length-scale bounds are taken from [rad, rad/s, rad/s²]
SPAN_Q_MIN, SPAN_DQ_MIN, SPAN_DDQ_MIN = 0.4, 0.5, 10.0
#: [rad/s] no GP training pairs below this speed (nor below 3 × sign_eps): the sticking phases
V_EXCLUDE = 0.03
#: fewer moving pairs than this: the log is a still-arm log, all its pairs are used
MIN_MOVING_PAIRS = 200


def stick_velocity_of(cfg: ModelConfig) -> float:
    return stick_velocity(cfg)


def smooth_pairs(cfg: ModelConfig, log: MeasuredLog, rate_hz: float = 100.0):
    """(Z, F) of :func:`timed_pairs`."""
    Z, F, _ = timed_pairs(cfg, log, rate_hz)
    return Z, F


def timed_pairs(cfg: ModelConfig, log: MeasuredLog, rate_hz: float = 100.0):
    """Training pairs and their sample times (Z, F, t) for the offline calibration: z = [q, q̇, q̈] and the load side's leftover
    f = r_load of the augmented model (eq:unknwn_load with τ_h,act = 0: the term the filter's
    load-side dynamics carry), both from the zero-phase kinematics of ``diagnose``
    (:func:`~sea_daemon.analysis.diagnose.residuals.residual_channels`: one smoother over the whole
    balance, static friction set-valued while the joint sticks).

    Why not r_load + r_motor (eq:loadsidewmotor, what the GP-AKF learns online): the filter
    applies f on the load side, so a motor-side leftover (cogging, a drive's friction or torque
    constant the physics missed) learned into f moves τ̂_h,act by its own size — the filter
    sees the motor side through θ_m and absorbs it there.  With the calibration's physics the
    two sides are measured apart (the spring's deflection gives τ_s), and each goes where it acts.

    Why not the causal pairs the GP-AKF learns online: their q̈ carries the differentiator's
    encoder noise both in the input and, times M, in the target — errors in variables: the GP
    then learns a spurious slope in q̈ (on 16-bit encoders at 100 Hz: ~0.2 N m of M q̈ noise) and
    its confident mean is wrong on any other session.  Decimated to ``rate_hz`` (neighbouring
    smoothed samples carry no new information)."""
    model = SEAModel.from_config(cfg)
    kin = kinematics_from_log(log)
    r = residual_channels(model, kin, passive=True, v_stick=stick_velocity(cfg))
    n = cfg.joints
    # eq:unknwn_load: the load side's leftover (r_motor stays with the motor side, see above)
    F = r[:, :n]
    q, _ = model.correct_measurement(kin.q_raw, kin.theta_m_raw)
    Z = np.hstack([q, kin.dq, kin.ddq])
    edge = window_samples(log.t)
    step = max(1, int(round(1.0 / (rate_hz * log.dt))))
    sl = slice(edge, len(log) - edge, step)
    Z, F, t = Z[sl], F[sl], np.asarray(log.t, float)[sl]
    # no pairs while the joint sticks (|q̇| < v_stick): static friction is set-valued there, the
    # torque it takes depends on how the joint came to rest (the controller's history), not on z;
    # learned, it would be a confident offset on every still arm (the physics' convention,
    # friction 0 at rest, is what the filter can hold)
    moving = np.all(np.abs(Z[:, n:2 * n]) >= max(stick_velocity(cfg), V_EXCLUDE), axis=1)
    if np.sum(moving) < MIN_MOVING_PAIRS:
        # a log that (almost) never moves (the paper's still-arm training, Sec. V-C): the static
        # balance at rest is all there is to learn, and friction holds nothing there
        return Z, F, t
    return Z[moving], F[moving], t[moving]


def fit_gp_hyper(Z: np.ndarray, F: np.ndarray, points: int, seed: int, min_ls_dq: float = 0.1,
                 ls_ddq: float | None = None) -> dict:
    """Maximum-likelihood hyperparameters (eq:SE, σ_on) on a subsample of the pairs, with the
    physics-first priors: l_q̇ ≥ ``min_ls_dq`` (the GP may not be sharper in q̇ than the filter
    knows the velocity near standstill: static friction is set-valued there, the physical model
    holds its smoothed sign), l_q̈ fixed long (default 2 × the pairs' q̈ range: inertia is the
    physical model's, diagnose fits it; the residual has no business keying on q̈)."""
    rng = np.random.default_rng(seed)
    idx = np.sort(rng.choice(len(Z), size=min(points, len(Z)), replace=False))
    X, y = Z[idx], F[idx, 0]
    # floors of the spans: a still-arm log spans a few encoder counts, and a length scale of that
    # size would make the GP forget its data at the first drift of the arm
    span = np.maximum(np.ptp(Z, axis=0), [SPAN_Q_MIN, SPAN_DQ_MIN, SPAN_DDQ_MIN])
    s = max(float(np.sqrt(np.mean(F[:, 0] ** 2))), 1e-4)
    l_dd = 2.0 * span[2] if ls_ddq is None else ls_ddq
    ls0 = np.array([0.2 * span[0], max(0.2 * span[1], 2 * min_ls_dq), l_dd])
    # σ_f at most twice the leftover's RMS and length scales at most half the data's span: a
    # local model that returns to zero (the physics) off its data — an ML fit left free drifts to
    # σ_f → ∞ with long length scales (a global trend that extrapolates, and whose variance never
    # grows towards σ_f², so the variance weighting could not switch it off)
    bounds = [(math.log(1e-4), math.log(2.0 * s)),
              (math.log(0.05 * span[0]), math.log(0.5 * span[0])),
              (math.log(min_ls_dq), math.log(max(0.5 * span[1], 1.0001 * min_ls_dq))),
              (math.log(l_dd), math.log(l_dd * 1.0000001)),
              (math.log(1e-4), math.log(2.0 * s))]
    sf, ls, sn = fit_hyperparameters(X, y, sigma_f=s, lengthscales=ls0, sigma_n=0.3 * s, bounds=bounds)
    return {"sigma_f": float(sf), "lengthscales": [float(v) for v in np.atleast_1d(ls)], "sigma_n": float(sn)}


def gp_cross_validation(Z: np.ndarray, F: np.ndarray, lc: LearningConfig, folds: int = 5) -> dict:
    """Blocked K-fold: a LoG-GP (learning config ``lc``, no online hyperparameters) trained on
    K−1 contiguous blocks predicts the held-out one; MSE against predicting 0 (the physics)."""
    N = len(Z)
    edges = np.linspace(0, N, folds + 1).astype(int)
    mse_gp = mse_0 = 0.0
    lc0 = dataclasses.replace(lc, hyperopt=False)
    for k in range(folds):
        test = np.arange(edges[k], edges[k + 1])
        train = np.setdiff1d(np.arange(N), test)
        gp = ResidualGP(1, lc0)
        gp.train(Z[train], F[train])
        mu, _ = gp.gps[0].predict_many(Z[test])
        mse_gp += float(np.sum((F[test, 0] - mu) ** 2))
        mse_0 += float(np.sum(F[test, 0] ** 2))
    return {"mse_gp": mse_gp / N, "mse_zero": mse_0 / N, "gain": 1.0 - mse_gp / max(mse_0, 1e-300)}


def leftover_latent_variance(F: np.ndarray, sigma_n: float) -> float:
    """s_0² [N² m²] of the weighted hook (:class:`~sea_daemon.core.estimators.weighted.WeightedResidual`):
    the mean square of the leftover ``F`` less the noise variance σ_on², at least 1e-12 (a leftover
    that is all noise: the GP's mean never enters)."""
    return float(max(np.mean(np.asarray(F, float) ** 2) - float(sigma_n) ** 2, 1e-12))


def offline_gp(cfg: ModelConfig, Z: np.ndarray, F: np.ndarray):
    """The residual GP trained on the pairs directly (when the online training faulted)."""
    gp = ResidualGP.from_config(cfg)
    gp.train(Z, F)
    return gp
