"""Hostile input: every malformed, oversized or ambiguous file or setting is refused with exit
status 2 and one line naming the file, the place and what was expected — never an internal error,
never silently accepted.  (docs/safety.md, "Bad input")"""
from __future__ import annotations

import io
import json
import os
import zipfile

import numpy as np
import pytest

from _cli import passive_log, refused, run
from sea_daemon.io import modelfile
from _paths import repo_root

CFG = str(repo_root() / "configs" / "exo_1dof.yaml")
ROBOT = "joints: 1\nrate_hz: 100\nmodel: {M: 0.12, J: 0.08, D_m: 0.6, K_s: 110.0, D_s: 0.25}\n"


@pytest.fixture
def log(tmp_path):
    """A valid passive log of 300 samples."""
    return passive_log(tmp_path / "log.csv")


def replay(log, cfg, tmp_path, capsys):
    return run(["replay", log, "--config", cfg, "--estimator", "akf", "--out", tmp_path / "e.csv"], capsys)


# ------------------------------------------------------------------ YAML
@pytest.mark.parametrize("text,expect", [
    (ROBOT + "estimator: {R: [1, [2, 3], 4, 5]}\n", r"estimator\.R: must be a list of 4 variances"),
    (ROBOT + "estimator: {R: abc}\n", r"estimator\.R"),
    (ROBOT + "estimator: {R: [0, 0, 0, 0]}\n", r"estimator\.R: must be positive"),
    (ROBOT + "estimator: {R: [1.0e+300, 1, 1, 1]}\n", r"estimator\.R: must be finite, within"),
    (ROBOT + "estimator: {Sigma_nom: [1.0e+300, 1, 1, 1, 1]}\n", r"Sigma_nom: must be finite, within"),
    (ROBOT.replace("K_s: 110.0", "K_s: 1.0e+300"), r"model\.K_s: must be finite, within"),
    (ROBOT.replace("K_s: 110.0", "K_s: " + "9" * 5000), r"value out of range"),
    (ROBOT.replace("K_s: 110.0", "K_s: " + "9" * 4000), r"model\.K_s"),
    (ROBOT.replace("K_s: 110.0", "K_s: 1_10"), r"model\.K_s: must be"),
    (ROBOT.replace("K_s: 110.0", "K_s: 1:50"), r"model\.K_s: must be"),
    (ROBOT + "rate_hz: 200\n", r"line 4: duplicate key 'rate_hz'"),
    (ROBOT + "x: " + "[" * 100 + "]" * 100 + "\n", r"nested deeper than 32 levels"),
])
def test_bad_yaml_is_refused_with_its_place(tmp_path, log, capsys, text, expect):
    cfg = tmp_path / "m.yaml"
    cfg.write_text(text)
    refused(*replay(log, cfg, tmp_path, capsys)[::2], expect)


def test_yaml_alias_bomb_is_refused_before_it_expands(tmp_path, log, capsys):
    levels = ["a: &a [1, 1, 1, 1, 1, 1, 1, 1, 1, 1]"]
    for i in range(1, 7):                    # 10^7 values once expanded, 60 aliases
        prev, name = chr(96 + i), chr(97 + i)
        levels.append(f"{name}: &{name} [" + ", ".join([f"*{prev}"] * 10) + "]")
    cfg = tmp_path / "bomb.yaml"
    cfg.write_text(ROBOT + "bomb:\n" + "\n".join("  " + ln for ln in levels) + "\nestimator:\n  R: [*g, 1, 1, 1]\n")
    code, _, err = replay(log, cfg, tmp_path, capsys)
    refused(code, err, r"expands to more than 100000 values|more than 64 aliases")
    assert len(err) < 400


def test_yaml_that_is_not_utf8_names_line_and_byte(tmp_path, log, capsys):
    cfg = tmp_path / "m.yaml"
    cfg.write_bytes(ROBOT.encode() + b"# caf\xe9\n")
    refused(*replay(log, cfg, tmp_path, capsys)[::2], r"m\.yaml:4: byte 0xE9 at column 6 is not UTF-8")


def test_oversized_yaml_is_refused(tmp_path, log, capsys):
    cfg = tmp_path / "m.yaml"
    cfg.write_text(ROBOT + "#" + "x" * (1 << 20) + "\n")
    refused(*replay(log, cfg, tmp_path, capsys)[::2], r"larger than 1048576 bytes")


