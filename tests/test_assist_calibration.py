"""The assistance's estimate where the assistance moves the arm (docs/assist.md, "Why the working range").

Calibrated on the tracking task's own passive moves, the GP has seen z = [q, q̇, q̈] only on the
curve a repeated minimum-jerk move traces; assisted, the arm moves faster and accelerates
differently, the GP extrapolates, and the bound that gates the push stops covering. The
calibration over the configuration's declared working range (``calibrate --excitation``) is what
``python -m benchmarks.assist`` runs by default.
"""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from benchmarks import assist as bench
from sea_daemon.core.excitation import MJ_PEAK_ACC, MJ_PEAK_VEL
from sea_daemon.io.scenario import load_scenario


def test_the_assist_configuration_declares_a_working_range_beyond_the_tasks_moves():
    sc = load_scenario(bench.SCENARIO)
    c, task = sc.nominal.calibration, sc.task
    q_lo, q_hi = sorted(task.q_deg)
    dq = np.radians(q_hi - q_lo)
    assert c.q_min_deg is not None and c.q_max_deg is not None
    assert c.q_min_deg < q_lo and c.q_max_deg > q_hi                     # the overshoot of an assisted move
    # faster and sharper than the task's own move, and than the assisted arm's 0.8 rad/s, 3 rad/s²
    assert c.v_max > max(1.0, MJ_PEAK_VEL * dq / task.move_s)
    assert c.a_max > max(3.0, MJ_PEAK_ACC * dq / task.move_s ** 2)


@pytest.mark.slow
def test_the_working_range_calibration_covers_the_assisted_task(tmp_path):
    """100 Hz, development seed 3, two task cycles: the bound covers ≥ 0.95 of the valid samples
    while assistance acts and the subject's effort still halves (calibrated on the task's own
    moves and without the subject's declared torque rate: coverage 0.89, estimate error 0.22 N m RMS)."""
    sc = load_scenario(bench.SCENARIO)
    cfg = bench.task_config(sc, 100.0)
    residual, beta, info = bench.calibrated(sc, cfg, 100.0, tmp_path, "excitation")
    assert info["calibration"] == "excitation"
    assert info["calibration_cycles"] == round(cfg.calibration.duration_s * 100)
    cfg = dataclasses.replace(cfg, estimator=dataclasses.replace(cfg.estimator, gp_beta=beta))
    scen = bench.scenario_copy(bench.SCENARIO, tmp_path / "task.yaml", seed=3)
    runs = {g: bench.metrics(bench.task_run(scen, cfg, residual, g, 18.0), sc.task, cfg.dt) for g in (0.0, 2.0)}
    assisted = runs[2.0]
    assert assisted["fault"] == "NONE"
    assert assisted["coverage"] >= 0.95, assisted
    assert assisted["est_rmse"] < 0.18, assisted
    assert 1.0 - assisted["tau_h_rms"] / runs[0.0]["tau_h_rms"] >= 0.5


def test_the_task_configuration_carries_what_the_scenario_declares_about_its_subject(tmp_path):
    """A ``tau_h_act_rate`` the scenario declares reaches the estimator's bound (docs/bounds.md §6)."""
    src = bench.scenario_copy(bench.SCENARIO, tmp_path / "declared.yaml", tau_h_act_rate=4.0)
    cfg = bench.task_config(load_scenario(src), 1000.0)
    assert cfg.estimator.tau_h_act_rate == 4.0 and cfg.rate_hz == 1000.0 and cfg.assist.enabled
    # the tracking task's subject is active: its scenario declares how fast its torque changes
    shipped = load_scenario(bench.SCENARIO)
    assert shipped.tau_h_act_rate and bench.task_config(shipped, 100.0).estimator.tau_h_act_rate == shipped.tau_h_act_rate
