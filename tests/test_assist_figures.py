"""Assistance a user can check: the dry run, the run's figures (engaged share and why not), the
log's τ_assist column and ``sea-daemon bench assist --json`` (docs/assist.md)."""
from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from sea_daemon.apps.cli import main
from sea_daemon.client import FLAG_ASSIST_DRY_RUN, FLAG_ASSIST_ENGAGED
from sea_daemon.core.config import AssistConfig, ModelConfig
from sea_daemon.core.effects import effect_from_dict
from sea_daemon.core.estimators.base import Estimate
from sea_daemon.core.log import log_columns
from sea_daemon.core.model import SEAModel
from sea_daemon.core.sim.plant import Plant
from sea_daemon.errors import ConfigError
from sea_daemon.hw.sim_hw import SimHardware
from sea_daemon.io.configfile import default_config_path, load_config, load_yaml
from sea_daemon.runtime.controller import AssistController, describe_assist
from sea_daemon.runtime.loop import FixedRateLoop
from sea_daemon.runtime.publish import Publisher

from _paths import repo_root


def cfg_with(assist: dict) -> ModelConfig:
    d = load_yaml(default_config_path())
    d["assist"] = assist
    return ModelConfig.from_dict(d, source="test")


class Scripted:
    """τ̂ = 1 N m with ρ = ``rho`` (per step k: a function), valid from step ``valid_from``."""

    n, name = 1, "scripted"

    def __init__(self, rho=lambda k: 0.1, hat=lambda k: 1.0, valid_from=3):
        self.rho, self.hat, self.valid_from = rho, hat, valid_from
        self.est = Estimate.zeros(1)
        self.nis = 1.0

    def reset(self, *a, **k):
        return self.est

    def update(self, q, theta_m, tau_m, dt=None):
        k = self.est.k
        self.est.k += 1
        self.est.valid = k >= self.valid_from
        self.est.tau_h_act_hat[:] = self.hat(k)
        self.est.tau_h_act_bound[:] = self.rho(k)
        return self.est


class ListLog:
    """A log writer keeping the loop's rows (the CSV's columns)."""

    def __init__(self):
        self.rows = []
        self.ncols = len(log_columns(1))

    def append(self, row):
        self.rows.append(np.array(row))

    def fault(self):
        return None


class Sent:
    """A TPDO publisher keeping what it sent."""

    def __init__(self):
        self.frames = []

    def send(self, k, hat, bound, vmask, fault, flags):
        self.frames.append((k, flags))


def loop_run(cfg, est, ctl, cycles=40, log=None, publisher=None):
    plant = Plant(cfg, q0=0.4, seed=0, torque_noise=0.0)
    hw = SimHardware(plant, cfg.dt, torque_limit=cfg.hardware.torque_limit)
    written = []
    hw_write = hw.write
    hw.write = lambda tau: (written.append(float(np.asarray(tau)[0])), hw_write(tau))[1]
    loop = FixedRateLoop(hw, est, ctl, 1, cfg.dt, realtime=False, log=log, publisher=publisher)
    hw.start(plant.hold_torque)
    loop.run(cycles)
    return loop, written


# ---------------------------------------------------------------------------- dry run
def test_dry_run_key_is_read_and_checked():
    assert cfg_with({"enabled": True}).assist.dry_run is False
    assert cfg_with({"enabled": True, "dry_run": True}).assist.dry_run is True
    with pytest.raises(ConfigError, match="assist.dry_run"):
        cfg_with({"enabled": True, "dry_run": "yes"})


