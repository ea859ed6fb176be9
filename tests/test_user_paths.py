"""A new user's first steps off the golden path: every bad input refused with exit 2 and one line
naming the value and what is allowed, no traceback, no nan."""
from __future__ import annotations

import numpy as np
import pytest

from _cli import refused, run
from sea_daemon.errors import InputError
from sea_daemon.io.configfile import default_config_path

CFG = default_config_path()


def _dead_q_log(p, samples: int = 400):
    """A log at 100 Hz whose load encoder column q reads 0 in every row while the motor turns 30 deg."""
    t = np.arange(samples) * 0.01
    th = 0.3 * np.sin(t)
    rows = "\n".join(f"{a:.4f},0,{b:.6f},{0.5 * np.cos(a):.5f}" for a, b in zip(t, th))
    p.write_text("t,q,theta_m,tau_m\n" + rows + "\n")
    return p


@pytest.mark.parametrize("argv", [
    ["replay", "LOG", "--config", CFG, "--estimator", "akf", "--out", "OUT/est.csv"],
    ["replay", "LOG", "--config", CFG, "--estimator", "spring", "--out", "OUT/est.csv"],
    ["calibrate-bound", "LOG", "--config", CFG, "--model", "OUT/m.npz"],
    ["diagnose", "GOOD", "--config", CFG, "--apply", "LOG", "--out", "OUT/diag", "--no-plots"],
])
def test_a_dead_encoder_column_is_named_before_any_estimator_runs(tmp_path, capsys, argv):
    # the AKF used to run into it and stop on an NIS divergence a few hundred samples in
    from _cli import passive_log
    log = _dead_q_log(tmp_path / "dead.csv")
    good = passive_log(tmp_path / "good.csv", 600)
    (tmp_path / "m.npz").write_bytes(b"")
    sub = {"LOG": log, "GOOD": good}
    args = [sub.get(a, str(a).replace("OUT", str(tmp_path))) for a in argv]
    code, _, err = run(args, capsys)
    refused(code, err, r"column q is 0 rad in all 400 rows while theta_m spans 30\.1 deg: the load encoder reports nothing")
    assert not (tmp_path / "est.csv").exists()


def _log(p, n: int, samples: int = 300):
    """A valid log of ``n`` joints at 100 Hz (columns q or q_1 … q_n, as docs/interfaces.md section 1)."""
    from sea_daemon.core.log import column_names
    t = np.arange(samples) * 0.01
    cols = ["t"] + [c for base in ("q", "theta_m", "tau_m") for c in column_names(base, n)]
    q = 0.3 * np.sin(t)
    vals = [t] + [q] * n + [q - 0.001] * n + [0.5 * np.cos(t)] * n
    p.write_text(",".join(cols) + "\n" + "\n".join(",".join(f"{v[i]:.6f}" for v in vals) for i in range(samples)) + "\n")
    return p


@pytest.mark.parametrize("log_joints, config", [(3, "exo_2dof.yaml"), (2, "exo_1dof.yaml"), (1, "exo_2dof.yaml")])
def test_a_log_of_another_joint_count_is_refused_whole(tmp_path, capsys, log_joints, config):
    # a three-joint log was read by the two-joint configuration as its first two joints
    from _paths import repo_root
    log = _log(tmp_path / "log.csv", log_joints)
    cfg = repo_root() / "configs" / config
    code, _, err = run(["replay", log, "--config", cfg, "--estimator", "spring", "--out", tmp_path / "est.csv"],
                       capsys)
    refused(code, err, rf"log.csv:1: has the columns of {log_joints} joint\(s\) \(q.*\); the configuration has "
                       r"\d \(joints: \d, columns t, q")
    assert not (tmp_path / "est.csv").exists()


@pytest.mark.parametrize("argv, pattern", [
    # an infinite window or range drew nan rows: ValueError in the drawing, once a daemon published
    (["--window", "inf"], r"--window inf: allowed > 0 and <= 3600 s"),
    (["--window", "0"], r"--window 0.0: allowed > 0 and <= 3600 s"),
    (["--refresh", "inf"], r"--refresh inf: allowed > 0 and <= 60 s"),
    (["--range", "inf"], r"--range inf: allowed a finite number > 0 N m"),
    (["--height", "100000"], r"--height 100000: allowed 5-200 rows"),
])
def test_watch_refuses_a_view_it_cannot_draw(tmp_path, capsys, argv, pattern):
    code, _, err = run(["watch", "--plain", "--timeout", "0", "--socket", tmp_path / "none.sock", *argv], capsys)
    refused(code, err, pattern)


def test_watch_draws_the_largest_window_and_range_allowed():
    from types import SimpleNamespace
    from sea_daemon.apps.commands.watch import MAX_HEIGHT, MAX_WINDOW_S, View
    view = View(MAX_WINDOW_S, MAX_HEIGHT, 1e300)
    for k in range(3):
        one = np.array([0.1 * k])
        view.add(SimpleNamespace(t=0.1 * k, tau_h_act_hat=one, tau_h_act_bound=one + 0.2, valid=np.array([1]),
                                 tau_assist=0 * one, tau_m=0 * one, q=0 * one))
    lines = view.joint_lines(0, 80)
    assert len(lines) == MAX_HEIGHT + 2 and "nan" not in "".join(lines)


def test_calibrate_takes_the_two_joint_scenario_for_a_two_joint_robot(tmp_path, capsys):
    # without --scenario the one-joint passive.yaml was taken and refused: "--scenario .../passive.yaml:
    # 1 joint(s), the configuration has 2", a file the user never named
    import json
    from _paths import repo_root
    from sea_daemon.apps.commands.calibrate import default_scenario
    from sea_daemon.io.scenario import load_scenario
    configs = repo_root() / "configs"
    code, out, err = run(["calibrate", "--config", configs / "exo_2dof.yaml", "--device-model",
                          configs / "scenarios" / "two_joint_passive.yaml", "--cycles", "30", "--no-progress",
                          "--out", tmp_path / "m.npz", "--log-dir", tmp_path / "L"], capsys)
    assert code == 0, err
    assert json.loads(out)["cycles"] == 30 and (tmp_path / "m.npz").exists()
    assert load_scenario(default_scenario(2)).nominal.joints == 2
    assert load_scenario(default_scenario(1)).nominal.joints == 1
    with pytest.raises(InputError, match=r"--scenario: none given and none embedded for 3 joints"):
        default_scenario(3)
