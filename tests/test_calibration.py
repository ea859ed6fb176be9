"""Issue 12: calibrate once from a passive log, hold on other sessions.

Behaviour checked: the compiled effect path equals the model; the excitation covers the
working range and the coverage map flags z outside it; the noise identification recovers the
simulator's torque noise and velocity error; the variance-weighted residual returns to the
physics off its data; bounded P and typed faults; the whole calibration on a simulated plant
(diagnose's effects, GP no worse than the physics alone on unlike sessions, given values kept);
``fit`` / ``replay --model`` / ``replay --train``.
"""
import dataclasses
import json
import math

import numpy as np
import pytest

from sea_daemon.apps import cli
from sea_daemon.analysis.noise import choose_kinematics, measurement_noise, motor_torque_noise
from sea_daemon.apps.calibration.pipeline import CalibrationOptions, HumanSpec, calibrate, decimate, given_keys, with_R
from sea_daemon.core.config import SEAParams
from sea_daemon.core.effects import make_effect
from sea_daemon.core.estimators import akf_core
from sea_daemon.core.estimators.akf import AKF
from sea_daemon.core.excitation import Coverage, WorkingRange, excitation, paper_moves
from sea_daemon.core.log import MeasuredLog
from sea_daemon.core.model import SEAModel
from sea_daemon.core.replay import replay
from sea_daemon.core.sim.session import BandLimitedTorque, run_session
from sea_daemon.errors import EstimatorFault
from sea_daemon.io.configfile import load_config, save_config
from _paths import repo_root
from sea_daemon.io.logcsv import write_log

NOMINAL = repo_root() / "configs" / "exo_1dof_robot.yaml"
HIDDEN = [make_effect("inertia", "load", dI=0.04), make_effect("gravity", "load", a=1.8, phi=0.05),
          make_effect("human_viscoelastic", "load", k_h=1.5, q_h0=1.2, b_h=0.25),
          make_effect("coulomb", "load", F_c=0.3), make_effect("viscous", "load", b=0.03)]


def _rmse(log, est):
    r = replay(log, est)
    return float(np.sqrt(np.mean((r.tau_h_act_hat - log.tau_h_act) ** 2)))


# ------------------------------------------------------------------ excitation and coverage


