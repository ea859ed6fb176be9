"""The accuracy a calibration can promise (step 7 of :mod:`.pipeline`), and what it rests on.

Three figures of the calibrated estimator, each a finite RMSE [N m] or ``None`` with the reason
("not measurable from this log"):

* ``passive`` — a passive subject (τ_h,act = 0) within the region the log covers: the
  estimator on the calibration log itself, its residual GP trained without the block it is
  scored on (blocked, :data:`FOLDS` blocks; the physics, a few parameters over the whole log, is
  kept) — every τ̂ there is model error leaking into the estimate;
* ``active_moving`` / ``active_still`` — a subject of the declared band and size
  (``calibration.human_band_hz``, ``human_torque_rms``) while the joint moves / with the arm held
  still: the identified model replayed as the plant with synthetic subjects (the filter's own
  error: lag of the random walk, noise), with the passive figure's model error added in
  quadrature (the synthetic plant is the model, so the model's own error is not in it).  From a
  still-arm log the moving figure is not measurable: nothing in it says how the model holds in
  motion.

Pure numerics and simulation: no files.
"""
from __future__ import annotations

import math

import numpy as np

from sea_daemon.analysis.sufficiency import Sufficiency, finite
from sea_daemon.core.estimators.calibrated import make_calibrated
from sea_daemon.core.log import MeasuredLog
from sea_daemon.core.replay import replay
from sea_daemon.errors import EstimatorFault

#: time blocks of the calibration log for the passive figure
FOLDS = 4
#: the keys of the synthetic figures, as the walk's scan names them
SYNTHETIC = ("synthetic_moving", "synthetic_still")
#: why a synthetic figure is missing
NO_SYNTHETIC = ("not measurable from this log: the identified model could not be simulated, or the filter faulted "
                "on the synthetic subject")


def rmse_of(log: MeasuredLog, est) -> float | None:
    """RMSE of τ̂_h,act against the log's truth (0 without one); None when the filter faulted
    or its estimate is not finite."""
    return scored(log, est)[0]


def scored(log: MeasuredLog, est) -> tuple[float | None, str | None]:
    """(:func:`rmse_of`, why it is None: the filter's fault in plain words)."""
    try:
        res = replay(log, est)
    except EstimatorFault as e:
        what = str(e).split(": ", 1)[-1].split(":")[0]
        return None, f"the estimator stops with a fault there ({what})"
    truth = log.tau_h_act if log.tau_h_act is not None else np.zeros_like(res.tau_h_act_hat)
    r = finite(np.sqrt(np.mean((res.tau_h_act_hat - truth) ** 2)))
    return r, None if r is not None else "the estimate is not finite there"


def _blocked_passive(result, log: MeasuredLog) -> float | None:
    """The calibrated estimator on each of :data:`FOLDS` time blocks of the passive log, its GP
    trained on the other blocks' pairs (the physics kept); the RMS over the blocks."""
    # local import: the residual GP's pairs live with the pipeline's step 4 (a cycle otherwise)
    from sea_daemon.apps.calibration.residual_gp import timed_pairs
    cfg, rep = result.cfg, result.report
    edges = np.linspace(0, len(log), FOLDS + 1).astype(int)
    pairs = timed_pairs(cfg, log) if result.gp is not None else None
    sq, n = 0.0, 0
    for k in range(FOLDS):
        block = log.slice(edges[k], edges[k + 1])
        if len(block) < 10:
            continue
        gp = None
        if pairs is not None:
            gp = _gp_without(cfg, pairs, log.t[edges[k]], log.t[edges[k + 1] - 1])
        est = make_calibrated(cfg, gp, result.coverage, dt=log.dt, kind="gp-akf" if gp is not None else "akf",
                              power=result.options.weight_power, v_gate=rep.get("gp_v_gate", 0.0),
                              var_ref=rep.get("gp_var_ref", 0.0))
        r = rmse_of(block, est)
        if r is None:
            return None
        sq += r * r * len(block)
        n += len(block)
    return finite(math.sqrt(sq / n)) if n else None


