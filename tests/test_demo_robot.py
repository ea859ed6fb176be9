"""The two-joint robot's user-facing path: the n-joint open-loop scenario controller (the still arm
of configs/scenarios/two_joint_active.yaml run by the daemon's loop), the resisting subject per
joint, each joint's debug columns in a simulated log, and `sea-daemon demo --robot`'s refusals,
table and plots per joint."""
import dataclasses
import math

import numpy as np
import pytest

from sea_daemon.apps.cli import main
from sea_daemon.apps.commands import demo_robot
from sea_daemon.core.control import cosine_torque
from sea_daemon.core.replay import ReplayResult
from sea_daemon.core.sim.session import run_session
from sea_daemon.io.scenario import load_scenario
from sea_daemon.runtime.controller import ScenarioController
from sea_daemon.runtime.rig import subject_torque
from tests._paths import repo_root

SCEN = repo_root() / "configs" / "scenarios"
ROBOT = repo_root() / "configs" / "exo_2dof.yaml"


@pytest.fixture(scope="module")
def active():
    return load_scenario(SCEN / "two_joint_active.yaml")


def test_open_loop_of_two_joints_commands_each_joints_cosine_on_its_holding_torque(active):
    """Sec. V-C per joint: τ_m = τ_comp + τ_des with each joint's own amplitude, frequency and
    offset in the estimation phase, τ_comp alone before it; tau_des is the (n,) command's."""
    cfg = active.nominal
    hold = np.array([5.0, 1.5])
    ctl = ScenarioController(active, cfg, hold, estimation_from=100)
    q, th = np.radians([40.0, 60.0]), np.radians([40.5, 60.3])
    before = ctl.update(50 * cfg.dt, q, th, None).copy()
    assert np.array_equal(before, hold) and np.array_equal(ctl.tau_des, [0.0, 0.0])
    for k in (100, 137, 450):
        u = ctl.update(k * cfg.dt, q, th, None)
        tp = (k - 100) * cfg.dt
        want = np.array([cosine_torque(tp, 2.0, 0.1, 2.0), cosine_torque(tp, 1.0, 0.15, 1.0)])
        assert np.allclose(ctl.tau_des, want, atol=1e-12) and np.allclose(u, hold + want, atol=1e-12)
    assert ctl.tau_des[0] != ctl.tau_des[1]          # each joint its own profile


def test_the_subject_resists_on_each_joint_in_the_estimation_phase(active):
    f = subject_torque(active, "estimation")
    for t in (0.0, 3.3, 7.0):
        want = -np.array([cosine_torque(t, 2.0, 0.1, 2.0), cosine_torque(t, 1.0, 0.15, 1.0)])
        assert np.allclose(f(t), want, atol=1e-12)
    assert np.array_equal(subject_torque(active, "training")(3.0), [0.0, 0.0])


def test_a_simulated_log_of_two_joints_has_each_joints_debug_columns(active):
    """q_true, q_ref, ... of joint 1 under their names (as before) and of every joint suffixed:
    q_ref_2 is the elbow's hold angle, q_true_2 the elbow's true angle."""
    q0 = np.radians([40.0, 60.0])
    log = run_session(active.true_config(), 0.3, hold_q=q0, seed=3, substep_hz=4000, sign_eps=0.003)
    x = log.extra
    for base in ("q_true", "dq_true", "q_ref", "theta_m_true", "dtheta_m_true"):
        assert np.array_equal(x[base], x[f"{base}_1"])
    assert np.allclose(x["q_ref_2"], q0[1]) and np.allclose(x["q_ref_1"], q0[0])
    assert np.max(np.abs(x["q_true_2"] - log.q[:, 1])) < 1e-3
    assert np.max(np.abs(x["q_true_1"] - log.q[:, 0])) < 1e-3