def test_dry_run_commands_no_assistance_but_logs_and_publishes_it():
    cfg = cfg_with({"enabled": True, "gain": 2.0, "smoothing_s": 0.0, "max_rate": 1e6, "dry_run": True})
    ctl = AssistController(cfg)
    assert ctl.dry_run
    log, tpdo = ListLog(), Sent()
    pub = Publisher(1, cfg.dt, tpdo=tpdo, controller=ctl)
    loop, written = loop_run(cfg, Scripted(), ctl, log=log, publisher=pub)
    assert loop.supervisor.ok
    cols = log_columns(1)
    assist = np.array([r[cols.index("tau_assist")] for r in log.rows])
    tau_m = np.array([r[cols.index("tau_m")] for r in log.rows])
    q = np.array([r[cols.index("q")] for r in log.rows])
    comp = np.array([SEAModel.from_config(cfg).load_torque(np.array([x]), np.zeros(1), np.zeros(1))[0] for x in q])
    # the assistance is computed (2 x (1 - 0.1 - 0.05) = 1.7 N m) and logged ...
    assert assist[-1] == pytest.approx(1.7)
    assert np.count_nonzero(assist) > 30
    # ... but the motor gets the compensation alone, in every cycle
    assert len(written) == 40 and np.allclose(written, comp, atol=1e-12)
    assert np.allclose(tau_m, comp, atol=1e-12)
    # published: engaged (the computed assistance is not zero) and flagged as a dry run
    flags = [f for _, f in tpdo.frames]
    assert flags[-1] & FLAG_ASSIST_DRY_RUN and flags[-1] & FLAG_ASSIST_ENGAGED
    # the same controller without the dry run commands it
    ctl2 = AssistController(cfg, dry_run=False)
    _, written2 = loop_run(cfg, Scripted(), ctl2)
    assert written2[-1] == pytest.approx(ctl2.tau_comp[0] + 1.7, abs=1e-9)


def test_the_log_has_a_tau_assist_column_after_the_loop_columns():
    cols = log_columns(2)
    assert cols[-2:] == ["tau_assist_1", "tau_assist_2"]
    assert cols.index("bound_cycle") < cols.index("tau_assist_1")


# ---------------------------------------------------------------------------- the run's figures
def test_summary_gives_engaged_share_and_the_reasons_with_counts():
    cfg = cfg_with({"enabled": True, "gain": 2.0, "smoothing_s": 0.0, "max_rate": 1e6, "rho_max": 1.5})
    ctl = AssistController(cfg)
    # steps 0-2 not valid; 3-12 ρ = 3 > rho_max; 13-22 τ̂ = 0.1 below ρ + deadband; then engaged
    rho = lambda k: 3.0 if 3 <= k < 13 else 0.1
    hat = lambda k: 0.1 if 13 <= k < 23 else 1.0
    loop, _ = loop_run(cfg, Scripted(rho=rho, hat=hat), ctl, cycles=40)
    s = ctl.summary(loop.stats.cycles)
    ne = s["not_engaged"]
    # the controller acts on the previous cycle's estimate: its first call has none
    assert ne["rho_above_max"] == 10 and ne["below_bound"] == 10
    assert ne["fault"] + ne["invalid"] + ne["rho_above_max"] + ne["below_bound"] + round(
        s["engaged_share"] * s["joint_cycles"]) == 40
    assert s["engaged_share"] == pytest.approx((40 - 10 - 10 - ne["invalid"] - ne["fault"]) / 40)
    # available: the gate open (a valid estimate, ρ̄ within rho_max), whether or not effort was certified
    assert s["available_share"] == pytest.approx((40 - 10 - ne["invalid"] - ne["fault"]) / 40)
    assert s["mode"] == "assist" and s["effort_reduction"] is None and "not known" in s["effort_note"]
    line = describe_assist(s)
    assert "rho_max" in line and "10 cycle(s)" in line and f"available {100 * s['available_share']:.1f} %" in line
    json.dumps(s, allow_nan=False)                              # no nan/inf in the summary


