"""``sea-daemon bench capstone`` on the real SEA bench (tests/data/capstone_sea), and what ``fit``
says of a block of it.

Behaviour checked: the per-block GP-AKF check runs on the bench's reference head in two 5 s
blocks and reports, per block, fit's one-line refusal (what the block lacks, what to record
instead), the calibration made anyway with the configured physics (no effect invented on a block
moving one way), and finite figures on the other block (RMSE, AKF with the input model, the
bound's coverage, valid share, bound / RMSE); bad options and a log without truth exit 2 with one
line; a log's length counts its last sample's period (2000 rows at 200 Hz are 10 s, not refused
as shorter than 10 s).
"""
import json
import math
import re

import numpy as np
import pytest

from _paths import repo_root
from sea_daemon.analysis.sufficiency import assess
from sea_daemon.apps.cli import main
from sea_daemon.core.log import MeasuredLog
from sea_daemon.io.configfile import load_config
from sea_daemon.io.logcsv import read_log

DATA = repo_root() / "tests" / "data" / "capstone_sea"
CONFIG = repo_root() / "configs" / "capstone_sea.yaml"
NAN = re.compile(r"\b(nan|inf|infinity)\b", re.IGNORECASE)


@pytest.mark.parametrize("argv, pattern", [
    (["--folds", "9"], r"--folds 9: allowed 2-5 for this 10 s log"),
    (["--folds", "1"], r"--folds 1: allowed 2-5"),
    (["--log", str(DATA / "disturbance.csv")], r"no tau_h_act column"),
    (["--checks", "gp"], r"--checks"),
    (["--calibrate-on", "8-12"], r"--calibrate-on 8-12: allowed A-B seconds within the log's 0-10 s"),
    (["--calibrate-on", "2-3"], r"at least 2 s long"),
])
def test_bad_options_exit_2_with_one_line(argv, pattern, capsys):
    rc = main(["bench", "capstone", *argv])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and re.search(pattern, err), err
    assert "\n" not in err and "Traceback" not in err


def test_a_ten_second_log_at_200_hz_is_ten_seconds_long():
    """2000 rows at 200 Hz moving twice each way: not refused as shorter than 10 s."""
    t = np.arange(2000) * 0.005
    q = math.radians(30) * (1 - np.cos(2 * np.pi * t / 4.5))
    c = lambda a: np.asarray(a, float).reshape(-1, 1)
    rng = np.random.default_rng(0)
    defl = 0.05 * np.sin(0.7 * t) + 0.02
    log = MeasuredLog(t=t, q=c(q), theta_m=c(q + defl), tau_m=c(0.4624 * defl + rng.normal(0, 1e-3, len(t))),
                      path="cal.csv")
    s = assess(log, load_config(CONFIG))
    assert s.figures["duration_s"] == pytest.approx(10.0)
    assert s.refusal is None, s.refusal


def test_fit_on_the_bench_head_names_the_motion_to_record():
    """The head moves once each way: refused with what it has, what it needs and what to record;
    never a length that reads as the limit it misses."""
    cfg = load_config(CONFIG)
    s = assess(read_log(DATA / "reference_head.csv", n=1), cfg)
    assert s.refusal and "1 move(s) up and 1 down" in s.refusal, s.refusal
    assert "record at least 10 s moving at least 2 times each way over at least 5 deg" in s.refusal
    assert "s long" not in s.refusal and not NAN.search(s.refusal)


def test_gp_akf_calibrated_per_block_of_the_bench(tmp_path, capsys):
    out = tmp_path / "capstone.json"
    rc = main(["bench", "capstone", "--folds", "2", "--checks", "gp-akf", "--json", str(out)])
    printed = capsys.readouterr().out
    assert rc == 0
    text = out.read_text()
    assert "NaN" not in text and "Infinity" not in text
    res = json.loads(text)
    folds = res["gp_akf_per_block"]
    assert [f["block"] for f in folds] == [1, 2]
    for f, moves in zip(folds, ("1 move(s) up and 0 down", "0 move(s) up and 1 down")):
        # a 5 s block moving one way: refused, naming what it lacks and what to record
        assert moves in f["fit"] and "5.0 s long (at least 10 s)" in f["fit"], f["fit"]
        assert "record at least 10 s" in f["fit"]
        # calibrated anyway: the configured physics kept, nothing invented
        assert f["calibration"]["physics"].startswith("configured") and f["calibration"]["effects"] == []
        (row,) = f["scored"]
        assert row["block"] == 3 - f["block"]
        g = row["gp_akf"]
        for v in (g["rmse"], g["coverage"], g["valid_share"], g["bound_over_rmse"], row["akf_input"],
                  row["gp_over_akf"]):
            assert math.isfinite(v) and v >= 0
        assert row["gp_over_akf"] == pytest.approx(g["rmse"] / row["akf_input"])
        # the guaranteed GP bound: a union over the calibration's own leaves, and a statement at
        # every step (the nested boxes hold each GP input set: none outside them all)
        assert 1 <= g["gp_union_leaves"] < 100 and g["gp_sqrt_beta"] > 1 and g["gp_box_left"] == 0.0
        assert set(row["met"]) == {"gp_over_akf", "coverage", "bound_over_rmse", "valid_share"}
    assert set(res["gp_akf_met"]) == set(res["targets"])
    assert "| 0.00-5.00 | 5.00-9.99 |" in printed and "fit refuses it" in printed


def test_the_bench_declares_its_subject_from_the_push_it_measured():
    """configs/capstone_sea.yaml declares the person of disturbance.csv (not the exoskeleton's
    1.5 N m default, above the drive's torque limit): a declared torque rate at least the spring
    torque's rate measured there (99th percentile over 0.25 s) and a size below the torque limit."""
    from sea_daemon.apps.calibration.pipeline import options_from_config
    cfg = load_config(CONFIG)
    human = options_from_config(cfg).human
    assert human.rms < cfg.hardware.torque_limit
    log = read_log(DATA / "disturbance.csv", n=1)
    tau_s = cfg.model.K_s[0, 0] * (log.theta_m[:, 0] - log.q[:, 0])
    w = int(round(0.25 / log.dt))
    rate = np.abs(tau_s[w:] - tau_s[:-w]) / (w * log.dt)
    assert human.rate >= np.percentile(rate, 99), (human.rate, np.percentile(rate, 99))
    assert human.rate <= 3 * np.percentile(rate, 99)


def test_the_bound_terms_of_one_calibration(tmp_path, capsys):
    """--terms: the mean of each term of ρ_k over the valid samples, which add up to ρ (the set of
    means' terms, the measurement's cut and the Gaussian part), the GP's the largest on this bench."""
    out = tmp_path / "terms.json"
    rc = main(["bench", "capstone", "--checks", "gp-akf", "--calibrate-on", "0-5", "--terms", "--json", str(out)])
    printed = capsys.readouterr().out
    assert rc == 0
    (fold,) = json.loads(out.read_text())["gp_akf_per_block"]
    (row,) = fold["scored"]
    g = row["gp_akf"]
    t = g["terms"]
    assert t["rho"] == pytest.approx(g["mean_bound"], rel=1e-9)
    assert t["rho"] == pytest.approx(t["h"] + t["gaussian"])
    assert t["h"] == pytest.approx(t["gp"] + t["rate"] + t["friction"] + t["linearisation"] + t["cut"], abs=1e-9)
    assert t["gp"] == max(t[k] for k in ("gp", "rate", "friction", "linearisation", "gaussian"))
    assert "| gp | rate | friction | linearisation | gaussian |" in printed
