"""Bad input everywhere: every CLI command and config path with malformed files.

Each case: exit status 2, exactly one line on stderr naming the file / key / value, no
traceback, nothing written.  Devices answering wrongly on the bus are reported by node and
object (start-up checks in tests/test_drivers_startup.py; here: an EDS with a wrong device
type and a TPDO of the wrong length at run time).
"""
from __future__ import annotations

import dataclasses
import re
import shutil
import subprocess
import sys
import uuid
from pathlib import Path

import numpy as np
import pytest
import yaml

from _cli import run
from sea_daemon.apps.cli import main
from sea_daemon.io.configfile import default_config_path, load_config
from _paths import repo_root
from sea_daemon.errors import InputError, LogFormatError
from sea_daemon.io.logcsv import read_log

CFG = str(default_config_path())
SCEN = str(repo_root() / "configs" / "scenarios" / "passive.yaml")


cli = run                               # (exit status, stdout, stderr) of sea-daemon ARGV


def assert_one_line(code, err, *expect):
    lines = err.strip().splitlines()
    assert code == 2, err
    assert len(lines) == 1, err
    assert "Traceback" not in err
    for e in expect:
        assert re.search(e, lines[0]), (e, lines[0])


# ------------------------------------------------------------------ measured logs
def good_rows(N=40, deg=False):
    t = np.arange(N) * 0.01
    q = 0.3 + 0.2 * np.sin(2 * np.pi * t)
    th = q - 0.01
    if deg:
        q, th = np.degrees(q), np.degrees(th)
    return [f"{a:.6g},{b:.9g},{c:.9g},{d:.6g}" for a, b, c, d in zip(t, q, th, 0.5 * np.cos(t))]


HEAD = "t,q,theta_m,tau_m\n"
BAD_CSV = {
    "truncated": (HEAD + "\n".join(good_rows()) + "\n0.4,0.3", r":42: has 2 fields, the header has 4 \(truncated"),
    "wrong columns": ("t,q,theta,tau\n" + "\n".join(r for r in good_rows()) + "\n",
                      r":1: missing required column\(s\) theta_m, tau_m"),
    "nan": (HEAD + "\n".join(good_rows()[:5]) + "\n0.05,nan,0.29,0\n", r":7: column q: nan is not finite"),
    "time going back": (HEAD + "\n".join(good_rows()[:5]) + "\n0.03,0.3,0.29,0\n", r":7: time does not increase"),
    "degrees": (HEAD + "\n".join(good_rows(deg=True)) + "\n", r"column q: .*degrees instead of radians\?"),
    "header only": (HEAD, r"has 0 data rows"),
    "binary": ("\x00\x01\x02garbage\n\x00", r"missing required column"),
}


@pytest.mark.parametrize("case", sorted(BAD_CSV))
@pytest.mark.parametrize("role", ["log", "train"])
def test_replay_bad_csv(tmp_path, capsys, case, role):
    text, expect = BAD_CSV[case]
    bad = tmp_path / "bad.csv"
    bad.write_text(text)
    good = tmp_path / "good.csv"
    good.write_text(HEAD + "\n".join(good_rows()) + "\n")
    log, train = (bad, good) if role == "log" else (good, bad)
    out = tmp_path / "est.csv"
    code, stdout, err = cli(["replay", str(log), "--config", CFG, "--train", str(train), "--estimator", "gp-akf",
                             "--out", str(out)], capsys)
    assert_one_line(code, err, re.escape(str(bad)), expect)
    assert not out.exists()


