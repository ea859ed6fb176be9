"""Simulator: true plant physics, encoders, controllers, scenarios and the simulate command."""
import dataclasses
import math
import os
import subprocess
import sys

import numpy as np
import pytest
import yaml

from sea_daemon.io.configfile import default_config_path, load_config
from _paths import repo_root
from sea_daemon.core.control import PID, MinJerkTrajectory, OpenLoopTorque, min_jerk
from sea_daemon.core.effects import make_effect
from sea_daemon.errors import ConfigError
from sea_daemon.io.logcsv import read_log
from sea_daemon.core.sim.plant import Plant
from sea_daemon.core.sim.session import run_session
from sea_daemon.runtime.sim_runner import simulate
from sea_daemon.io.scenario import load_scenario
from sea_daemon.core.sim.sensors import Encoders, load_quantum, motor_quantum

SCEN = repo_root() / "configs" / "scenarios"
ROOT = repo_root()


def nominal():
    return load_config(default_config_path())


def lossless(cfg, effects=(), gravity=True):
    """Nominal model without damping, noise or effects (energy-conserving)."""
    m = dataclasses.replace(cfg.model, D_m=np.zeros((1, 1)), D_s=np.zeros((1, 1)),
                            gravity=cfg.model.gravity if gravity else np.zeros(1), effects=tuple(effects))
    return dataclasses.replace(cfg, model=m, hardware=dataclasses.replace(cfg.hardware, torque_noise=0.0))


def quiet(cfg, effects=()):
    """Nominal model + effects, no torque noise."""
    c = cfg.with_effects(effects)
    return dataclasses.replace(c, hardware=dataclasses.replace(c.hardware, torque_noise=0.0))


# ---------------------------------------------------------------------------- plant physics

@pytest.mark.parametrize("gravity", [True, False])
def test_energy_conserved_without_damping_and_effects(gravity):
    cfg = lossless(nominal(), gravity=gravity)
    p = Plant(cfg, q0=0.0)
    M, J, K, g = 0.12, 0.08, 110.0, float(cfg.model.gravity[0])
    # initial condition away from rest; no input torque
    p._y = np.array([0.6, 0.5, 0.4, -0.3])
    p._hist_u = [np.zeros(1)]

    def energy():
        q, th, dq, dth = p._y
        # ½Mq̇² + ½Jθ̇_m² + ½K_sθ_s² + gravity potential ∫ g sin q dq
        return 0.5 * M * dq**2 + 0.5 * J * dth**2 + 0.5 * K * (q - th) ** 2 + g * (1.0 - math.cos(q))

    E0 = energy()
    Es = []
    for _ in range(300):                       # 3 s, several spring periods
        p.step(0.0, 0.01, 0.0)
        Es.append(energy())
    assert np.max(np.abs(np.array(Es) - E0)) < 1e-6 * E0
    assert np.std(p._y) > 0.01                 # it really moved


def test_damping_dissipates():
    cfg = quiet(nominal())
    p = Plant(cfg, q0=0.0)
    p._y = np.array([0.6, 0.5, 0.4, -0.3])
    p._hist_u = [np.zeros(1)]

    def energy():
        q, th, dq, dth = p._y
        return 0.5 * 0.12 * dq**2 + 0.5 * 0.08 * dth**2 + 0.5 * 110.0 * (q - th) ** 2 + 2.9 * (1.0 - math.cos(q))

    Es = [energy()]
    for _ in range(500):
        p.step(0.0, 0.01, 0.0)
        Es.append(energy())
    assert np.all(np.diff(Es) <= 1e-12)        # D_m, D_s > 0 only dissipate
    assert Es[-1] < 0.01 * Es[0]


