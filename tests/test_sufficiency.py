"""What a calibration log cannot identify is not identified.

Behaviour checked: :mod:`sea_daemon.analysis.sufficiency` on small seeded logs (moving both
ways, still, one way, short, swapped, constant, at the torque limit, at another rate); session
lengths in seconds at every rate.  The commands on degenerate logs: test_calibration_degenerate.py.
"""
import argparse
import dataclasses
import math
import re

import numpy as np
import pytest

from _paths import repo_root
from sea_daemon.analysis.sufficiency import assess, at_config_rate
from sea_daemon.core.log import MeasuredLog
from sea_daemon.io.configfile import load_config

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
    # no working range declared: the still-arm protocol (the estimate at the held angle)
    free = dataclasses.replace(robot, calibration=dataclasses.replace(robot.calibration, q_min_deg=None,
                                                                      q_max_deg=None))
    t = np.arange(0, 6, 0.01)
    s = assess(_log(t, np.full(len(t), 0.17)), free)
    assert s.refusal is None and s.still
    assert s.verdicts["effects"].status == "nominal" and s.verdicts["sign_eps"].status == "nominal"
    assert s.verdicts["R"].status == "identify"
    assert any("configured value kept: effects" in line for line in s.lines())


def test_a_still_arm_is_refused_where_the_configuration_declares_a_working_range(robot):
    # a still arm shows nothing of the load side over the declared 0-100 deg: refused, not calibrated
    # on (the nominal physics with the noise of a still log was worse than the nominal robot alone
    # on held-out still-arm sessions of bench generalize --degenerate)
    t = np.arange(0, 6, 0.01)
    s = assess(_log(t, np.full(len(t), 0.17)), robot)
    assert s.still and s.refusal is not None
    assert re.search(r"held still at 10 deg .*working range 0-100 deg .*calibrate --excitation", s.refusal)
    assert not NAN.search(s.refusal)


@pytest.mark.parametrize("case, pattern", [
    ("one_way", r"0 down .*each way.*calibrate --excitation"),
    ("short", r"1\.\d+ s of data.*at least 2 s"),
    ("swapped", r"q and theta_m swapped"),
    ("constant", r"do not change.*check the encoders"),
    ("saturated", r"at the hardware limit \(hardware.torque_limit\) in \d+ %"),
    ("zero_q", r"column q is 0 rad in all 2100 rows while theta_m spans 6[5-7]\.\d deg: the load encoder"),
    ("zero_theta_m", r"column theta_m is 0 rad .* q spans 65\.\d deg: the motor encoder reports nothing"),
    ("zero_tau_m", r"column tau_m is 0 N m in all 2100 rows while the joint moves over 6[5-7]\.\d deg"),
    ("torque_x10", r"the motor torque is 10(\.\d+)? x K_s times the spring's deflection .*allowed 0\.25-4 x"),
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
    elif case == "torque_x10":                      # tau_m in units ten times too small
        t21 = _log(t, _moves(t))
        log = dataclasses.replace(t21, tau_m=10 * t21.tau_m)
    elif case.startswith("zero_"):                  # a sensor column that reports nothing
        log = _log(t, _moves(t))
        log = dataclasses.replace(log, **{case[5:]: np.zeros_like(getattr(log, case[5:]))})
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
