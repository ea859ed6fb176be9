"""bench generalize --joints 2: the two-joint family (seeded), the figures per joint, the one-joint
summary per joint and the targets per joint; --joints outside 1..2 refused in one line."""
import math
import subprocess
import sys

import numpy as np

from sea_daemon.apps.bench._family_joints import draw_plant_joints, sessions_joints
from sea_daemon.apps.bench.generalize import by_rate, summarize
from sea_daemon.apps.bench._generalize_joints import (DEVELOPMENT_SEEDS, _joint_stats, joint_view,
                                                     summarize_joints)
from tests._paths import repo_root


def test_two_joint_family_is_seeded_and_differs_from_the_nominal_arm():
    a, b = draw_plant_joints(7), draw_plant_joints(7)
    assert a.summary == b.summary and a.summary != draw_plant_joints(8).summary
    q = np.array([0.7, 1.1])
    g_true, g_nom = a.true.model.rigid.gravity(q), a.nominal.model.rigid.gravity(q)
    assert not np.allclose(g_true, g_nom, rtol=0.01)                 # links' masses and lengths ±30 %
    assert all(0.7 <= f <= 1.3 for f in a.summary["link_mass"].values())
    assert {e.joint for e in a.true.model.effects} == {0, 1} and not a.nominal.model.effects
    names = [s.name for s in sessions_joints(a)]
    assert names == ["slow", "fast", "wide", "sines", "active_low", "active_high", "still_cosine", "still_band"]
    tau = sessions_joints(a)[4].human(3.0)
    assert tau.shape == (2,) and tau[0] != tau[1]                     # a torque on each joint, its own


def test_the_passive_moving_sessions_stay_in_the_declared_range_and_off_the_stops():
    """The moving passive sessions, but ``wide`` (8° past the range on purpose), keep every joint's
    reference inside its declared working range; ``wide`` stays clear of the URDF's end stops (what
    a stop pushes would read as the wearer's torque on a passive session)."""
    for seed in range(10):
        pd = draw_plant_joints(seed)
        rb = pd.true.model.rigid
        for s in sessions_joints(pd):
            if s.reference is None:
                continue
            Q = np.array([s.reference.reference(t)[0] for t in np.arange(0.0, s.duration_s, 0.01)])
            for j, w in enumerate(pd.working_range):
                lo, hi = (w.q_min, w.q_max) if s.name != "wide" else (rb.q_min[j] + math.radians(3), rb.q_max[j] - math.radians(3))
                assert lo - 1e-9 <= Q[:, j].min() and Q[:, j].max() <= hi + 1e-9, (seed, s.name, j)


def _res(rmse1, rmse2, bound=None):
    out = {"rmse": math.hypot(rmse1, rmse2) / math.sqrt(2), "finite": True,
           "joints": [{"rmse": rmse1, "finite": True}, {"rmse": rmse2, "finite": True}]}
    if bound:
        for j, (cov, rho, r) in enumerate(bound):
            out["joints"][j]["bound"] = {"coverage": cov, "coverage_valid": cov, "mean_rho": rho, "mean_rho_valid": rho,
                                         "rmse_valid": r, "ratio": 1.0, "valid_share": 1.0}
    return out


def rows():
    row = {"seed": 5, "rate_hz": 100.0, "plant": {"rate_hz": 100.0},
           "session_kinds": {"slow": "passive", "active_low": "active"},
           "sessions": {"slow": {"gp-akf": _res(0.02, 0.04, [(1.0, 0.1, 0.02), (0.97, 0.1, 0.04)]),
                                 "oracle": _res(0.02, 0.02)},
                        "active_low": {"gp-akf": _res(0.1, 0.3, [(0.99, 0.2, 0.1), (0.9, 1.2, 0.3)]),
                                       "oracle": _res(0.05, 0.3)}}}
    return [row, {**row, "seed": DEVELOPMENT_SEEDS[0]}]


def test_figures_and_targets_per_joint():
    """Each joint's ratio to the oracle, its passive RMSE, coverage and mean bound / RMSE on active
    sessions — a joint that misses a target is named, the other is not."""
    s = summarize_joints(rows(), summarize, by_rate)
    assert s["seeds"] == {"development": [DEVELOPMENT_SEEDS[0]], "held_out": [5]}
    j1, j2 = s["joints"]["1"], s["joints"]["2"]
    assert j1["by_rate"]["100"]["gp_over_oracle"]["median"] == 1.5        # ratios 1.0 and 2.0
    assert j2["by_rate"]["100"]["gp_over_oracle"]["median"] == 1.5        # ratios 2.0 and 1.0
    assert j1["done_when"]["held"] == {"passive_rmse": True, "coverage": True, "active_bound_over_rmse": True}
    assert j2["done_when"]["held"] == {"passive_rmse": True, "coverage": False, "active_bound_over_rmse": False}
    assert j2["done_when"]["coverage_min"] == 0.9
    assert j2["done_when"]["active_bound_over_rmse_max"] == 1.2 / 0.3
    assert j1["by_rate"]["100"]["plants"] == [5] and j1["by_rate_development"]["100"]["plants"] == [DEVELOPMENT_SEEDS[0]]
    assert joint_view(rows(), 1)[0]["sessions"]["slow"]["oracle"]["rmse"] == 0.02


def test_joint_stats_of_one_joint():
    e = np.array([0.1, -0.2, 0.0, 0.3])
    st = _joint_stats(e, np.full(4, 0.25), np.array([True, True, False, True]), True)
    assert st["rmse"] == float(np.sqrt(np.mean(e ** 2)))
    assert st["bound"]["coverage"] == 0.75 and st["bound"]["coverage_valid"] == 2 / 3


def test_joints_outside_the_range_are_refused(tmp_path):
    r = subprocess.run([sys.executable, "-m", "sea_daemon", "bench", "generalize", "--joints", "3", "--seeds", "5",
                        "--out", str(tmp_path / "g")], cwd=repo_root(), capture_output=True, text=True, timeout=300)
    assert r.returncode == 2, r.stderr
    line = [x for x in r.stderr.splitlines() if "--joints" in x]
    assert line and "allowed 1 or 2" in line[0]


def test_the_still_arm_subject_holds_the_arm_out_of_the_stops():
    """Plant 6's ``still_band``: the open loop alone lets the arm drift into its end stops (every
    estimator then reads the stop as the wearer); the subject holding the arm (HOLD) keeps it
    within a degree, and the log's τ_h,act is the torque the subject applied, hold included."""
    from sea_daemon.apps.bench._family_joints import HOLD
    from sea_daemon.apps.calibration.joints import plant_substep
    from sea_daemon.core.sim.session import run_session
    pd = draw_plant_joints(6)
    s = {x.name: x for x in sessions_joints(pd)}["still_band"]
    sub = plant_substep(pd.true, 3e-3, pd.nominal.rate_hz)
    q0 = np.degrees(s.hold_q)

    def run(hold):
        log = run_session(pd.true, 10.0, hold_q=s.hold_q, human=s.human, seed=3, substep_hz=sub, hold=hold)
        q = np.degrees(np.column_stack([log.extra["q_true_1"], log.extra["q_true_2"]]))
        return np.max(np.abs(q - q0)), log.tau_h_act
    free, tau_free = run(None)
    held, tau_held = run(HOLD)
    assert free > 10.0 and held < 1.0
    # the truth is the torque the subject applied: what it resists with (a function of time, the
    # same in both runs) plus the hold, which stays small
    assert 1e-4 < np.max(np.abs(tau_held - tau_free)) < 1.0