def test_excitation_spreads_over_the_working_range_and_coverage_flags_outside():
    wr = WorkingRange(math.radians(5), math.radians(100), v_max=1.5, a_max=12.0)
    ex = excitation(wr, 60.0, seed=3)
    t = np.arange(0, ex.duration, 0.01)
    z = np.array([ex.reference(tt) for tt in t])
    assert z[:, 0].min() >= wr.q_min - 1e-9 and z[:, 0].max() <= wr.q_max + 1e-9
    assert np.ptp(z[:, 0]) > 0.95 * wr.width                    # both ends reached
    peaks = []                                                   # peak speed per move: spread, not one
    for i in range(len(ex.targets)):
        sl = (t >= ex._t[i]) & (t < ex._t[i] + ex.durations[i])
        peaks.append(np.abs(z[sl, 1]).max())
    assert np.max(np.abs(z[:, 1])) <= wr.v_max * 1.001 and np.max(np.abs(z[:, 2])) <= wr.a_max * 1.001
    assert np.percentile(peaks, 90) > 2.0 * np.percentile(peaks, 10)
    assert excitation(wr, 60.0, seed=3) == ex and excitation(wr, 60.0, seed=4) != ex
    cov = Coverage(wr)
    cov.add(z)
    rep = cov.report()
    one = Coverage(wr)                                            # the paper's one repeated move
    pm = paper_moves(math.radians(10), math.radians(75), 3.5, 17)
    one.add(np.array([pm.reference(tt) for tt in t]))
    assert rep["q_qdot_share"] > 1.5 * one.report()["q_qdot_share"]
    assert cov.covered(z[len(z) // 2]) and not cov.covered([wr.q_max + 0.3, 0.0, 0.0])
    assert Coverage.from_dict(cov.to_dict()).report() == rep


# ------------------------------------------------------------------ noise identification


@pytest.fixture(scope="module")
def plant():
    nom = load_config(NOMINAL)
    return nom, nom.with_effects(HIDDEN)


@pytest.fixture(scope="module")
def cal_log(plant):
    nom, true = plant
    wr = WorkingRange(math.radians(5), math.radians(95), 1.4, 12.0)
    return run_session(true, 60.0, reference=excitation(wr, 60.0, seed=1), seed=11)


def test_motor_torque_noise_is_recovered_at_100_hz_and_1_khz(plant):
    nom, true = plant
    for rate in (100.0, 1000.0):
        tc = dataclasses.replace(true, rate_hz=rate)
        log = run_session(tc, 12.0, reference=paper_moves(math.radians(10), math.radians(75), 2.0, 10), seed=3)
        cfg = dataclasses.replace(tc.with_effects(HIDDEN), kinematics=choose_kinematics(rate))
        s, _ = motor_torque_noise(log, cfg)
        assert abs(s / tc.hardware.torque_noise - 1) < 0.15, (rate, s)


def test_measured_velocity_noise_matches_the_error_against_the_truth(plant, cal_log):
    nom, _ = plant
    cfg = dataclasses.replace(nom, kinematics=choose_kinematics(nom.rate_hz))
    R, info = measurement_noise(cal_log, cfg)
    from sea_daemon.analysis.noise import causal_measurements
    y, _ = causal_measurements(cal_log, cfg)
    ex = cal_log.extra
    v_true = np.column_stack([ex["dtheta_m_true"], ex["dq_true"] - ex["dtheta_m_true"]])
    err = np.var((y[:, 2:] - v_true)[50:], axis=0)
    ratio = np.diag(R)[2:] / err
    assert np.all((ratio > 0.6) & (ratio < 1.6)), ratio
    q_var = (2 * np.pi / 2 ** 19) ** 2 / 12
    assert R[1, 1] >= q_var                                      # the load encoder's quantisation is a floor


def test_decimate_keeps_the_mean_torque():
    t = np.arange(0, 1.0, 0.001)
    log = MeasuredLog(t=t, q=np.sin(t)[:, None], theta_m=np.cos(t)[:, None], tau_m=np.arange(len(t), dtype=float)[:, None])
    d = decimate(log, 250.0)
    assert np.allclose(np.diff(d.t), 0.004) and d.tau_m[0, 0] == pytest.approx(1.5) and d.q[1, 0] == log.q[4, 0]


# ------------------------------------------------------------------ the weighted residual


def test_weighted_residual_returns_to_the_physics_off_its_data_and_clips_steep_slopes():
    from sea_daemon.core.estimators.weighted import WeightedResidual
    from sea_daemon.core.config import LearningConfig
    from sea_daemon.core.learning import ResidualGP
    rng = np.random.default_rng(0)
    Z = np.column_stack([rng.uniform(0.2, 1.2, 600), rng.uniform(-1, 1, 600), rng.uniform(-5, 5, 600)])
    F = (0.3 * np.sin(3 * Z[:, 0]) + 0.2 * Z[:, 1])[:, None] + 0.005 * rng.normal(size=(600, 1))
    gp = ResidualGP(1, LearningConfig(sigma_f=0.3, lengthscales=(0.3, 0.5, 50.0), sigma_n=0.01, hyperopt=False))
    gp.train(Z, F)
    M = np.array([[0.16]])
    hook = WeightedResidual(gp, margin=10.0, noise_in_Q=False, M=M, dt=0.01)
    mu, J, var = (np.array(a) for a in hook.predict(np.array([0.7, 0.3, 0.0])))
    assert hook.w[0] > 0.95 and mu[0] == pytest.approx(0.3 * np.sin(2.1) + 0.06, abs=0.02)
    mu, J, var = (np.array(a) for a in hook.predict(np.array([4.0, 0.3, 0.0])))    # far off the data in q
    assert hook.w[0] < 0.01 and abs(mu[0]) < 1e-3 and np.all(np.abs(J) < 1e-2)
    assert var[0] == pytest.approx(0.09, rel=0.05)              # the prior variance goes to Q
    steep = ResidualGP(1, LearningConfig(sigma_f=5.0, lengthscales=(0.3, 0.002, 50.0), sigma_n=0.01, hyperopt=False))
    steep.train(Z, 5 * np.sign(Z[:, 1:2]))
    h2 = WeightedResidual(steep, M=M, dt=0.01)
    for v in np.linspace(-0.01, 0.01, 21):
        _, J, _ = h2.predict(np.array([0.7, v, 0.0]))
        assert abs(J[0, 1]) <= 0.5 * 0.16 / 0.01 + 1e-12


def test_weighted_residual_trusts_the_mean_only_where_its_variance_is_below_the_leftovers():
    """The weight's reference is the leftover's latent mean square s_0² (what predicting 0 costs
    on the calibration data), not σ_f² alone: a GP whose σ_f is inflated over a small, noisy
    leftover keeps its mean out; a GP that knows its well-sampled leftover keeps it in."""
    from sea_daemon.apps.calibration.residual_gp import leftover_latent_variance
    from sea_daemon.core.config import LearningConfig
    from sea_daemon.core.estimators.weighted import WeightedResidual
    from sea_daemon.core.learning import ResidualGP
    rng = np.random.default_rng(1)
    # sparse noisy pairs of a small leftover (latent RMS 0.035, noise 0.05), σ_f at 0.3
    Z = np.column_stack([rng.uniform(0.2, 1.2, 40), rng.uniform(-1, 1, 40), np.zeros(40)])
    F = (0.05 * np.sin(3 * Z[:, 0]))[:, None] + 0.05 * rng.normal(size=(40, 1))
    lc = LearningConfig(sigma_f=0.3, lengthscales=(0.3, 0.5, 50.0), sigma_n=0.05, hyperopt=False)
    gp = ResidualGP(1, lc)
    gp.train(Z, F)
    s0 = leftover_latent_variance(F, lc.sigma_n)
    assert 0 < s0 < 0.01
    z = np.array([0.7, 0.2, 0.0])
    old = WeightedResidual(gp, margin=10.0, noise_in_Q=False)
    mu_old = float(old.predict(z)[0][0])
    w_old = float(old.w[0])
    new = WeightedResidual(gp, margin=10.0, noise_in_Q=False, var_ref=s0)
    mu_new, _, var_new = (np.array(a) for a in new.predict(z))
    assert w_old > 0.7 and new.w[0] < 0.5 * w_old and abs(mu_new[0]) < abs(mu_old)
    assert var_new[0] == pytest.approx(float(old.var[0]))       # the variance in Q is the GP's own
    # a reference above σ_f² changes nothing
    big = WeightedResidual(gp, margin=10.0, noise_in_Q=False, var_ref=1.0)
    big.predict(z)
    assert big.w[0] == w_old
    # dense, nearly noise-free pairs of a leftover the GP resolves: the weight stays ~1
    Z2 = np.column_stack([rng.uniform(0.2, 1.2, 600), rng.uniform(-1, 1, 600), rng.uniform(-5, 5, 600)])
    F2 = (0.3 * np.sin(3 * Z2[:, 0]) + 0.2 * Z2[:, 1])[:, None] + 0.005 * rng.normal(size=(600, 1))
    gp2 = ResidualGP(1, LearningConfig(sigma_f=0.3, lengthscales=(0.3, 0.5, 50.0), sigma_n=0.01, hyperopt=False))
    gp2.train(Z2, F2)
    h2 = WeightedResidual(gp2, margin=10.0, noise_in_Q=False, var_ref=leftover_latent_variance(F2, 0.01))
    h2.predict(z)
    assert h2.w[0] > 0.9
    with pytest.raises(ValueError):
        WeightedResidual(gp, var_ref=float("nan"))


# ------------------------------------------------------------------ bounded P, typed faults


def test_cap_covariance_keeps_psd_and_correlations():
    rng = np.random.default_rng(1)
    A = rng.normal(size=(5, 5))
    P = A @ A.T * np.array([1, 1, 1, 1, 1e12])[:, None] * np.array([1, 1, 1, 1, 1e12])[None, :] + np.eye(5)
    corr = P / np.sqrt(np.outer(np.diag(P), np.diag(P)))
    cap = np.full(5, 1e4)
    assert akf_core.cap_covariance(P, cap) >= 1
    assert np.all(np.diag(P) <= cap * (1 + 1e-12)) and np.all(np.linalg.eigvalsh(P) > -1e-9)
    assert np.allclose(P / np.sqrt(np.outer(np.diag(P), np.diag(P))), corr)


def test_a_log_that_does_not_fit_the_model_is_a_typed_fault_and_exit_2(plant, tmp_path, capsys):
    nom, true = plant
    log = run_session(true, 6.0, hold_q=0.3, human=BandLimitedTorque(3.0, 1.0, 3.0, seed=1), seed=2)
    # a wild segment: the load encoder jumps by 0.5 rad for 0.5 s
    q = log.q.copy()
    q[200:250] += 0.5
    bad = MeasuredLog(t=log.t, q=q, theta_m=log.theta_m, tau_m=log.tau_m, tau_h_act=log.tau_h_act)
    cfg = dataclasses.replace(nom, estimator=dataclasses.replace(nom.estimator, R=np.diag([1e-12, 1e-12, 1e-8, 1e-8]),
                                                                Sigma_nom=np.diag([1e-16, 1e-16, 0, 0, 1e-8])))
    try:
        r = replay(bad, AKF(cfg))
        assert np.all(np.isfinite(r.tau_h_act_hat)) and np.all(np.isfinite(r.x_hat))
    except EstimatorFault as e:
        assert "sample" in str(e)
    p_log, p_cfg = tmp_path / "bad.csv", tmp_path / "cfg.yaml"
    write_log(p_log, bad)
    save_config(cfg, p_cfg)
    code = cli.main(["replay", str(p_log), "--config", str(p_cfg), "--estimator", "akf", "--out", str(tmp_path / "e.csv")])
    err = capsys.readouterr().err
    assert code in (0, 2) and "Traceback" not in err and "internal" not in err
    if code == 2:
        assert "sample" in err and "fault" in err


# ------------------------------------------------------------------ the whole calibration


@pytest.fixture(scope="module")
def calibrated(plant, cal_log):
    nom, _ = plant
    return calibrate(cal_log, nom, opts=CalibrationOptions(human=HumanSpec((0.1, 1.0), 1.5), gp="on", synth_s=10.0))


def test_calibration_finds_the_physics_and_keeps_given_values(plant, cal_log, calibrated):
    nom, true = plant
    res = calibrated
    found = {d["type"] for d in res.report["diagnose"]["effects_added"]}
    assert {"gravity", "human_viscoelastic", "coulomb", "inertia"} <= found
    g = next(e for e in res.cfg.model.effects if e.type == "gravity")
    assert g.a == pytest.approx(1.8, rel=0.05)
    assert res.report["leftover"]["rms"] < 0.05
    # the residual GP's tree splits in length scales
    assert res.cfg.learning.split_in_lengthscales and all(g.split_in_lengthscales for g in res.gp.gps)
    assert 0 < res.cfg.estimator.tau_m_noise < 0.05 and res.report["tau_h_act_walk"]["q_tau"] > 0
    # given values are kept
    given = with_R(nom, np.diag([1e-10, 2e-10, 3e-5, 4e-5]))
    res2 = calibrate(cal_log, given, given={"R", "Sigma_nom"}, opts=CalibrationOptions(gp="off", synth_s=10.0))
    assert np.allclose(res2.cfg.estimator.R, given.estimator.R)
    assert np.allclose(res2.cfg.estimator.Sigma_nom, nom.estimator.Sigma_nom)
    assert given_keys({"estimator": {"R": [1, 2, 3, 4]}, "kinematics": {"window": 5}}) == {"R", "kinematics"}


def test_friction_smoothing_from_the_passive_log_and_walk_from_the_synthetic_subjects(calibrated):
    """sign_eps is chosen on the passive log alone (every candidate scored there, none on the
    synthetic subjects); q_τ on the synthetic subjects alone, at the chosen sign_eps: the smallest q_τ
    within 2 % of the best RMS (the estimate's rule, the default)."""
    from sea_daemon.apps.calibration.pipeline import EPS_GRID
    walk = calibrated.report["tau_h_act_walk"]
    grid, chosen = walk["grid"], walk["chosen"]
    eps = chosen["sign_eps"]
    assert eps == calibrated.cfg.estimator.sign_eps and eps in EPS_GRID
    scored = [r for r in grid if "passive_log" in r and r["q_tau"] == chosen["q_tau"]]
    assert {r["sign_eps"] for r in scored} == set(EPS_GRID)
    assert chosen["passive_log"] == min(r["passive_log"] for r in scored)
    synth = [r for r in grid if "synthetic_moving" in r]
    assert len(synth) >= 6 and {r["sign_eps"] for r in synth} == {eps}
    best = min(math.hypot(r["synthetic_moving"], r["synthetic_still"]) for r in synth)
    assert walk["choice"]["rule"] == "rmse"          # calibration.walk_for: estimate, the default
    near = [r["q_tau"] for r in synth if math.hypot(r["synthetic_moving"], r["synthetic_still"]) <= 1.02 * best]
    assert walk["q_tau"] == min(near)


def test_walk_for_the_bound(plant, cal_log):
    """``walk_for="bound"`` (calibration.walk_for: bound): among the walks within 10 % of the best
    synthetic RMS, the one whose Theorem-1 bound on the synthetic sessions is smallest, each of them
    covering; it is never slower than the estimate's rule's walk."""
    from sea_daemon.apps.calibration.walk_bound import RMSE_TOL, bound_score
    nom, _ = plant
    res = calibrate(cal_log, nom, opts=CalibrationOptions(human=HumanSpec((0.1, 1.0), 1.5), gp="off", synth_s=10.0,
                                                          walk_for="bound", diagnose=False))
    walk = res.report["tau_h_act_walk"]
    active = ("synthetic_moving", "synthetic_still")
    synth = [r for r in walk["grid"] if all(k in r for k in active)]
    best = min(math.hypot(*(r[k] for k in active)) for r in synth)
    bounded = {r["q_tau"]: bound_score(r["bound"], active) for r in synth
               if "bound" in r and math.hypot(*(r[k] for k in active)) <= (1 + RMSE_TOL) * best}
    assert walk["choice"]["rule"] == "bound" and len(bounded) >= 2
    q = min(bounded, key=bounded.get)
    assert walk["q_tau"] == q and walk["choice"]["mean_rho"] == bounded[q] < math.inf
    assert walk["q_tau"] >= walk["choice"]["rmse_rule_walk"]


def test_gp_akf_is_never_much_worse_than_the_physics_on_unlike_sessions(plant, calibrated):
    nom, true = plant
    res = calibrated
    assert res.gp is not None
    d = math.radians
    sessions = [run_session(true, 12.0, reference=paper_moves(d(10), d(105), 2.0, 10), seed=21),   # wider, faster
                run_session(true, 12.0, hold_q=d(20), human=BandLimitedTorque(1.5, 0.1, 1.0, seed=2), seed=22)]
    for log in sessions:
        g = _rmse(log, res.estimator(dt=log.dt))
        a = _rmse(log, res.estimator(dt=log.dt, kind="akf"))
        assert g <= 1.1 * a + 1e-3, (g, a)
        assert g < 0.15


def test_fit_writes_a_complete_model_that_replay_and_run_load(plant, cal_log, tmp_path, capsys):
    nom, true = plant
    p_cal, p_log = tmp_path / "cal.csv", tmp_path / "log.csv"
    write_log(p_cal, MeasuredLog(t=cal_log.t[:2500], q=cal_log.q[:2500], theta_m=cal_log.theta_m[:2500],
                                 tau_m=cal_log.tau_m[:2500]))
    log = run_session(true, 5.0, hold_q=0.3, human=BandLimitedTorque(1.0, 0.1, 0.5, seed=4), seed=5)
    write_log(p_log, log)
    code = cli.main(["fit", str(p_cal), "--config", str(NOMINAL), "--out", str(tmp_path / "m")])
    out = json.loads(capsys.readouterr().out)
    assert code == 0 and out["effects"] and (tmp_path / "m.yaml").exists() and (tmp_path / "m.npz").exists()
    cfg = load_config(tmp_path / "m.yaml")
    assert any(e.type == "gravity" for e in cfg.model.effects)
    from sea_daemon.apps.calibration.modelio import estimator_from_model
    from sea_daemon.io.gpmodel import load_gp_model
    residual, meta = load_gp_model(tmp_path / "m.npz", cfg)
    loaded = estimator_from_model(cfg, residual, meta)
    if meta["provenance"]["calibration"]["gp_used"]:
        # the weight's reference travels with the model file
        assert loaded.residual.var_ref == pytest.approx(meta["provenance"]["calibration"]["gp_var_ref"])
        assert loaded.residual.var_ref > 0
    code = cli.main(["replay", str(p_log), "--config", str(tmp_path / "m.yaml"), "--model", str(tmp_path / "m.npz"),
                     "--estimator", "gp-akf", "--out", str(tmp_path / "e.csv")])
    s = json.loads(capsys.readouterr().out)
    assert code == 0 and s["rmse"] < 0.2
    # a provenance field that does not fit (a hand-edited or corrupt file) is a typed refusal
    import copy
    from sea_daemon.errors import ModelFileError
    for key, bad in (("gp_var_ref", float("nan")), ("gp_v_gate", "fast"), ("coverage", None)):
        m2 = copy.deepcopy(meta)
        m2["provenance"]["calibration"][key] = bad
        with pytest.raises(ModelFileError, match="calibration provenance"):
            estimator_from_model(cfg, residual, m2)


def test_the_summary_names_effects_the_log_cannot_tell_apart(calibrated):
    """diagnose's collinear pairs reach the calibration's plain-words summary with the angles
    and speeds the log spans (the physics may extrapolate wrongly beyond them)."""
    import copy
    from sea_daemon.apps.calibration.modelio import summary
    assert isinstance(calibrated.report["diagnose"]["correlated_pairs"], list)
    res = copy.copy(calibrated)
    res.report = copy.deepcopy(calibrated.report)
    res.report["diagnose"]["correlated_pairs"] = [{"kept": "human_viscoelastic/load", "dropped": "gravity/load",
                                                   "correlation": 0.997}]
    s = summary(res)
    line = next(t for t in s["text"] if "cannot tell apart" in t)
    q = res.report["data_range"]["q"]
    assert "human_viscoelastic/load from gravity/load (parameter correlation +1.00" in line
    assert f"{math.degrees(q[0]):.0f}-{math.degrees(q[1]):.0f} deg" in line and "--excitation" in line
    assert s["ambiguous"] == res.report["diagnose"]["correlated_pairs"]
    if not calibrated.report["diagnose"]["correlated_pairs"]:
        assert not any("cannot tell apart" in t for t in summary(calibrated)["text"])


def test_the_gp_pairs_carry_the_load_sides_leftover_only(plant):
    """A motor-side torque the physics misses (cogging) stays out of the residual GP's targets:
    the filter applies f on the load side, where it would move τ̂_h,act by its size."""
    from sea_daemon.apps.calibration.residual_gp import smooth_pairs
    from sea_daemon.analysis.diagnose.residuals import kinematics_from_log, residual_channels, stick_velocity
    nom, true = plant
    cog = make_effect("cogging", "motor", A=0.08, periods=6.0, phi=0.3)
    aug = true                                                    # the model: the load side's physics complete
    log = run_session(true.with_effects(tuple(true.model.effects) + (cog,)), 12.0,
                      reference=paper_moves(math.radians(10), math.radians(75), 2.0, 10), seed=7)
    Z, F = smooth_pairs(aug, log)
    r = residual_channels(SEAModel.from_config(aug), kinematics_from_log(log), passive=True,
                          v_stick=stick_velocity(aug))
    rms = lambda a: float(np.sqrt(np.mean(a ** 2)))
    assert rms(r[50:-50, 1]) > 0.04                              # the cogging is in the motor side's balance
    assert len(Z) > 200 and rms(F[:, 0]) < 0.25 * rms(r[50:-50, 1])


# ------------------------------------------------------------------ off the covered region


def test_off_the_covered_region_the_filter_widens_its_walk_there_only(plant, tmp_path):
    """estimator.tau_h_act_walk_outside: the step after a sample outside the covered region
    predicts with the τ_h,act walk at least q_out·dt, inside it with the configured Σ_nom; the
    key round-trips through the configuration file."""
    from sea_daemon.core.estimators.calibrated import make_calibrated
    nom, true = plant
    q_out = 25.0
    cfg = dataclasses.replace(nom, estimator=dataclasses.replace(nom.estimator, tau_h_act_walk_outside=q_out))
    save_config(cfg, tmp_path / "c.yaml")
    assert load_config(tmp_path / "c.yaml").estimator.tau_h_act_walk_outside == q_out
    wr = WorkingRange(0.0, math.radians(110), 2.0, 20.0)
    cov = Coverage(wr)
    pm = paper_moves(math.radians(10), math.radians(60), 3.0, 4)          # covered: 10-60 deg
    cov.add(np.array([pm.reference(t) for t in np.arange(0, pm.duration, 0.01)]))
    log = run_session(true, 12.0, reference=paper_moves(math.radians(10), math.radians(95), 3.0, 4), seed=5)
    est = make_calibrated(cfg, None, cov, kind="akf")
    base = None
    seen = {True: 0, False: 0}
    for k in range(len(log)):
        outside = est.z_outside
        est.update(log.q[k], log.theta_m[k], log.tau_m[k])
        if k < 20:
            continue
        s = est.Sigma_nom[4, 4]
        if outside:
            assert s >= q_out * est.dt * (1 - 1e-12)
        else:
            base = s if base is None else base
            assert s == pytest.approx(base) and s < q_out * est.dt
        seen[outside] += 1
    assert seen[True] > 50 and seen[False] > 50 and est.n_outside > 50
    # without the key the walk is the configured one everywhere
    est0 = make_calibrated(nom, None, cov, kind="akf")
    r = replay(log, est0)
    assert np.all(np.isfinite(r.tau_h_act_hat)) and np.max(est0.Sigma_nom[4, 4]) == pytest.approx(base)
