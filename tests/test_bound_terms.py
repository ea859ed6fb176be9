"""The bound's terms (core/bounds/terms.py): ρ_k unchanged, the terms add up to the set of means'
τ_h,act half-width."""
import dataclasses

import numpy as np

from sea_daemon.core.bounds.akf_bound import AKFTheoremBound
from sea_daemon.core.bounds.terms import TERMS, TermsRecorder
from sea_daemon.core.config import ModelConfig
from sea_daemon.core.estimators import AKF
from sea_daemon.core.model import SEAModel

from synth import simulate


def _cfg():
    """100 Hz, gravity, declared Coulomb + Stribeck load friction, a declared human-torque rate."""
    cfg = ModelConfig.from_dict({"joints": 1, "rate_hz": 100, "model": {
        "M": 0.12, "J": 0.08, "D_m": 0.6, "K_s": 110.0, "D_s": 0.25, "gravity": 1.5, "effects": [
            {"type": "coulomb", "side": "load", "F_c": 0.4},
            {"type": "stribeck", "side": "load", "F_s": 0.3, "v_s": 0.05}]},
        "estimator": {"sign_eps": 0.005, "tau_h_act_rate": 3.0}})
    return dataclasses.replace(cfg, estimator=dataclasses.replace(cfg.estimator, init_after_kinematics=False))


def _run(akf, log):
    akf.reset(log.q[0], log.theta_m[0], log.tau_m[0])
    return np.array([akf.update(log.q[k], log.theta_m[k], log.tau_m[k], log.t[k] - log.t[k - 1]).tau_h_act_bound[0]
                     for k in range(1, len(log))])


def test_terms_add_up_to_the_set_of_means_and_leave_rho_unchanged():
    """Without order reduction the zonotope's τ half-width is the sum of its generators' |e_τᵀg|,
    so the per-input zonotopes of TermShadow add up to the bound's h exactly; the recorder
    publishes the Python step's ρ_k; the declared rate and friction both show, no GP term."""
    cfg = _cfg()
    log = simulate(SEAModel.from_config(cfg), T=1.5, tau_h=lambda t: np.array([0.4 * np.sin(2 * np.pi * t)]), seed=1)
    ref = AKF(cfg)
    ref.bound = AKFTheoremBound(ref, compiled=False)
    ref.bound.sm.max_generators = 10 ** 6
    # the measurement's strips cut the set (not a sum of the inputs' sets): off in both here
    ref.bound.friction.cut = lambda *a: None
    rho_ref = _run(ref, log)
    akf = AKF(cfg, bound=TermsRecorder)
    akf.bound.bound.sm.max_generators = akf.bound.shadow.max_generators = 10 ** 6
    akf.bound.bound.friction.cut = lambda *a: None
    rho = _run(akf, log)
    np.testing.assert_allclose(rho, rho_ref, rtol=1e-12, atol=1e-15)
    R = np.array(akf.bound.rows_)
    cols = TermsRecorder.COLUMNS
    h, terms = R[:, cols.index("h")], R[:, [cols.index(t) for t in TERMS]]
    np.testing.assert_allclose(terms.sum(axis=1), h, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(R[:, 0], rho)
    assert np.all(terms[:, TERMS.index("gp")] == 0.0)
    assert np.all(terms[5:, TERMS.index("rate")] > 0.0) and np.any(terms[:, TERMS.index("friction")] > 0.0)
    tab = akf.bound.table()
    assert abs(tab["gaussian"] - (tab["rho"] - tab["h"])) < 1e-12 and tab["sigma_g"] > 0.0


def test_terms_with_the_order_reduction_and_the_strips_hold_the_bound():
    """With the bound's order reduction (each input's zonotope reduced apart) and the measurement's
    strips the terms hold h: their sum is at least 0.9 h on average, and ``cut`` is h minus it."""
    cfg = _cfg()
    log = simulate(SEAModel.from_config(cfg), T=2.0, tau_h=lambda t: np.array([0.4 * np.sin(2 * np.pi * t)]), seed=1)
    akf = AKF(cfg, bound=TermsRecorder)
    _run(akf, log)
    R = np.array(akf.bound.rows_)
    cols = TermsRecorder.COLUMNS
    s = R[:, [cols.index(t) for t in TERMS]].sum(axis=1)
    assert s.mean() >= 0.9 * R[:, 1].mean()
    np.testing.assert_allclose(R[:, cols.index("cut")], R[:, 1] - s, atol=1e-12)


def test_bound_terms_benchmark_refuses_bad_options(tmp_path, capsys):
    """Exit 2 with one line naming the option, the value and what is allowed, before any simulation."""
    import benchmarks.bound_terms as bt
    from benchmarks._cli import main
    for argv, flag in ((["--sessions", "bogus"], "--sessions bogus"), (["--rate", "0"], "--rate 0"),
                       (["--cal-s", "-1"], "--cal-s -1"), (["--q-tau", "0"], "--q-tau 0")):
        assert main(bt, argv + ["--cache", str(tmp_path)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and flag in err[0] and "allowed" in err[0]
    assert not any(tmp_path.iterdir())
