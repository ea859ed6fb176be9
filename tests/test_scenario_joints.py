"""Scenario files of the two-joint example (configs/scenarios/two_joint_*.yaml): per-joint values,
the true arm's links, the simulated logs with n joints, and the coverage per joint; every bad
value a one-line ConfigError naming the key."""
import dataclasses
import math

import numpy as np
import pytest
import yaml

from sea_daemon.core.excitation import Coverage, JointsCoverage, WorkingRange, coverage_from_dict
from sea_daemon.errors import ConfigError
from sea_daemon.io.logcsv import read_log, write_log
from sea_daemon.io.scenario import Scenario, load_scenario, make_plant
from sea_daemon.runtime.sim_runner import simulate
from tests._paths import repo_root

SCEN = repo_root() / "configs" / "scenarios"


def short(sc, train=150, est=200):
    return dataclasses.replace(sc, training_samples=train, estimation_samples=est)


def test_two_joint_passive_scenario_simulates_both_joints(tmp_path):
    """The true plant is the URDF with the scenario's link factors (its gravity and inertia torques
    differ from the nominal model's) and the hidden effects per joint; the log has q_1, q_2, ...
    and each joint follows its own moves."""
    sc = load_scenario(SCEN / "two_joint_passive.yaml")
    assert sc.nominal.joints == 2
    true, nominal = sc.true_config(), sc.nominal
    q = np.array([0.8, 1.0])
    assert np.all(np.abs(true.model.rigid.gravity(q) / nominal.model.rigid.gravity(q) - 1.0) > 0.005)
    assert abs(true.model.rigid.mass_matrix(q)[1, 1] / nominal.model.rigid.mass_matrix(q)[1, 1] - 1.0) > 0.005
    assert {e.joint for e in true.model.effects} == {0, 1}
    res = simulate(short(sc))
    assert res.training.q.shape == (150, 2) and res.estimation.q.shape == (200, 2)
    assert not np.any(res.estimation.tau_h_act)
    assert res.estimation.t[0] == pytest.approx(1.5)
    # both joints move (the elbow's moves are faster than the shoulder's)
    assert np.ptp(res.estimation.q[:, 0]) > 0.1 and np.ptp(res.estimation.q[:, 1]) > 0.1
    p = tmp_path / "p.csv"
    write_log(p, res.estimation)
    back = read_log(p, n=2)
    np.testing.assert_allclose(back.q, res.estimation.q, rtol=1e-8)
    assert "q_2" in p.read_text().splitlines()[0].split(",")


def test_two_joint_active_scenario_subject_resists_on_both_joints():
    """Sec. V-C on two joints: the arm held still, the subject's torque −τ_des on each joint in the
    estimation phase only (0 in training)."""
    sc = short(load_scenario(SCEN / "two_joint_active.yaml"), 100, 300)
    res = simulate(sc)
    assert not np.any(res.training.tau_h_act)
    tau = res.estimation.tau_h_act
    assert tau.shape == (300, 2)
    tp = res.estimation.t - res.estimation.t[0]
    c = sc.controller
    for j in range(2):
        want = -(-c.amplitude[j] * np.cos(2 * np.pi * c.frequency_hz[j] * tp) + c.offset[j])
        np.testing.assert_allclose(tau[:-1, j], want[:-1], atol=1e-9)
    assert np.max(np.abs(res.estimation.q - np.radians([40.0, 60.0]))) < 0.05      # held


def load_with(tmp_path, mutate, name="two_joint_passive.yaml"):
    d = yaml.safe_load((SCEN / name).read_text())
    mutate(d)
    d["model"] = str(SCEN.parent / ("exo_2dof.yaml" if "two_joint" in name else "exo_1dof.yaml"))
    return Scenario.from_dict(d, source=str(tmp_path / "s.yaml"))


@pytest.mark.parametrize("mutate, key", [
    (lambda d: d["controller"].__setitem__("kp", [1.0, 2.0, 3.0]), "controller.kp"),
    (lambda d: d["controller"]["trajectory"].__setitem__("q_end_deg", [70, 400]), "controller.trajectory.q_end_deg"),
    (lambda d: d["plant"]["links"]["mass"].__setitem__("no_such_link", 1.1), "plant.links.mass.no_such_link"),
    (lambda d: d["plant"]["links"]["length"].__setitem__("human_forearm_hand", 0.0), "plant.links.length"),
    (lambda d: d.__setitem__("human", "resist"), "human"),
    (lambda d: d["plant"]["effects"][0].pop("joint"), "plant.effects[0].joint"),
])
def test_bad_two_joint_scenarios_are_refused_in_one_line(tmp_path, mutate, key):
    with pytest.raises(ConfigError) as e:
        load_with(tmp_path, mutate)
    msg = str(e.value)
    assert key in msg and "\n" not in msg