def test_scalar_path_matches_seamodel():
    effs = [make_effect("inertia", "load", dI=0.05), make_effect("gravity", "load", a=2.2, phi=0.1),
            make_effect("human_viscoelastic", k_h=1.5, q_h0=0.6, b_h=0.3),
            make_effect("coulomb", "load", F_c=0.4), make_effect("stribeck", "load", F_s=0.3, v_s=0.07),
            make_effect("viscous", "motor", b=0.1), make_effect("cogging", A=0.05, periods=8.0, phi=0.3),
            make_effect("spring_cubic", k3=300.0), make_effect("spring_backlash", width=0.004),
            make_effect("spring_saturation", theta_max=0.03, k_stop=500.0), make_effect("torque_scale", kappa=0.9)]
    p = Plant(quiet(nominal(), effs), q0=0.3)
    m = p.model
    rng = np.random.default_rng(0)
    for _ in range(20):
        q, th, dq, dth = rng.normal(0, [0.5, 0.5, 0.3, 0.3])
        u, tau_h = rng.normal(0, 2, 2)
        ddq, ddth = p._deriv_scalar(q, th, dq, dth, u, tau_h)
        x = np.array([th, q - th, dth, dq - dth, tau_h])
        ref_th, ref_q = m.accelerations(x, np.array([u]))
        assert ddq == pytest.approx(ref_q[0], rel=1e-12, abs=1e-12)
        assert ddth == pytest.approx(ref_th[0], rel=1e-12, abs=1e-12)


def test_generic_path_matches_scalar_path():
    """The any-n numpy path (SEAModel.accelerations) integrates like the n = 1 scalar path."""
    effs = [make_effect("gravity", "load", a=2.2, phi=0.0), make_effect("coulomb", "load", F_c=0.4),
            make_effect("delay", seconds=0.02), make_effect("cogging", A=0.05, periods=8.0, phi=0.0)]
    a = Plant(quiet(nominal(), effs), q0=0.3)
    b = Plant(quiet(nominal(), effs), q0=0.3)
    b._scalar = False
    for k in range(50):
        u = a.hold_torque + math.sin(0.2 * k)
        a.step(u, 0.01, 0.1)
        b.step(u, 0.01, 0.1)
    np.testing.assert_allclose(a.state, b.state, atol=1e-10)


def test_outside_effects_on_the_scalar_path():
    """Load effects that evaluate themselves (outside the compiled vocabulary) ride the one-joint
    path in Python around the compiled accelerations, integrating like the numpy path."""
    from sea_daemon.apps.bench._family import AsymmetricFriction, PositionFriction
    effs = [make_effect("gravity", "load", a=2.2, phi=0.0), make_effect("coulomb", "load", F_c=0.3),
            PositionFriction(side="load", F0=0.2, r=0.5, phi=0.4), AsymmetricFriction(side="load", d=0.1)]
    a = Plant(quiet(nominal(), effs), q0=0.3)
    b = Plant(quiet(nominal(), effs), q0=0.3)
    assert a._scalar and len(a._py_load) == 2
    b._scalar = False
    x = np.array([0.2, 0.01, 0.3, -0.1, 0.4])
    ref_th, ref_q = a.model.accelerations(x, np.array([1.0]))
    ddq, ddth = a._deriv_scalar(0.21, 0.2, 0.2, 0.3, 1.0, 0.4)
    assert ddq == pytest.approx(ref_q[0], rel=1e-12) and ddth == pytest.approx(ref_th[0], rel=1e-12)
    for k in range(60):
        u = a.hold_torque + 2.0 * math.sin(0.2 * k)
        a.step(u, 0.01, 0.1)
        b.step(u, 0.01, 0.1)
    np.testing.assert_allclose(a.state, b.state, atol=1e-10)


def test_extra_load_torque_held_over_the_step():
    """extra_held: f(q, q̇) evaluated once per step and held, i.e. τ_h,act − f on the compiled path."""
    effs = [make_effect("gravity", "load", a=2.2, phi=0.0)]
    a = Plant(quiet(nominal(), effs), q0=0.3, extra_load_torque=lambda q, dq: np.array([0.3]), extra_held=True)
    b = Plant(quiet(nominal(), effs), q0=0.3)
    c = Plant(quiet(nominal(), effs), q0=0.3, extra_load_torque=lambda q, dq: 0.2 * dq + 0.1 * q)
    d = Plant(quiet(nominal(), effs), q0=0.3, extra_load_torque=lambda q, dq: 0.2 * dq + 0.1 * q, extra_held=True)
    assert a._scalar and d._scalar and not c._scalar
    for k in range(50):
        u = a.hold_torque + math.sin(0.2 * k)
        a.step(u, 0.001, 0.5)
        b.step(u, 0.001, 0.2)
        c.step(u, 0.001, 0.5)
        d.step(u, 0.001, 0.5)
    np.testing.assert_allclose(a._y, b._y, atol=1e-12)
    np.testing.assert_allclose(d._y, c._y, atol=2e-4)          # first order in the step


