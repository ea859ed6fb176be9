"""The estimate where labs look: ``run --lsl`` streams every cycle to a Lab Streaming Layer inlet
in another process, ``run --mcap`` records it beside the CSV log; both carry the CSV log's values,
row for row (docs/interfaces.md §7)."""
import csv
import json
import subprocess
import sys
import uuid
from dataclasses import dataclass

import numpy as np
import pytest
import yaml

from sea_daemon.core.config import ModelConfig
from sea_daemon.core.log import DaemonLogLayout
from sea_daemon.errors import ConfigError, InputError
from sea_daemon.io.configfile import load_config
from sea_daemon.runtime.logwriter import LogWriter
from sea_daemon.runtime.loop import FixedRateLoop
from sea_daemon.runtime.rig import make_rig
from sea_daemon.runtime.sinks import JOINT_CHANNELS, OPEN, ROW_CHANNELS, TOPIC, McapSpec
from _cli import refused, run as cli
from _model import small_model
from _paths import repo_root

ROOT = repo_root()
CFG = ROOT / "configs" / "exo_1dof_sim.yaml"
PASSIVE = str(ROOT / "configs" / "scenarios" / "passive.yaml")
CYCLES = 300
FMT = "%.10g"                        # the CSV log's format of a value (runtime/logwriter.py)

# the inlet: resolve the stream by name, read its description, pull until `expected` samples came
INLET = r"""
import json, sys, pylsl
name, expected = sys.argv[1], int(sys.argv[2])
t_start = pylsl.local_clock()
found = pylsl.resolve_byprop("name", name, 1, 120)
if not found:
    sys.exit("no stream named " + name)
inlet = pylsl.StreamInlet(found[0], max_buflen=60)
info = inlet.info(30)
inlet.open_stream(30)
chans, ch = [], info.desc().child("channels").child("channel")
while not ch.empty():
    chans.append({k: ch.child_value(k) for k in ("label", "unit", "type")})
    ch = ch.next_sibling()
samples, stamps, idle = [], [], 0
while len(samples) < expected and idle < 30:
    try:
        data, ts = inlet.pull_chunk(timeout=1.0)
    except Exception as e:                      # pylsl's LostError: the outlet closed
        if type(e).__name__ != "LostError":
            raise
        break
    idle = 0 if data else idle + 1
    samples += data
    stamps += ts
print(json.dumps({"format": info.channel_format(), "double64": pylsl.cf_double64, "rate": info.nominal_srate(),
                  "channels": chans, "samples": samples, "stamps": stamps, "t_start": t_start,
                  "t_end": pylsl.local_clock()}))
"""


@pytest.fixture(scope="module")
def model(tmp_path_factory):
    """A model file for the simulated exoskeleton: a small residual GP, no calibration run."""
    p = tmp_path_factory.mktemp("model") / "m.npz"
    small_model(load_config(CFG), p)
    return p


def _config(tmp_path, publish: dict):
    d = yaml.safe_load(CFG.read_text())
    d["publish"] = publish
    p = tmp_path / "model.yaml"
    p.write_text(yaml.safe_dump(d))
    return p


def _run(capsys, cfg, model, log_dir, *extra):
    code, out, err = cli(["run", "--config", cfg, "--model", model, "--device-model", PASSIVE,
                          "--log-dir", log_dir, "--cycles", CYCLES, *extra], capsys)
    assert code == 0, err
    return json.loads([ln for ln in out.splitlines() if ln.startswith("{")][-1])


def _csv(path):
    """The CSV log's header and its rows as the text of each value."""
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    return rows[0], rows[1:]


def _expected_labels():
    return [base for base, _, _ in JOINT_CHANNELS] + [name for name, _, _ in ROW_CHANNELS]


