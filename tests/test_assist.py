"""Assist-as-needed: the configuration, the bound gate (AssistLaw), the innovation check, the
controller, and the loop's fault policy with assistance (docs/assist.md)."""
from __future__ import annotations

import dataclasses
import logging
import math

import numpy as np
import pytest

from sea_daemon.core.assist import BELOW_BOUND, ENGAGED, RESTART_RATIO, RHO_ABOVE_MAX, AssistLaw, InnovationGuard, InnovationOutlier
from sea_daemon.core.config import AssistConfig, ModelConfig
from sea_daemon.core.estimators.base import Estimate
from sea_daemon.errors import ConfigError, Fault
from sea_daemon.io.configfile import default_config_path, load_yaml
from sea_daemon.errors import fault_of


def cfg_with(assist: dict | None = None, torque_limit: float = 10.0) -> ModelConfig:
    raw = load_yaml(default_config_path())
    raw.setdefault("hardware", {})["torque_limit"] = torque_limit
    if assist is not None:
        raw["assist"] = assist
    return ModelConfig.from_dict(raw, "test.yaml")


# ---------------------------------------------------------------------------- configuration
def test_assist_is_off_unless_asked():
    c = cfg_with()
    assert c.assist.enabled is False
    assert c.to_dict()["assist"]["enabled"] is False
    assert ModelConfig.from_dict(c.to_dict(), "round").assist == c.assist


def test_default_max_torque_within_a_small_torque_limit():
    assert cfg_with(torque_limit=1.5).assist.max_torque == 1.5


@pytest.mark.parametrize("assist, key, words", [
    ({"gain": 11}, "assist.gain", "[0.0, 10.0]"),
    ({"gain": -1}, "assist.gain", "[0.0, 10.0]"),
    ({"max_torque": 20}, "assist.max_torque", "hardware.torque_limit = 10"),
    ({"max_rate": 0}, "assist.max_rate", "> 0"),
    ({"enabled": "yes"}, "assist.enabled", "true or false"),
    ({"compensation": "full"}, "assist.compensation", "nominal, none"),
    ({"smoothing_s": 20}, "assist.smoothing_s", "[0.0, 10.0]"),
    ({"innovation_max": -3}, "assist.innovation_max", "> 0"),
    ({"gian": 2}, "assist.gian", "unknown"),
])
def test_bad_assist_settings_name_key_and_range(assist, key, words):
    with pytest.raises(ConfigError) as e:
        cfg_with(assist)
    assert key in str(e.value) and words in str(e.value)


def test_per_joint_settings_are_read_checked_and_written_back():
    read = lambda d: AssistConfig.from_dict(d, 2, "test.yaml", 10.0)
    c = read({"enabled": True, "rho_max": [1.5, 0.8], "max_torque": [3.0, 1.0], "gain": 2.0})
    assert c.rho_max == (1.5, 0.8) and c.max_torque == (3.0, 1.0) and c.gain == 2.0
    assert list(c.per_joint("gain", 2)) == [2.0, 2.0] and list(c.per_joint("rho_max", 2)) == [1.5, 0.8]
    back = c.to_dict()
    assert back["rho_max"] == [1.5, 0.8] and back["gain"] == 2.0
    assert read(back) == c
    # a torque limit per joint bounds each joint's max_torque (and its default)
    assert AssistConfig.from_dict({}, 2, "test.yaml", [40.0, 2.0]).max_torque == (3.0, 2.0)
    # the wording of every per-joint setting (hardware.gear_ratio, torque_limit, ... the same)
    for bad, words in (({"rho_max": [1.5]}, "assist.rho_max: must be a number > 0 or a list of 2 such numbers "
                                            "(one per joint), got [1.5]"),
                       ({"rho_max": [1.5, -1]}, "assist.rho_max: must be a number > 0 or a list of 2 such numbers "
                                                "(one per joint), got [1.5, -1] (joint 2: -1)"),
                       ({"max_torque": [3.0, 12.0]}, "(joint 2)"),
                       ({"gain": [2, "x"]}, "assist.gain: must be a number in [0.0, 10.0] or a list of 2 such "
                                            "numbers (one per joint), got [2, 'x'] (joint 2: 'x')")):
        with pytest.raises(ConfigError) as e:
            read({"enabled": True, **bad})
        assert words in str(e.value)