def test_two_joints_conserve_energy():
    d = {"joints": 2, "rate_hz": 100,
         "model": {"M": [0.12, 0.2], "J": [0.08, 0.1], "D_m": 0.0, "K_s": [110.0, 200.0], "D_s": 0.0,
                   "gravity": [2.9, 1.0]},
         "hardware": {"torque_noise": 0.0}}
    from sea_daemon.core.config import ModelConfig
    p = Plant(ModelConfig.from_dict(d), q0=[0.2, -0.3])
    assert p.n == 2 and not p._scalar
    p._y = np.array([0.6, 0.1, 0.5, 0.12, 0.4, -0.2, -0.3, 0.1])
    p._hist_u = [np.zeros(2)]
    M, J, K, g = np.array([0.12, 0.2]), np.array([0.08, 0.1]), np.array([110.0, 200.0]), np.array([2.9, 1.0])

    def energy():
        q, th, dq, dth = p._y[:2], p._y[2:4], p._y[4:6], p._y[6:]
        return float(np.sum(0.5 * M * dq**2 + 0.5 * J * dth**2 + 0.5 * K * (q - th) ** 2 + g * (1 - np.cos(q))))
    E0 = energy()
    for _ in range(100):
        p.step(np.zeros(2), 0.01, np.zeros(2))
    assert abs(energy() - E0) < 1e-6 * E0


def test_starts_in_static_equilibrium():
    effs = [make_effect("gravity", "load", a=2.2, phi=0.0), make_effect("human_viscoelastic", k_h=1.5, q_h0=0.6, b_h=0.3),
            make_effect("spring_backlash", width=0.002), make_effect("torque_scale", kappa=0.8)]
    p = Plant(quiet(nominal(), effs), q0=math.radians(40))
    ddq, ddth = p.accelerations()
    assert abs(ddq[0]) < 1e-9 and abs(ddth[0]) < 1e-9
    q0 = p.q[0]
    for _ in range(100):
        p.step(p.hold_torque, 0.01, 0.0)
    assert p.q[0] == pytest.approx(q0, abs=1e-9)


def test_substep_refinement_converges():
    """RK4 at the default 1 kHz agrees with 8 kHz (friction with stiction included) to 1e-4 rad."""
    effs = [make_effect("coulomb", "load", F_c=0.4), make_effect("stribeck", "load", F_s=0.3, v_s=0.07),
            make_effect("gravity", "load", a=2.2, phi=0.0)]
    out = []
    for hz in (1000.0, 8000.0):
        p = Plant(quiet(nominal(), effs), q0=0.2, substep_hz=hz)
        for k in range(200):
            p.step(p.hold_torque + 2.0 * math.sin(0.05 * k), 0.01, 0.0)
        out.append(p.state)
    np.testing.assert_allclose(out[0][:2], out[1][:2], atol=1e-4)     # angles [rad]
    np.testing.assert_allclose(out[0][2:4], out[1][2:4], atol=1e-3)   # velocities [rad/s]


def test_too_coarse_substep_rejected():
    with pytest.raises(ValueError, match="substep"):
        Plant(quiet(nominal(), [make_effect("coulomb", "load", F_c=0.4)]), substep_hz=50.0, sign_eps=1e-3)


def _response(effects, n=30, u_extra=1.0, q0=0.3):
    """q and θ_m after a torque step of u_extra on top of the holding torque."""
    p = Plant(quiet(nominal(), effects), q0=q0)
    hold = p.hold_torque.copy()
    th = []
    q = []
    for _ in range(n):
        p.step(hold + u_extra, 0.01, 0.0)
        th.append(p.theta_m[0])
        q.append(p.q[0])
    return np.array(q), np.array(th), p


