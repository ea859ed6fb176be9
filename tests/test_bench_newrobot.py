"""`sea-daemon bench newrobot`'s plant directories: one plant per directory, never the project's
development plant; a table that mixes plants or names a session twice is refused before any
simulation.  (The table itself takes minutes: docs/calibration.md, not run here.)"""
from __future__ import annotations

import shutil

import pytest

from sea_daemon.apps.bench.newrobot import load_table
from sea_daemon.io.configfile import load_config
from _paths import repo_root
from sea_daemon.io.scenario import load_scenario

from tests._cli import refused, run

PLANTS = ("newrobot", "newrobot2", "newrobot3")


@pytest.mark.parametrize("name", PLANTS)
def test_a_plant_directory_is_one_plant_unlike_the_development_plant(name):
    cal, sessions = load_table(repo_root() / "configs" / "scenarios" / name)
    assert cal.human == "passive" and len(sessions) >= 5
    assert {s.scenario.human for s in sessions} == {"passive", "resist"}
    # the estimator is told the nominal robot only, and it is not exo_1dof's
    assert cal.nominal.model.effects == ()
    base = load_config(repo_root() / "configs" / "exo_1dof.yaml").model
    for k in ("M", "J", "D_m", "K_s", "D_s", "gravity"):
        a, b = float(getattr(cal.nominal.model, k).flat[0]), float(getattr(base, k).flat[0])
        assert abs(a / b - 1.0) >= 0.2, k
    dev = load_scenario(repo_root() / "configs" / "scenarios" / "passive.yaml")
    assert cal.plant.effects != dev.plant.effects
    # the hidden effects of the arm and something beyond them
    types = {(e.type, e.side) for e in cal.plant.effects}
    assert {("inertia", "load"), ("gravity", "load"), ("human_viscoelastic", "load"), ("coulomb", "load")} <= types
    assert any(side == "motor" for _, side in types)


def test_a_table_mixing_plants_or_naming_a_session_twice_is_refused(tmp_path, capsys):
    d = tmp_path / "plant"
    shutil.copytree(repo_root() / "configs" / "scenarios" / "newrobot", d)
    sc = d / "faster17.yaml"
    sc.write_text(sc.read_text().replace("F_c: 0.3}", "F_c: 0.35}"))
    code, _, err = run(["bench", "newrobot", "--plant", d, "--out", tmp_path / "out"], capsys)
    refused(code, err, r"faster17\.yaml", "not the plant of")
    shutil.copy(repo_root() / "configs" / "scenarios" / "newrobot" / "faster17.yaml", sc)
    t = d / "table.yaml"
    t.write_text(t.read_text().replace("name: faster40", "name: faster17"))
    code, _, err = run(["bench", "newrobot", "--plant", d, "--out", tmp_path / "out"], capsys)
    refused(code, err, r"sessions\[1\]\.name", "named twice")
    assert not (tmp_path / "out").exists()


def test_the_excitation_calibration_log_spans_the_declared_working_range():
    """--calibration excitation: the moves calibrate --excitation drives, on the plant's true
    plant with a passive subject, over robot.yaml's working range."""
    import math

    import numpy as np

    from sea_daemon.apps.bench.newrobot import excitation_log
    cal, _ = load_table(repo_root() / "configs" / "scenarios" / "newrobot3")
    c = cal.nominal.calibration
    log = excitation_log(cal)
    # the excitation (plus the move from the scenario's start angle onto it)
    assert c.duration_s - 0.5 <= log.t[-1] <= c.duration_s + 5.0 and not np.any(log.tau_h_act)
    q = np.degrees(log.q[:, 0])
    lo, hi = c.q_min_deg, c.q_max_deg
    assert q.min() < lo + 0.1 * (hi - lo) and q.max() > hi - 0.1 * (hi - lo)
    dq = np.gradient(log.q[:, 0], log.t)
    assert np.max(np.abs(dq)) > 0.5 * c.v_max and math.isfinite(float(np.max(np.abs(dq))))


def test_the_held_out_plants_are_drawn_around_newrobot_with_their_own_hidden_effects():
    """newrobot4-6 (held out: written before any run on them): each one plant, its nominal
    parameters within ±30 % of newrobot's robot.yaml, its hidden effects unlike the other
    plants'; among them a torque-constant error and an arm's weight with an elbow stiffness."""
    base = load_config(repo_root() / "configs" / "scenarios" / "newrobot" / "robot.yaml").model
    effects = []
    for name in ("newrobot4", "newrobot5", "newrobot6"):
        cal, sessions = load_table(repo_root() / "configs" / "scenarios" / name)
        assert cal.human == "passive" and {s.scenario.human for s in sessions} == {"passive", "resist"}
        assert cal.nominal.model.effects == ()
        for k in ("M", "J", "D_m", "K_s", "D_s", "gravity"):
            a, b = float(getattr(cal.nominal.model, k).flat[0]), float(getattr(base, k).flat[0])
            assert abs(a / b - 1.0) <= 0.3, (name, k)
        effects.append({(e.type, e.side) for e in cal.plant.effects})
    others = [load_table(repo_root() / "configs" / "scenarios" / n)[0].plant.effects for n in PLANTS]
    assert all(load_table(repo_root() / "configs" / "scenarios" / n)[0].plant.effects not in others
               for n in ("newrobot4", "newrobot5", "newrobot6"))
    assert any(("torque_scale", "motor") in t for t in effects)
    assert any({("gravity", "load"), ("human_viscoelastic", "load")} <= t for t in effects)
