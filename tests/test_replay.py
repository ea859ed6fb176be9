"""``sea-daemon replay``: EST.csv + JSON summary; bad inputs give exit 2 and one line."""
import csv
import json

import time

import numpy as np
import pytest

from sea_daemon.apps import cli
from sea_daemon.io.configfile import default_config_path, load_config
from sea_daemon.core.estimators import AKF
from sea_daemon.io.logcsv import read_log, write_log
from sea_daemon.core.model import SEAModel
from sea_daemon.core.replay import est_columns, replay, summarize

from synth import simulate

CFG = str(default_config_path())


@pytest.fixture(scope="module")
def log_path(tmp_path_factory):
    d = tmp_path_factory.mktemp("replay")
    model = SEAModel.from_config(load_config(CFG))
    log = simulate(model, T=1.5, tau_h=lambda t: np.array([1.0 + 0.5 * np.sin(2 * np.pi * 0.5 * t)]), seed=4)
    p = d / "log.csv"
    write_log(p, log)
    return p


def run_cli(argv, capsys):
    code = cli.main(argv)
    out, err = capsys.readouterr()
    return code, out, err


@pytest.mark.parametrize("estimator", ["akf", "spring"])
def test_replay_writes_est_and_summary(log_path, tmp_path, capsys, estimator):
    out_csv = tmp_path / "est.csv"
    code, out, err = run_cli(["replay", str(log_path), "--config", CFG, "--estimator", estimator,
                              "--out", str(out_csv)], capsys)
    assert code == 0, err
    summary = json.loads(out)
    assert summary["estimator"] == estimator and summary["samples"] == 151
    assert summary["rmse"] is not None and summary["rmse"] > 0
    assert 0 <= summary["coverage"] <= 1 and summary["step_time_us"]["runs"] == 150
    with open(out_csv) as fh:
        header = next(csv.reader(fh))
    for c in ("t", "tau_h_act_hat", "tau_h_act_bound", "tau_h_act_sigma", "tau_h_act", "dtheta_s_hat"):
        assert c in header
    est = np.genfromtxt(out_csv, delimiter=",", names=True)
    log = read_log(log_path)
    err_ = est["tau_h_act_hat"] - log.tau_h_act[:, 0]
    assert summary["rmse"] == pytest.approx(np.sqrt(np.mean(err_**2)), rel=1e-6)
    if estimator == "akf":     # correctly specified plant: the AKF tracks
        assert summary["rmse"] < 0.3


def test_replay_pure_loop_matches_manual_loop(log_path):
    log = read_log(log_path)
    cfg = load_config(CFG)
    res = replay(log, AKF(cfg, dt=log.dt))
    a = AKF(cfg, dt=log.dt)
    a.reset(log.q[0], log.theta_m[0], log.tau_m[0])
    for k in range(1, len(log)):
        e = a.update(log.q[k], log.theta_m[k], log.tau_m[k], log.t[k] - log.t[k - 1])
    np.testing.assert_array_equal(res.tau_h_act_hat[-1], e.tau_h_act_hat)
    s = summarize(res)
    assert "step_time_us" not in s and s["samples"] == len(log)
    assert set(est_columns(res)) >= {"t", "tau_h_act_hat", "tau_h_act_bound", "tau_h_act_sigma"}


def _write(path, text):
    path.write_text(text)
    return str(path)


GOOD_HEAD = "t,q,theta_m,tau_m\n"
BAD_LOGS = {
    "missing column": ("t,q,tau_m\n0,0,0\n0.01,0,0\n", "missing required column(s) theta_m"),
    "non-numeric": (GOOD_HEAD + "0,0,0,0\n0.01,abc,0,0\n", ":3: column q: 'abc' is not a number"),
    "nan": (GOOD_HEAD + "0,0,0,0\n0.01,0,nan,0\n", ":3: column theta_m: nan is not finite"),
    "inf": (GOOD_HEAD + "0,0,0,inf\n0.01,0,0,0\n", ":2: column tau_m: inf is not finite"),
    "time not increasing": (GOOD_HEAD + "0,0,0,0\n0.01,0,0,0\n0.01,0,0,0\n", ":4: time does not increase"),
    "too few rows": (GOOD_HEAD + "0,0,0,0\n", "needs at least 2"),
    "empty": ("", "empty file"),
}


