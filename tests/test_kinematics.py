"""Causal differentiator: stated delays, exactness on polynomials; offline smoother."""
import numpy as np
import pytest

from sea_daemon.core.kinematics import CausalDifferentiator, smooth_derivatives

DT = 0.01


def run(d, x):
    out = np.array([np.concatenate(d.update(np.atleast_1d(v))) for v in x])
    return out[:, 0], out[:, 1], out[:, 2]


@pytest.mark.parametrize("W", [1, 3, 5, 8])
def test_ma_delay_is_analytic(W):
    d = CausalDifferentiator(DT, W, method="ma")
    ang, vel, acc = d.delay_samples()
    assert ang == pytest.approx(0.0, abs=1e-12)
    assert vel == pytest.approx(W / 2)
    assert acc == pytest.approx((W + 1) / 2)


@pytest.mark.parametrize("W", [3, 5, 9])
def test_ma_velocity_on_sine_lags_by_stated_delay(W):
    """MA of differences is linear-phase: on sin(ωt) it returns exactly
    ω·sinc·cos(ω(t − τ)) with τ = W/2 samples, and is far from the unshifted derivative."""
    w = 2 * np.pi * 1.5
    t = np.arange(400) * DT
    d = CausalDifferentiator(DT, W, method="ma")
    _, vel, acc = run(d, np.sin(w * t))
    tau = d.delay_samples()[1] * DT
    gain = np.sin(w * W * DT / 2) / (W * DT / 2)       # |H| of the averaged difference
    k = slice(W + 2, None)
    np.testing.assert_allclose(vel[k], gain * np.cos(w * (t[k] - tau)), atol=1e-9)
    err_unshifted = np.max(np.abs(vel[k] - gain * np.cos(w * t[k])))
    assert err_unshifted > 0.5 * gain * w * tau           # the lag is real and visible
    # acceleration: lags by (W+1)/2 samples
    tau_a = d.delay_samples()[2] * DT
    ga = gain * np.sin(w * DT / 2) / (DT / 2)
    np.testing.assert_allclose(acc[k], -ga * np.sin(w * (t[k] - tau_a)), atol=1e-6)


def test_ma_ramp_exact_and_primed_start():
    d = CausalDifferentiator(DT, 5, method="ma")
    t = np.arange(50) * DT
    ang, vel, acc = run(d, 0.3 + 2.0 * t)
    assert vel[0] == 0.0 and abs(acc[0]) < 1e-9          # primed with the first sample
    np.testing.assert_allclose(vel[6:], 2.0, rtol=1e-9)
    np.testing.assert_allclose(acc[7:], 0.0, atol=1e-8)
    np.testing.assert_allclose(ang, 0.3 + 2.0 * t)


@pytest.mark.parametrize("W,deg", [(5, 2), (7, 2), (7, 3)])
def test_savgol_is_delay_free_on_polynomials(W, deg):
    d = CausalDifferentiator(DT, W, method="savgol", degree=deg)
    dl = d.delay_samples()
    assert dl[0] == pytest.approx(0, abs=1e-9) and dl[1] == pytest.approx(0, abs=1e-9)
    # the top derivative is the fit's centred coefficient
    assert dl[2] == pytest.approx((W - 1) / 2 if deg == 2 else 0.0, abs=1e-9)
    t = np.arange(60) * DT
    a, b, c = 0.1, -0.7, 3.0
    ang, vel, acc = run(d, a + b * t + c * t**2)
    k = slice(W, None)
    np.testing.assert_allclose(ang[k], (a + b * t + c * t**2)[k], atol=1e-12)
    np.testing.assert_allclose(vel[k], (b + 2 * c * t)[k], atol=1e-9)
    np.testing.assert_allclose(acc[k], 2 * c, atol=1e-6)


def test_multichannel_and_noise_gain():
    d = CausalDifferentiator(DT, 5, n=2, method="ma")
    t = np.arange(30) * DT
    for tk in t:
        _, vel, _ = d.update(np.array([tk, -3 * tk]))
    np.testing.assert_allclose(vel, [1.0, -3.0])
    # noise gain: ‖c‖ matches the empirical std on white noise
    rng = np.random.default_rng(0)
    d = CausalDifferentiator(DT, 5, method="ma")
    _, vel, _ = run(d, rng.normal(0, 1e-4, 20000))
    assert np.std(vel[10:]) == pytest.approx(1e-4 * d.noise_gain()[1], rel=0.05)


def test_bad_arguments():
    with pytest.raises(ValueError):
        CausalDifferentiator(0.0, 5)
    with pytest.raises(ValueError):
        CausalDifferentiator(DT, 5, method="kalman")
    with pytest.raises(ValueError):
        CausalDifferentiator(DT, 3, method="savgol", degree=3)


def test_smooth_derivatives_zero_phase():
    t = np.arange(500) * DT
    w = 2 * np.pi * 0.7
    x = np.column_stack([np.sin(w * t), 0.5 * np.cos(w * t)])
    ang, vel, acc = smooth_derivatives(t, x)
    k = slice(20, -20)
    np.testing.assert_allclose(vel[k, 0], w * np.cos(w * t[k]), atol=1e-3)
    np.testing.assert_allclose(acc[k, 1], -0.5 * w**2 * np.cos(w * t[k]), atol=0.01 * 0.5 * w**2)
    np.testing.assert_allclose(ang[k], x[k], atol=1e-4)
    a1, v1, _ = smooth_derivatives(t[:4], np.sin(w * t[:4]))
    assert v1.shape == (4,)


def test_public_ring_state_and_forget():
    """The ring's public state is what :func:`fir_push` reads and writes; ``forget`` makes the
    next update prime the buffer again (velocity 0)."""
    from sea_daemon.core.kinematics import fir_push
    d = CausalDifferentiator(DT, 5, n=2)
    for k in range(10):
        d.update(np.array([k * DT, -k * DT]))
    assert d.primed and d.buf.shape == (2 * d.L, 2) and d.out.shape == (3, 2)
    buf, head, out = d.buf.copy(), d.head, d.out.copy()
    a = np.array([10 * DT, -10 * DT])
    h = fir_push(buf, head, d.C, a, out)
    ang, vel, acc = d.update(a)
    assert h == d.head and np.array_equal(buf, d.buf) and np.array_equal(out, d.out)
    np.testing.assert_allclose(vel, [1.0, -1.0])
    d.forget()
    assert not d.primed
    _, vel, _ = d.update(np.array([5.0, 5.0]))
    assert d.primed and np.array_equal(vel, [0.0, 0.0])