def test_radian_logs_of_a_real_joint_are_never_taken_for_degrees(tmp_path):
    # a full range of motion just under one turn, near ±π, and a still joint at 6 rad
    t = np.arange(200) * 0.01
    for q in (-3.1 + 6.2 * t / t[-1], 3.1 * np.sin(2 * np.pi * t), np.full(t.size, 6.0) + 1e-4 * np.sin(t)):
        p = tmp_path / "ok.csv"
        p.write_text(HEAD + "".join(f"{a},{b},{b - 0.01},0\n" for a, b in zip(t, q)))
        assert read_log(p).q.shape == (200, 1)
    # a small motion logged in degrees but beyond 2π in value is caught, in theta_m too
    p.write_text(HEAD + "".join(f"{a},0.1,{10 + a},0\n" for a in t))
    with pytest.raises(LogFormatError, match=r":2: column theta_m: 10 rad \(\|theta_m\| > 2π\): degrees"):
        read_log(p)


# ------------------------------------------------------------------ model configuration (YAML)
def bad_config(tmp_path, mutate) -> Path:
    raw = yaml.safe_load(Path(CFG).read_text())
    mutate(raw)
    p = tmp_path / "model.yaml"
    p.write_text(yaml.safe_dump(raw))
    return p


BAD_CONFIGS = {
    "unknown top key": (lambda r: r.update(rate=100), r"rate"),
    "unknown model key": (lambda r: r["model"].update(K_spring=1.0), r"K_spring"),
    "unknown estimator key": (lambda r: r["estimator"].update(nis_windw=10), r"nis_windw"),
    "negative inertia": (lambda r: r["model"].update(M=-0.12), r"model\.M.*-0\.12"),
    "zero stiffness": (lambda r: r["model"].update(K_s=0.0), r"model\.K_s"),
    "missing key": (lambda r: r["model"].pop("J"), r"J"),
    "unknown effect": (lambda r: r["model"].update(effects=[{"type": "magic", "x": 1}]), r"magic"),
    "bad nis level": (lambda r: r["estimator"].update(nis_alpha=2.0), r"estimator\.nis_alpha: must be in \(0, 1\)"),
    "bad bus": (lambda r: r.setdefault("hardware", {}).update(bus={"interface": "pcan"}),
                r"interface.*virtual, socketcan, remote"),
    "nan in R": (lambda r: r["estimator"].update(R=[float("nan"), 1, 1, 1]), r"estimator\.R"),
}


@pytest.mark.parametrize("case", sorted(BAD_CONFIGS))
def test_replay_bad_config(tmp_path, capsys, case):
    mutate, expect = BAD_CONFIGS[case]
    cfg = bad_config(tmp_path, mutate)
    log = tmp_path / "log.csv"
    log.write_text(HEAD + "\n".join(good_rows()) + "\n")
    code, _, err = cli(["replay", str(log), "--config", str(cfg), "--estimator", "akf",
                        "--out", str(tmp_path / "e.csv")], capsys)
    assert_one_line(code, err, re.escape(str(cfg)), expect)


@pytest.mark.parametrize("text,expect", [
    ("joints: 1\nrate_hz: [100\n", r"YAML|yaml|parse|line"),           # truncated / malformed YAML
    ("- 1\n- 2\n", r"mapping|dict|top"),                                  # not a mapping
    ("", r"empty|mapping|missing"),                                      # empty file
])
def test_replay_malformed_yaml(tmp_path, capsys, text, expect):
    cfg = tmp_path / "model.yaml"
    cfg.write_text(text)
    log = tmp_path / "log.csv"
    log.write_text(HEAD + "\n".join(good_rows()) + "\n")
    code, _, err = cli(["replay", str(log), "--config", str(cfg), "--estimator", "akf",
                        "--out", str(tmp_path / "e.csv")], capsys)
    assert_one_line(code, err, re.escape(str(cfg)), expect)


def test_missing_files_are_named(tmp_path, capsys):
    log = tmp_path / "log.csv"
    log.write_text(HEAD + "\n".join(good_rows()) + "\n")
    code, _, err = cli(["replay", str(tmp_path / "nope.csv"), "--config", CFG, "--estimator", "akf",
                        "--out", str(tmp_path / "e.csv")], capsys)
    assert_one_line(code, err, "nope.csv")
    code, _, err = cli(["replay", str(log), "--config", str(tmp_path / "nope.yaml"), "--estimator", "akf",
                        "--out", str(tmp_path / "e.csv")], capsys)
    assert_one_line(code, err, "nope.yaml")
    code, _, err = cli(["replay", str(log), "--config", str(tmp_path), "--estimator", "akf",
                        "--out", str(tmp_path / "e.csv")], capsys)     # a directory
    assert_one_line(code, err, re.escape(str(tmp_path)))