@pytest.mark.parametrize("case", sorted(BAD_LOGS))
def test_bad_csv_exit_2_one_line(tmp_path, capsys, case):
    text, expect = BAD_LOGS[case]
    p = _write(tmp_path / "bad.csv", text)
    code, out, err = run_cli(["replay", p, "--config", CFG, "--estimator", "akf",
                              "--out", str(tmp_path / "e.csv")], capsys)
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and p in lines[0] and expect in lines[0], err
    assert out == "" and not (tmp_path / "e.csv").exists()


def test_bad_train_csv_and_config_exit_2(log_path, tmp_path, capsys):
    bad = _write(tmp_path / "train.csv", "t,q\n0,0\n")
    code, _, err = run_cli(["replay", str(log_path), "--config", CFG, "--train", bad, "--estimator", "akf",
                            "--out", str(tmp_path / "e.csv")], capsys)
    assert code == 2 and bad in err and len(err.strip().splitlines()) == 1
    cfg = _write(tmp_path / "m.yaml", "joints: 1\nrate_hz: 100\nmodel: {M: 0.1}\n")
    code, _, err = run_cli(["replay", str(log_path), "--config", cfg, "--estimator", "akf",
                            "--out", str(tmp_path / "e.csv")], capsys)
    assert code == 2 and "model.J" in err and len(err.strip().splitlines()) == 1


def test_gp_akf_without_train_and_bad_choice(log_path, tmp_path, capsys):
    code, _, err = run_cli(["replay", str(log_path), "--config", CFG, "--estimator", "gp-akf",
                            "--out", str(tmp_path / "e.csv")], capsys)
    assert code == 2 and "--train" in err and len(err.strip().splitlines()) == 1
    with pytest.raises(SystemExit) as ei:
        cli.main(["replay", str(log_path), "--config", CFG, "--estimator", "magic", "--out", "x.csv"])
    assert ei.value.code == 2


def test_bad_csv_through_subprocess(tmp_path):
    """The installed entry point path: one line on stderr, no traceback, exit 2."""
    import os
    import subprocess
    import sys
    from pathlib import Path
    p = _write(tmp_path / "bad.csv", GOOD_HEAD + "0,0,0,0\n0.01,x,0,0\n")
    root = Path(__file__).resolve().parent.parent
    env = {**os.environ, "PYTHONPATH": str(root)}
    r = subprocess.run([sys.executable, "-m", "sea_daemon", "replay", p, "--config", CFG, "--estimator", "akf",
                        "--out", str(tmp_path / "e.csv")], capture_output=True, text=True, env=env, timeout=60)
    assert r.returncode == 2
    assert r.stderr.count("\n") == 1 and "Traceback" not in r.stderr and f"{p}:3" in r.stderr


def test_bench_latency_runs(capsys):
    code = cli.main(["bench", "latency", "--seconds", "1", "--repeat", "1", "--estimators", "akf,spring"])
    out, _ = capsys.readouterr()
    assert code == 0
    assert "machine:" in out and "akf: per step median" in out and "(50 runs)" in out
    assert cli.main(["bench", "latency", "--estimators", "magic"]) == 2
    # steps after the loop's idle time: each step timed after a sleep, said in the header
    c0 = time.process_time()
    code = cli.main(["bench", "latency", "--seconds", "1", "--repeat", "1", "--estimators", "akf", "--idle-ms", "2"])
    asleep = time.process_time() - c0
    out, _ = capsys.readouterr()
    assert code == 0 and "2 ms asleep before each step" in out and "akf: per step median" in out
    assert cli.main(["bench", "latency", "--estimators", "akf", "--idle-ms", "-1"]) == 2
    # or busy-waiting that long: ~100 steps, each 2 ms more on the CPU than asleep
    c0 = time.process_time()
    code = cli.main(["bench", "latency", "--seconds", "1", "--repeat", "1", "--estimators", "akf", "--idle-ms", "2",
                     "--idle-spin"])
    spun = time.process_time() - c0
    out, _ = capsys.readouterr()
    assert code == 0 and "2 ms busy-waiting before each step" in out
    assert spun - asleep > 0.6 * 0.002 * 100