def test_each_joint_gated_and_limited_by_its_own_settings():
    cfg = AssistConfig(enabled=True, gain=(2.0, 1.0), deadband=0.05, rho_max=(1.5, 0.5), max_torque=(3.0, 0.2),
                       max_rate=1e9, smoothing_s=0.0)
    lw = AssistLaw(cfg, 2, 0.01)
    # the same estimate and bound on both joints: joint 2's bound is above its own rho_max
    tau = lw.step(np.array([1.0, 1.0]), np.array([0.8, 0.8]), True)
    assert tau[0] == pytest.approx(2.0 * (1.0 - 0.8 - 0.05)) and tau[1] == 0.0
    assert list(lw.state) == [ENGAGED, RHO_ABOVE_MAX]
    # within joint 2's rho_max: its own gain, clipped at its own max_torque
    tau = lw.step(np.array([1.0, 1.0]), np.array([0.1, 0.1]), True)
    assert tau[0] == pytest.approx(2.0 * 0.85) and tau[1] == pytest.approx(0.2)


# ---------------------------------------------------------------------------- the gate
def law(dt=0.01, **kw) -> AssistLaw:
    base = dict(enabled=True, gain=2.0, deadband=0.05, rho_max=1.5, max_torque=3.0, max_rate=1e9, smoothing_s=0.0)
    base.update(kw)
    return AssistLaw(AssistConfig(**base), 1, dt)


def test_certified_part_times_gain_without_smoothing():
    a = law()
    out = a.step([1.0], [0.3], True)
    assert out[0] == pytest.approx(2.0 * (1.0 - 0.3 - 0.05))
    assert a.trust[0] == pytest.approx(0.65)
    assert a.step([-1.0], [0.3], True)[0] == pytest.approx(-1.3)      # the sign of the estimate
    assert a.step([0.3], [0.3], True)[0] == 0.0                       # inside the bound: nothing
    assert a.step([5.0], [0.1], True)[0] == 3.0                       # max_torque


def test_invalid_or_nonfinite_estimate_gives_zero_at_once():
    a = law(max_rate=1.0)                                              # slow, except for this
    for _ in range(200):
        a.step([2.0], [0.1], True)
    assert a.tau[0] > 1.0
    assert a.step([2.0], [0.1], False)[0] == 0.0
    for _ in range(200):
        a.step([2.0], [0.1], True)
    assert a.step([float("nan")], [0.1], True)[0] == 0.0
    for _ in range(200):
        a.step([2.0], [0.1], True)
    assert a.step([2.0], [math.inf], True)[0] == 0.0


def test_loose_bound_gives_no_assistance():
    a = law(rho_max=0.5)
    assert a.step([3.0], [0.6], True)[0] == 0.0
    assert a.step([3.0], [0.4], True)[0] > 0.0


def test_rate_limit_both_ways():
    a = law(max_rate=10.0, dt=0.01)
    steps = [a.step([2.0], [0.0], True)[0] for _ in range(50)]
    assert np.all(np.diff([0.0] + steps) <= 0.1 + 1e-12)
    assert steps[-1] == pytest.approx(min(3.0, 2 * 1.95))
    down = [a.step([0.0], [0.0], True)[0] for _ in range(5)]
    assert np.all(np.diff([steps[-1]] + down) >= -0.1 - 1e-12)


def test_smoothing_delays_and_keeps_the_bound():
    """The averaged estimate and bound are the same low-pass of each: wherever |τ − τ̂| ≤ ρ held,
    the target never exceeds gain × the subject's averaged torque and has its sign."""
    rng = np.random.default_rng(4)
    dt, T = 0.01, 0.5
    a = law(smoothing_s=T, dt=dt, max_torque=100.0, rho_max=3.0)
    beta = 1 - math.exp(-dt / T)
    tau = 1.5 * np.sin(np.arange(3000) * dt * 1.3) + 0.3 * rng.standard_normal(3000).cumsum() * 0.05
    tau_avg = tau[0]
    for k in range(3000):
        # bursts of a wide bound (a standstill) now and then: the averages restart after them
        rho = 0.2 + 0.5 * rng.random() if k % 500 > 100 else 5.0 + 5.0 * rng.random()
        hat = tau[k] + rho * (2 * rng.random() - 1)                  # the bound holds
        restart = a.rho_avg[0] > a.rho_maxes[0] and RESTART_RATIO * rho < a.rho_avg[0]
        a.step([hat], [rho], True)
        if k:
            tau_avg = tau[k] if restart else tau_avg + beta * (tau[k] - tau_avg)
        t = a.target[0]
        assert abs(t) <= 2.0 * abs(tau_avg) + 1e-9
        assert t == 0.0 or np.sign(t) == np.sign(tau_avg)