def test_effort_reduction_where_the_subjects_torque_is_known():
    cfg = cfg_with({"enabled": True, "gain": 2.0, "smoothing_s": 0.0, "max_rate": 1e6})
    subject = np.array([1.0])
    ctl = AssistController(cfg, subject=subject)
    e = Estimate.zeros(1)
    e.valid = True
    e.tau_h_act_hat[:] = 1.0
    e.tau_h_act_bound[:] = 0.1
    for _ in range(10):
        ctl.update(0.0, np.array([0.4]), np.array([0.4]), e)
    s = ctl.summary(10)
    # τ_h = 1, τ_assist = 1.7: the assistance gave 1.7 / 2.7 of the task's torque
    assert s["effort_reduction"] == pytest.approx(1 - 1 / 2.7)
    assert s["engaged_share"] == 1.0


def test_summary_per_joint_gives_each_joints_gate_and_effort():
    cfg = load_config(repo_root() / "configs" / "exo_2dof.yaml")
    cfg = dataclasses.replace(cfg, assist=AssistConfig(enabled=True, gain=2.0, smoothing_s=0.0, max_rate=1e6,
                                                       rho_max=1.5))
    subject = np.array([1.0, 0.5])
    ctl = AssistController(cfg, subject=subject)
    e = Estimate.zeros(2)
    e.valid = True
    e.tau_h_act_hat[:] = [1.0, 0.5]
    q = np.array([0.3, 0.6])
    for k in range(20):
        # joint 1: certified from the start; joint 2: its bound above rho_max for 5 steps, then nothing certified
        e.tau_h_act_bound[:] = [0.1, 3.0 if k < 5 else 0.6]
        ctl.update(0.0, q, q, e)
    s = ctl.summary(20)
    j1, j2 = s["joints"]
    assert (j1["joint"], j2["joint"]) == (1, 2) and j1["joint_cycles"] == j2["joint_cycles"] == 20
    assert j1["engaged_share"] == 1.0 and j1["not_engaged"]["rho_above_max"] == 0
    assert j2["engaged_share"] == 0.0 and j2["available_share"] == 0.75
    assert j2["not_engaged"]["rho_above_max"] == 5 and j2["not_engaged"]["below_bound"] == 15
    # τ_h = 1 with τ_assist = 1.7 on joint 1; nothing given on joint 2
    assert j1["effort_reduction"] == pytest.approx(1 - 1 / 2.7) and j2["effort_reduction"] == 0.0
    assert j2["rho_avg_mean"] == pytest.approx((5 * 3.0 + 15 * 0.6) / 20)
    # the totals are over both joints' cycles
    assert s["joint_cycles"] == 40 and s["engaged_share"] == 0.5 and s["not_engaged"]["rho_above_max"] == 5
    line = describe_assist(s)
    assert "joint 1 engaged 100.0 %" in line and "joint 2 engaged 0.0 %, available 75.0 %" in line
    assert "mostly the bound certified no effort" in line
    json.dumps(s, allow_nan=False)


# ---------------------------------------------------------------------------- run and bench, end to end
@pytest.mark.slow
def test_run_assist_dry_run_summary_and_log(tmp_path, capsys):
    from _model import small_model
    from _paths import repo_root
    from sea_daemon.io.configfile import load_config, save_config
    from sea_daemon.io.logcsv import read_log

    root = repo_root()
    cfg = load_config(root / "configs" / "exo_1dof_assist.yaml")
    cfg = dataclasses.replace(cfg, assist=dataclasses.replace(cfg.assist, enabled=True))
    save_config(cfg, tmp_path / "assist.yaml")
    small_model(cfg, tmp_path / "m.npz")
    track = str(root / "configs" / "scenarios" / "assist_track.yaml")
    rc = main(["run", "--config", str(tmp_path / "assist.yaml"), "--model", str(tmp_path / "m.npz"), "--sim", track,
               "--log-dir", str(tmp_path), "--cycles", "300", "--assist-dry-run", "--socket", "none"])
    out, err = capsys.readouterr()
    summary = json.loads([ln for ln in out.splitlines() if ln.startswith("{")][-1])
    assert rc == 0 and summary["controller"] == "assist-dry-run", (summary["fault"], err[-500:])
    a = summary["assist"]
    assert a["mode"] == "dry_run" and set(a["not_engaged"]) == {"fault", "invalid", "rho_above_max", "below_bound"}
    assert sum(a["not_engaged"].values()) + round(a["engaged_share"] * a["joint_cycles"]) == 300
    assert a["effort_reduction"] is None and "dry run" in a["effort_note"]
    log = read_log(summary["log"], n=1)
    assert "tau_assist" in log.extra and len(log.extra["tau_assist"]) == 300


