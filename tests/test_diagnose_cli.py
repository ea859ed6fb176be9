"""``sea-daemon diagnose`` end to end (docs/interfaces.md §3, §4): files, JSON keys, the augmented model
loadable by the other commands, and bad input → exit 2 with one line."""
from __future__ import annotations

import json

import numpy as np
import pytest

from sea_daemon.apps.cli import main
from sea_daemon.io.configfile import load_config, save_config
from sea_daemon.core.effects import make_effect
from sea_daemon.core.log import MeasuredLog
from sea_daemon.io.logcsv import read_log, write_log

from diagnose_sim import passive_log

CONTRACT_KEYS = {"samples", "residual_rms_before", "residual_rms_after", "effects_added",
                 "unexplained_fraction", "estimate_rmse_before", "estimate_rmse_after"}


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("diag")
    log, cfg = passive_log([make_effect("torque_scale", "motor", kappa=0.85)], moves=2)
    write_log(d / "log.csv", log)
    save_config(cfg, d / "model.yaml")
    return d


def test_diagnose_command_writes_everything(files, capsys):
    out = files / "out"
    rc = main(["diagnose", str(files / "log.csv"), "--config", str(files / "model.yaml"), "--out", str(out)])
    assert rc == 0
    printed = capsys.readouterr().out
    assert "torque_scale" in printed and "AKF estimation RMSE" in printed
    res = json.loads((out / "diagnosis.json").read_text())
    assert CONTRACT_KEYS <= set(res)
    assert res["samples"] == len(read_log(files / "log.csv"))
    eff = res["effects_added"][0]
    assert {"type", "side", "params", "explained_fraction"} <= set(eff)
    assert eff["type"] == "torque_scale" and abs(eff["params"]["kappa"] - 0.85) < 0.02
    total = sum(e["explained_fraction"] for e in res["effects_added"]) + res["unexplained_fraction"]
    assert total == pytest.approx(1.0, abs=1e-6)
    # the augmented model: the input config plus the effect, loadable by every command
    aug = load_config(out / "model_augmented.yaml")
    base = load_config(files / "model.yaml")
    assert len(aug.model.effects) == len(base.model.effects) + 1
    assert aug.model.effects[-1].type == "torque_scale"
    assert aug.estimator.to_dict() == base.estimator.to_dict()
    report = (out / "report.md").read_text()
    assert "Candidates tried" in report and "torque_scale/motor **(chosen)**" in report
    assert (out / "residuals.png").stat().st_size > 1000
    assert list(out.glob("effect_1_torque_scale_motor.png"))
    rc = main(["replay", str(files / "log.csv"), "--config", str(out / "model_augmented.yaml"),
               "--estimator", "akf", "--out", str(files / "est.csv")])
    assert rc == 0


def _bad(capsys, argv):
    rc = main(argv)
    err = capsys.readouterr().err.strip()
    return rc, err


def test_bad_input_exits_2_with_one_line(files, tmp_path, capsys):
    cfg = str(files / "model.yaml")
    log = read_log(files / "log.csv")
    # missing config file
    rc, err = _bad(capsys, ["diagnose", str(files / "log.csv"), "--config", str(tmp_path / "nope.yaml"),
                            "--out", str(tmp_path / "o")])
    assert rc == 2 and len(err.splitlines()) == 1 and "nope.yaml" in err
    # a log without theta_m
    p = tmp_path / "nocol.csv"
    p.write_text("t,q,tau_m\n0,0,0\n0.01,0,0\n")
    rc, err = _bad(capsys, ["diagnose", str(p), "--config", cfg, "--out", str(tmp_path / "o")])
    assert rc == 2 and len(err.splitlines()) == 1 and "theta_m" in err
    # too short for the smoothing
    short = tmp_path / "short.csv"
    write_log(short, log.slice(0, 30))
    rc, err = _bad(capsys, ["diagnose", str(short), "--config", cfg, "--out", str(tmp_path / "o")])
    assert rc == 2 and len(err.splitlines()) == 1 and "at least" in err
    # a gap in the sampling
    gap = log.slice(0, 400)
    gap.t = gap.t.copy()
    gap.t[200:] += 0.5
    p = tmp_path / "gap.csv"
    write_log(p, gap)
    rc, err = _bad(capsys, ["diagnose", str(p), "--config", cfg, "--out", str(tmp_path / "o")])
    assert rc == 2 and len(err.splitlines()) == 1 and "uniform" in err
    # two-joint log against a one-joint model
    two = MeasuredLog(t=log.t, q=np.repeat(log.q, 2, 1), theta_m=np.repeat(log.theta_m, 2, 1),
                      tau_m=np.repeat(log.tau_m, 2, 1))
    p = tmp_path / "two.csv"
    write_log(p, two)
    rc, err = _bad(capsys, ["diagnose", str(p), "--config", cfg, "--out", str(tmp_path / "o")])
    assert rc == 2 and len(err.splitlines()) == 1
    # bad option value
    rc, err = _bad(capsys, ["diagnose", str(files / "log.csv"), "--config", cfg, "--out", str(tmp_path / "o"),
                            "--min-fraction", "-1"])
    assert rc == 2 and len(err.splitlines()) == 1 and "min-fraction" in err
