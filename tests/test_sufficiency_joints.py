"""Sufficiency per joint for two joints: what one joint's log refuses is refused, naming the joint.

Degenerate two-joint calibration logs of development plant 3 of the two-joint family
(:func:`sea_daemon.apps.bench._family_joints.degenerate_calibration_joints`, 12 s, 100 Hz): a
frozen elbow, a frozen shoulder (each held by its drive at mid-range while the other joint runs
the calibration excitation: the held joint is shaken a few degrees by the other's motion, with
no move of 5 deg either way), the elbow moving one way only, a 3 s log.  ``fit`` and
``replay --train`` (the calibration paths share :func:`~sea_daemon.apps.calibration.pipeline.sufficient_log`)
refuse each in one line naming the joint and what to record; a joint truly held still (its
angle spanning less than 1 deg, the still-arm log of one joint) keeps the nominal model and the
report says so on that joint.
"""
import json
import re

import numpy as np
import pytest

from _cli import refused, run
from _paths import repo_root
from sea_daemon.analysis.sufficiency import Sufficiency
from sea_daemon.apps.bench._family_joints import DEGENERATE_JOINTS, degenerate_calibration_joints, draw_plant_joints
from sea_daemon.apps.calibration.joints import assess_joints
from sea_daemon.io.configfile import config_text
from sea_daemon.io.logcsv import write_log

ROOT = repo_root()
NAN = re.compile(r"\b(nan|inf|infinity)\b", re.IGNORECASE)
#: the joint each case must name, and what its line says is missing
EXPECT = {"frozen_elbow": ("joint 2 \\(elbow\\)", "0 move\\(s\\) up and 0 down"),
          "frozen_shoulder": ("joint 1 \\(shoulder\\)", "0 move\\(s\\) up and 0 down"),
          "one_direction_elbow": ("joint 2 \\(elbow\\)", "up and 0 down"),
          "short": ("joint 1 \\(shoulder\\)", "3.0 s long")}


@pytest.fixture(scope="module")
def plant():
    return draw_plant_joints(3)


@pytest.fixture(scope="module")
def logs(plant, tmp_path_factory):
    """The degenerate logs (12 s; short 3 s) as CSV files and the user's configuration beside them."""
    d = tmp_path_factory.mktemp("suff2j")
    cfg_path = d / "robot.yaml"
    text = config_text(plant.nominal, cfg_path)
    cfg_path.write_text(re.sub(r"(?m)^(\s*urdf:).*$", rf"\1 {ROOT / 'configs' / 'exo_2dof_arm.urdf'}", text))
    out = {}
    for case in DEGENERATE_JOINTS:
        log, _ = degenerate_calibration_joints(plant, case, 12.0)
        write_log(d / f"{case}.csv", log)
        out[case] = log
    return d, cfg_path, out


@pytest.mark.parametrize("case", DEGENERATE_JOINTS)
def test_fit_refuses_naming_the_joint(logs, case, tmp_path, capsys):
    d, cfg, _ = logs
    code, out, err = run(["fit", d / f"{case}.csv", "--config", cfg, "--out", tmp_path / "m"], capsys)
    joint, missing = EXPECT[case]
    refused(code, err, "^sea-daemon fit: error: " + joint, missing, "record at least 10 s", "calibrate --excitation")
    assert not NAN.search(out + err) and not (tmp_path / "m.yaml").exists()


def test_replay_train_refuses_a_frozen_elbow(logs, tmp_path, capsys):
    d, cfg, _ = logs
    code, out, err = run(["replay", d / "short.csv", "--config", cfg, "--train", d / "frozen_elbow.csv",
                          "--out", tmp_path / "e.csv"], capsys)
    refused(code, err, "joint 2 \\(elbow\\)", "0 move\\(s\\) up and 0 down", "calibrate --excitation")