def test_run_assist_dry_run_needs_assist_enabled(tmp_path, capsys):
    from _paths import repo_root
    root = repo_root()
    rc = main(["run", "--config", str(root / "configs" / "exo_1dof_sim.yaml"), "--model", str(tmp_path / "m.npz"),
               "--log-dir", str(tmp_path), "--assist-dry-run"])
    err = capsys.readouterr().err
    assert rc == 2 and "assist.enabled" in err


@pytest.mark.slow
def test_bench_assist_json_schema(tmp_path, capsys):
    out = tmp_path / "assist.json"
    rc = main(["bench", "assist", "--seeds", "600", "--rate", "100", "--seconds", "4", "--cal-s", "20",
               "--json", str(out), "--out", str(tmp_path / "o")])
    assert rc == 0
    d = json.loads(out.read_text())
    assert isinstance(d["plants"], list) and len(d["plants"]) == 1
    p = d["plants"][0]
    assert p["seed"] == 600 and isinstance(p["faults"], list)
    for key in ("effort_reduction", "engaged_share"):
        assert p[key] is None or 0.0 <= p[key] <= 1.0 or key == "effort_reduction"
    if not p["faults"]:
        assert 0.0 <= p["engaged_share"] <= p["available_share"] <= 1.0 and p["effort_reduction"] < 1.0
        assert set(p["not_engaged"]) == {"fault", "invalid", "rho_above_max", "below_bound"}
        ph = p["by_phase"]
        assert ph["hold"]["share"] + ph["move"]["share"] == pytest.approx(1.0) and p["friction_at_rest"] >= 0.0
    json.dumps(d, allow_nan=False)


def test_bench_assist_refuses_bad_values(tmp_path, capsys):
    rc = main(["bench", "assist", "--seeds", "600", "--rate", "5"])
    assert rc == 2 and "--rate" in capsys.readouterr().err


def test_bench_assist_says_where_the_engaged_time_goes_holds_and_moves():
    from sea_daemon.apps.bench.assist import SKIP_S, friction_at_rest, phase_metrics
    from sea_daemon.core.assist import BELOW_BOUND, ENGAGED, RHO_ABOVE_MAX
    t = np.arange(0.0, 6.0, 0.01)
    hold = (t % 3.0 < 1.0).astype(float)                   # scored (t ≥ 2 s): holds 3-4 s, moves 2-3 and 4-6 s
    state = np.where(hold > 0, RHO_ABOVE_MAX, ENGAGED).astype(float)
    state[(hold == 0) & (t % 3.0 > 2.5)] = BELOW_BOUND      # 2.5-3 and 5.5-6 s: nothing certified
    r = {"t": t, "hold": hold, "state": state, "valid": np.ones_like(t), "rho": np.where(hold > 0, 4.0, 0.3),
         "tau_h_act": np.where(hold > 0, 0.2, 1.0)}
    scored = t >= SKIP_S
    h, m = phase_metrics(r, scored & (hold > 0)), phase_metrics(r, scored & (hold == 0))
    assert h["share"] + m["share"] == pytest.approx(1.0) and h["share"] == pytest.approx(0.25, abs=0.01)
    assert h["engaged_share"] == 0.0 and h["available_share"] == 0.0 and h["states"]["rho_above_max"] > 0
    assert m["engaged_share"] == pytest.approx(2 / 3, abs=0.01) and m["available_share"] == 1.0
    assert h["rho_median"] == 4.0 and m["tau_h_rms"] == pytest.approx(1.0)
    cfg = cfg_with({})
    cfg = cfg.with_effects([effect_from_dict(e, 1, "test", "e") for e in (
        {"type": "coulomb", "side": "load", "F_c": 0.3}, {"type": "stribeck", "side": "load", "F_s": 0.2, "v_s": 0.05},
        {"type": "viscous", "side": "load", "b": 0.1}, {"type": "coulomb", "side": "motor", "F_c": 0.4})])
    assert friction_at_rest(cfg) == pytest.approx(0.5)       # load side only: the motor's is behind the spring


