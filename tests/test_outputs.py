"""Outputs never destroy inputs, every output is written atomically, and an output path that
cannot be written is refused before any long work (issue 15, items 2, 5 and 8)."""
from __future__ import annotations

import os
import shutil

import pytest

from _cli import passive_log, refused, run
from _paths import repo_root

ROOT = repo_root()
CFG = ROOT / "configs" / "exo_1dof.yaml"
PASSIVE = ROOT / "configs" / "scenarios" / "passive.yaml"


@pytest.fixture
def log(tmp_path):
    return passive_log(tmp_path / "p.csv")


@pytest.fixture
def cfg(tmp_path):
    p = tmp_path / "c.yaml"
    shutil.copy(CFG, p)
    return p


@pytest.fixture
def scenario(tmp_path, cfg):
    p = tmp_path / "s.yaml"
    p.write_text(PASSIVE.read_text().replace("model: ../exo_1dof.yaml", f"model: {cfg}"))
    return p


def _unchanged(*paths):
    return {p: p.read_bytes() for p in paths}


@pytest.mark.parametrize("argv", [
    lambda log, cfg, sc, d: ["replay", log, "--config", cfg, "--estimator", "akf", "--out", log],
    lambda log, cfg, sc, d: ["replay", log, "--config", cfg, "--estimator", "akf", "--out", cfg],
    lambda log, cfg, sc, d: ["replay", log, "--config", cfg, "--train", d / "t.csv", "--out", d / "t.csv"],
    lambda log, cfg, sc, d: ["identify-noise", log, "--config", cfg, "--write", log],
    lambda log, cfg, sc, d: ["identify-noise", log, "--config", cfg, "--write", cfg],
    lambda log, cfg, sc, d: ["calibrate-bound", log, "--config", cfg, "--model", d / "m.npz", "--write", log],
    lambda log, cfg, sc, d: ["calibrate-bound", log, "--config", cfg, "--model", d / "m.npz", "--write", cfg],
    lambda log, cfg, sc, d: ["simulate", sc, "--out", sc],
    lambda log, cfg, sc, d: ["simulate", sc, "--out", d / "e.csv", "--train-out", cfg],   # the model it names
    lambda log, cfg, sc, d: ["simulate", sc, "--out", d / "e.csv", "--train-out", d / "e.csv"],
    lambda log, cfg, sc, d: ["calibrate", "--config", cfg, "--sim", sc, "--out", cfg, "--log-dir", d / "L"],
    lambda log, cfg, sc, d: ["calibrate", "--config", cfg, "--sim", sc, "--scenario", sc, "--out", sc,
                             "--log-dir", d / "L"],
])
def test_no_command_writes_over_one_of_its_inputs(tmp_path, log, cfg, scenario, capsys, argv):
    (tmp_path / "t.csv").write_bytes(log.read_bytes())
    (tmp_path / "m.npz").write_bytes(b"not read")
    before = _unchanged(log, cfg, scenario, tmp_path / "t.csv")
    code, _, err = run(argv(log, cfg, scenario, tmp_path), capsys)
    refused(code, err, r"is also (an input|the output)")
    assert _unchanged(log, cfg, scenario, tmp_path / "t.csv") == before
    assert not list(tmp_path.glob(".*.tmp")) and not (tmp_path / "L").exists()


def test_an_input_reached_through_a_link_is_still_an_input(tmp_path, log, cfg, capsys):
    link = tmp_path / "link.csv"
    os.symlink(log, link)
    before = log.read_bytes()
    refused(*run(["replay", log, "--config", cfg, "--estimator", "akf", "--out", link], capsys)[::2],
            r"is also an input")
    os.link(log, tmp_path / "hard.csv")
    refused(*run(["replay", log, "--config", cfg, "--estimator", "akf", "--out", tmp_path / "hard.csv"],
                 capsys)[::2], r"is also an input")
    assert log.read_bytes() == before


def test_diagnose_refuses_an_out_dir_holding_its_config(tmp_path, log, capsys):
    d = tmp_path / "diag"
    d.mkdir()
    aug = d / "model_augmented.yaml"
    shutil.copy(CFG, aug)
    before = aug.read_bytes()
    refused(*run(["diagnose", log, "--config", aug, "--out", d], capsys)[::2], r"is also an input")
    assert aug.read_bytes() == before


