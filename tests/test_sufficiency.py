"""What a calibration log cannot identify is not identified.

Behaviour checked: :mod:`sea_daemon.analysis.sufficiency` on small seeded logs (moving both
ways, still, one way, short, swapped, constant, at the torque limit, at another rate); ``fit``
on degenerate logs made with ``simulate`` and by editing its CSV — each refused with one line
saying what to record instead, or calibrated with the nominal physics and a report that says so,
never a nan/inf printed or written, never an internal error; ``calibrate-bound`` on a model
without a GP; the expected accuracy filled when the walk is given; session lengths in seconds.
"""
import argparse
import json
import math
import re

import numpy as np
import pytest

from _cli import refused, run
from _paths import repo_root
from sea_daemon.analysis.sufficiency import assess, at_config_rate
from sea_daemon.core.log import MeasuredLog
from sea_daemon.io.configfile import load_config, save_config
from sea_daemon.io.logcsv import read_log, write_log

ROOT = repo_root()
ROBOT = ROOT / "configs" / "exo_1dof_robot.yaml"
NAN = re.compile(r"\b(nan|inf|infinity)\b", re.IGNORECASE)


def _log(t, q, *, swap=False, seed=0, K=110.0, tau=None):
    """A log of one joint whose motor torque holds the spring's deflection (τ_m ≈ K_s (θ_m − q))."""
    rng = np.random.default_rng(seed)
    defl = 0.02 * np.sin(0.5 * t) + 0.01
    th = q + defl
    u = K * defl + rng.normal(0.0, 0.02, len(t)) if tau is None else tau
    q = q + rng.normal(0.0, 1e-5, len(t))
    th = th + rng.normal(0.0, 1e-7, len(t))
    if swap:
        q, th = th, q
    c = lambda a: np.asarray(a, float).reshape(-1, 1)
    return MeasuredLog(t=t, q=c(q), theta_m=c(th), tau_m=c(u), path="cal.csv")


def _moves(t, period=7.0):
    return math.radians(10) + math.radians(32.5) * (1 - np.cos(2 * np.pi * t / period))


@pytest.fixture(scope="module")
def robot():
    return load_config(ROBOT)


def test_a_log_moving_both_ways_identifies_everything(robot):
    t = np.arange(0, 21, 0.01)
    s = assess(_log(t, _moves(t)), robot)
    assert s.refusal is None and s.figures["strokes_up"] == 3 and s.figures["strokes_down"] == 3
    assert all(s.verdicts[k].status == "identify" for k in ("R", "effects", "tau_m_noise", "sign_eps"))
    assert s.figures["snr"]["speed_down"] > 100 and s.figures["spring_slope"]["slope"] == pytest.approx(1, abs=0.05)
    # 10-75 deg of the declared 0-100 deg: the report says the model is extrapolated beyond
    assert s.figures["working_range_share"]["angle"] == pytest.approx(0.65, abs=0.02)
    assert any("65 % of the declared working range" in line and "--excitation" in line for line in s.lines())


def test_a_still_arm_keeps_the_nominal_physics_and_says_so(robot):
    t = np.arange(0, 6, 0.01)
    s = assess(_log(t, np.full(len(t), 0.17)), robot)
    assert s.refusal is None and s.still
    assert s.verdicts["effects"].status == "nominal" and s.verdicts["sign_eps"].status == "nominal"
    assert s.verdicts["R"].status == "identify"
    assert any("configured value kept: effects" in line for line in s.lines())


