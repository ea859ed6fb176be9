"""The daemon on a kernel's SocketCAN bus, as on the exoskeleton: ``sea-daemon device-model --bus
socketcan --channel vcan0`` in one process (the drive and the load encoder), ``sea-daemon
calibrate`` (the GP-AKF online in the fixed-rate loop) on the same interface in another, 300
cycles at 100 Hz in real time, and a reader in this process that receives the daemon's published
TPDOs on its own SocketCAN socket.  Needs ``vcan0``: skipped with the reason where there is none (a failure with
``SEA_DAEMON_REQUIRE_SOCKETCAN=1``); ``.ci/vcan.sh`` runs it in a virtual machine with a real kernel.
"""
from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys

import numpy as np
import pytest

from _hil import REQUIRE_SOCKETCAN, need_socketcan
from _paths import repo_root
from test_drivers_remote import DeviceProcess
from test_publish_hil import CanListener

ROOT = repo_root()
CONFIG = ROOT / "configs" / "exo_1dof_sim.yaml"
PASSIVE = str(ROOT / "configs" / "scenarios" / "passive.yaml")
CHANNEL = "vcan0"
CYCLES = 300            # 3 s at the configuration's 100 Hz


def daemon(*args, timeout=900):
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    r = subprocess.run([sys.executable, "-m", "sea_daemon", *map(str, args)], capture_output=True, text=True,
                       env=env, timeout=timeout)
    lines = [ln for ln in r.stdout.splitlines() if ln.startswith("{")]
    return r, (json.loads(lines[-1]) if lines else None)


def read_log(path) -> dict[str, np.ndarray]:
    """The measured log's columns (docs/interfaces.md §1)."""
    with open(path) as f:
        names = f.readline().strip().split(",")
    data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    return {n: data[:, i] for i, n in enumerate(names)}


def bus_config(path) -> str:
    """The simulation configuration on vcan0, its timeouts for a loaded or emulated machine (the
    device model is a Python process sharing its CPUs): the TPDOs may take up to 100 ms after the
    SYNC, two late cycles are held, a heartbeat may take 5 s (also the drives' watch of the daemon's
    heartbeat, from the start-up to the loop's first cycle); an overrun is logged, not a fault.
    The bus's timing at 1 kHz is measured by ``sea-daemon bench``, not here."""
    from sea_daemon.io.configfile import load_config, save_config
    cfg = load_config(CONFIG)
    bus = dataclasses.replace(cfg.hardware.bus, interface="socketcan", channel=CHANNEL, pdo_timeout_ms=100.0,
                              max_missed_cycles=2, heartbeat_timeout_ms=5000, sdo_timeout_ms=2000)
    save_config(dataclasses.replace(cfg, hardware=dataclasses.replace(cfg.hardware, bus=bus)), path)
    return str(path)


def check_session(r, summary, what):
    """Exit 0, no fault, every cycle in the log, none of its rows with a fault."""
    assert r.returncode == 0 and summary is not None, f"{what}: exit {r.returncode}: {r.stderr[-3000:]}"
    assert summary["fault"] == "NONE", summary
    assert summary["cycles"] == summary["rows_written"] == CYCLES and summary["rows_lost"] == 0, summary
    log = read_log(summary["log"])
    assert len(log["t"]) == CYCLES and np.all(log["fault"] == 0)
    assert np.all(np.isfinite(log["tau_m"])) and np.all(np.diff(log["t"]) > 0)
    return log


@pytest.mark.socketcan
@pytest.mark.slow
def test_a_calibration_on_vcan0_with_the_device_model_in_another_process(tmp_path):
    need_socketcan(CHANNEL)
    from sea_daemon.client import tpdo_cob_ids, tpdo_cycles

    cfg = bus_config(tmp_path / "vcan.yaml")
    dev = DeviceProcess(CHANNEL, "--config", cfg, "--scenario", PASSIVE, bus="socketcan", duration=1800,
                        ready_s=900)
    reader = None
    try:
        reader = CanListener(CHANNEL, tpdo_cob_ids(127, 1).values(), interface="socketcan")
        r, cal = daemon("calibrate", "--config", cfg, "--scenario", PASSIVE, "--cycles", CYCLES, "--socket", "none",
                        "--rt-priority", "0", "--overrun-streak", "0", "--no-progress",
                        "--out", tmp_path / "m.npz", "--log-dir", tmp_path)
    finally:
        if reader is not None:
            reader.close()
        code = dev.close()
    log = check_session(r, cal, "calibrate")
    assert code == 0, f"device-model exit {code}: {dev.proc.stderr.read()[-3000:]}"
    assert cal["hardware"] == f"CAN socketcan {CHANNEL}" and cal["pace"] == "realtime", cal
    assert cal["gp_points"] > 0 and (tmp_path / "m.npz").is_file()
    # the scenario's PID moved the joint through the drive and the encoder on the kernel's bus
    assert np.ptp(log["q"]) > 0.05
    # the published estimate of every cycle, as logged (REAL32), arrived on another socket
    by_cycle = tpdo_cycles(reader.frames)
    cycles = log["cycle"].astype(int)
    missing = [k for k in cycles if k not in by_cycle]
    assert not missing, f"TPDO1/TPDO2 of {len(missing)} of {len(cycles)} cycles missing, first {missing[:5]}"
    hat = np.array([by_cycle[k][0]["tau_h_act_hat"] for k in cycles])
    logged = log["tau_h_act_hat"].astype(np.float32)
    assert np.all(np.abs(hat - logged) <= np.abs(np.spacing(logged))), np.max(np.abs(hat - logged))
    assert all(by_cycle[k][1]["fault"] == 0 for k in cycles)


def test_a_missing_interface_skips_with_the_reason_or_fails_when_required(monkeypatch):
    monkeypatch.delenv(REQUIRE_SOCKETCAN, raising=False)
    with pytest.raises(pytest.skip.Exception, match=r"^socketcan: "):
        need_socketcan("sea-no-vcan")
    monkeypatch.setenv(REQUIRE_SOCKETCAN, "1")
    with pytest.raises(pytest.fail.Exception, match=r"^socketcan: .*\(SEA_DAEMON_REQUIRE_SOCKETCAN=1\)$"):
        need_socketcan("sea-no-vcan")
