"""The calibrated model on disk: ``OUT.yaml`` (the complete configuration) + ``OUT.npz``.

``OUT.yaml`` is an ordinary model configuration (docs/interfaces.md §2): the nominal robot with the
effects ``diagnose`` found, the identified R, process noise, kinematics and GP hyperparameters,
with a header saying what was identified and what was given.  ``OUT.npz`` is the model file
of :mod:`sea_daemon.io.gpmodel` (versioned, checksummed, atomic): the residual GP (empty when
the calibration kept none) with, in its provenance, ``calibration`` = the coverage map, whether
the GP is used, and the calibration's summary.  ``sea-daemon run --config OUT.yaml --model
OUT.npz`` and ``replay`` load both.
"""
from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np

from sea_daemon.analysis.sufficiency import RECORD, Sufficiency
from sea_daemon.apps.calibration.expected import expected_lines, with_figures
from sea_daemon.core.bounds.floor import floor_line
from sea_daemon.core.config import ModelConfig
from sea_daemon.core.estimators.calibrated import CalibratedAKF, CalibratedGPAKF
from sea_daemon.core.excitation import coverage_from_dict
from sea_daemon.core.learning import ResidualGP
from sea_daemon.io.configfile import save_config
from sea_daemon.io.files import atomic_write_text
from sea_daemon.io.gpmodel import save_gp_model
from sea_daemon.errors import ModelFileError, shown


