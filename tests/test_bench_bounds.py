"""``python -m benchmarks.bounds`` end to end on shortened scenarios (the figures are in docs/benchmarks.md)."""
import json

import pytest
import yaml

from benchmarks import bounds as bench_bounds
from benchmarks._cli import main as bench_main
from _paths import repo_root


def _short(tmp_path, name, train, est):
    src = repo_root() / "configs" / "scenarios" / f"{name}.yaml"
    d = yaml.safe_load(src.read_text())
    d["model"] = str(repo_root() / "configs" / "exo_1dof.yaml")
    d["phases"] = {"training": {"samples": train}, "estimation": {"samples": est}}
    out = tmp_path / f"{name}.yaml"
    out.write_text(yaml.safe_dump(d))
    return out


def test_bench_bounds_runs_both_betas_and_an_unseen_pair(tmp_path, capsys):
    passive = _short(tmp_path, "passive", 700, 150)
    unseen = _short(tmp_path, "unseen_load", 2, 150)
    code = bench_main(bench_bounds, ["--als", "--estimators", "akf,gp-akf,gp-akf/conformal",
                     "--scenarios", str(passive), f"{unseen}@{passive}", "--out", str(tmp_path / "b")])
    out = capsys.readouterr().out
    assert code == 0
    assert "scenario unseen_load, trained on passive" in out
    res = json.loads((tmp_path / "b" / "results.json").read_text())
    assert set(res) == {"passive", "unseen_load"}
    for sc in res.values():
        g, c = sc["gp-akf"], sc["gp-akf/conformal"]
        assert g["gp_beta_method"] == "lederer" and c["gp_beta_method"] == "conformal"
        assert c["conformal_calibration_pairs"] > 600
        # same estimate, different bound: the GP-AKF's error is the same in both columns (to
        # rounding: the calibration run leaves the LoG-GP's cached solves computed in another order)
        assert g["mean_abs_error"] == pytest.approx(c["mean_abs_error"], rel=1e-4)
        assert g["mean_rho"] >= g["mean_kf_bound"] and c["mean_rho"] >= c["mean_kf_bound"]
        assert g["bound_time_median_us"] > 0
    assert (tmp_path / "b" / "passive.png").stat().st_size > 10000


def test_a_latched_fault_ends_the_run_and_is_reported():
    """An estimator fault (e.g. NIS divergence on an unseen load) latches as in the daemon: the
    samples after it are not estimates; _run_one cuts them off and returns the step and cause."""
    import numpy as np
    from benchmarks.bounds import _run_one
    from sea_daemon.core.estimators.health import NISDivergence
    from sea_daemon.core.log import MeasuredLog

    class Est:
        delta = 0.05

        def __init__(self):
            from sea_daemon.core.estimators.base import Estimate
            self.e = Estimate.zeros(1)
            self.k = 0

        def reset(self, *a):
            return self.e

        def update(self, *a):
            self.k += 1
            if self.k == 7:
                raise NISDivergence("NIS divergence at step 7")
            self.e.tau_h_act_hat[:] = 0.1 * self.k
            return self.e

    N = 20
    t = np.arange(N) * 0.01
    log = MeasuredLog(t=t, q=np.zeros((N, 1)), theta_m=np.zeros((N, 1)), tau_m=np.zeros((N, 1)),
                      tau_h_act=np.zeros((N, 1)), path="<test>")
    hat, rho, kf, times, btimes, fault = _run_one(Est(), log)
    assert fault[0] == 7 and "NISDivergence" in fault[1]
    assert len(hat) == len(rho) == 7 and len(times) == 6 and btimes is None
    assert hat[6, 0] == pytest.approx(0.6)


def test_bench_bounds_torque_and_exact_columns(tmp_path, capsys):
    # torque: beta calibrated on the held-out session's torque error, which it then covers;
    # exact: η from the simulator's truth, which must cover the estimation log (Theorem 1
    # with the GP error known) and is at most the torque/conformal bounds' job to approach
    passive = _short(tmp_path, "passive", 700, 300)
    code = bench_main(bench_bounds, ["--estimators", "gp-akf/torque,gp-akf/exact",
                     "--gp-beta", "torque,exact", "--scenarios", str(passive), "--out", str(tmp_path / "b")])
    out = capsys.readouterr().out
    assert code == 0 and "calibration log covered" in out
    r = json.loads((tmp_path / "b" / "results.json").read_text())["passive"]
    t, x = r["gp-akf/torque"], r["gp-akf/exact"]
    cal = t["torque_calibration"]
    assert cal["coverage"] >= cal["target"] >= 0.95 and t["gp_beta"] == cal["beta"]
    assert x["gp_beta_method"] == "exact" and x["coverage_rho"] >= 0.95
    assert t["mean_abs_error"] == pytest.approx(x["mean_abs_error"], rel=1e-4)
    assert bench_main(bench_bounds, ["--gp-beta", "exactly"]) == 2
    assert "exact" in capsys.readouterr().err
