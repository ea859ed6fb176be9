"""``sea-daemon bench bounds`` end to end on shortened scenarios (the figures are in docs/bounds.md)."""
import json

import pytest
import yaml

from sea_daemon import cli
from sea_daemon.config import repo_root

pytest.importorskip("sea_daemon.estimators.gpakf")


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
    code = cli.main(["bench", "bounds", "--als", "--estimators", "akf,gp-akf,gp-akf/conformal",
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
