"""What the calibration declares and scans for the model of τ_h,act (``estimator.tau_h_act_model``).

* the random walk (``walk``, the paper's): the walk q_τ of τ_h,act [N² m²/s] is scanned, and the
  bound's deterministic input is the declared wearer's rate |τ̇_h,act| ≤ r = 2π f_max √2 RMS;
* the integrated random walk (``integrated``): the walk of τ̇_h,act [N² m²/s³] is scanned, over the
  same grid scaled by (2π f_max)² (a walk whose spread over one period of the fastest declared
  component is the torque's size, differentiated once more), and the bound's input is the wearer's
  |τ̈_h,act| ≤ a = (2π f_max)² √2 RMS (docs/bounds.md §6).

A value given in the configuration is kept.  Pure functions of the configuration and the declared
subject.
"""
from __future__ import annotations

import dataclasses
import math

from sea_daemon.core.bounds.floor import wearer_accel, wearer_rate
from sea_daemon.core.config import ModelConfig


def walk_scale(cfg: ModelConfig, human) -> float:
    """The factor from the random walk's q_τ grid [N² m²/s] to the one scanned: 1, or (2π f_max)²
    [1/s²] for the integrated walk."""
    return (2.0 * math.pi * float(human.band_hz[1])) ** 2 if cfg.estimator.integrated else 1.0


def declared_inputs(cfg: ModelConfig, human) -> ModelConfig:
    """The configuration with the bound's declared input for the subject ``human`` (its band and
    RMS) where none is configured: ``tau_h_act_rate`` always (the floor's declaration), and
    ``tau_h_act_accel`` for the integrated walk."""
    est = cfg.estimator
    kw = {"tau_h_act_rate": est.tau_h_act_rate or wearer_rate(human.band_hz, human.rms)}
    if est.integrated:
        kw["tau_h_act_accel"] = est.tau_h_act_accel or wearer_accel(human.band_hz, human.rms)
    return dataclasses.replace(cfg, estimator=dataclasses.replace(est, **kw))