# ------------------------------------------------------------------ CSV
@pytest.mark.parametrize("row,expect", [
    ("0.01,0.0,0.0,1_0", r":3: column tau_m: '1_0' is not a number"),
    ("0.01,0.0,0.0,0x10", r":3: column tau_m: '0x10' is not a number"),
    ("0.01,0.0,0.0,\u0661", r":3: column tau_m: .* is not a number"),
    ("0.01,0.0,0.0,1e30", r":3: column tau_m: 1e\+30 N m, allowed \|tau_m\| <= 1e\+06"),
    ("0.01,0.0,0.0," + "1" * 300, r":3: column tau_m: .* is not a number"),
    ("0.01,0.0,0.0," + "1" * 70000, r":3: line longer than 65536 bytes"),
])
def test_bad_csv_value_is_refused_with_its_line(tmp_path, capsys, row, expect):
    p = tmp_path / "bad.csv"
    p.write_text("t,q,theta_m,tau_m\n0.0,0.0,0.0,1.0\n" + row + "\n0.02,0.0,0.0,1.0\n")
    refused(*replay(p, CFG, tmp_path, capsys)[::2], expect)


def test_csv_with_a_latin1_byte_names_line_and_column(tmp_path, capsys):
    p = tmp_path / "bad.csv"
    p.write_bytes(b"t,q,theta_m,tau_m\n0.0,0.0,0.0,1.0\n0.01,0.0,0.0,\xb51.0\n")
    refused(*replay(p, CFG, tmp_path, capsys)[::2], r"bad\.csv:3: byte 0xB5 at column 14 is not UTF-8")


def test_csv_with_a_byte_order_mark_and_crlf_is_read(tmp_path, capsys, log):
    p = tmp_path / "bom.csv"
    p.write_bytes(b"\xef\xbb\xbf" + log.read_bytes().replace(b"\n", b"\r\n"))
    code, out, err = replay(p, CFG, tmp_path, capsys)
    assert code == 0, err
    assert json.loads(out)["samples"] == 300


def test_a_path_that_is_not_utf8_is_named_printably(tmp_path, capsys):
    bad = os.fsdecode(bytes(tmp_path) + b"/\xff\xfe.csv")
    for argv in (["diagnose", bad, "--config", CFG, "--out", tmp_path / "d"],
                 ["identify-noise", bad, "--config", CFG]):
        code, _, err = run(argv, capsys)
        refused(code, err, r"\\xff\\xfe\.csv")


# ------------------------------------------------------------------ model files
def test_a_model_file_that_would_unpack_beyond_the_limit_is_refused_unread(tmp_path, monkeypatch):
    p = tmp_path / "bomb.npz"
    with zipfile.ZipFile(p, "w", zipfile.ZIP_DEFLATED) as zf:
        buf = io.BytesIO()
        np.save(buf, np.zeros(4 << 20))              # 32 MB of zeros, ~32 kB compressed
        zf.writestr("x.npy", buf.getvalue())
        zf.writestr("__meta__.npy", b"")
    assert p.stat().st_size < 1 << 20
    monkeypatch.setattr(modelfile, "MAX_UNPACKED_BYTES", 1 << 20)
    with pytest.raises(modelfile.ModelFileError, match=r"unpacks to \d+ bytes, allowed <= 1048576"):
        modelfile.load_model(p)


def test_a_model_file_is_written_atomically_and_a_failed_write_leaves_the_old_one(tmp_path, monkeypatch):
    p = tmp_path / "m.npz"
    modelfile.save_model(p, {"a": np.arange(3.0)}, {"x": 1})
    before = p.read_bytes()

    def broken_fsync(fd):
        raise OSError(28, "No space left on device")
    monkeypatch.setattr(os, "fsync", broken_fsync)
    from sea_daemon.errors import InputError
    with pytest.raises(InputError, match="No space left on device"):
        modelfile.save_model(p, {"a": np.arange(5.0)}, {"x": 2})
    assert p.read_bytes() == before
    assert [f.name for f in tmp_path.iterdir()] == ["m.npz"]        # no stray temporary file


# ------------------------------------------------------------------ long logs (issue 15, item 6)
def test_a_long_log_is_read_into_float_blocks(tmp_path):
    """read_log keeps 8 bytes a value: 200 000 rows x 4 columns peak far below a list of floats."""
    import tracemalloc
    from sea_daemon.io.logcsv import read_log
    p = tmp_path / "long.csv"
    N = 200_000
    t = np.arange(N) * 0.01
    np.savetxt(p, np.column_stack([t, 0.3 * np.sin(t), 0.3 * np.sin(t), np.cos(t)]), delimiter=",",
               header="t,q,theta_m,tau_m", comments="", fmt="%.6g")
    tracemalloc.start()
    log = read_log(p)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert len(log) == N
    assert peak < 4 * (N * 4 * 8)          # data 6.4 MB; the rows as Python lists took ~6x that