@pytest.mark.parametrize("argv, words", [
    (["--robot", str(repo_root() / "configs" / "exo_1dof.yaml")], "a model of 1 joint(s) without model.urdf"),
    (["--robot", str(ROBOT), "--config", str(repo_root() / "configs" / "exo_1dof.yaml")], "--robot and --config"),
    (["--robot", str(ROBOT), "--online-gp"], "--online-gp: one joint only"),
])
def test_demo_robot_refuses_what_it_cannot_run_in_one_line(tmp_path, capsys, argv, words):
    assert main(["demo", "--out", str(tmp_path / "out"), *argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and words in err[0] and "internal error" not in err[0], err


def test_a_step_stopped_by_overruns_says_why_and_what_runs_instead():
    """--pace realtime at a rate the host cannot keep (two joints at 1 kHz on a busy host: the
    calibration's first cycles overrun): the demo's line names the cause and lock-step."""
    from sea_daemon.apps.commands.demo_flow import daemon
    from sea_daemon.errors import RunFault

    def calibrate(argv):
        print('{"fault": "OVERRUN_STREAK", "cycles": 5}')
        return 1
    with pytest.raises(RunFault) as e:
        daemon(["calibrate", "--pace", "realtime"], calibrate)
    msg = str(e.value)
    assert msg.startswith("sea-daemon calibrate stopped with exit status 1 (OVERRUN_STREAK: the daemon's cycles "
                          "took longer than their period on this host; --pace lockstep")
    assert "\n" not in msg and msg.endswith("the demo stops there")


def test_the_robot_scenario_runs_the_robots_model(tmp_path, active):
    p = demo_robot.robot_scenario(ROBOT, "active", tmp_path / "active_scenario.yaml")
    sc = load_scenario(p)
    assert sc.model_path.resolve() == ROBOT.resolve()
    assert sc.plant == active.plant and sc.controller == active.controller


def _result(name, t, hat, bound):
    n = hat.shape[1]
    return ReplayResult(t=t, tau_h_act_hat=hat, tau_h_act_sigma=bound / 2, tau_h_act_bound=bound,
                        x_hat=np.zeros((t.size, 5 * n)), tau_h_act=None, step_time_s=None, estimator=name,
                        valid=np.ones(t.size, bool))


def test_joint_result_is_the_joints_one_joint_result():
    t = np.arange(4) * 0.01
    res = _result("akf", t, np.arange(8.0).reshape(4, 2), np.ones((4, 2)))
    res.x_hat = np.arange(40.0).reshape(4, 10)
    r2 = demo_robot.joint_result(res, 1)
    assert r2.n == 1 and np.array_equal(r2.tau_h_act_hat[:, 0], [1.0, 3.0, 5.0, 7.0])
    assert np.array_equal(r2.x_hat[0], [1.0, 3.0, 5.0, 7.0, 9.0])      # theta_m, theta_s, ... of joint 2


def test_scoring_gives_a_row_and_a_plot_per_joint_and_estimator(tmp_path, active, monkeypatch):
    """The table: per scenario, joint and estimator (spring, AKF, oracle AKF, the online GP-AKF),
    each joint scored on its own truth; a PNG per joint; summary per joint by its name."""
    cfg = active.nominal
    log = run_session(active.true_config(), 0.5, hold_q=np.radians([40.0, 60.0]), seed=1,
                      human=lambda t: np.array([0.5, -0.25]), substep_hz=4000)
    N = len(log)
    truth = np.tile([0.5, -0.25], (N, 1))
    x = dict(log.extra)
    for j in range(2):                    # the daemon's own columns, per joint (docs/interfaces.md §1)
        x[f"tau_h_act_hat_{j + 1}"] = truth[:, j] + (0.1 if j == 0 else 0.02)
        x[f"tau_h_act_bound_{j + 1}"] = np.full(N, 0.2)
        x[f"tau_h_act_sigma_{j + 1}"] = np.full(N, 0.1)
    x.update(compute=np.full(N, 1e-4), valid=np.ones(N), cycle=np.arange(N, dtype=float),
             bound_cycle=np.arange(N, dtype=float))
    est_log = dataclasses.replace(log, tau_h_act=truth, extra=x)
    names = ["joint 1 (shoulder)", "joint 2 (elbow)"]
    summaries = {}
    rows = demo_robot.score_joints(tmp_path, "active", est_log, cfg, active.true_config(), names,
                                   ("shoulder", "elbow"), summaries)
    assert [(r[1], r[2]) for r in rows] == [(jn, e) for jn in names for e in demo_robot.ROBOT_ESTIMATORS]
    gp = {r[1]: r for r in rows if r[2] == "gp-akf"}
    assert gp[names[0]][3] == pytest.approx(0.1) and gp[names[1]][3] == pytest.approx(0.02)
    assert gp[names[0]][4] == 1.0 and gp[names[0]][5] == pytest.approx(0.2)
    assert summaries["gp-akf"]["joints"][names[1]]["rmse"] == pytest.approx(0.02)
    assert summaries["oracle"]["joints"][names[0]]["samples"] == N
    for f in ("active_shoulder.png", "active_elbow.png", "active_oracle.csv", "active_gp-akf.csv"):
        assert (tmp_path / f).stat().st_size > 0
    assert all(math.isfinite(r[3]) for r in rows)


def test_run_sim_with_the_two_joint_open_loop_scenario(tmp_path, capsys):
    """`sea-daemon run --sim two_joint_active.yaml`: the scenario's open loop per joint in the
    daemon's loop — each joint's command is its holding torque plus its own cosine τ_des."""
    import json

    from sea_daemon.core.learning import ResidualGP
    from sea_daemon.io.configfile import load_config
    from sea_daemon.io.gpmodel import save_gp_model
    from sea_daemon.io.logcsv import read_log

    cfg = load_config(ROBOT)
    res = ResidualGP(2, cfg.learning, hyperopt=False)
    rng = np.random.default_rng(0)
    for _ in range(30):
        res.update(rng.uniform(-1, 1, 6), np.zeros(2))
    save_gp_model(tmp_path / "m.npz", cfg, res, {"test": True})
    scen = str(SCEN / "two_joint_active.yaml")
    rc = main(["run", "--config", str(ROBOT), "--model", str(tmp_path / "m.npz"), "--sim", scen, "--scenario", scen,
               "--log-dir", str(tmp_path), "--cycles", "150", "--socket", "none", "--pace", "lockstep"])
    out, err = capsys.readouterr()
    summary = json.loads([ln for ln in out.splitlines() if ln.startswith("{")][-1])
    assert rc == 0 and summary["fault"] == "NONE", err[-800:]
    log = read_log(summary["log"], n=2)
    k = np.arange(len(log))
    des = np.stack([[cosine_torque(i * cfg.dt, 2.0, 0.1, 2.0) for i in k],
                    [cosine_torque(i * cfg.dt, 1.0, 0.15, 1.0) for i in k]], axis=1)
    assert np.allclose(log.tau_m - log.tau_m[0], des - des[0], atol=1e-7)      # the log's 9 digits
    assert np.all(np.abs(des[-1]) > 0.01)