def test_effects_change_behaviour_in_expected_direction():
    q_ref, th_ref, _ = _response([])

    # torque_scale 0.8: the motor's early (inertia-dominated) response to a torque step is 0.8x
    _, th, _ = _response([make_effect("torque_scale", kappa=0.8)])
    p0 = Plant(quiet(nominal()), q0=0.3)
    th_init = p0.theta_m[0]
    ratio = (th[0] - th_init) / (th_ref[0] - th_init)
    assert ratio == pytest.approx(0.8, abs=0.02)

    # delay 0.05 s: no response for 5 samples, then exactly the undelayed response shifted
    p = Plant(quiet(nominal(), [make_effect("delay", seconds=0.05)]), q0=0.3)
    th_d = []
    for _ in range(30):
        p.step(p.hold_torque + 1.0, 0.01, 0.0)
        th_d.append(p.theta_m[0])
    th_d = np.array(th_d)
    assert np.all(np.abs(th_d[:5] - th_init) < 1e-12)
    np.testing.assert_allclose(th_d[5:] - th_init, th_ref[:-5] - th_init, atol=1e-12)

    # extra load inertia slows the link's response
    q_i, _, _ = _response([make_effect("inertia", "load", dI=0.1)])
    assert abs(q_i[10] - q_i[0]) < abs(q_ref[10] - q_ref[0])

    # extra motor inertia slows the motor
    _, th_i, _ = _response([make_effect("inertia", "motor", dI=0.05)])
    assert abs(th_i[3] - th_i[0]) < abs(th_ref[3] - th_ref[0])

    # load friction (stiction): a torque step below F_c + F_s barely moves the link
    q_f, _, _ = _response([make_effect("coulomb", "load", F_c=0.6), make_effect("stribeck", "load", F_s=0.3, v_s=0.05)],
                          n=100, u_extra=0.5)
    q_n, _, _ = _response([], n=100, u_extra=0.5)
    assert abs(q_f[-1] - q_f[0]) < 0.05 * abs(q_n[-1] - q_n[0])

    # viscous load damping and human damping reduce the link velocity
    for eff in (make_effect("viscous", "load", b=2.0), make_effect("human_viscoelastic", k_h=0.0, q_h0=0.0, b_h=2.0)):
        _, _, p = _response([eff], n=10)
        _, _, p0 = _response([], n=10)
        assert abs(p.dq[0]) < abs(p0.dq[0])

    # motor viscous friction slows the motor
    _, th_v, _ = _response([make_effect("viscous", "motor", b=2.0)])
    assert abs(th_v[10] - th_v[0]) < abs(th_ref[10] - th_ref[0])

    # extra gravity/human stiffness: more holding torque at q0 = 0.3
    for eff in (make_effect("gravity", "load", a=2.2, phi=0.0), make_effect("human_viscoelastic", k_h=2.0, q_h0=0.0, b_h=0.0)):
        assert Plant(quiet(nominal(), [eff]), q0=0.3).hold_torque[0] > Plant(quiet(nominal()), q0=0.3).hold_torque[0]

    # cogging adds a position-dependent motor torque: different holding torque
    assert Plant(quiet(nominal(), [make_effect("cogging", A=0.2, periods=1.0, phi=0.0)]), q0=0.3).hold_torque[0] != \
        pytest.approx(Plant(quiet(nominal()), q0=0.3).hold_torque[0], abs=1e-3)

    # stiffening spring effects reduce the static deflection; backlash increases it
    def defl(eff):
        return Plant(quiet(nominal(), eff), q0=1.0).state[1]
    base = defl([])
    assert abs(defl([make_effect("spring_cubic", k3=5000.0)])) < abs(base)
    assert abs(defl([make_effect("spring_saturation", theta_max=0.01, k_stop=1000.0)])) < abs(base)
    assert abs(defl([make_effect("spring_backlash", width=0.01)])) == pytest.approx(abs(base) + 0.005, abs=1e-9)

    # encoder offsets shift the reading by delta (up to one count)
    for side in ("load", "motor"):
        p = Plant(quiet(nominal(), [make_effect("encoder_offset", side, delta=0.01)]), q0=0.3)
        p0 = Plant(quiet(nominal()), q0=0.3)
        i = 0 if side == "load" else 1
        d = p.measure()[i][0] - p0.measure()[i][0]
        assert d == pytest.approx(0.01, abs=2 * load_quantum())


# ---------------------------------------------------------------------------- sensors