# ------------------------------------------------------------------ the rest of issue 15, item 7
@pytest.mark.parametrize("text,expect", [
    (ROBOT + "estimator: {P0: [1.0e+300, 1, 1, 1, 1]}\n", r"estimator\.P0: must be finite, within"),
    (ROBOT + "estimator: {P0_tau: 1.0e+300}\n", r"estimator\.P0_tau: must be a finite number"),
    (ROBOT + "x: " + "[" * 1000 + "]" * 1000 + "\n", r"nested deeper than 32 levels"),
    (ROBOT + "estimator: {tau_h_act_max: -1}\n", r"estimator\.tau_h_act_max: must be > 0"),
])
def test_more_bad_yaml_is_refused(tmp_path, log, capsys, text, expect):
    cfg = tmp_path / "m.yaml"
    cfg.write_text(text)
    refused(*replay(log, cfg, tmp_path, capsys)[::2], expect)


def test_zero_process_noise_is_an_estimator_fault_not_an_internal_error(tmp_path, capsys):
    from sea_daemon.io.logcsv import write_log
    from sea_daemon.io.scenario import load_scenario
    from sea_daemon.runtime.sim_runner import simulate
    p = tmp_path / "p.csv"
    write_log(p, simulate(load_scenario(repo_root() / "configs" / "scenarios" / "passive.yaml")).estimation)
    cfg = tmp_path / "m.yaml"
    cfg.write_text(ROBOT + "estimator: {Sigma_nom: [0, 0, 0, 0, 0]}\n")
    code, _, err = replay(p, cfg, tmp_path, capsys)
    refused(code, err, r"p\.csv: sample \d+ .*NIS divergence")


def test_a_gap_in_a_log_is_refused_at_its_sample(tmp_path, log, capsys):
    rows = log.read_text().splitlines()
    head, body = rows[0], rows[1:]
    shifted = [",".join([f"{float(r.split(',')[0]) + (1000 if i >= 150 else 0):.4f}"] + r.split(",")[1:])
               for i, r in enumerate(body)]
    p = tmp_path / "gap.csv"
    p.write_text("\n".join([head] + shifted) + "\n")
    refused(*replay(p, CFG, tmp_path, capsys)[::2], r"gap\.csv: sample 150 .*step of 1000.01 s, allowed 0 < dt <= 10")
    code, _, err = run(["replay", log, "--config", CFG, "--train", p, "--out", tmp_path / "e.csv"], capsys)
    # the calibration on the training log refuses it at its line, naming the gap
    refused(code, err, r"gap\.csv:152: a gap of 1000\.01 s after t = 1\.49 s", r"split the log there")


def test_a_training_log_at_another_rate_is_refused(tmp_path, log, capsys):
    rows = log.read_text().splitlines()
    half = tmp_path / "t50.csv"
    half.write_text("\n".join([rows[0]] + rows[1::2]) + "\n")          # 50 Hz
    code, _, err = run(["replay", log, "--config", CFG, "--train", half, "--out", tmp_path / "e.csv"], capsys)
    refused(code, err, r"--train .*t50\.csv: sample period 0\.02 s, the log's is 0\.01 s; allowed within 1 %")


def test_a_200_kb_field_is_refused_by_the_line_limit(tmp_path, capsys):
    p = tmp_path / "big.csv"
    p.write_text("t,q,theta_m,tau_m\n0.0,0.0,0.0,1.0\n0.01,0.0,0.0," + "1" * 200_000 + "\n")
    refused(*replay(p, CFG, tmp_path, capsys)[::2], r"big\.csv:3: line longer than 65536 bytes")


def test_a_closed_stderr_still_gives_exit_2(tmp_path):
    import subprocess
    import sys
    r = subprocess.run([sys.executable, "-m", "sea_daemon", "replay", str(tmp_path / "none.csv"), "--config", CFG,
                        "--out", str(tmp_path / "e.csv")], stderr=subprocess.DEVNULL, close_fds=True,
                       env=dict(os.environ, PYTHONPATH=str(repo_root())), cwd=tmp_path,
                       preexec_fn=lambda: os.close(2))
    assert r.returncode == 2
