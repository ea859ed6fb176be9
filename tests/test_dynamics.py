"""The dynamics kernels (sea_daemon.core.dynamics) against independent references: values
computed by hand from the equations of the paper, finite differences for the Jacobians, and
the identities between the forward and the inverse dynamics."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from sea_daemon.core import dynamics as dyn
from sea_daemon.core.config import SEAParams
from sea_daemon.core.effects import make_effect
from sea_daemon.core.model import SEAModel
from sea_daemon.core.model_core import ModelTables


def _effects(n):
    eff = []
    for j in range(n):
        eff += [make_effect("coulomb", "load", j, F_c=0.3), make_effect("stribeck", "load", j, F_s=0.2, v_s=0.05),
                make_effect("gravity", "load", j, a=1.2, phi=0.1),
                make_effect("human_viscoelastic", "load", j, k_h=2.0, q_h0=1.0, b_h=0.3),
                make_effect("viscous", "motor", j, b=0.1), make_effect("coulomb", "motor", j, F_c=0.05),
                make_effect("cogging", "motor", j, A=0.02, periods=3.0, phi=0.2),
                make_effect("spring_cubic", "spring", j, k3=100.0),
                make_effect("spring_saturation", "spring", j, theta_max=0.03, k_stop=300.0),
                make_effect("spring_backlash", "spring", j, width=0.002),
                make_effect("torque_scale", "motor", j, kappa=0.9), make_effect("inertia", "load", j, dI=0.03)]
    return tuple(eff)


def _model(n, effects=True):
    I = np.eye(n)
    p = SEAParams(M=I * 0.12 + 0.01 * (1 - I), J=I * 0.08, D_m=I * 0.6, K_s=I * 110 + 5 * (1 - I), D_s=I * 0.25,
                  gravity=np.full(n, 2.9), effects=_effects(n) if effects else ())
    return SEAModel(p, sign_eps=0.01)


def _fd(f, x, h=1e-7):
    f0 = f(x)
    J = np.zeros((f0.size, x.size))
    for i in range(x.size):
        e = np.zeros(x.size)
        e[i] = h
        J[:, i] = (f(x + e) - f(x - e)) / (2 * h)
    return J


def _state(rng, n):
    # deflections beyond the backlash band and the stop's smoothing (smooth points for FD)
    return rng.normal(size=5 * n) * np.repeat([0.5, 0.04, 0.5, 0.2, 1.0], n)


def test_one_joint_by_hand():
    """f_nom of one joint without effects, from eq:thetadd and eq:xsdd written out."""
    m = _model(1, effects=False)
    th_m, th_s, dth_m, dth_s, tau_h, u = 0.3, 0.02, -0.4, 0.1, 0.7, 1.5
    x = np.array([th_m, th_s, dth_m, dth_s, tau_h])
    tau_s = 110.0 * th_s + 0.25 * dth_s
    ddth_m = (u + tau_s - 0.6 * dth_m) / 0.08
    ddq = (tau_h - 2.9 * math.sin(th_m + th_s) - tau_s) / 0.12
    xd = m.f_nom(x, np.array([u]))
    np.testing.assert_allclose(xd, [dth_m, dth_s, ddth_m, ddq - ddth_m, 0.0], rtol=1e-13)
    assert m.spring_torque(np.array([th_s]), np.array([dth_s]))[0] == pytest.approx(tau_s, rel=1e-15)
    # eq:loadsidewmotor at the accelerations the forward model gives: f = 0 (τ_h,act = 0)
    f = m.residual_from_kinematics(np.array([th_m + th_s]), np.array([dth_m + dth_s]), np.array([ddq]),
                                   np.array([th_m]), np.array([dth_m]), np.array([ddth_m]), np.array([u]),
                                   tau_h_act=np.array([tau_h]))
    assert abs(f[0]) < 1e-12


def test_spring_with_backlash_and_effects_by_hand():
    m = _model(1)
    th_s, dth_s = 0.05, 0.3
    g = th_s - 0.001                                     # dead band ±0.001

    def sat(t):                                          # the stop, softplus of width 0.002
        return 300.0 * (0.002 * math.log1p(math.exp((t - 0.03) / 0.002))
                        - 0.002 * math.log1p(math.exp((-t - 0.03) / 0.002)))
    ref = 110.0 * g + 0.25 * dth_s + 100.0 * th_s ** 3 + sat(th_s)
    assert m.spring_torque(np.array([th_s]), np.array([dth_s]))[0] == pytest.approx(ref, rel=1e-12)
    # inside the band only the damping and the effects act
    assert m.spring_torque(np.array([0.0005]), np.array([0.0]))[0] == pytest.approx(
        100.0 * 0.0005 ** 3 + sat(0.0005), rel=1e-12)


@pytest.mark.parametrize("n", [1, 2])
def test_jacobians_are_the_finite_differences(n):
    m = _model(n)
    rng = np.random.default_rng(n)
    for _ in range(20):
        x = _state(rng, n)
        if np.any(np.abs(np.abs(x[n:2 * n]) - 0.001) < 1e-4):
            continue                                      # the dead band's kink
        u = rng.normal(size=n)
        np.testing.assert_allclose(m.F_nom(x, u), _fd(lambda y: m.f_nom(y, u), x), rtol=1e-5, atol=1e-4)
        ths = x[n:2 * n]
        np.testing.assert_allclose(m.spring_torque_jac(ths),
                                   _fd(lambda y: m.spring_torque(y, np.zeros(n)), ths), rtol=1e-6, atol=1e-5)
        B = _fd(lambda v: m.f_nom(x, v), u)
        np.testing.assert_allclose(m.B_nom(), B, rtol=1e-6, atol=1e-7)


@pytest.mark.parametrize("n", [1, 2])
def test_inverse_dynamics_inverts_the_forward_dynamics(n):
    """residual (eq:loadsidewmotor) at the accelerations of f_nom with a residual load torque f
    (eq:unknwn_load) returns that f."""
    m = _model(n)
    rng = np.random.default_rng(10 + n)
    for _ in range(20):
        x = _state(rng, n)
        u = rng.normal(size=n)
        f = rng.normal(size=n)
        ddth_m, ddq = m.accelerations(x, u, f)
        q, dq = x[:n] + x[n:2 * n], x[2 * n:3 * n] + x[3 * n:4 * n]
        r = m.residual_from_kinematics(q, dq, ddq, x[:n], x[2 * n:3 * n], ddth_m, u, tau_h_act=x[4 * n:])
        np.testing.assert_allclose(r, f, rtol=1e-9, atol=1e-9)
        out = np.empty(n)
        dyn.residual(m.kernel, q, dq, ddq, x[:n], x[2 * n:3 * n], ddth_m, u, out)
        np.testing.assert_allclose(out + x[4 * n:], f, rtol=1e-9, atol=1e-9)


def test_one_joint_form_equals_the_general_form():
    m = _model(1)
    rng = np.random.default_rng(3)
    for _ in range(30):
        x = _state(rng, 1)
        u = float(rng.normal())
        th_m, th_s, dth_m, dth_s, tau_h = x
        ddq, ddth = dyn.accel_1(m.kernel, th_m + th_s, th_m, dth_m + dth_s, dth_m, u, tau_h)
        ref_th, ref_q = m.accelerations(x, np.array([u]))
        assert ddq == pytest.approx(ref_q[0], rel=1e-12, abs=1e-12)
        assert ddth == pytest.approx(ref_th[0], rel=1e-12, abs=1e-12)


@pytest.mark.parametrize("n", [1, 2])
def test_affine_form_equals_the_general_form(n):
    """nominal_affine / residual_affine (the filter's path without declared effects) equal
    f_nom, F_nom and the eq:loadsidewmotor residual."""
    m = _model(n, effects=False)
    d = 5 * n
    A_lin = m.F_nom(np.zeros(d), np.zeros(n))
    MinvG = m.Minv * m.gravity[None, :]
    A_lin[3 * n:4 * n, :n] += MinvG
    A_lin[3 * n:4 * n, n:2 * n] += MinvG
    rng = np.random.default_rng(5)
    for _ in range(20):
        x, u = _state(rng, n), rng.normal(size=n)
        A, xd = np.zeros((d, d)), np.zeros(d)
        dyn.nominal_affine(x, u, A_lin, m.B_nom(), MinvG, A, xd)
        np.testing.assert_allclose(xd, m.f_nom(x, u), rtol=1e-12, atol=1e-10)
        np.testing.assert_allclose(A, m.F_nom(x, u), rtol=1e-12, atol=1e-10)
        k = [rng.normal(size=n) for _ in range(7)]
        f = np.empty(n)
        dyn.residual_affine(k[0], k[1], k[2], k[4], k[5], k[6], m.M, m.gravity, m.J, m.D_m, f)
        np.testing.assert_allclose(f, m.residual_from_kinematics(*k), rtol=1e-12, atol=1e-10)


def test_spring_torque_over_a_log():
    m = _model(2)
    rng = np.random.default_rng(7)
    ths, dths = rng.normal(size=(40, 2)) * 0.04, rng.normal(size=(40, 2))
    out = np.empty((40, 2))
    dyn.spring_torque_many(m.kernel, ths, dths, out)
    for k in range(40):
        np.testing.assert_array_equal(out[k], m.spring_torque(ths[k], dths[k]))


def test_effects_outside_the_vocabulary_enter_as_a_load_torque():
    from sea_daemon.apps.bench._family import PositionFriction
    pf = PositionFriction(side="load", F0=0.2, r=0.5, phi=0.4)
    I = np.eye(1)
    base = SEAParams(M=I * 0.12, J=I * 0.08, D_m=I * 0.6, K_s=I * 110, D_s=I * 0.25, gravity=np.full(1, 2.9),
                     effects=())
    m0 = SEAModel(base)
    m = SEAModel(dataclasses.replace(base, effects=(pf,)))
    x, u = np.array([0.2, 0.01, 0.3, -0.1, 0.4]), np.array([1.0])
    q, dq = 0.21, 0.2
    f = np.array([pf.torque(q, dq, 0.0)])
    np.testing.assert_allclose(m.f_nom(x, u), m0.f_nom(x, u, f), rtol=1e-14)
    np.testing.assert_allclose(m.F_nom(x, u), _fd(lambda y: m.f_nom(y, u), x), rtol=1e-5, atol=1e-4)


@pytest.mark.parametrize("n", [1, 2])
def test_model_tables_for_the_filter(n):
    """ModelTables (the filter with declared effects): f_nom and F_nom in place, the training
    residual, and the linearisation-error box = the maximum over the sampled points."""
    m = _model(n)
    t = ModelTables(m)
    rng = np.random.default_rng(n)
    for _ in range(20):
        x, u = _state(rng, n), rng.normal(size=n)
        A, xd = np.zeros((5 * n, 5 * n)), np.zeros(5 * n)
        t.f_and_F(x, u, A, xd)
        np.testing.assert_array_equal(A, m.F_nom(x, u))
        np.testing.assert_array_equal(xd, m.f_nom(x, u))
        k = [rng.normal(size=n) for _ in range(7)]
        out = np.zeros(n)
        t.residual(*k, out)
        np.testing.assert_array_equal(out, m.residual_from_kinematics(*k))
        X = x + rng.normal(size=(7, 5 * n)) * 0.01
        b = t.lin_error_box(X, u, x, A)
        ref = np.max([np.abs(m.f_nom(xx, u) - xd - A @ (xx - x)) for xx in X], axis=0)
        assert np.allclose(b, ref, rtol=1e-9, atol=1e-12)
