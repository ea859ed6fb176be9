"""The bound's floor (core/bounds/floor.py): how long a declared change of the wearer's torque
stays within one encoder count, checked against the plant simulator's own integration."""
import dataclasses
import math

import numpy as np
import pytest

from sea_daemon.core.bounds.floor import bound_floor
from sea_daemon.core.sim.plant import Plant
from sea_daemon.io.configfile import data_root, load_config


def _config(name):
    cfg = load_config(data_root() / "configs" / name)
    return dataclasses.replace(cfg, hardware=dataclasses.replace(cfg.hardware, torque_noise=0.0))


def _separation_counts(cfg, q0, joint, rate, accel, t_end, h=1e-5):
    """Two plants at rest at q0 under the same motor torque; the second wearer's torque on
    ``joint`` changes at ``rate`` (rising at ``accel`` first); the largest encoder share of
    their separation, in counts, at each step (the simulator's RK4 on the non-linear plant)."""
    a, b = Plant(cfg, q0=q0, seed=0), Plant(cfg, q0=q0, seed=0)
    u = a.hold_torque.copy()
    dq, dth = cfg.hardware.encoder_resolution(cfg.joints)
    n = cfg.joints
    out, t = [], 0.0
    while t < t_end:
        tm = t + 0.5 * h                                  # the change held over the step at its midpoint
        if accel is None:
            d = rate * tm
        else:
            t1 = rate / accel
            d = 0.5 * accel * tm * tm if tm <= t1 else rate * tm - 0.5 * rate * t1
        tau_b = np.zeros(n)
        tau_b[joint] = d
        a.step(u, h, np.zeros(n))
        b.step(u, h, tau_b)
        t += h
        c = np.concatenate([np.abs(b.q - a.q) / dq, np.abs(b.theta_m - a.theta_m) / dth])
        out.append((t, float(c.max())))
    return np.array(out)


@pytest.mark.parametrize("accel", [None, 750.0])
def test_one_joint_change_hidden_for_the_floor_time(accel):
    cfg = _config("exo_1dof.yaml")
    q0 = math.radians(40.0)
    f = bound_floor(cfg, rate=40.0, accel=accel, q=q0)
    T = float(f.hidden_s[0])
    sep = _separation_counts(cfg, q0, 0, 40.0, accel, 1.1 * T)
    before = sep[sep[:, 0] <= 0.95 * T, 1]
    after = sep[sep[:, 0] >= 1.05 * T, 1]
    assert before.max() < 1.0            # within one count until T: the same counts for both wearers
    assert after.min() >= 1.0            # seen right after
    # ρ_floor is half the torque apart at T
    if accel is None:
        apart = 40.0 * T
    else:
        apart = 0.5 * accel * T * T if T <= 40.0 / accel else 40.0 * T - 0.5 * 40.0 ** 2 / accel
    assert f.rho[0] == pytest.approx(0.5 * apart, rel=1e-3)


def test_two_joints_each_change_hidden_for_its_floor_time():
    cfg = _config("exo_2dof.yaml")
    q0 = np.radians([30.0, 60.0])
    f = bound_floor(cfg, rate=40.0, q=q0)
    for j in range(2):
        T = float(f.hidden_s[j])
        sep = _separation_counts(cfg, q0, j, 40.0, None, 1.1 * T)
        assert sep[sep[:, 0] <= 0.95 * T, 1].max() < 1.0
        assert sep[sep[:, 0] >= 1.05 * T, 1].min() >= 1.0


def test_floor_grows_with_the_declared_rate_and_coarser_encoders():
    cfg = _config("exo_1dof.yaml")
    fine = bound_floor(cfg, rate=40.0).rho[0]
    assert bound_floor(cfg, rate=10.0).rho[0] < fine
    coarse = dataclasses.replace(cfg, hardware=dataclasses.replace(cfg.hardware, encoder_bits=16))
    assert bound_floor(coarse, rate=40.0).rho[0] > fine
    # a declared τ̈ (a band-limited wearer) can only lower it
    assert bound_floor(cfg, rate=40.0, accel=750.0).rho[0] < fine


def test_no_declared_rate_no_floor_and_bad_accel_refused():
    cfg = _config("exo_1dof.yaml")
    assert cfg.estimator.tau_h_act_rate == 0.0
    assert bound_floor(cfg) is None
    with pytest.raises(ValueError, match="accel"):
        bound_floor(cfg, rate=40.0, accel=float("nan"))