def test_the_averages_restart_when_the_bound_falls_after_a_standstill():
    """A standstill's wide bound (10 N m for 2 s) does not hold the assistance off once the bound
    is tight again: with ρ̄ above rho_max the averages restart from the first estimate whose bound
    is below half of theirs, so the subject's 1.5 N m is certified in the next step, not after the
    low-pass has forgotten the standstill (1.3 s at smoothing_s 0.6).  Within rho_max they never
    restart (the bound's ordinary ups and downs are averaged)."""
    a = law(smoothing_s=0.6, dt=0.01)
    for _ in range(200):
        a.step([1.5], [10.0], True)
    assert a.state[0] == RHO_ABOVE_MAX and a.target[0] == 0.0
    a.step([1.5], [0.3], True)
    assert a.rho_avg[0] == pytest.approx(0.3) and a.tau_hat_avg[0] == pytest.approx(1.5)
    assert a.state[0] == ENGAGED and a.target[0] == pytest.approx(2.0 * (1.5 - 0.3 - 0.05))
    # a bound that grows is averaged in as before (no restart): the average follows it with the low-pass
    a.step([1.5], [0.5], True)
    assert 0.3 < a.rho_avg[0] < 0.31
    for _ in range(300):
        a.step([1.5], [1.2], True)              # ρ̄ → 1.2, within rho_max 1.5
    a.step([1.5], [0.3], True)                  # a quarter of it: no restart within rho_max
    assert a.rho_avg[0] > 1.1


def test_the_subject_reversing_stops_the_assistance_at_once():
    """The averaged estimate still says +1 N m when the subject has turned to -1 N m (the braking
    half of a move): the current estimate certifies the other direction, so the target is 0 in
    that step, not after the low-pass has followed; a current estimate that certifies nothing
    (a burst of its bound) leaves the averaged assistance as it is."""
    a = law(smoothing_s=0.6, dt=0.01)
    for _ in range(300):
        a.step([1.0], [0.2], True)
    assert a.target[0] == pytest.approx(2.0 * (1.0 - 0.2 - 0.05))
    a.step([-0.1], [0.8], True)                 # uncertain, not reversed: the average decides
    assert a.target[0] > 1.0
    a.step([-1.0], [0.2], True)                 # reversed: the average is still positive
    assert a.tau_hat_avg[0] > 0.8 and a.target[0] == 0.0 and a.state[0] == BELOW_BOUND


# ---------------------------------------------------------------------------- innovation check
class FakeFilter:
    n, name = 1, "fake"

    def __init__(self):
        self.nis = 1.0
        self.est = Estimate.zeros(1)
        self.est.valid = True
        self.extra = "passed through"

    def reset(self, *a, **k):
        return self.est

    def update(self, q, theta_m, tau_m, dt=None):
        self.est.k += 1
        return self.est


def test_innovation_guard_faults_on_an_outlier():
    f = FakeFilter()
    g = InnovationGuard(f, 100.0)
    assert g.update([0], [0], [0]) is f.est and g.extra == "passed through"
    f.nis = 1e6
    with pytest.raises(InnovationOutlier) as e:
        g.update([0], [0], [0])
    assert "100" in str(e.value) and fault_of(e.value) is Fault.INNOVATION_OUTLIER
    f.est.valid = False                                                # the filter is not running yet
    assert g.update([0], [0], [0]) is f.est
    f.nis, f.est.valid = float("nan"), True
    with pytest.raises(InnovationOutlier):
        g.update([0], [0], [0])


# ---------------------------------------------------------------------------- controller + loop
def test_controller_is_compensation_plus_assistance():
    from sea_daemon.core.model import SEAModel
    from sea_daemon.runtime.controller import AssistController

    cfg = cfg_with({"enabled": True, "gain": 2.0, "smoothing_s": 0.0, "max_rate": 1e6})
    c = AssistController(cfg)
    q = np.array([0.5])
    comp = SEAModel.from_config(cfg).load_torque(q, np.zeros(1), np.zeros(1))
    assert c.update(0.0, q, q, None) == pytest.approx(comp)            # no estimate: compensation only
    e = Estimate.zeros(1)
    e.tau_h_act_hat[:] = 1.0
    e.tau_h_act_bound[:] = 0.2
    assert c.update(0.01, q, q, e) == pytest.approx(comp)              # not valid
    e.valid = True
    assert c.update(0.02, q, q, e) == pytest.approx(comp + 2 * 0.75)
    assert AssistController(cfg, gain=0.0).update(0.0, q, q, e) == pytest.approx(comp)


class ScriptedEstimator(FakeFilter):
    """τ̂ = 1 N m, ρ = 0.1 N m; NaN from step ``nan_at``, an innovation outlier at ``outlier_at``."""

    def __init__(self, nan_at=None, outlier_at=None):
        super().__init__()
        self.nan_at, self.outlier_at = nan_at, outlier_at
        self.est.tau_h_act_hat[:] = 1.0
        self.est.tau_h_act_bound[:] = 0.1

    def update(self, q, theta_m, tau_m, dt=None):
        from sea_daemon.core.estimators.health import EstimatorNonFinite
        k = self.est.k
        self.est.k += 1
        if self.nan_at is not None and k >= self.nan_at:
            raise EstimatorNonFinite(f"state not finite at step {k}")
        self.nis = 1e9 if k == self.outlier_at else 1.0
        return self.est