def test_a_joint_held_still_keeps_the_nominal_model_and_the_report_names_it(logs, plant):
    """The frozen-elbow log with the elbow's angles replaced by a still elbow's (the encoders'
    noise about one angle, seeded, the spring deflected by the drive's torque): the shoulder identifies its physics, the elbow keeps the
    nominal model, and the printed sentences say so on the elbow; each joint's motion is named."""
    _, _, out = logs
    log = out["frozen_elbow"]
    rng = np.random.default_rng(5)
    q, th = log.q.copy(), log.theta_m.copy()
    q[:, 1] = 1.1 + 2e-5 * rng.standard_normal(len(log))
    K_s = float(np.diag(np.atleast_2d(plant.nominal.model.K_s))[1])
    th[:, 1] = q[:, 1] + log.tau_m[:, 1] / K_s + 2e-5 * rng.standard_normal(len(log))   # the spring holds
    still = type(log)(t=log.t, q=q, theta_m=th, tau_m=log.tau_m, path="still_elbow.csv")
    s = assess_joints(still, plant.nominal)
    assert s.refusal is None
    assert s.joints[0].identifies("effects") and s.joints[1].verdicts["effects"].status == "nominal"
    lines = Sufficiency.lines_of(s.to_dict())
    assert lines[0].startswith("This log: 12.0 s at 100 Hz, joint 1 (shoulder) moves ")
    assert lines[0].endswith("; joint 2 (elbow) held still.")
    assert any(x.startswith("Not identified from this log, the configured value kept on joint 2 (elbow): effects")
               for x in lines)
    assert not any("joint 1" in x for x in lines[1:])


def test_one_joint_report_reads_as_before():
    """A one-joint log's sentences do not name a joint."""
    d = {"figures": {"duration_s": 6.0, "rate_hz": 100.0, "still": True}, "notes": [],
         "verdicts": {"effects": {"status": "nominal", "why": "held"}}}
    assert Sufficiency.lines_of(d) == ["This log: 6.0 s at 100 Hz, the arm held still.",
                                       "Not identified from this log, the configured value kept: effects (held)."]


def test_bench_generalize_joints_2_degenerate_reports_each_refusal(tmp_path, capsys):
    """``bench generalize --joints 2 --degenerate`` (development plant 3, 12 s logs, two cases):
    each case calibrated by ``fit`` in its own process, refused naming the joint, the table and
    the counts the rule names."""
    code, out, err = run(["bench", "generalize", "--joints", "2", "--degenerate", "--seeds", "3", "--rates", "100",
                          "--cal-s", "12", "--cases", "frozen_elbow,short", "--out", tmp_path, "--no-cache"], capsys)
    assert code == 0, err
    assert "| frozen_elbow | refused 3 |" in out and "| short | refused 3 |" in out
    assert "2 of 2 as the rule asks (2 refused, 0 held, 0 failed); invented effects 0, nan/inf printed or written 0, " \
           "internal errors 0" in out
    rows = json.loads((tmp_path / "results.json").read_text())["degenerate"]
    assert rows[0]["cases"]["frozen_elbow"]["line"].startswith("sea-daemon fit: error: joint 2 (elbow): ")


def test_the_still_arm_synthetic_session_stays_where_the_arm_was_held():
    """The τ_h,act walk's still-arm synthetic session of two joints (the declared subject's torque
    on each joint, 1.5 N m RMS up to 1 Hz, from the two-joint demo's still-arm calibration, 6 s held
    at 40 and 60 deg): the arm stays within 2 deg of where it was held (the elbow wandered over
    10 deg, away from the one angle a still-arm calibration knows, and the promise was the model's
    error there)."""
    from sea_daemon.apps.calibration.pipeline import HumanSpec, synthetic_sessions
    from sea_daemon.io.configfile import load_config
    cfg = load_config(ROOT / "configs" / "exo_2dof.yaml")
    held = np.radians([40.0, 60.0])
    log = run_session_still(cfg, held)
    moving, still = synthetic_sessions(cfg, log, HumanSpec((0.1, 1.0), 1.5), 0.01, 6.0, seed=3)
    span = np.degrees(np.ptp(still.q, axis=0))
    assert np.all(span < 2.0), span


def run_session_still(cfg, held):
    """6 s of the nominal two-joint robot held still at ``held`` by its drives (no subject)."""
    from sea_daemon.core.sim.session import run_session
    from sea_daemon.apps.calibration.joints import plant_substep
    return run_session(cfg, 6.0, hold_q=held, seed=4, substep_hz=plant_substep(cfg, 3e-3, cfg.rate_hz))