def test_quantisation_is_exactly_19_bit():
    cfg = nominal()
    enc = Encoders(cfg.hardware)
    assert enc.q_load == 2 * math.pi / 2**19 == load_quantum(19)
    assert enc.q_motor == 2 * math.pi / (2**19 * 100) == motor_quantum(19, 100.0)
    q = np.linspace(0.1, 0.1 + 50 * enc.q_load, 2001)
    qm, _ = enc.read(q, q)
    th = np.linspace(1.3, 1.3 + 50 * enc.q_motor, 2001)
    _, thm = enc.read(th, th)
    steps_q = np.unique(np.round(np.diff(np.unique(qm)) / enc.q_load, 6))
    steps_m = np.unique(np.round(np.diff(np.unique(thm)) / enc.q_motor, 6))
    assert list(steps_q) == [1.0] and list(steps_m) == [1.0]     # one count = one quantum
    assert np.unique(qm).size in (50, 51) and np.unique(thm).size in (50, 51)
    # floor quantisation: reading <= angle < reading + quantum (up to float rounding)
    assert np.all(qm <= q + 1e-15) and np.all(q - qm < enc.q_load * (1 + 1e-9))
    assert np.all(thm <= th + 1e-15) and np.all(th - thm < enc.q_motor * (1 + 1e-6))
    # readings are integer multiples of the quantum
    np.testing.assert_allclose(qm / enc.q_load, np.round(qm / enc.q_load), atol=1e-6)


def test_raw_counts_roundtrip_multiturn():
    enc = Encoders(nominal().hardware)
    q = np.array([0.1, 1.3, 2.0])
    th = np.array([0.1, 1.3, -0.4])                 # many motor-shaft turns, also negative
    raw = enc.raw(q, th)
    assert np.all((raw["load_count"] >= 0) & (raw["load_count"] < 2**19))
    assert np.all((raw["motor_count"] >= 0) & (raw["motor_count"] < 2**19))
    assert raw["motor_turns"][1] == math.floor(1.3 * 100 / (2 * math.pi))
    qa, tha = enc.angles_from_raw(raw["load_count"], raw["motor_count"], raw["motor_turns"])
    qm, thm = enc.read(q, th)
    np.testing.assert_allclose(qa, qm, rtol=0, atol=1e-15)
    np.testing.assert_allclose(tha, thm, rtol=0, atol=1e-13)


# ---------------------------------------------------------------------------- controllers

def test_min_jerk_trajectory_hits_endpoints():
    tr = MinJerkTrajectory(math.radians(10), math.radians(75), 3.5, 6)
    assert tr.duration == pytest.approx(21.0)
    for k, target in ((0, 10), (1, 75), (2, 10), (3, 75), (6, 10)):
        q, dq, ddq = tr.reference(3.5 * k)
        assert math.degrees(q) == pytest.approx(target, abs=1e-9)
        assert dq == pytest.approx(0.0, abs=1e-9)
    assert min_jerk(0.5)[0] == pytest.approx(0.5)
    # peak velocity of a min-jerk move: 1.875 * distance / duration
    assert tr.reference(1.75)[1] == pytest.approx(1.875 * math.radians(65) / 3.5)


def test_pid_track_into_is_reference_then_step():
    """The loop's one compiled call (minimum-jerk reference and PID step) gives the commands and
    references of reference() followed by step_into(), sample by sample, with holds and cycling."""
    tr = MinJerkTrajectory(math.radians(10), math.radians(75), 0.5, 2, cyclic=True, hold_s=0.2)
    a = PID([40.0, 30.0], [5.0, 0.0], [2.0, 1.5], 0.01, torque_limit=3.0, derivative="motor")
    b = PID([40.0, 30.0], [5.0, 0.0], [2.0, 1.5], 0.01, torque_limit=3.0, derivative="motor")
    rng = np.random.default_rng(7)
    q = np.full(2, math.radians(12))
    for p in (a, b):
        p.reset(q, np.array([0.4, -0.2]))
    for k in range(400):                      # 4 s: holds, moves both ways, past the last move
        t = 0.01 * k
        q = np.full(2, tr.reference(t)[0]) + 0.02 * rng.standard_normal(2)
        th = q + 0.01 * rng.standard_normal(2)
        ua = a.track_into(tr.fields, t, q, th).copy()
        q_ref, dq_ref, _ = tr.reference(t)
        ub = b.step_into(q_ref, q, dq_ref, th)
        np.testing.assert_array_equal(ua, ub)
        assert np.all(a.ref[0] == q_ref) and np.all(a.ref[1] == dq_ref)
    assert np.any(np.abs(ua) > 0.1)


