"""Two-joint degenerate calibrations of ``sea-daemon bench generalize --joints 2 --degenerate``.

For each two-joint plant (:mod:`._family_joints`) and rate, each calibration log of
:data:`._family_joints.DEGENERATE_JOINTS` (one joint held by its drive while the other runs the
calibration excitation, the elbow moving one way only, a short log) is calibrated by
``sea-daemon fit`` in a child process, as a user runs it (:func:`._degenerate.run_fit`), with
the user's configuration (the nominal two-joint robot, its URDF):

* exit 2: **refused**, with its one line (which names the joint);
* exit 0: the calibrated model (``replay --model``, Theorem-1 bound) on the plant's held-out
  two-joint sessions next to the AKF on the robot-only model, per joint: RMSE, coverage of the
  bound over the valid samples; and the effects it added on a joint without the motion that
  reveals them (:func:`._degenerate.invented_effects` of that joint);
* anything else: an internal error.

The verdict is :func:`._degenerate.verdict`'s, with each joint's figures as a session of its own.
"""
from __future__ import annotations

import dataclasses
import json
import traceback
from pathlib import Path

from sea_daemon.apps.bench._degenerate import FIT_TIMEOUT_S, guarded, invented_effects, motion_of, run_fit, verdict
from sea_daemon.apps.bench._family import DegenerateLog
from sea_daemon.apps.bench._family_joints import (DEGENERATE_JOINTS, DEGENERATE_JOINTS_S,
                                                  degenerate_calibration_joints, draw_plant_joints)
from sea_daemon.apps.bench._generalize_joints import plant_logs_joints, score_joints
from sea_daemon.apps.commands.replay import build_estimator
from sea_daemon.core.estimators.akf import AKF
from sea_daemon.io.configfile import data_root, load_config

def user_config_joints(pd):
    """The configuration a user gives ``fit`` for a two-joint plant: the nominal robot as drawn,
    its URDF named by an absolute path (the file is written in another folder)."""
    urdf = (data_root() / "configs" / pd.nominal.model.urdf).resolve()
    return dataclasses.replace(pd.nominal, model=dataclasses.replace(pd.nominal.model, urdf=str(urdf)))


def effects_by_joint(prefix: Path) -> list[tuple[str, int]]:
    """(``type(side)``, joint 0-based) of every effect ``fit`` added (diagnose's and the body
    correction's), from its report."""
    try:
        rep = json.loads(Path(str(prefix) + ".report.json").read_text())
    except (OSError, ValueError):
        return []
    out = [(f"{d['type']}({d['side']})", int(d.get("joint", 1)) - 1)
           for d in (rep.get("diagnose") or {}).get("effects_added", [])]
    for label in (rep.get("body") or {}).get("effects_added", []):
        name, _, j = label.rpartition("[")
        out.append((name, int(j.rstrip("]")) - 1))
    return out


def _with_joint(log, j: int):
    """Joint ``j`` of ``log`` as joint 0 (what :func:`._degenerate.motion_of` reads)."""
    return dataclasses.replace(log, q=log.q[:, [j]], theta_m=log.theta_m[:, [j]], tau_m=log.tau_m[:, [j]],
                               tau_h_act=None, extra={})


def _scored(tests: dict, make) -> dict:
    """{session: {"joint 1": figures, "joint 2": ...}} of the estimator ``make(log)`` on every log."""
    def one(log):
        r = guarded(lambda: score_joints(log, make(log), bound=True))
        if "joints" not in r:
            return {f"joint {j + 1}": r for j in range(log.n)}
        return {f"joint {j + 1}": {**jr, "finite": r["finite"]} for j, jr in enumerate(r["joints"])}
    return {name: one(log) for name, log in tests.items()}


def run_degenerate_plant_joints(seed: int, rate_hz, workdir: Path, cache, cal_s: float = DEGENERATE_JOINTS_S,
                                cases=DEGENERATE_JOINTS, timeout_s: float = FIT_TIMEOUT_S, on_case=None) -> dict:
    """Every two-joint degenerate calibration ``cases`` of plant ``seed`` at ``rate_hz``; the held-out
    sessions simulated only when a case is calibrated.  ``on_case(pd, case)`` after each."""
    pd = draw_plant_joints(seed, rate_hz)
    cfg = user_config_joints(pd)
    row = {"seed": seed, "joints": 2, "rate_hz": pd.nominal.rate_hz, "plant": pd.summary, "cases": {}}
    held: dict = {}
    for case in cases:
        c: dict = {"case": case}
        try:
            log, what = degenerate_calibration_joints(pd, case, cal_s)
            c["what"], c["log_rate_hz"] = what, 1.0 / log.dt
            c["motion"] = [motion_of(_with_joint(log, j)) for j in range(log.n)]
            c.update(run_fit(DegenerateLog(case, log, cfg, what), workdir / case, timeout_s))
        except Exception as e:    # the benchmark's own failure: shown as such, the other cases go on
            c.update(outcome="internal_error", line=f"bench: {type(e).__name__}: {e}",
                     traceback=traceback.format_exc()[-1500:])
        if c.get("outcome") == "calibrated":
            added = effects_by_joint(Path(c["prefix"]))
            c["effects"] = [f"{e}[{j + 1}]" for e, j in added]
            c["invented"] = [f"{e}[{j + 1}]" for e, j in added if invented_effects([e], c["motion"][j])]
            c["sessions"] = _calibrated_sessions(pd, cfg, Path(c["prefix"]), held, cal_s, cache)
        c.update(verdict(c))
        row["cases"][case] = c
        if on_case is not None:
            on_case(pd, c)
    return row


def _calibrated_sessions(pd, cfg, prefix: Path, held: dict, cal_s: float, cache) -> dict:
    """The calibrated model ``prefix`` and the robot-only AKF on the plant's held-out sessions,
    each joint a session of its own (``session/joint j``) as :func:`._degenerate.verdict` reads."""
    if "tests" not in held:
        held["tests"] = plant_logs_joints(pd.seed, cal_s, cache, pd.nominal.rate_hz)[2]
        robot = dataclasses.replace(cfg, estimator=dataclasses.replace(cfg.estimator, nis_scale=1e12))
        held["akf"] = _scored(held["tests"], lambda log: AKF(robot, dt=log.dt))
    model = load_config(prefix.with_suffix(".yaml"))

    def make(log):
        est, _ = build_estimator("gp-akf", model, log.dt, model_path=prefix.with_suffix(".npz"))
        return est
    mine = _scored(held["tests"], make)
    return {f"{name}/{j}": {"gp-akf": r, "akf-robot": held["akf"][name][j]}
            for name, per in mine.items() for j, r in per.items()}
