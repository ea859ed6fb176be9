"""One configuration at any loop rate: :func:`at_rate`.

A model configuration is written (and a model file calibrated) at one ``rate_hz``; the daemon
may run it at another (100 Hz → 1 kHz).  What depends on the rate is carried by the model, not
retuned by hand:

* the nominal process noise Σ_nom is per ``estimator.Sigma_nom_dt`` seconds and scaled to the
  filter's step already (:meth:`~sea_daemon.core.estimators.akf.AKF.fill_sigma_nom`), and
  ``estimator.tau_m_noise`` is a torque error held over each step (the plant's is drawn per step);
* the causal differentiator's ``kinematics.window`` is a number of samples: :func:`at_rate`
  keeps its span in time — (W − 1)·dt for ``savgol`` (the fit's support; the acceleration's
  delay (W − 1)/2 samples stays 20 ms at W = 5, 100 Hz → W = 41 at 1 kHz), W·dt for ``ma`` — so
  the velocities of y and the GP input z = [q, q̇, q̈] have the same delay and, for white angle
  noise, a smaller noise gain (q̈'s noise would otherwise grow as 1/dt²: ×100 at 1 kHz with
  W = 5);
* the measurement noise R is scaled by the rate ratio (×10 from 100 Hz to 1 kHz): the same
  information per second.  Its velocity entries are set by the differentiator's lag during motion
  (6e-6 (rad/s)² measured against 1.5e-7 from the angle quantum through the W = 5
  differentiator), an error the kept span keeps and that is correlated over that span, so ten
  samples in its place do not tell the filter ten times as much; with R as identified the filter
  would weigh them as independent.  The cost: at 1 kHz the filter's velocity posterior, and
  with it the Theorem-1 bound's Gaussian part, is wider than the lag alone would make it.

:func:`same_in_time` is the model file's compatibility rule (:mod:`sea_daemon.io.gpmodel`): a
residual learned at one rate is valid at another when the kinematics are the same in time.
"""
from __future__ import annotations

import dataclasses

from sea_daemon.core.config import KinematicsConfig, ModelConfig
from sea_daemon.errors import InputError


def window_at(kin: KinematicsConfig, rate_from: float, rate_to: float) -> int:
    """The differentiator window at ``rate_to`` with the span in time it has at ``rate_from``."""
    r = float(rate_to) / float(rate_from)
    if kin.method == "savgol":
        return max(kin.degree + 1, int(round((kin.window - 1) * r)) + 1)
    return max(1, int(round(kin.window * r)))


def at_rate(cfg: ModelConfig, rate_hz: float | None) -> ModelConfig:
    """``cfg`` for a loop at ``rate_hz`` (None or the same rate: ``cfg`` itself; see the module
    docstring).  InputError when the window this needs is outside 1..100 samples."""
    if rate_hz is None or float(rate_hz) == float(cfg.rate_hz):
        return cfg
    if not 1.0 <= float(rate_hz) <= 100000.0:
        raise InputError(f"rate {rate_hz!r} Hz: allowed 1..100000")
    w = window_at(cfg.kinematics, cfg.rate_hz, rate_hz)
    if not 1 <= w <= 100:
        raise InputError(f"rate {rate_hz:g} Hz: kinematics.window would be {w} samples to keep its span of the "
                         f"configuration's {cfg.rate_hz:g} Hz (allowed 1..100)")
    r = float(rate_hz) / float(cfg.rate_hz)
    kin = dataclasses.replace(cfg.kinematics, window=w)
    est = dataclasses.replace(cfg.estimator, R=cfg.estimator.R * r,
                              nis_window=max(1, min(100000, int(round(cfg.estimator.nis_window * r)))))
    return dataclasses.replace(cfg, rate_hz=float(rate_hz), kinematics=kin, estimator=est)


def same_in_time(saved: ModelConfig, cfg: ModelConfig) -> bool:
    """The kinematics of ``saved`` brought to ``cfg``'s rate are ``cfg``'s."""
    try:
        return at_rate(saved, cfg.rate_hz).kinematics == cfg.kinematics
    except InputError:
        return False