@pytest.mark.parametrize("case, pattern", [
    ("one_way", r"0 down .*each way.*calibrate --excitation"),
    ("short", r"1\.\d+ s of data.*at least 2 s"),
    ("swapped", r"q and theta_m swapped"),
    ("constant", r"do not change.*check the encoders"),
    ("saturated", r"at the hardware limit \(hardware.torque_limit\) in \d+ %"),
])
def test_degenerate_logs_are_refused_with_what_to_record(robot, case, pattern):
    t = np.arange(0, 21, 0.01)
    if case == "one_way":
        log = _log(t, math.radians(10) + math.radians(60) * t / 21)          # 21 s, always up
    elif case == "short":
        log = _log(t[:150], _moves(t[:150]))
    elif case == "swapped":
        log = _log(t, _moves(t), swap=True)
    elif case == "constant":
        log = MeasuredLog(t=t, q=np.full((len(t), 1), 0.2), theta_m=np.full((len(t), 1), 0.21),
                          tau_m=np.ones((len(t), 1)), path="cal.csv")
    else:
        u = np.clip(np.random.default_rng(1).normal(0, 15, len(t)), -10.0, 10.0)
        log = _log(t, _moves(t), tau=u)
    s = assess(log, robot)
    assert s.refusal is not None and re.search(pattern, s.refusal), s.refusal
    assert "\n" not in s.refusal and not NAN.search(s.refusal)


def test_a_log_at_a_multiple_of_the_rate_is_decimated_another_rate_refused(robot):
    t = np.arange(0, 21, 0.001)
    log, note = at_config_rate(_log(t, _moves(t)), robot)
    assert log.dt == pytest.approx(0.01) and len(log) == 2100 and "every 10th sample" in note
    assert at_config_rate(_log(t[::10], _moves(t[::10])), robot)[1] is None
    from sea_daemon.errors import InputError
    t80 = np.arange(0, 21, 0.0125)
    with pytest.raises(InputError, match=r"recorded at 80 Hz, the configuration runs at 100 Hz"):
        at_config_rate(_log(t80, _moves(t80)), robot)


# ------------------------------------------------------------------ the commands


@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    """The passive scenario's calibration phase (21 s of moves, seed 7) and the active
    scenario's (6 s, the arm held still), simulated."""
    d = tmp_path_factory.mktemp("suff")
    from sea_daemon.apps.cli import main
    for name in ("passive", "active"):
        assert main(["simulate", str(ROOT / "configs" / "scenarios" / f"{name}.yaml"), "--seed", "7",
                     "--out", str(d / f"{name}.csv")]) == 0
    return d


def _edited(sim, name, how):
    """The passive calibration log with one edit (seeded), written as ``name``.csv."""
    log = read_log(sim / "passive.train.csv", n=1)
    t, q, th, u = log.t.copy(), log.q.copy(), log.theta_m.copy(), log.tau_m.copy()
    if how == "constant":
        q[:], th[:] = q[0], th[0]
    elif how == "swapped":
        q, th = th, q
    elif how == "short":
        t, q, th, u = t[:300], q[:300], th[:300], u[:300]
    elif how == "rate":
        t = t * 1.25                                          # 80 Hz
    out = sim / f"{name}.csv"
    write_log(out, MeasuredLog(t=t, q=q, theta_m=th, tau_m=u))
    return out


@pytest.mark.parametrize("how, pattern", [("constant", "do not change"), ("swapped", "swapped"),
                                          ("short", r"3\.0 s long.*each way"), ("rate", "recorded at 80 Hz")])
def test_fit_refuses_a_degenerate_log_with_one_line(sim, tmp_path, capsys, how, pattern):
    code, out, err = run(["fit", _edited(sim, how, how), "--config", ROBOT, "--out", tmp_path / "m"], capsys)
    refused(code, err, pattern)
    assert not NAN.search(out + err) and not (tmp_path / "m.npz").exists()


def test_fit_refuses_a_log_at_the_torque_limit(sim, tmp_path, capsys):
    log = read_log(sim / "passive.train.csv", n=1)
    lim = float(np.quantile(np.abs(log.tau_m), 0.6))           # 40 % of the samples at the limit
    cfg = load_config(ROBOT)
    import dataclasses
    save_config(dataclasses.replace(cfg, hardware=dataclasses.replace(cfg.hardware, torque_limit=lim)),
                tmp_path / "robot.yaml")
    write_log(tmp_path / "sat.csv", MeasuredLog(t=log.t, q=log.q, theta_m=log.theta_m,
                                                tau_m=np.clip(log.tau_m, -lim, lim)))
    code, out, err = run(["fit", tmp_path / "sat.csv", "--config", tmp_path / "robot.yaml", "--out", tmp_path / "m"],
                         capsys)
    refused(code, err, r"at the hardware limit \(hardware.torque_limit\) in \d+ %", "v_max")