def test_links_need_a_urdf_model(tmp_path):
    def mutate(d):
        d["plant"]["links"] = {"mass": {"forearm": 1.2}}
    with pytest.raises(ConfigError, match="plant.links.*model.urdf"):
        load_with(tmp_path, mutate, "passive.yaml")


def test_coverage_per_joint():
    """z ∈ R^{3n} is covered only where every joint's (q_j, q̇_j, q̈_j) is; saved and read back."""
    wrs = [WorkingRange(0.0, 1.0, 1.0, 10.0), WorkingRange(0.0, 2.0, 1.0, 10.0)]
    cov = JointsCoverage(wrs)
    rng = np.random.default_rng(0)
    Z = np.column_stack([rng.uniform(0.0, 0.5, 500), rng.uniform(0.0, 2.0, 500), rng.uniform(-0.5, 0.5, (500, 2)),
                         rng.uniform(-5, 5, (500, 2))])
    cov.add(Z)
    assert cov.covered(np.array([0.25, 1.0, 0.0, 0.0, 0.0, 0.0]))
    assert not cov.covered(np.array([0.9, 1.0, 0.0, 0.0, 0.0, 0.0]))      # joint 1 never went there
    back = coverage_from_dict(cov.to_dict())
    assert isinstance(back, JointsCoverage) and back.report() == cov.report()
    assert cov.report()["q_share"] == pytest.approx(0.5, abs=0.11)
    one = Coverage(wrs[0])
    assert isinstance(coverage_from_dict(one.to_dict()), Coverage)
    assert math.isclose(cov.report()["joints"][1]["q_share"], 1.0)


def test_scenario_controller_runs_the_moves_of_every_joint():
    """The daemon's scenario controller (calibrate on the bus, --excitation or the scenario's moves)
    tracks each joint's reference with its per-joint gains: a (2,) command, the bumpless start."""
    from sea_daemon.core.excitation import excitation_joints
    from sea_daemon.runtime.controller import ScenarioController
    sc = load_scenario(SCEN / "two_joint_passive.yaml")
    hold = np.array([10.0, 3.0])
    ctl = ScenarioController(sc, sc.nominal, hold, estimation_from=None)
    q0 = np.radians([20.0, 30.0])
    u = ctl.update(0.0, q0, q0 + 0.01, None)
    np.testing.assert_allclose(u, hold)
    u = ctl.update(1.0, q0, q0 + 0.01, None)
    assert u.shape == (2,) and np.all(u > hold)            # both references moved up, both joints pushed
    ref = excitation_joints([WorkingRange(0.3, 1.2), WorkingRange(0.5, 1.5)], 10.0, seed=1, q0=q0)
    ctl = ScenarioController(sc, sc.nominal, hold, estimation_from=None, reference=ref)
    ctl.update(0.0, q0, q0, None)
    assert ctl.update(2.0, q0, q0, None).shape == (2,)


def test_plant_torque_noise_override_per_joint(tmp_path):
    """``plant.torque_noise`` takes a number (every joint) or one per joint, as
    ``hardware.torque_noise`` does; the true plant draws each joint's own noise."""
    sc = load_with(tmp_path, lambda d: d["plant"].__setitem__("torque_noise", [0.03, 0.0]))
    assert sc.plant.torque_noise == (0.03, 0.0)
    assert make_plant(sc).noise_std.tolist() == [0.03, 0.0]
    every = load_with(tmp_path, lambda d: d["plant"].__setitem__("torque_noise", 0.01))
    assert every.plant.torque_noise == 0.01 and make_plant(every).noise_std.tolist() == [0.01, 0.01]
    one = load_with(tmp_path, lambda d: d["plant"].__setitem__("torque_noise", 0.01), "passive.yaml")
    assert one.plant.torque_noise == 0.01 and make_plant(one).noise_std == 0.01


@pytest.mark.parametrize("value, got", [([0.03, 0.0, 0.01], "[0.03, 0.0, 0.01]"),
                                        ([0.03, -0.01], "[0.03, -0.01] (joint 2: -0.01)")])
def test_bad_plant_torque_noise_is_refused_in_one_line(tmp_path, value, got):
    with pytest.raises(ConfigError) as e:
        load_with(tmp_path, lambda d: d["plant"].__setitem__("torque_noise", value))
    assert str(e.value).endswith("plant.torque_noise: must be a number >= 0 or a list of 2 such numbers "
                                 f"(one per joint), got {got}")