# ------------------------------------------------------------------ simulate (scenario YAML)
def test_simulate_bad_scenario_and_its_model(tmp_path, capsys):
    raw = yaml.safe_load(Path(SCEN).read_text())
    raw["model"] = str(bad_config(tmp_path, lambda r: r["model"].update(M=-1.0)))
    sc = tmp_path / "sc.yaml"
    sc.write_text(yaml.safe_dump(raw))
    code, _, err = cli(["simulate", str(sc), "--out", str(tmp_path / "o.csv")], capsys)
    assert_one_line(code, err, r"model\.M")
    raw = yaml.safe_load(Path(SCEN).read_text())
    raw["model"] = str(Path(SCEN).parent / raw["model"])
    raw["unknwn"] = 1
    sc.write_text(yaml.safe_dump(raw))
    code, _, err = cli(["simulate", str(sc), "--out", str(tmp_path / "o.csv")], capsys)
    assert_one_line(code, err, r"unknwn")
    assert not (tmp_path / "o.csv").exists()


# ------------------------------------------------------------------ device-model and bench
@pytest.mark.parametrize("argv,expect", [
    (["device-model", "--fault", "melt:target=drive"], r"fault kind 'melt'"),
    (["device-model", "--fault", "drop:target=gearbox"], r"target 'gearbox'"),
    (["device-model", "--fault", "drop:count=-3"], r"count must be a number >= 0"),
    (["device-model", "--bus", "remote", "--channel", "127.0.0.1:5"], r"ws://"),
    (["bench", "faults", "--kinds", "tpdo_missing,meteor"], r"--kinds meteor"),
    (["bench", "faults", "--cycles", "10"], r"--cycles 10"),
    (["bench", "soak", "--cycles", "1000", "--warmup", "5000"], r"--warmup 5000"),
    (["replay", "x.csv", "--config", CFG, "--estimator", "kalman", "--out", "e.csv"], r"invalid choice: 'kalman'"),
])
def test_other_commands_bad_arguments(capsys, argv, expect):
    code, _, err = cli(argv, capsys)
    assert_one_line(code, err, expect)


@pytest.mark.parametrize("name,argv,expect", [
    ("bounds", ["--gp-beta", "lederer,huge"], r"--gp-beta huge"),
    ("bounds", ["--gp-beta", "-1"], r"--gp-beta -1"),
    ("accuracy", ["--bound", "tight"], r"invalid choice: 'tight'"),
    ("rt_budget", ["--duty", "3"], r"--duty must be in 0\.\.1, got 3\.0"),
    ("rt_budget", ["--seconds", "0"], r"--seconds must be in \(0, 60\], got 0\.0"),
    ("bound_stages", ["--rate", "5"], r"--rate must be in 10\.\.10000 Hz, got 5\.0"),
])
def test_research_benchmarks_bad_arguments(capsys, name, argv, expect):
    import importlib

    from benchmarks._cli import main
    try:
        code = main(importlib.import_module(f"benchmarks.{name}"), argv)
    except SystemExit as e:
        code = e.code
    assert_one_line(code, capsys.readouterr().err, expect)


def test_device_model_bad_config(tmp_path, capsys):
    cfg = bad_config(tmp_path, lambda r: r["model"].update(D_m=-0.6, extra_key=1))
    code, _, err = cli(["device-model", "--config", str(cfg), "--duration", "0"], capsys)
    assert_one_line(code, err, re.escape(str(cfg)))


