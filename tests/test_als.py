"""Autocovariance least squares (Odelson et al. 2006) on a simulated discretised SEA."""
import numpy as np
import pytest

from sea_daemon.analysis.als import identify, innovations, model_autocov, sample_autocov, stable_gain
from sea_daemon.io.configfile import default_config_path, load_config
from sea_daemon.errors import InputError
from sea_daemon.core.linalg import discretize
from sea_daemon.core.model import SEAModel


@pytest.fixture(scope="module")
def sea_data():
    """The SEA linearised at rest, discretised at 100 Hz; known Q, and R of Sec. V-B."""
    cfg = load_config(default_config_path())
    m = SEAModel.from_config(cfg)
    x0, u0 = np.zeros(5), np.zeros(1)
    F = discretize(m.F_nom(x0, u0), m.f_nom(x0, u0), cfg.dt)[0]
    H = np.hstack([np.eye(4), np.zeros((4, 1))])
    R = np.array(cfg.estimator.R)
    Q = np.diag([1e-8, 1e-8, 1e-5, 1e-6, 1e-3])
    L = stable_gain(F, H, 10 * Q, R / 5)              # deliberately sub-optimal gain
    rng = np.random.default_rng(0)
    N = 20000
    W = rng.standard_normal((N, 5)) * np.sqrt(np.diag(Q))
    V = rng.standard_normal((N, 4)) * np.sqrt(np.diag(R))
    x, Y = np.zeros(5), np.empty((N, 4))
    for k in range(N):
        Y[k] = H @ x + V[k]
        x = F @ x + W[k]
    return F, H, L, Q, R, innovations(F, H, L, Y)


@pytest.mark.parametrize("mode", ["diag", "diag_Q_known", "full"])
def test_als_recovers_R_within_10_percent(sea_data, mode):
    F, H, L, Q, R, e = sea_data
    kw = {"diag": dict(), "diag_Q_known": dict(Q=Q), "full": dict(diag=False)}[mode]
    Qh, Rh = identify(F, np.eye(5), H, L, e, lags=10, burn_in=100, **kw)
    assert np.allclose(np.diag(Rh), np.diag(R), rtol=0.10), np.diag(Rh) / np.diag(R)
    assert np.all(np.linalg.eigvalsh(Rh) >= -1e-15) and np.all(np.linalg.eigvalsh(Qh) >= -1e-15)
    # the well-excited process noise (τ_h,act random walk) is found too
    if mode == "diag":
        assert Qh[4, 4] == pytest.approx(Q[4, 4], rel=0.3)


def test_model_autocov_matches_sample_autocov(sea_data):
    F, H, L, Q, R, e = sea_data
    Cm = model_autocov(F, np.eye(5), H, L, Q, R, 4)
    Cs = sample_autocov(e[100:], 4)
    scale = np.sqrt(np.outer(np.diag(Cm[0]), np.diag(Cm[0])))
    assert np.max(np.abs(Cs - Cm) / scale) < 0.05


def test_als_rejects_unstable_gain_and_short_data(sea_data):
    F, H, L, Q, R, e = sea_data
    with pytest.raises(InputError, match="spectral radius"):
        identify(F * 1.2, np.eye(5), H, np.zeros_like(L), e)
    with pytest.raises(InputError, match="innovations"):
        identify(F, np.eye(5), H, L, e[:20], lags=15)


def test_model_autocov_of_a_badly_scaled_filter_is_exact_and_raises_no_warning():
    """States of very different scales (encoder angles 1e-7 rad, torques N m) make the direct
    solve's Kronecker system I − Ā⊗Ā numerically singular (scipy warned, rcond ~1e-16, in the
    middle of bench generalize's output at 1 kHz) although the covariance is well determined:
    Ā = D⁻¹ M D with M well-conditioned, whose solution is D⁻¹ Y D⁻¹ for Y = M Y Mᵀ + I."""
    import warnings
    from scipy.linalg import LinAlgWarning, solve_discrete_lyapunov
    rng = np.random.default_rng(7)
    M = rng.standard_normal((5, 5))
    M *= 0.95 / np.max(np.abs(np.linalg.eigvals(M)))
    d = np.array([1e-7, 1e-5, 1e-2, 1.0, 1e2])
    A = M * d[None, :] / d[:, None]                     # D⁻¹ M D
    Q = np.eye(5) / np.outer(d, d)                      # D⁻¹ I D⁻¹
    Y = solve_discrete_lyapunov(M, np.eye(5))           # well-conditioned, no warning
    with pytest.warns(LinAlgWarning):                   # what the direct solve does on A
        solve_discrete_lyapunov(A, Q)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        C = model_autocov(A, np.eye(5), np.eye(5), np.zeros((5, 5)), Q, np.zeros((5, 5)), 2)
    P = Y / np.outer(d, d)
    np.testing.assert_allclose(C[0], P, rtol=1e-9, atol=0)     # every entry, at its own scale
    np.testing.assert_allclose(C[1], A @ P, rtol=1e-9, atol=0)
