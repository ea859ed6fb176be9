"""``diagnose`` one step off the golden path: logs that cannot reveal what a fit would claim.

* constant angles: every effect of the vocabulary needs some motion; none is a candidate, the
  report says what motion is missing, and no figure is nan/inf;
* a joint held still (the passive scenario's PID holding 10°, nominal model): no friction
  "found" (it needs sliding both ways);
* a log with the load and motor columns swapped: refused (exit 2, one line);
* a zero-width interval is never "high" confidence.

Small seeded logs (600–700 samples at 100 Hz).
"""
from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

from sea_daemon.analysis.diagnose.candidates import CoulombC
from sea_daemon.analysis.diagnose.records import Selection
from sea_daemon.analysis.diagnose.summary import effects_json
from sea_daemon.apps.cli import main
from sea_daemon.apps.diagnose import diagnose
from sea_daemon.core.log import MeasuredLog
from sea_daemon.errors import InputError
from sea_daemon.io.configfile import load_config
from sea_daemon.io.logcsv import write_log
from sea_daemon.io.scenario import load_scenario
from sea_daemon.runtime.sim_runner import simulate
from _paths import repo_root

EXO = repo_root() / "configs" / "exo_1dof.yaml"


def _no_nonfinite(text: str) -> None:
    for bad in ("NaN", "Infinity", " nan", " inf", "nan ", "inf "):
        assert bad not in text, bad