def test_fit_on_a_still_arm_keeps_the_nominal_physics_and_prints_no_nan(sim, tmp_path, capsys):
    """The active scenario's calibration phase holds the arm still: no effect is invented, the
    printed and written figures are finite or "not measurable from this log"."""
    code, out, err = run(["fit", sim / "active.train.csv", "--config", ROBOT, "--out", tmp_path / "m"], capsys)
    assert code == 0, err
    assert not NAN.search(out + err), [ln for ln in (out + err).splitlines() if NAN.search(ln)]
    s = json.loads(out)
    assert s["effects"] == [] and "diagnose was not run" in err and "configured value kept: effects" in err
    assert s["expected_accuracy"]["active_moving"]["rmse"] is None
    assert "not measurable from this log" in s["expected_accuracy"]["active_moving"]["why"]
    assert s["expected_accuracy"]["passive"]["rmse"] > 0 and s["expected_accuracy"]["active_still"]["rmse"] > 0
    rep = json.loads((tmp_path / "m.report.json").read_text(), parse_constant=lambda c: pytest.fail(c))
    assert rep["sufficiency"]["verdicts"]["effects"]["status"] == "nominal"
    assert "Expected accuracy" in err and "not measurable from this log" in err


def test_calibrate_bound_on_a_model_without_a_gp_is_one_clear_line(sim, tmp_path, capsys):
    from sea_daemon.core.learning import ResidualGP
    from sea_daemon.io.gpmodel import save_gp_model
    cfg = load_config(ROOT / "configs" / "exo_1dof_sim.yaml")
    save_gp_model(tmp_path / "m.npz", cfg, ResidualGP.from_config(cfg), {"command": "test"})
    code, out, err = run(["calibrate-bound", sim / "passive.train.csv", "--config",
                          ROOT / "configs" / "exo_1dof_sim.yaml", "--model", tmp_path / "m.npz"], capsys)
    refused(code, err, "holds no residual GP")
    assert "concatenate" not in err


def test_the_expected_accuracy_is_filled_when_the_walk_is_given(sim):
    """A configuration that gives Sigma_nom (no walk scan) still gets finite expected figures."""
    from sea_daemon.apps.calibration.modelio import summary
    from sea_daemon.apps.calibration.pipeline import CalibrationOptions, calibrate
    log = read_log(sim / "passive.train.csv", n=1)
    cfg = load_config(ROOT / "configs" / "exo_1dof_sim.yaml")
    res = calibrate(log, cfg, given={"R", "Sigma_nom"}, opts=CalibrationOptions(gp="off", synth_s=10.0))
    s = summary(res)
    assert all(v is not None and math.isfinite(v) for v in s["expected_rmse"].values()), s["expected_rmse"]
    line = next(t for t in s["text"] if t.startswith("Expected accuracy"))
    assert not NAN.search(line)


def test_session_lengths_are_seconds_at_every_rate(tmp_path):
    """The calibration session lasts the scenario's seconds at 1 kHz as at 100 Hz; --duration is
    seconds at the configured rate."""
    from sea_daemon.apps.calibration import session_cycles
    from sea_daemon.apps.commands import daemon_args
    from sea_daemon.core.rates import at_rate
    from sea_daemon.io.scenario import load_scenario
    sc = load_scenario(ROOT / "configs" / "scenarios" / "passive.yaml")
    cfg = load_config(ROBOT)
    assert session_cycles(cfg, sc) == 2100 and session_cycles(at_rate(cfg, 1000.0), sc) == 21000
    p = argparse.ArgumentParser()
    daemon_args.add_common(p, cycles_help="")
    args = p.parse_args(["--config", str(ROBOT), "--log-dir", str(tmp_path), "--sim", "x.yaml", "--rate", "1000",
                         "--duration", "2.5"])
    daemon_args.load(args)
    assert args.cycles == 2500
    from sea_daemon.errors import InputError
    args.duration = 2.5
    with pytest.raises(InputError, match="--cycles and --duration"):
        daemon_args.load(args)