def test_pid_antiwindup_and_limit():
    pid = PID(100.0, 100.0, 0.0, 0.01, torque_limit=2.0, derivative="load")
    pid.reset(np.zeros(1), 0.0)
    for _ in range(500):                           # large error held for 5 s: saturated
        u = pid.step(1.0, 0.0)
    assert u[0] == pytest.approx(2.0)
    assert abs(pid.integral[0] * 100.0) <= 2.0 + 1e-9  # integrator did not wind up past the limit
    u = pid.step(0.0, 0.01)                      # error (almost) gone: output leaves saturation at once
    assert -2.0 < u[0] < 2.0


def test_open_loop_profile():
    ol = OpenLoopTorque(tau_comp=np.array([0.3]))
    assert ol.command(0.0)[0] == pytest.approx(0.3)
    assert ol.command(5.0)[0] == pytest.approx(4.3)
    assert ol.command(5.0, active=False)[0] == pytest.approx(0.3)


# ---------------------------------------------------------------------------- scenarios

@pytest.fixture(scope="module")
def passive_run():
    return simulate(load_scenario(SCEN / "passive.yaml"))


@pytest.fixture(scope="module")
def active_run():
    return simulate(load_scenario(SCEN / "active.yaml"))


def test_passive_scenario(passive_run):
    tr, est = passive_run.training, passive_run.estimation
    assert len(tr) == 2100 and len(est) == 2100
    assert np.all(np.diff(np.concatenate([tr.t, est.t])) > 0)
    ref = np.degrees(tr.extra["q_ref"])
    assert ref.min() == pytest.approx(10.0, abs=1e-6) and ref.max() == pytest.approx(75.0, abs=0.01)
    assert np.all(tr.tau_h_act == 0) and np.all(est.tau_h_act == 0)
    # PID tracking on measured angles: within 2 deg RMS and 3 deg max of the reference
    for log in (tr, est):
        err = np.degrees(log.extra["q_ref"] - log.extra["q_true"])
        assert np.sqrt(np.mean(err**2)) < 2.0 and np.max(np.abs(err)) < 3.0
    # the estimation phase runs the same trajectory again
    np.testing.assert_allclose(est.extra["q_ref"], tr.extra["q_ref"], atol=1e-9)
    # logged angles are quantised truth
    assert np.all(np.abs(tr.q[:, 0] - tr.extra["q_true"]) < load_quantum())
    assert np.all(np.abs(tr.theta_m[:, 0] - tr.extra["theta_m_true"]) < motor_quantum())
    # noise: applied torque differs from the logged command by ~ hardware.torque_noise
    d = tr.extra["tau_m_applied"] - tr.tau_m[:, 0]
    assert 0.015 < np.std(d) < 0.025


def test_active_scenario(active_run):
    tr, est = active_run.training, active_run.estimation
    assert len(tr) == 600 and len(est) == 2000
    assert np.all(tr.tau_h_act == 0) and np.all(tr.extra["tau_des"] == 0)
    t = est.t - est.t[0]
    tau_des = -2.0 * np.cos(2 * np.pi * 0.1 * t) + 2.0
    np.testing.assert_allclose(est.extra["tau_des"], tau_des, atol=1e-12)
    np.testing.assert_array_equal(est.tau_h_act[:, 0], -est.extra["tau_des"])
    np.testing.assert_allclose(est.tau_m[:, 0], tau_des + active_run.tau_comp[0], atol=1e-12)
    # the subject holds the arm at q0 = 10 deg
    assert np.max(np.abs(np.degrees(est.extra["q_true"]) - 10.0)) < 0.1