def test_replay_two_joints_suffixed_columns(tmp_path, capsys):
    import yaml
    from sea_daemon.core.config import ModelConfig
    d = {"joints": 2, "rate_hz": 100, "model": {
        "M": [[0.2, 0.03], [0.03, 0.1]], "J": [0.08, 0.05], "D_m": [0.6, 0.4], "K_s": [110.0, 80.0],
        "D_s": [0.25, 0.2], "gravity": [2.0, 0.5]}}
    cfg = ModelConfig.from_dict(d)
    cp = tmp_path / "two.yaml"
    cp.write_text(yaml.safe_dump(d))
    log = simulate(SEAModel.from_config(cfg), T=1.0, tau_h=lambda t: np.array([0.5, -0.3 * t]), seed=5)
    lp = tmp_path / "two.csv"
    write_log(lp, log)
    code, out, err = run_cli(["replay", str(lp), "--config", str(cp), "--estimator", "akf",
                              "--out", str(tmp_path / "e.csv")], capsys)
    assert code == 0, err
    s = json.loads(out)
    assert s["joints"] == 2 and len(s["rmse_per_joint"]) == 2 and s["rmse"] < 0.3
    header = (tmp_path / "e.csv").read_text().splitlines()[0].split(",")
    for c in ("tau_h_act_hat_1", "tau_h_act_hat_2", "tau_h_act_bound_2", "tau_h_act_sigma_1", "tau_h_act_2",
              "dtheta_s_hat_2"):
        assert c in header
    # a one-joint log against the two-joint config names the missing columns
    code, _, err = run_cli(["replay", str(log_path_one(tmp_path)), "--config", str(cp), "--estimator", "akf",
                            "--out", str(tmp_path / "e2.csv")], capsys)
    assert code == 2 and "q_1" in err


def log_path_one(tmp_path):
    return _write(tmp_path / "one.csv", GOOD_HEAD + "0,0,0,0\n0.01,0,0,0\n")


def test_train_is_validated_and_noted_for_akf(log_path, tmp_path, capsys):
    code, out, err = run_cli(["replay", str(log_path), "--config", CFG, "--train", str(log_path),
                              "--estimator", "spring", "--out", str(tmp_path / "e.csv")], capsys)
    assert code == 0 and "--train is used only by gp-akf" in err
    assert json.loads(out)["estimator"] == "spring"


def test_summary_scores_a_lagging_bound_against_its_own_sample():
    """A bound worker's ρ belongs to an earlier sample (bound_of): coverage_own_sample pairs each ρ
    with that sample's error, not with the estimate published beside it."""
    from sea_daemon.core.replay import ReplayResult, bound_rows
    N = 6
    truth = np.zeros((N, 1))
    # errors 0, 1, 0, 1, 0, 1; each row publishes the bound of the row before it, 0.5 where the
    # error of that earlier sample is 0 and 1.5 where it is 1
    hat = np.array([[0.0], [1.0], [0.0], [1.0], [0.0], [1.0]])
    cycle = np.arange(10, 10 + N)
    bound_cycle = np.array([-1, 10, 11, 12, 13, 14])
    bound = np.array([[0.0], [0.5], [1.5], [0.5], [1.5], [0.5]])
    of = bound_rows(cycle, bound_cycle)
    np.testing.assert_array_equal(of, [-1, 0, 1, 2, 3, 4])
    res = ReplayResult(t=np.arange(N) * 0.01, tau_h_act_hat=hat, tau_h_act_sigma=np.zeros((N, 1)),
                       tau_h_act_bound=bound, x_hat=np.zeros((N, 5)), tau_h_act=truth, step_time_s=None,
                       estimator="gp-akf", valid=bound_cycle >= 0, bound_of=of)
    s = summarize(res)
    assert s["coverage_own_sample"] == 1.0 and s["bound_age_max"] == 1
    assert s["coverage_valid"] == 0.4            # against the estimates published with them: 2 of 5
    # a bound_cycle with no row in the log (before its first row) points nowhere
    np.testing.assert_array_equal(bound_rows(cycle, np.array([9, 10, -1, 15, 16, 3])), [-1, 0, -1, 5, -1, -1])