def jsonable(x):
    """``x`` as plain JSON values: arrays as lists, numbers as floats, every non-finite number
    None (a figure the log could not measure; JSON has no nan or inf)."""
    if isinstance(x, dict):
        return {str(k): jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return jsonable(x.tolist())
    if x is None or isinstance(x, (bool, str)):
        return x
    if isinstance(x, (int, np.integer)) and not isinstance(x, np.bool_):
        return int(x)
    if isinstance(x, np.bool_):
        return bool(x)
    try:
        v = float(x)
    except (TypeError, ValueError):
        return str(x)
    return v if math.isfinite(v) else None


def save_calibrated(prefix: str | Path, result, provenance: dict | None = None) -> tuple[Path, Path]:
    """Write ``prefix.yaml`` and ``prefix.npz`` (and ``prefix.urdf``, the rigid body -- the
    robot's links and the wearer's arm -- as the calibration corrected it, when it did);
    returns the paths of the first two."""
    prefix = Path(prefix)
    yaml_path, npz_path = prefix.with_suffix(".yaml"), prefix.with_suffix(".npz")
    rep = result.report
    header = ["sea-daemon calibration of " + str(rep.get("log")) + ": the complete model",
              "identified: " + ", ".join(k for k in ("kinematics", "R", "effects", "tau_m_noise", "Sigma_nom", "learning")
                                         if k not in rep.get("given", []))]
    if rep.get("given"):
        header.append("kept as given: " + ", ".join(rep["given"]))
    cfg = result.cfg
    if (rep.get("body") or {}).get("kept"):
        # the corrected rigid body: its URDF beside the configuration (prefix.urdf), which names it
        urdf = prefix.with_suffix(".urdf")
        atomic_write_text(urdf, cfg.model.rigid.urdf)
        cfg = dataclasses.replace(cfg, source=str(yaml_path), model=dataclasses.replace(cfg.model, urdf=urdf.name))
        header.append(f"the rigid body (links and the wearer's arm) corrected by the calibration: {urdf.name}")
    save_config(cfg, yaml_path, header="\n".join(header))
    gp = result.gp if result.gp is not None else ResidualGP.from_config(result.cfg)
    prov = {"command": "calibration", **(provenance or {}),
            "calibration": {"gp_used": result.gp is not None, "coverage": result.coverage.to_dict(),
                            "gp_v_gate": float(result.report.get("gp_v_gate", 0.0)),
                            "gp_var_ref": float(result.report.get("gp_var_ref", 0.0)),
                            "summary": jsonable(summary(result))}}
    save_gp_model(npz_path, result.cfg, gp, prov)
    return yaml_path, npz_path


def estimator_from_model(cfg: ModelConfig, residual, meta: dict, dt: float | None = None, bound=None):
    """The estimator a calibrated model file describes (GP-AKF with the weighted residual, or
    the AKF when the calibration kept no GP); ``None`` if the file is not a calibration's.
    ``bound``: a bound factory (:class:`~sea_daemon.core.estimators.akf.AKF`)."""
    cal = (meta.get("provenance") or {}).get("calibration")
    if not cal:
        return None
    try:        # a model file is user data: a field that does not fit is a typed refusal
        cov = coverage_from_dict(cal["coverage"])
        v_gate, var_ref = float(cal.get("gp_v_gate", 0.0)), float(cal.get("gp_var_ref", 0.0))
        if not (math.isfinite(v_gate) and v_gate >= 0.0 and math.isfinite(var_ref) and var_ref >= 0.0):
            raise ValueError(f"gp_v_gate {v_gate}, gp_var_ref {var_ref}: expected finite values >= 0")
    except (KeyError, TypeError, ValueError, AttributeError) as e:
        raise ModelFileError(f"model file's calibration provenance does not fit: {shown(e, 200)}") from None
    if cal.get("gp_used"):
        return CalibratedGPAKF(cfg, residual, dt=dt, coverage=cov, v_gate=v_gate, var_ref=var_ref, bound=bound)
    return CalibratedAKF(cfg, dt=dt, coverage=cov, bound=bound)


def summary(result) -> dict:
    """What was identified and the expected accuracy, as numbers and plain sentences."""
    rep = result.report
    cfg = result.cfg
    n = cfg.joints
    eff = rep.get("diagnose", {}).get("effects_added", [])
    walk = rep.get("tau_h_act_walk", {})
    chosen = walk.get("chosen") or {}
    cov = rep.get("coverage", {})
    lines = Sufficiency.lines_of(rep["sufficiency"]) if rep.get("sufficiency") else []
    lines.append(f"Measurement noise R: {'given' if 'R' in rep.get('given', []) else 'identified'} "
                 f"(velocity std {np.sqrt(np.diag(cfg.estimator.R))[2 * n:].round(4).tolist()} rad/s).")
    skipped = rep.get("diagnose", {}).get("skipped")
    if eff:
        names = ", ".join(f"{d['type']} ({d['side']})" for d in eff)
        lines.append(f"Physical effects found by diagnose and added to the model: {names}; the residual fell "
                     f"from {rep['diagnose']['residual_rms_before']:.3g} to {rep['diagnose']['residual_rms_after']:.3g} N m RMS.")
    elif skipped:
        lines.append(f"diagnose was not run: {skipped}. The configured physical model is kept; to identify the "
                     f"effects, {RECORD}.")
    else:
        lines.append("diagnose found no effect to add: the configured model explains the log.")
    pairs = rep.get("diagnose", {}).get("correlated_pairs", [])
    if pairs:
        box = rep.get("data_range")
        where = (f" ({math.degrees(box['q'][0]):.0f}-{math.degrees(box['q'][1]):.0f} deg, up to "
                 f"{box['dq']:.2g} rad/s)") if box else ""
        lines.append("This log cannot tell apart " + "; ".join(
            f"{c['kept']} from {c['dropped']} (parameter correlation {c['correlation']:+.2f}; {c['kept']} kept)"
            for c in pairs) + f": beyond the angles and speeds the log covers{where} the model may be wrong "
            "there. Calibrate over the working range (sea-daemon calibrate --excitation).")
    lines.append(f"Motor-torque noise: {cfg.estimator.tau_m_noise:.3g} N m.")
    if "q_tau" in walk:
        h = walk["human"]
        q = ", ".join(f"{v:.3g}" for v in walk.get("q_tau_per_joint", [walk["q_tau"]]))
        what = ("Active-torque rate random walk (integrated walk)", "N^2 m^2/s^3") \
            if cfg.estimator.integrated else ("Active-torque random walk", "N^2 m^2/s")
        lines.append(f"{what[0]} {q} {what[1]}{' (per joint)' if ', ' in q else ''}, chosen for a subject torque of "
                     f"{h['band_hz'][0]:g}-{h['band_hz'][1]:g} Hz at {h['rms']:g} N m RMS.")
    lines.append(f"What the physical model leaves: {rep['leftover']['rms']:.3g} N m RMS; residual GP "
                 f"{'kept' if rep.get('gp_kept') else 'not used (it did not predict the leftover better than zero on held-out parts of the log)'}.")
    lines += directions_lines(rep.get("gp_directions"))
    lines.append(f"The log covers {100 * cov.get('q_qdot_share', 0):.0f} % of the (angle, speed) box of the working range "
                 f"({100 * cov.get('box_share', 0):.0f} % of (angle, speed, acceleration)); estimation flags samples outside it"
                 + (f" and lets the active-torque estimate move faster there (random walk at least "
                    f"{cfg.estimator.tau_h_act_walk_outside:.3g} N^2 m^2/s: the model is extrapolated)."
                    if cfg.estimator.tau_h_act_walk_outside else "."))
    exp = rep.get("expected_accuracy")
    if exp:
        lines += expected_lines(exp)
    floor = floor_line(rep.get("bound_floor"))
    if floor:
        lines.append(floor)
    return {"text": lines, "effects": [f"{d['type']}({d['side']})" for d in eff], "ambiguous": pairs,
            "gp_directions": rep.get("gp_directions"), "q_tau": walk.get("q_tau"), "tau_m_noise": cfg.estimator.tau_m_noise, "gp_kept": rep.get("gp_kept"),
            "coverage": cov, "expected_rmse": with_figures(chosen, exp),
            "expected_accuracy": {k: v for k, v in (exp or {}).items() if k != "raw"},
            "sufficiency": rep.get("sufficiency"), "bound_floor": rep.get("bound_floor")}


def directions_lines(rec: dict | None) -> list[str]:
    """The residual GP's directions of motion (:meth:`~sea_daemon.core.learning.ResidualGP.directions_record`)
    in plain words: one line per joint that its pairs covered one way only (none for a joint
    covered both ways or neither, or without the record)."""
    if not rec:
        return []
    out = []
    for j, ((down, up), (c_down, c_up)) in enumerate(zip(rec["pairs_down_up"], rec["covered_down_up"])):
        if c_down == c_up:
            continue
        learned, missing = ("up only", "down") if c_up else ("down only", "up")
        out.append(f"Residual GP, joint {j + 1}: learned moving {learned} ({up} pairs up, {down} down above "
                   f"{rec['speed']:g} rad/s; {rec['min_pairs']} needed each way). Moving {missing}, the GP-AKF "
                   f"uses the physical model alone (GP mean 0; its bound carries the GP's error there) until it "
                   f"learns that direction online; to calibrate it, {RECORD}.")
    return out