@pytest.mark.parametrize("kind", ["nan", "outlier"])
def test_corrupted_estimate_zero_torque_in_that_cycle(kind):
    from sea_daemon.hw.sim_hw import SimHardware
    from sea_daemon.core.sim.plant import Plant
    from sea_daemon.runtime.controller import AssistController
    from sea_daemon.runtime.loop import FixedRateLoop

    cfg = cfg_with({"enabled": True, "gain": 2.0, "smoothing_s": 0.0, "max_rate": 1e6, "innovation_max": 1e3})
    plant = Plant(cfg, q0=0.4, seed=0, torque_noise=0.0)
    hw = SimHardware(plant, cfg.dt, torque_limit=10.0)
    est = ScriptedEstimator(nan_at=30 if kind == "nan" else None, outlier_at=30 if kind == "outlier" else None)
    ctl = AssistController(cfg)
    written = []
    hw_write = hw.write
    hw.write = lambda tau: (written.append(float(np.asarray(tau)[0])), hw_write(tau))[1]
    assisted = []
    loop = FixedRateLoop(hw, InnovationGuard(est, 1e3), ctl, 1, cfg.dt, realtime=False,
                         on_cycle=lambda k, m, e, tau: assisted.append((k, float(tau[0]), float(ctl.tau_assist[0]))))
    hw.start(plant.hold_torque)
    loop.run(40)
    code = Fault.ESTIMATOR_NONFINITE if kind == "nan" else Fault.INNOVATION_OUTLIER
    assert loop.supervisor.latched is code and loop.supervisor.latched_cycle == 30
    # the cycle of the fault and every later one: zero torque acting, zero written last
    for k, tau, _ in assisted[30:]:
        assert tau == 0.0
    assert assisted[29][2] > 1.0                      # it was assisting until then
    assert written[-1] == 0.0


def test_each_joints_max_torque_within_its_own_torque_limit(tmp_path):
    import shutil
    import yaml
    from _paths import repo_root
    from sea_daemon.io.configfile import load_config
    configs = repo_root() / "configs"
    shutil.copy(configs / "exo_2dof_arm.urdf", tmp_path / "exo_2dof_arm.urdf")
    raw = load_yaml(configs / "exo_2dof.yaml")
    raw["hardware"]["torque_limit"] = [40.0, 2.0]
    raw["assist"] = {"enabled": True}
    (tmp_path / "arm.yaml").write_text(yaml.safe_dump(raw))
    assert load_config(tmp_path / "arm.yaml").assist.max_torque == (3.0, 2.0)   # min(3, each joint's limit)
    raw["assist"] = {"enabled": True, "max_torque": 2.5}
    (tmp_path / "arm.yaml").write_text(yaml.safe_dump(raw))
    with pytest.raises(ConfigError) as e:
        load_config(tmp_path / "arm.yaml")
    assert "assist.max_torque" in str(e.value) and "torque_limit = 2] N m (joint 2)" in str(e.value)


class _Said(logging.Handler):
    """The messages a logger was given (whatever the command line did to its propagation)."""

    def __init__(self):
        super().__init__(logging.WARNING)
        self.said = []

    def emit(self, record):
        self.said.append(record.getMessage())


def test_rho_max_below_the_encoders_floor_is_said_and_reported():
    """A rho_max below the tightest bound the encoders allow for the declared wearer can never
    open the gate: the controller says so at start and its summary carries the floor."""
    from sea_daemon.runtime.controller import AssistController

    raw = load_yaml(default_config_path())
    raw["assist"] = {"enabled": True, "rho_max": 0.05}
    raw.setdefault("estimator", {})["tau_h_act_rate"] = 40.0
    cfg = ModelConfig.from_dict(raw, "test.yaml")
    log, h = logging.getLogger("sea_daemon.assist"), _Said()
    log.addHandler(h)
    try:
        c = AssistController(cfg)
        assert 0.05 < c.rho_floor[0] < 0.5
        assert any("below the tightest bound" in m for m in h.said), h.said
        assert c.summary(1)["rho_floor"] == pytest.approx(float(c.rho_floor[0]))
        # within reach: nothing said; no declared rate: no floor
        raw["assist"]["rho_max"] = 1.5
        h.said.clear()
        AssistController(ModelConfig.from_dict(raw, "test.yaml"))
        assert not h.said
    finally:
        log.removeHandler(h)
    raw["estimator"]["tau_h_act_rate"] = 0.0
    assert AssistController(ModelConfig.from_dict(raw, "test.yaml")).summary(1)["rho_floor"] is None