def test_an_lsl_inlet_in_another_process_gets_every_cycle_equal_to_the_log(model, tmp_path, capsys):
    pytest.importorskip("pylsl")
    name = f"sea-daemon-test-{uuid.uuid4().hex[:8]}"
    # the YAML's switch; the daemon waits for the inlet before its loop starts
    cfg = _config(tmp_path, {"lsl": True, "lsl_name": name, "lsl_wait_s": 120})
    inlet = subprocess.Popen([sys.executable, "-c", INLET, name, str(CYCLES)], stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True)
    try:
        summary = _run(capsys, cfg, model, tmp_path / "logs")
        out, err = inlet.communicate(timeout=180)
    finally:
        inlet.kill()
    assert inlet.returncode == 0, err
    got = json.loads(out)
    assert summary["outputs"] == [{"output": "lsl", "name": name, "source_id": f"sea-daemon:{name}",
                                   "rows": CYCLES, "consumer": True, "error": None}]
    # the description: one channel per quantity (one joint), units, double64 at the loop's rate
    assert [c["label"] for c in got["channels"]] == _expected_labels()
    assert {c["label"]: c["unit"] for c in got["channels"]}["tau_h_act_hat"] == "N*m"
    assert {c["label"]: c["unit"] for c in got["channels"]}["q"] == "rad"
    assert got["format"] == got["double64"] and got["rate"] == load_config(CFG).rate_hz
    # every cycle, each value the CSV's (formatted as the CSV formats it)
    header, rows = _csv(summary["log"])
    samples = got["samples"]
    assert len(samples) == len(rows) == CYCLES
    for label_i, label in enumerate(_expected_labels()):
        if label == "tau_assist":                     # not in the CSV: no assist controller, none
            assert all(s[label_i] == 0.0 for s in samples)
            continue
        col = header.index(label)
        assert [FMT % s[label_i] for s in samples] == [r[col] for r in rows], label
    # stamped with each cycle's start on LSL's clock: after the inlet started, before it ended,
    # spaced as the log's period column says
    stamps = np.array(got["stamps"])
    assert got["t_start"] < stamps[0] and stamps[-1] < got["t_end"]
    period = np.array([float(r[header.index("period")]) for r in rows])
    np.testing.assert_allclose(np.diff(stamps), period[1:], atol=1e-6)


def test_the_mcap_recording_reads_back_equal_to_the_log(model, tmp_path, capsys):
    pytest.importorskip("mcap")
    from mcap.reader import make_reader
    summary = _run(capsys, str(CFG), model, tmp_path, "--mcap")
    csv_path = summary["log"]
    mcap_path = csv_path[:-len(".csv")] + ".mcap"
    assert summary["outputs"] == [{"output": "mcap", "path": mcap_path, "rows": CYCLES, "error": None}]
    header, rows = _csv(csv_path)
    with open(mcap_path, "rb") as f:
        reader = make_reader(f)
        meta = {m.name: m.metadata for m in reader.iter_metadata()}
        msgs = list(reader.iter_messages(topics=[TOPIC]))
    assert meta["sea_daemon"]["log"] == csv_path and meta["sea_daemon"]["joints"] == "1"
    assert len(msgs) == len(rows) == CYCLES
    schema, channel, _ = msgs[0]
    assert channel.message_encoding == "json" and schema.encoding == "jsonschema"
    props = json.loads(schema.data)["properties"]
    assert set(props) == {"t", "cycle", "valid", "fault"} | {base for base, _, _ in JOINT_CHANNELS}
    log_times = []
    for (_, _, m), row in zip(msgs, rows):
        d = json.loads(m.data)
        assert set(d) == set(props)
        for key in ("t", "cycle", "valid", "fault"):
            assert FMT % d[key] == row[header.index(key)], key
        for base, _, _ in JOINT_CHANNELS:
            if base == "tau_assist":
                assert d[base] == [0.0]
            else:
                assert [FMT % v for v in d[base]] == [row[header.index(base)]], base
        assert m.log_time == m.publish_time
        log_times.append(m.log_time)
    # log time: each cycle's start [ns], spaced as the log's period column says
    period = np.array([float(r[header.index("period")]) for r in rows])
    np.testing.assert_allclose(np.diff(log_times) * 1e-9, period[1:], atol=1e-6)


def test_lsl_without_pylsl_installed_is_refused_with_the_extra_to_install(model, tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "pylsl", None)          # import pylsl raises ImportError
    code, _, err = cli(["run", "--config", CFG, "--model", model, "--sim", PASSIVE, "--log-dir", tmp_path,
                        "--cycles", 5, "--lsl"], capsys)
    refused(code, err, r"--lsl", r"pip install sea-daemon\[lsl\]")


@pytest.mark.parametrize("publish, key", [({"lsl": "yes"}, "publish.lsl"), ({"mcap": 1}, "publish.mcap"),
                                          ({"lsl_wait_s": -1}, "publish.lsl_wait_s"),
                                          ({"lsl_name": ""}, "publish.lsl_name"),
                                          ({"lsl_name": "a\nb"}, "publish.lsl_name"),
                                          ({"stream": True}, "publish.stream")])
