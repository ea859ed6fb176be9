"""hardware.encoder_counts: encoders of any resolution, per joint side (load / motor)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from sea_daemon.core.config import ModelConfig
from sea_daemon.errors import ConfigError

BASE = {"joints": 1, "rate_hz": 200,
        "model": {"M": 2e-3, "J": 6e-4, "D_m": 0.0, "K_s": 0.46, "D_s": 0.0}}


def _cfg(hw, joints=1):
    d = {**BASE, "joints": joints, "hardware": hw}
    return ModelConfig.from_dict(d)


def test_counts_give_joint_side_quanta():
    # a 2000-line load encoder (8000 counts) and a 500-line motor encoder (2000 counts) before 16:1
    c = _cfg({"gear_ratio": 16, "encoder_counts": {"load": 8000, "motor": 2000}})
    dq, dm = c.hardware.encoder_resolution()
    assert dq[0] == pytest.approx(2 * math.pi / 8000)
    assert dm[0] == pytest.approx(2 * math.pi / 32000)
    # round trip through the YAML dict
    assert ModelConfig.from_dict(c.to_dict()).hardware == c.hardware


def test_missing_side_falls_back_to_encoder_bits():
    c = _cfg({"gear_ratio": 100, "encoder_bits": 19, "encoder_counts": {"load": 4096}})
    dq, dm = c.hardware.encoder_resolution()
    assert dq[0] == pytest.approx(2 * math.pi / 4096)
    assert dm[0] == pytest.approx(2 * math.pi / 2**19 / 100)
    assert "motor" not in c.to_dict()["hardware"]["encoder_counts"]
    # without encoder_counts the key is not written at all
    assert "encoder_counts" not in _cfg({}).to_dict()["hardware"]


def test_per_joint_counts():
    d = {**BASE, "joints": 2, "hardware": {"encoder_counts": {"load": [1000, 2000], "motor": 500}},
         "model": {"M": [[2e-3, 0], [0, 2e-3]], "J": [[6e-4, 0], [0, 6e-4]], "D_m": [[0, 0], [0, 0]],
                   "K_s": [[0.46, 0], [0, 0.46]], "D_s": [[0, 0], [0, 0]]}}
    c = ModelConfig.from_dict(d)
    dq, dm = c.hardware.encoder_resolution(2)
    assert np.allclose(dq, 2 * math.pi / np.array([1000, 2000]))
    assert np.allclose(dm, 2 * math.pi / 500 / 100)


@pytest.mark.parametrize("bad", [{"shaft": 100}, {"load": 0}, {"load": 12.5}, {"load": True}, 8000,
                                 {"load": [1, 2, 3]}])
def test_bad_counts_are_config_errors(bad):
    with pytest.raises(ConfigError, match="encoder_counts"):
        _cfg({"encoder_counts": bad})


def test_noise_floor_uses_the_counts():
    """identify-noise floors the encoder variances at each encoder's own Δ²/12."""
    from sea_daemon.analysis.als import floored_R
    from sea_daemon.core.kinematics import CausalDifferentiator
    c = _cfg({"gear_ratio": 16, "encoder_counts": {"load": 8000, "motor": 2000}})
    fir = CausalDifferentiator(c.dt, c.kinematics.window, 2, c.kinematics.method, c.kinematics.degree).C
    res = {"R": np.zeros((4, 4)), "encoder_variances": {"theta_m": [0.0], "q": [0.0]}, "fir": fir}
    _, enc, floored = floored_R(c, res)
    assert enc["q"][0] == pytest.approx((2 * math.pi / 8000) ** 2 / 12, rel=1e-12)
    assert enc["theta_m"][0] == pytest.approx((2 * math.pi / 32000) ** 2 / 12, rel=1e-12)
    assert floored == ["theta_m_1", "q_1"]
    # a variance above the floor is kept
    res["encoder_variances"] = {"theta_m": [1e-6], "q": [1e-6]}
    _, enc, floored = floored_R(c, res)
    assert enc["q"][0] == 1e-6 and floored == []