class ScriptedJoints(Scripted):
    """Two joints: τ̂ = 1 N m on both, ρ = 0.1 on joint 1 and 3 N m (above rho_max) on joint 2."""

    n = 2

    def __init__(self):
        super().__init__()
        self.est = Estimate.zeros(2)

    def update(self, q, theta_m, tau_m, dt=None):
        k = self.est.k
        self.est.k += 1
        self.est.valid = k >= self.valid_from
        self.est.tau_h_act_hat[:] = 1.0
        self.est.tau_h_act_bound[:] = [0.1, 3.0]
        return self.est


def test_two_joints_in_the_loop_each_with_its_own_gate_column_and_figures():
    cfg = load_config(repo_root() / "configs" / "exo_2dof.yaml")
    cfg = dataclasses.replace(cfg, assist=AssistConfig(enabled=True, gain=2.0, smoothing_s=0.0, max_rate=1e6))
    q0 = np.array([0.3, 0.6])
    plant = Plant(cfg, q0=q0, seed=0, torque_noise=0.0)
    hw = SimHardware(plant, cfg.dt, torque_limit=cfg.hardware.torque_limit)
    written = []
    hw_write = hw.write
    hw.write = lambda tau: (written.append(np.array(tau, dtype=float)), hw_write(tau))[1]
    ctl = AssistController(cfg)
    log = ListLog()
    log.ncols = len(log_columns(2))
    loop = FixedRateLoop(hw, ScriptedJoints(), ctl, 2, cfg.dt, realtime=False, log=log)
    hw.start(plant.hold_torque)
    loop.run(20)
    cols = log_columns(2)
    last = log.rows[-1]
    assert last[cols.index("tau_assist_1")] == pytest.approx(2.0 * (1.0 - 0.1 - 0.05))
    assert last[cols.index("tau_assist_2")] == 0.0
    # joint 2's motor torque is its compensation alone (the coupled arm's gravity at the measured angles)
    assert written[-1][1] == pytest.approx(ctl.tau_comp[1], abs=1e-12)
    assert written[-1][0] == pytest.approx(ctl.tau_comp[0] + 1.7, abs=1e-9)
    assert abs(ctl.tau_comp[0]) > 0.1 and abs(ctl.tau_comp[1]) > 0.1
    j1, j2 = ctl.summary(loop.stats.cycles)["joints"]
    assert j1["engaged_share"] > 0.5 and j2["engaged_share"] == 0.0
    assert j2["not_engaged"]["rho_above_max"] == j1["not_engaged"]["rho_above_max"] + round(
        j1["engaged_share"] * j1["joint_cycles"])


def test_bench_assist_joints_refused_beyond_two_and_figures_per_joint(capsys):
    from sea_daemon.apps.bench.assist import _least, joint_row
    rc = main(["bench", "assist", "--seeds", "2", "--joints", "3"])
    assert rc == 2 and "--joints 3: must be 1 or 2" in capsys.readouterr().err
    m = lambda h, cov: {"tau_h_rms": h, "coverage_acting": cov, "pushes_against_while_invalid": 0, "by_phase": {}}
    jr = joint_row(m(0.5, 1.0), m(0.8, 0.99), m(1.0, None), 0.3)
    assert jr["effort_reduction"] == pytest.approx(0.5) and jr["effort_reduction_gated"] == pytest.approx(0.375)
    assert jr["friction_at_rest"] == 0.3 and jr["coverage_acting"] == 1.0
    assert _least([None, 0.4, 0.2]) == 0.2 and _least([None]) is None