def test_every_effect_type_simulates():
    """A scenario whose plant has one of every effect type runs and stays finite (diagnose uses this)."""
    from sea_daemon.core.effects import EFFECT_TYPES
    vals = {"F_c": 0.3, "b": 0.2, "F_s": 0.2, "v_s": 0.07, "dI": 0.02, "a": 0.5, "phi": 0.2, "k_h": 1.2,
            "q_h0": 0.4, "b_h": 0.3, "k3": 300.0, "width": 0.004, "kappa": 0.9, "delta": 0.01,
            "seconds": 0.02, "A": 0.05, "periods": 6.0, "theta_max": 0.06, "k_stop": 300.0, "tau_0": -0.05}
    effs = [make_effect(t, cls.sides[0], **{k: vals[k] for k in cls.param_names}) for t, cls in EFFECT_TYPES.items()]
    for name in ("passive", "active"):
        sc = load_scenario(SCEN / f"{name}.yaml")
        sc = dataclasses.replace(sc, plant=dataclasses.replace(sc.plant, effects=tuple(effs)),
                                 training_samples=350, estimation_samples=350)
        r = simulate(sc)
        for log in (r.training, r.estimation):
            assert np.all(np.isfinite(log.q)) and np.all(np.isfinite(log.extra["tau_s_true"]))
        if name == "passive":   # still tracks, no spring-mode oscillation (20 ms delay included)
            err = np.degrees(r.estimation.extra["q_ref"] - r.estimation.extra["q_true"])
            assert np.max(np.abs(err)) < 5.0
            ts = r.estimation.extra["tau_s_true"]
            assert np.sqrt(np.mean(np.diff(ts, 2) ** 2)) < 0.2


def test_deterministic_under_seed():
    sc = load_scenario(SCEN / "active.yaml")
    sc = dataclasses.replace(sc, training_samples=50, estimation_samples=50)
    a, b, c = simulate(sc, seed=7), simulate(sc, seed=7), simulate(sc, seed=8)
    np.testing.assert_array_equal(a.estimation.theta_m, b.estimation.theta_m)
    assert not np.array_equal(a.estimation.extra["tau_m_applied"], c.estimation.extra["tau_m_applied"])


# ---------------------------------------------------------------------------- CLI

def _cli(*args, cwd=None):
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.run([sys.executable, "-m", "sea_daemon", "simulate", *args], capture_output=True,
                          text=True, env=env, cwd=cwd)


def test_cli_simulate_writes_both_logs(tmp_path):
    sc = yaml.safe_load((SCEN / "active.yaml").read_text())
    sc["model"] = str(ROOT / "configs" / "exo_1dof.yaml")
    sc["phases"] = {"training": {"samples": 20}, "estimation": {"samples": 30}}
    f = tmp_path / "s.yaml"
    f.write_text(yaml.safe_dump(sc))
    r = _cli(str(f), "--out", str(tmp_path / "p.csv"))
    assert r.returncode == 0, r.stderr
    assert "p.train.csv" in r.stdout
    est = read_log(tmp_path / "p.csv")
    tr = read_log(tmp_path / "p.train.csv")
    assert len(est) == 30 and len(tr) == 20 and est.tau_h_act is not None
    assert est.t[0] == pytest.approx(tr.t[-1] + 0.01)


def _bad_cases():
    base = yaml.safe_load((SCEN / "passive.yaml").read_text())
    base["model"] = str(ROOT / "configs" / "exo_1dof.yaml")

    def mod(fn):
        d = yaml.safe_load(yaml.safe_dump(base))
        fn(d)
        return d
    return [
        ("unknown key", mod(lambda d: d.update(colour="red")), "colour"),
        ("missing key", mod(lambda d: d.pop("phases")), "phases"),
        ("bad value", mod(lambda d: d["phases"]["training"].update(samples=-5)), "phases.training.samples"),
        ("bad human", mod(lambda d: d.update(human="sleepy")), "human"),
        ("negative rate", mod(lambda d: d.update(tau_h_act_rate=-1.0)), "tau_h_act_rate"),
        ("unknown effect", mod(lambda d: d["plant"]["effects"].append({"type": "magic", "side": "load"})),
         "plant.effects[7].type"),
        ("bad controller", mod(lambda d: d["controller"].update(type="mpc")), "controller.type"),
        ("missing model file", mod(lambda d: d.update(model="nope/missing.yaml")), "model"),
        ("not yaml", "a: [1, 2\n", "line"),
    ]