def constant_log(n: int = 600, seed: int = 5) -> MeasuredLog:
    """q and θ_m constant (a joint that never moved), a commanded torque holding it with noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 0.01
    q = np.full((n, 1), 0.5)
    th = np.full((n, 1), 0.45)
    tau = 2.0 + 0.01 * rng.standard_normal((n, 1))
    return MeasuredLog(t=t, q=q, theta_m=th, tau_m=tau, tau_h_act=np.zeros((n, 1)), path="constant.csv")


def still_log():
    """The passive scenario with its PID holding 10° for 7 s (the arm never moves), and the
    nominal (robot-only) model the user starts from."""
    sc = load_scenario(repo_root() / "configs" / "scenarios" / "passive.yaml")
    tr = dataclasses.replace(sc.controller.trajectory, q_end_deg=sc.controller.trajectory.q_start_deg, moves=2)
    sc = dataclasses.replace(sc, controller=dataclasses.replace(sc.controller, trajectory=tr),
                             training_samples=2, estimation_samples=700)
    return simulate(sc, 3).estimation, sc.nominal


def moving_log():
    """Two passive moves 10°→75°→10° (700 samples) and the nominal model."""
    sc = load_scenario(repo_root() / "configs" / "scenarios" / "passive.yaml")
    tr = dataclasses.replace(sc.controller.trajectory, moves=2)
    sc = dataclasses.replace(sc, controller=dataclasses.replace(sc.controller, trajectory=tr),
                             training_samples=2, estimation_samples=700)
    return simulate(sc, 4).estimation, sc.nominal


def test_constant_angles_add_nothing_and_say_what_motion_is_missing(tmp_path):
    cfg = load_config(EXO)
    res = diagnose(constant_log(), cfg, tmp_path, plots=False)
    assert res["effects_added"] == [], res["effects_added"]
    says = " ".join(res["statements"])
    assert "Not identifiable from this log" in says and "never moves" in says, says
    missing = {(d["type"], d["side"]) for d in res["not_identifiable"]}
    assert {("coulomb", "load"), ("coulomb", "motor"), ("gravity", "load"), ("inertia", "load")} <= missing
    _no_nonfinite((tmp_path / "diagnosis.json").read_text())
    _no_nonfinite((tmp_path / "report.md").read_text())


def test_constant_angles_cli_prints_no_nan(tmp_path, capsys):
    log_path = tmp_path / "constant.csv"
    write_log(log_path, constant_log())
    rc = main(["diagnose", str(log_path), "--config", str(EXO), "--out", str(tmp_path / "d"), "--no-plots"])
    out = capsys.readouterr().out
    assert rc == 0
    assert "no undeclared effect found" in out
    _no_nonfinite(out)


def test_zero_width_interval_is_never_high_confidence():
    sel = Selection(chosen=[(CoulombC("load"), {"F_c": 3.84})], ci=[{"F_c": (3.84, 3.84)}], explained=[0.95],
                    unexplained=0.05, steps=[], alternatives=[[]], tau_int=1.0, structure={}, rss0=1.0,
                    rss_final=0.05, r_final=np.zeros((1, 2)))
    d = effects_json(sel, 1, False)[0]
    assert d["confidence"] == "low"
    assert d["ci95_not_measurable"] == ["F_c"]


def test_a_joint_held_still_reveals_no_friction(tmp_path):
    log, cfg = still_log()
    assert float(np.ptp(log.q)) < 0.05
    res = diagnose(log, cfg, tmp_path, plots=False, options=None)
    found = {(d["type"], d["side"]) for d in res["effects_added"]}
    assert not found & {("coulomb", "load"), ("coulomb", "motor"), ("stribeck", "load"), ("stribeck", "motor"),
                        ("viscous", "load"), ("viscous", "motor")}, found
    for d in res["effects_added"]:
        if d["confidence"] == "high":
            assert all(lo is not None and hi is not None and hi > lo for lo, hi in d["ci95"].values()), d
    missing = {(d["type"], d["side"]) for d in res["not_identifiable"]}
    assert ("coulomb", "load") in missing and ("stribeck", "motor") in missing
    _no_nonfinite((tmp_path / "diagnosis.json").read_text())


@pytest.fixture(scope="module")
def moving():
    return moving_log()


def test_swapped_columns_are_refused(moving, tmp_path, capsys):
    log, cfg = moving
    swapped = dataclasses.replace(log, q=log.theta_m.copy(), theta_m=log.q.copy(), path="swapped.csv")
    with pytest.raises(InputError, match="swapped"):
        diagnose(swapped, cfg, None, plots=False)
    p = tmp_path / "swapped.csv"
    write_log(p, swapped)
    rc = main(["diagnose", str(p), "--config", str(EXO), "--out", str(tmp_path / "d"), "--no-plots"])
    err = capsys.readouterr().err
    assert rc == 2
    assert len(err.strip().splitlines()) == 1 and "swapped" in err
    assert not (tmp_path / "d" / "diagnosis.json").exists()


@pytest.mark.parametrize("column, what", [("q", "the load encoder"), ("theta_m", "the motor encoder"),
                                          ("tau_m", "the drive's torque")])
def test_a_column_of_zeros_is_refused(moving, tmp_path, capsys, column, what):
    # a sensor that reports nothing while the joint moves: diagnose fitted a 113 N m offset or a
    # 200 N m gravity term to such a log
    log, cfg = moving
    dead = dataclasses.replace(log, **{column: np.zeros_like(getattr(log, column))}, path="dead.csv")
    with pytest.raises(InputError, match=f"column {column} is 0 .* while .*{what}"):
        diagnose(dead, cfg, None, plots=False)
    p = tmp_path / "dead.csv"
    write_log(p, dead)
    rc = main(["diagnose", str(p), "--config", str(EXO), "--out", str(tmp_path / "d"), "--no-plots"])
    err = capsys.readouterr().err
    assert rc == 2 and len(err.strip().splitlines()) == 1 and what in err, err
    assert not (tmp_path / "d" / "diagnosis.json").exists()


def test_consistent_log_passes_the_balance_check(moving):
    from sea_daemon.analysis.diagnose.consistency import motor_balance_gain
    from sea_daemon.analysis.diagnose.residuals import kinematics_from_log
    log, cfg = moving
    (g, hw), = motor_balance_gain(cfg, kinematics_from_log(log))
    assert math.isfinite(g) and g - hw > 0.5, (g, hw)