def _gp_without(cfg, pairs, t0: float, t1: float):
    """The residual GP on the pairs whose sample time lies outside [t0, t1] (None: none left)."""
    # local import: the offline GP of the pipeline's step 4
    from sea_daemon.apps.calibration.residual_gp import offline_gp
    Z, F, t = pairs
    keep = (t < t0) | (t > t1)
    if np.sum(keep) < 10:
        return None
    return offline_gp(cfg, Z[keep], F[keep])


def _missing(synth: dict, key: str) -> str:
    """Why the synthetic figure ``key`` is missing, for the report."""
    why = synth.get(f"{key}_why")
    if why:
        return (f"not measurable: on a synthetic subject of the declared band and size {why}; a τ_h,act random "
                "walk chosen by the calibration (leave estimator.Sigma_nom out) follows such a subject")
    return NO_SYNTHETIC


def _quad(a: float | None, b: float | None) -> float | None:
    return None if a is None or b is None else finite(math.hypot(a, b))


def expected_accuracy(result, log: MeasuredLog, suff: Sufficiency, synth: dict) -> dict:
    """The module docstring's figures: ``{name: {"rmse": float | None, "why": str}}`` and the raw
    figures they rest on (``passive_log`` in sample, ``passive_blocked``, and ``synth``: the
    synthetic subjects' RMSE, :data:`SYNTHETIC` → float or None)."""
    in_sample = rmse_of(log, result.estimator(dt=log.dt))
    blocked = _blocked_passive(result, log) if result.gp is not None else in_sample
    model = blocked if blocked is not None else in_sample
    out: dict = {"raw": {"passive_log": in_sample, "passive_blocked": blocked,
                         **{k: synth.get(k) for k in SYNTHETIC}}}
    out["passive"] = {"rmse": model, "why": "the calibration log, the residual GP scored on blocks it was not "
                      "trained on" if result.gp is not None else "the calibration log (physics only)"}
    if model is None:
        out["passive"]["why"] = "not measurable from this log: the estimator faulted on it"
    moving = _quad(synth["synthetic_moving"], model)
    out["active_moving"] = {"rmse": moving, "why": "synthetic subjects while moving, plus the passive model error"}
    if suff.still:
        out["active_moving"] = {"rmse": None, "why": "not measurable from this log: the arm held still, nothing in "
                                                     "it says how the model holds in motion"}
    elif moving is None:
        out["active_moving"]["why"] = _missing(synth, "synthetic_moving")
    still = _quad(synth["synthetic_still"], model)
    out["active_still"] = {"rmse": still, "why": "synthetic subjects with the arm held still, plus the passive "
                                                 "model error" if still is not None else
                           _missing(synth, "synthetic_still")}
    return out


def expected_lines(exp: dict) -> list[str]:
    """The expected accuracy in plain words, "not measurable from this log" for a missing figure."""
    def fig(key: str, what: str) -> str:
        e = exp.get(key) or {}
        r = e.get("rmse")
        return f"{r:.3g} N m {what}" if r is not None else f"{what}: {e.get('why', 'not measurable from this log')}"
    return [f"Expected accuracy (RMSE of the active-torque estimate): {fig('passive', 'with a passive subject')}; "
            f"{fig('active_moving', 'with an active subject while moving')}; "
            f"{fig('active_still', 'with the arm held still')}. Within the angles and speeds the log covers; "
            "beyond them the model is extrapolated."]


def with_figures(chosen: dict, exp: dict) -> dict:
    """The summary's ``expected_rmse`` (synthetic_moving, synthetic_still, passive_log): finite
    figures or None, from the walk's chosen row or the expected accuracy's raw figures."""
    raw = exp.get("raw", {}) if exp else {}
    return {k: finite(chosen.get(k)) if finite(chosen.get(k)) is not None else raw.get(k)
            for k in ("synthetic_moving", "synthetic_still", "passive_log")}