@pytest.mark.parametrize("out,expect", [
    (lambda d: d / "missing" / "m.npz", r"directory .*missing does not exist"),
    (lambda d: d, r"is a directory, expected a file path"),
    (lambda d: "/proc/m.npz", r"directory /proc is not writable"),
])
def test_a_bad_out_of_calibrate_is_refused_before_the_calibration(tmp_path, cfg, scenario, capsys, out, expect):
    code, stdout, err = run(["calibrate", "--config", cfg, "--sim", scenario, "--out", out(tmp_path),
                             "--log-dir", tmp_path / "logs", "--no-progress"], capsys)
    refused(code, err, r"--out", expect)
    assert stdout == "" and not (tmp_path / "logs").exists()          # nothing ran, no log
    assert not [p for p in tmp_path.rglob("*") if p.name.endswith(".tmp")]


def test_a_log_dir_that_cannot_be_written_is_refused_before_the_start(tmp_path, cfg, scenario, capsys):
    (tmp_path / "file").write_text("x")
    refused(*run(["run", "--config", cfg, "--model", tmp_path / "m.npz", "--sim", scenario,
                  "--log-dir", tmp_path / "file"], capsys)[::2], r"--log-dir .*file: (is not a directory|cannot)")
    refused(*run(["run", "--config", cfg, "--model", tmp_path / "m.npz", "--sim", scenario,
                  "--log-dir", "/proc/sea"], capsys)[::2], r"--log-dir /proc/sea: cannot create")


def test_a_write_that_fails_leaves_the_target_as_it_was(tmp_path, log, cfg, capsys, monkeypatch):
    # a log path that is not UTF-8 goes into the written configuration's header: escaped, no error
    odd = tmp_path / os.fsdecode(b"\xff.csv")
    shutil.copy(log, odd)
    target = tmp_path / "out.yaml"
    code, _, err = run(["identify-noise", odd, "--config", cfg, "--write", target], capsys)
    assert code == 0, err
    assert "\\xff.csv" in target.read_text()
    before = target.read_bytes()

    def full(fd):                                  # the disk fills while the new file is written
        raise OSError(28, "No space left on device")
    monkeypatch.setattr(os, "fsync", full)
    refused(*run(["identify-noise", log, "--config", cfg, "--write", target], capsys)[::2],
            r"out\.yaml: cannot write: No space left on device")
    assert target.read_bytes() == before
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")]


def test_diagnose_never_writes_a_model_its_loader_refuses(tmp_path, capsys, monkeypatch):
    """K_s off by 10x: what diagnose writes loads; an effect fitted out of its range is refused
    before anything is written."""
    import sea_daemon.apps.diagnose as dg
    from sea_daemon.errors import ConfigError
    from sea_daemon.io.configfile import load_config
    from sea_daemon.io.logcsv import write_log
    from sea_daemon.io.scenario import load_scenario
    from sea_daemon.runtime.sim_runner import simulate
    log = tmp_path / "p.csv"
    write_log(log, simulate(load_scenario(PASSIVE)).estimation)
    cfg = tmp_path / "k.yaml"
    cfg.write_text(CFG.read_text().replace("K_s: 110.0", "K_s: 1100.0"))
    found = {}
    diagnosis = dg.run_diagnosis

    def remembered(*a, **k):
        found["dg"] = diagnosis(*a, **k)
        return found["dg"]
    monkeypatch.setattr(dg, "run_diagnosis", remembered)
    code, _, err = run(["diagnose", log, "--config", cfg, "--out", tmp_path / "d", "--no-plots"], capsys)
    assert code == 0, err
    load_config(tmp_path / "d" / "model_augmented.yaml")            # the loader takes what was written

    def refuse(c, path):
        raise ConfigError(str(path), "effects[0].params.kappa", "must be > 0, got -0.219")
    monkeypatch.setattr(dg, "config_text", refuse)
    # the same diagnosis again (not recomputed): only what is written differs
    monkeypatch.setattr(dg, "run_diagnosis", lambda *a, **k: found["dg"])
    code, _, err = run(["diagnose", log, "--config", cfg, "--out", tmp_path / "e", "--no-plots"], capsys)
    refused(code, err, r"the effects found make a configuration the loader refuses", r"kappa", r"nothing written")
    assert not (tmp_path / "e").exists() or not list((tmp_path / "e").iterdir())


def test_calibrate_bound_torque_refuses_a_log_too_short_for_its_quantile(tmp_path, capsys):
    from sea_daemon.errors import InputError
    from sea_daemon.core.bounds.torque_beta import torque_calibrated_beta

    class Est:                       # the check comes after the first replay; its result is not used
        delta = 0.05

    import sea_daemon.core.bounds.torque_beta as tb
    orig = tb.torque_coverage
    tb.torque_coverage = lambda est, log, b, truth=None: (1.0, 1)         # a 2-row log: one step
    try:
        with pytest.raises(ValueError, match=r"the log has 1 steps, split conformal at delta = 0.05 needs at least 19"):
            torque_calibrated_beta(Est(), None, 0.05)
    finally:
        tb.torque_coverage = orig
    assert issubclass(InputError, Exception)