@pytest.mark.parametrize("name, content, key", _bad_cases(), ids=[c[0] for c in _bad_cases()])
def test_cli_bad_scenario_exit_2_one_line(tmp_path, capsys, name, content, key):
    from sea_daemon.apps.cli import main
    f = tmp_path / "bad.yaml"
    f.write_text(content if isinstance(content, str) else yaml.safe_dump(content))
    if name in ("unknown key", "unknown effect"):     # a real process for two of them
        r = _cli(str(f), "--out", str(tmp_path / "o.csv"))
        code, err = r.returncode, r.stderr
    else:                                             # the same entry point, in-process (fast)
        code = main(["simulate", str(f), "--out", str(tmp_path / "o.csv")])
        err = capsys.readouterr().err
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err
    assert key in lines[0] and "bad.yaml" in lines[0]
    assert not (tmp_path / "o.csv").exists()


def test_cli_bad_out_dir_and_seed(tmp_path, capsys):
    from sea_daemon.apps.cli import main
    assert main(["simulate", str(SCEN / "active.yaml"), "--out", str(tmp_path / "no" / "o.csv")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--out" in err[0]
    assert main(["simulate", str(SCEN / "active.yaml"), "--out", str(tmp_path / "o.csv"), "--seed", "-1"]) == 2
    assert "--seed" in capsys.readouterr().err


def test_cli_missing_scenario_file(tmp_path):
    r = _cli(str(tmp_path / "none.yaml"), "--out", str(tmp_path / "o.csv"))
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and "none.yaml" in r.stderr


def test_scenario_errors_name_allowed_values(tmp_path):
    d = yaml.safe_load((SCEN / "active.yaml").read_text())
    d["model"] = str(ROOT / "configs" / "exo_1dof.yaml")
    d["controller"]["type"] = "pid"
    f = tmp_path / "x.yaml"
    f.write_text(yaml.safe_dump(d))
    with pytest.raises(ConfigError) as ei:
        load_scenario(f)
    assert ei.value.key.startswith("controller")
    d = yaml.safe_load((SCEN / "passive.yaml").read_text())
    d["model"] = str(ROOT / "configs" / "exo_1dof.yaml")
    d["human"] = "resist"
    f.write_text(yaml.safe_dump(d))
    with pytest.raises(ConfigError, match="allowed"):
        load_scenario(f)


def test_scenario_declares_the_human_torque_rate_to_the_bound():
    # active.yaml declares |dτ_h,act/dt| <= 2 pi f A of its cosine; passive.yaml declares nothing
    from sea_daemon.io.configfile import load_config
    act, pas = load_scenario(SCEN / "active.yaml"), load_scenario(SCEN / "passive.yaml")
    c = act.controller
    assert act.tau_h_act_rate == pytest.approx(2 * np.pi * c.frequency_hz * c.amplitude, rel=0.01)
    settings = load_config(ROOT / "configs" / "exo_1dof_sim.yaml")
    assert act.declared(settings).estimator.tau_h_act_rate == act.tau_h_act_rate
    assert pas.tau_h_act_rate is None and pas.declared(settings) is settings


def test_simulate_and_run_session_are_the_same_samples():
    """The daemon's loop over SimHardware (``simulate``) and the core's ``run_session`` run the
    same per-sample steps: the passive scenario's training phase, as a session of its plant,
    reference and gains, gives the same numbers."""
    sc = load_scenario(repo_root() / "configs" / "scenarios" / "passive.yaml")
    train = simulate(sc).training
    tr = sc.controller.trajectory
    ref = MinJerkTrajectory(math.radians(tr.q_start_deg), math.radians(tr.q_end_deg), tr.move_s, tr.moves,
                            cyclic=True, hold_s=tr.hold_s)
    log = run_session(sc.true_config(), len(train) * sc.nominal.dt, reference=ref, seed=sc.seed, gains=sc.controller,
                      substep_hz=sc.plant.substep_hz, sign_eps=sc.plant.sign_eps, torque_noise=sc.plant.torque_noise)
    assert len(log) == len(train)
    for k in ("t", "q", "theta_m", "tau_m", "tau_h_act"):
        assert np.array_equal(getattr(log, k), getattr(train, k)), k
    for k, v in log.extra.items():
        assert np.array_equal(v, train.extra[k]), k