def test_the_publish_section_refuses_bad_values_naming_the_key(publish, key):
    d = yaml.safe_load(CFG.read_text())
    d["publish"] = publish
    with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
        ModelConfig.from_dict(d, "m.yaml")


class _WideLog:
    """A log that takes the loop's whole row (the CSV's columns and the sinks'); it fails (the
    loop latches LOG_FAILED) from its ``fail_at``-th row."""

    def __init__(self, n, fail_at):
        self.ncols, self.rows, self.fail_at = DaemonLogLayout.of(n).width, [], fail_at

    def append(self, row):
        self.rows.append(row.copy())
        return True

    def fault(self):
        return "log: full" if len(self.rows) > self.fail_at else None


class _Assisting:
    """A controller with an assistance vector of its own (as the assist-as-needed controller)."""

    def __init__(self, n):
        self.tau_assist = np.zeros(n)

    def update(self, t, q, theta_m, estimate):
        self.tau_assist[:] = 0.25 + t
        return np.zeros_like(self.tau_assist)


def test_the_loop_row_carries_the_assistance_and_the_cycle_start_for_the_sinks():
    cfg = load_config(CFG)
    rig = make_rig(cfg, sim=PASSIVE, phase="estimation")
    log, ctl = _WideLog(1, fail_at=20), _Assisting(1)
    loop = FixedRateLoop(rig.hw, None, ctl, n=1, period=cfg.dt, log=log, realtime=False)
    rig.start()
    try:
        loop.run(30)
    finally:
        rig.stop()
    assert loop.supervisor.latched.name == "LOG_FAILED" and loop.supervisor.latched_cycle == 20
    L = DaemonLogLayout.of(1)
    rows = np.array(log.rows)
    assert rows.shape == (30, L.width)
    # the assistance the controller gave in each cycle; 0 once a fault is latched
    np.testing.assert_allclose(rows[:21, L.tau_assist][:, 0], 0.25 + rows[:21, L.t])
    assert np.all(rows[21:, L.tau_assist] == 0.0)
    # the cycle's start on the loop's clock: increasing, spaced by the period column
    np.testing.assert_allclose(np.diff(rows[:, L.cycle_start]), rows[1:, L.period], atol=1e-9)


class _FullDisk:
    """An output whose writes fail from the first (as a full disk would)."""

    def __init__(self, board, slot):
        self.board, self.slot = board, slot
        board.set(slot, OPEN)

    def write(self, block):
        raise OSError(28, "No space left on device")

    def close(self):
        pass


@dataclass(frozen=True)
class _FullDiskSpec:
    kind = "mcap"

    def open(self, board, slot):
        return _FullDisk(board, slot)

    def describe(self):
        return {"output": "full-disk"}


def test_an_output_that_fails_stops_alone_and_the_csv_log_is_complete(tmp_path):
    L = DaemonLogLayout.of(1)
    w = LogWriter(tmp_path / "x.csv", list(L.columns), sink_columns=L.sink_columns, sinks=(_FullDiskSpec(),),
                  flush_interval=0.04)
    assert w.wait_sinks(60) == [OPEN]
    row = np.zeros(L.width)
    for k in range(500):
        row[L.cycle] = k
        assert w.append(row)
    final = w.close()
    assert final["rows_written"] == 500 and final["rows_lost"] == 0 and final["error"] is None
    assert final["sinks"] == [{"output": "full-disk", "rows": 0, "error": "_FullDisk: [Errno 28] No space left on device"}]
    _, rows = _csv(tmp_path / "x.csv")
    assert [int(r[L.cycle]) for r in rows] == list(range(500))


def test_an_output_that_cannot_open_stops_the_start_up_naming_it(tmp_path):
    pytest.importorskip("mcap")
    L = DaemonLogLayout.of(1)
    spec = McapSpec(str(tmp_path / "missing" / "x.mcap"), 1, 100.0, str(tmp_path / "x.csv"))
    w = LogWriter(tmp_path / "x.csv", list(L.columns), sink_columns=L.sink_columns, sinks=(spec,))
    try:
        with pytest.raises(InputError, match=r"mcap: cannot open: .*No such file or directory"):
            w.wait_sinks(60)
    finally:
        w.close()