def test_bad_input_through_a_real_process_has_no_traceback(tmp_path):
    bad = tmp_path / "deg.csv"
    bad.write_text(BAD_CSV["degrees"][0])
    r = subprocess.run([sys.executable, "-m", "sea_daemon", "replay", str(bad), "--config", CFG,
                        "--estimator", "akf", "--out", str(tmp_path / "e.csv")],
                       capture_output=True, text=True, cwd=repo_root(), timeout=120)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr
    assert "degrees instead of radians" in r.stderr


# ------------------------------------------------------------------ saved model files
def test_model_files_corrupt_foreign_or_pickled_are_refused(tmp_path):
    from sea_daemon.io.modelfile import load_model, save_model
    p = tmp_path / "m.npz"
    save_model(p, {"a": np.arange(5.0)}, {"what": "test"})
    data = p.read_bytes()
    (tmp_path / "trunc.npz").write_bytes(data[: len(data) // 2])
    np.save(tmp_path / "obj.npy", np.array([{"x": 1}], dtype=object), allow_pickle=True)
    np.savez(tmp_path / "pickled.npz", a=np.array([{"x": 1}], dtype=object))
    for name, expect in (("trunc.npz", "corrupt"), ("obj.npy", "corrupt|not a sea-daemon model"),
                         ("pickled.npz", "corrupt|not a sea-daemon model"), ("none.npz", "no such model file")):
        with pytest.raises(InputError, match=expect):
            load_model(tmp_path / name)


# ------------------------------------------------------------------ devices on the bus
@pytest.fixture
def eds_rig(tmp_path, monkeypatch):
    """Device model whose drive is built from a copied EDS with 0x1000 changed (a CiA 406 device)."""
    from sea_daemon.hw.bus import make_bus
    from sea_daemon.hw.canopen_hw import CanopenHardware
    from sea_daemon.hw.canopen_setup import DRIVE_EDS
    from sea_daemon.hw.device_model import DeviceModel
    from sea_daemon.hw.device_model.drive import DriveNode
    from sea_daemon.core.sim.plant import Plant

    eds = tmp_path / "wrong_drive.eds"
    shutil.copy(DRIVE_EDS, eds)
    text = eds.read_text()
    sec = re.search(r"\[1000\][^\[]*", text).group(0)
    new = re.sub(r"(?im)^DefaultValue\s*=.*$", "DefaultValue=0x00010196", sec)
    eds.write_text(text.replace(sec, new))
    monkeypatch.setattr(DriveNode, "EDS", str(eds))          # absolute: EDS_DIR / abs == abs
    cfg = load_config(default_config_path())
    b = dataclasses.replace(cfg.hardware.bus, channel=f"bad-{uuid.uuid4().hex[:8]}", sdo_timeout_ms=1000,
                            heartbeat_ms=20, heartbeat_timeout_ms=1000, pdo_timeout_ms=500.0)
    cfg = dataclasses.replace(cfg, hardware=dataclasses.replace(cfg.hardware, bus=b))
    dev_bus, drv_bus = make_bus(b), make_bus(b)
    model = DeviceModel(dev_bus, Plant(cfg, q0=0.3, seed=0, torque_noise=0.0)).start()
    hw = CanopenHardware(cfg, drv_bus)
    yield model, hw
    try:
        hw.stop()
    finally:
        model.stop()
        dev_bus.shutdown()
        drv_bus.shutdown()


def test_eds_with_a_wrong_device_type_is_named(eds_rig):
    from sea_daemon.hw.errors import DeviceMismatch
    model, hw = eds_rig
    assert model.drives[0].sdo[0x1000].raw == 0x00010196
    with pytest.raises(DeviceMismatch, match=r"^node 1: 0x1000 device type: is 0x00010196 \(profile 406\), "
                                             r"expected profile 402"):
        hw.start()


def test_tpdo_of_the_wrong_length_is_named_at_run_time():
    from sea_daemon.hw.device_model import FaultSpec  # noqa: F401
    from sea_daemon.hw.errors import PdoLengthError
    from sea_daemon.apps.bench._rig import bench_config, bench_rig
    from sea_daemon.errors import Fault
    rig = bench_rig(bench_config(pdo_timeout_ms=500.0, sdo_timeout_ms=1000, heartbeat_timeout_ms=1000))
    try:
        rig.hw.read()
        rig.hw.write(np.zeros(1))
        gate = rig.device_model.network.gate

        def short(can_id, data):                 # the encoder sends 2 of its 4 bytes
            if can_id == 0x182:
                rig.device_model.network.send_now(can_id, data[:2])
                return False
            return gate(can_id, data)
        rig.device_model.network.gate = short
        with pytest.raises(PdoLengthError, match=r"node 2: TPDO 0x182 has 2 bytes, expected 4") as e:
            rig.hw.read()
        assert e.value.fault is Fault.TPDO_MISSING
    finally:
        rig.stop()


# ------------------------------------------------------------------ diagnose
@pytest.mark.parametrize("case", ["truncated", "wrong columns", "nan", "time going back", "degrees"])
def test_diagnose_bad_csv(tmp_path, capsys, case):
    text, expect = BAD_CSV[case]
    bad = tmp_path / "bad.csv"
    bad.write_text(text)
    code, _, err = cli(["diagnose", str(bad), "--config", CFG, "--out", str(tmp_path / "d"), "--no-plots"], capsys)
    assert_one_line(code, err, re.escape(str(bad)), expect)
    assert not (tmp_path / "d" / "diagnosis.json").exists()


@pytest.mark.parametrize("case", ["unknown top key", "negative inertia", "bad nis level"])
def test_diagnose_bad_config(tmp_path, capsys, case):
    mutate, expect = BAD_CONFIGS[case]
    cfg = bad_config(tmp_path, mutate)
    log = tmp_path / "log.csv"
    log.write_text(HEAD + "\n".join(good_rows(400)) + "\n")
    code, _, err = cli(["diagnose", str(log), "--config", str(cfg), "--out", str(tmp_path / "d"), "--no-plots"],
                       capsys)
    assert_one_line(code, err, re.escape(str(cfg)), expect)


# ------------------------------------------------------------------ calibrate / run / reset
@pytest.fixture(scope="module")
def model_file(tmp_path_factory):
    """A model file to corrupt (what it holds does not matter here), calibrated with the bus
    timeouts of tests/_hil.py: a heartbeat the loaded host delivers late must not fail it."""
    from _hil import hil_config
    from sea_daemon.io.configfile import save_config
    d = tmp_path_factory.mktemp("cal")
    save_config(hil_config(), d / "c.yaml")
    r = subprocess.run([sys.executable, "-m", "sea_daemon", "calibrate", "--config", str(d / "c.yaml"),
                        "--log-dir", str(d / "L"), "--out", str(d / "m.npz"), "--device-model", SCEN,
                        "--cycles", "120", "--no-progress"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr[-2000:]
    return d / "m.npz"


def _corrupt_models(tmp_path, good: Path) -> dict:
    data = good.read_bytes()
    (tmp_path / "trunc.npz").write_bytes(data[: len(data) // 2])
    flipped = bytearray(data)
    flipped[len(flipped) // 2] ^= 0xFF
    (tmp_path / "flipped.npz").write_bytes(bytes(flipped))
    np.savez(tmp_path / "pickled.npz", a=np.array([{"x": 1}], dtype=object))
    from sea_daemon.io.modelfile import load_model, save_model
    arrays, meta = load_model(good)
    save_model(tmp_path / "future.npz", arrays, {k: v for k, v in meta.items() if k not in ("format", "version", "sha256")})
    z = dict(np.load(tmp_path / "future.npz"))
    import json as _json
    m = _json.loads(bytes(z["__meta__"]).decode())
    m["version"] = 99
    z["__meta__"] = np.frombuffer(_json.dumps(m).encode(), dtype=np.uint8)
    np.savez(tmp_path / "future.npz", **z)
    return {"trunc.npz": r"corrupt|checksum", "flipped.npz": r"corrupt|checksum", "pickled.npz": r"not a sea-daemon model",
            "future.npz": r"version 99 is incompatible", "missing.npz": r"no such model file"}


def test_run_refuses_bad_model_files(tmp_path, capsys, model_file):
    for name, expect in _corrupt_models(tmp_path, model_file).items():
        code, _, err = cli(["run", "--model", str(tmp_path / name), "--config", CFG, "--log-dir", str(tmp_path / "L"),
                            "--device-model", SCEN, "--cycles", "5"], capsys)
        assert_one_line(code, err, re.escape(name), expect)


@pytest.mark.parametrize("cmd", ["run", "calibrate"])
@pytest.mark.parametrize("case", ["unknown top key", "negative inertia", "unknown estimator key"])
def test_daemon_commands_bad_config(tmp_path, capsys, model_file, cmd, case):
    mutate, expect = BAD_CONFIGS[case]
    cfg = bad_config(tmp_path, mutate)
    extra = ["--model", str(model_file)] if cmd == "run" else ["--out", str(tmp_path / "m.npz")]
    code, _, err = cli([cmd, *extra, "--config", str(cfg), "--log-dir", str(tmp_path / "L"), "--device-model", SCEN,
                        "--cycles", "5", *([] if cmd == "run" else ["--no-progress"])], capsys)
    assert_one_line(code, err, re.escape(str(cfg)), expect)
    assert not (tmp_path / "m.npz").exists()


@pytest.mark.parametrize("argv,expect", [
    (["reset", "--state-dir", "{tmp}/nobody"], r"no running sea-daemon"),
    (["run", "--model", "{model}", "--config", CFG, "--log-dir", "{tmp}/L", "--cycles", "0"], r"--cycles 0"),
    (["run", "--model", "{model}", "--config", CFG, "--log-dir", "{tmp}/L", "--pace", "lockstep"], r"--pace lockstep"),
    (["calibrate", "--config", CFG, "--log-dir", "{tmp}/L", "--out", "{tmp}/m.npz", "--device-model", "{tmp}/none.yaml",
      "--cycles", "5", "--no-progress"], r"none\.yaml"),
    (["calibrate", "--config", CFG, "--log-dir", "{tmp}/L", "--out", "{tmp}/m.npz", "--sim", SCEN,
      "--overrun-streak", "-1"], r"--overrun-streak -1"),
])
def test_daemon_commands_bad_arguments(tmp_path, capsys, model_file, argv, expect):
    argv = [a.format(tmp=tmp_path, model=model_file) for a in argv]
    code, _, err = cli(argv, capsys)
    assert_one_line(code, err, expect)


def test_run_on_a_device_with_the_wrong_eds_names_node_and_object(tmp_path, capsys, model_file, monkeypatch):
    from sea_daemon.hw.canopen_setup import DRIVE_EDS
    from sea_daemon.hw.device_model.drive import DriveNode
    eds = tmp_path / "wrong_drive.eds"
    text = DRIVE_EDS.read_text()
    sec = re.search(r"\[1000\][^\[]*", text).group(0)
    eds.write_text(text.replace(sec, re.sub(r"(?im)^DefaultValue\s*=.*$", "DefaultValue=0x00010196", sec)))
    monkeypatch.setattr(DriveNode, "EDS", str(eds))
    code, _, err = cli(["run", "--model", str(model_file), "--config", CFG, "--log-dir", str(tmp_path / "L"),
                        "--device-model", SCEN, "--cycles", "5"], capsys)
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    assert "node 1: 0x1000 device type: is 0x00010196 (profile 406), expected profile 402" in lines[0]
    assert code == 2, f"exit {code}: a wrong device on the bus is a configuration error (issue 7 item 4)"
