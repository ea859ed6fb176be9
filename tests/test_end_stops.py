"""The simulated arm's end stops: a joint whose URDF declares its range (``<limit lower upper>``)
stops there as a real arm does (a stiff spring with a damper, pushing only), and a motion within
the range is integrated bit for bit as without stops."""
from __future__ import annotations

import math
import re

import numpy as np
import pytest

from sea_daemon.core.config import ModelConfig
from sea_daemon.core.model import SEAModel
from sea_daemon.core.sim.endstops import PENETRATION, end_stops, stop_torque
from sea_daemon.core.sim.plant import Plant
from sea_daemon.io.configfile import data_root, load_yaml

URDF = (data_root() / "configs" / "exo_2dof_arm.urdf").read_text()
SHOULDER_MAX, ELBOW_MIN = 2.0944, 0.0


def arm(urdf: str = URDF) -> ModelConfig:
    path = data_root() / "configs" / "exo_2dof.yaml"
    return ModelConfig.from_dict(load_yaml(path), str(path), urdf_text=urdf)


def wide(urdf: str = URDF) -> str:
    """The same arm with ranges no motion here reaches (±100 rad)."""
    return re.sub(r'lower="[^"]*" upper="[^"]*"', 'lower="-100" upper="100"', urdf)


def run(cfg: ModelConfig, tau_h, seconds: float, q0=(0.3, 0.5)) -> np.ndarray:
    """The joint angles every 10 ms with the motor commanding zero torque (a fault) and the
    subject's torque ``tau_h``."""
    p = Plant(cfg, q0=list(q0), seed=0, torque_noise=0.0, substep_hz=4000)
    out = []
    for _ in range(int(round(seconds / 0.01))):
        p.step(np.zeros(2), 0.01, np.asarray(tau_h, dtype=float))
        out.append(p.q)
    return np.array(out)


def test_the_declared_stops_and_their_spring():
    cfg = arm()
    s = end_stops(SEAModel(cfg.model), cfg.hardware.torque_limits(2))
    np.testing.assert_allclose(s[:, 0], [-0.5236, 0.0])
    np.testing.assert_allclose(s[:, 1], [2.0944, 2.2689])
    np.testing.assert_allclose(s[:, 2], cfg.hardware.torque_limits(2) / math.radians(1.0))
    assert np.all(s[:, 3] > 0)
    # beyond the upper limit it pushes back (f > 0: a torque the joint overcomes), never pulls
    assert stop_torque(s, 0, 2.0944 + PENETRATION, 0.0) == pytest.approx(40.0)
    assert stop_torque(s, 0, 2.0944 + 1e-4, -50.0) == 0.0              # leaving fast: no pull
    assert stop_torque(s, 1, -PENETRATION, 0.0) == pytest.approx(-40.0)
    assert stop_torque(s, 0, 1.0, 3.0) == 0.0
    # no URDF: no stops
    one = ModelConfig.from_dict(load_yaml(data_root() / "configs" / "exo_1dof.yaml"), "exo_1dof.yaml")
    assert end_stops(SEAModel(one.model), one.hardware.torque_limits(1)) is None


def test_a_pushed_arm_stops_at_its_declared_range():
    """The subject pushes the unpowered shoulder up with 30 N m and the elbow down with 10 N m for
    2 s: without stops the shoulder swings past a full turn; with them it goes a few degrees into
    its stop as it hits it, then rests there (30 N m presses it less than 1° in), and the elbow
    stays at its lower one."""
    push = (30.0, -10.0)
    free = run(arm(wide()), push, 2.0)
    assert free[:, 0].max() > 2 * math.pi
    q = run(arm(), push, 2.0)
    assert np.all(np.isfinite(q))
    assert q[:, 0].max() < SHOULDER_MAX + math.radians(5.0)
    assert q[:, 1].min() > ELBOW_MIN - math.radians(5.0)
    assert SHOULDER_MAX < q[-1, 0] < SHOULDER_MAX + math.radians(1.0)     # resting on the stop


def test_within_the_range_the_motion_is_bit_for_bit_as_without_stops():
    push = (3.0, 2.0)
    a, b = run(arm(), push, 1.0, q0=(0.6, 1.0)), run(arm(wide()), push, 1.0, q0=(0.6, 1.0))
    assert -0.5236 < a[:, 0].min() and a[:, 0].max() < SHOULDER_MAX and a[:, 1].min() > ELBOW_MIN
    assert np.array_equal(a, b)
