"""The passive arm's τ̂_h,act noise for a walk (analysis/passive_noise.py): what the encoders'
counts and the motor-torque noise put into the estimate, checked against the oracle AKF on a
simulated passive session of the two-joint example."""
import dataclasses
import math

import numpy as np
import pytest

from sea_daemon.analysis.noise import measurement_noise
from sea_daemon.analysis.passive_noise import passive_noise, walk_for_noise
from sea_daemon.apps.bench._family_joints import draw_plant_joints
from sea_daemon.apps.bench._generalize_joints import DONE_WHEN, passive_noise_record
from sea_daemon.apps.calibration.pipeline import sigma_nom_for, with_R
from sea_daemon.core.estimators.akf import AKF
from sea_daemon.core.excitation import PerJoint
from sea_daemon.core.replay import replay
from sea_daemon.core.sim.session import SineReference, run_session
from sea_daemon.io.configfile import data_root, load_config

#: the two-joint example's middle angles [rad] (shoulder, elbow)
MID = np.array([0.8, 1.1])


def _two_joint(bits: int, torque_noise: float = 0.02):
    cfg = load_config(data_root() / "configs" / "exo_2dof.yaml")
    hw = dataclasses.replace(cfg.hardware, encoder_bits=bits, torque_noise=torque_noise)
    return dataclasses.replace(cfg, hardware=hw, estimator=dataclasses.replace(cfg.estimator, tau_m_noise=torque_noise))


def test_noise_grows_with_the_walk_and_falls_with_finer_encoders():
    coarse, fine = _two_joint(16), _two_joint(19)
    walks = (0.1, 1.0, 10.0)
    noise = np.array([passive_noise(coarse, w, q=MID).rms for w in walks])
    assert np.all(np.diff(noise, axis=0) > 0)                  # a faster walk passes more noise, each joint
    for w in walks:
        assert np.all(passive_noise(fine, w, q=MID).rms < passive_noise(coarse, w, q=MID).rms)
    # no counts to speak of and no torque noise: nothing reaches τ̂
    ideal = _two_joint(26, 0.0)
    assert np.all(passive_noise(ideal, 10.0, q=MID).rms < 1e-3)
    # the lag per N m/s is larger at the slow walk (the price of a quiet estimate)
    assert np.all(passive_noise(coarse, 0.1, q=MID).lag_per_rate > passive_noise(coarse, 1.0, q=MID).lag_per_rate)


def test_walk_for_noise_is_the_walk_at_the_target():
    cfg = _two_joint(16)
    w = walk_for_noise(cfg, 0.05, q=MID)
    for j in range(2):
        assert passive_noise(cfg, w[j], q=MID).rms[j] == pytest.approx(0.05, rel=1e-6)
        assert passive_noise(cfg, 1.2 * w[j], q=MID).rms[j] > 0.05
    assert w[0] < w[1]                      # the shoulder, carrying the whole arm, needs the slower walk


@pytest.mark.parametrize("bad", [0.0, -1.0, math.nan, math.inf])
def test_a_walk_that_is_not_a_positive_number_is_refused(bad):
    with pytest.raises(ValueError, match="q_tau"):
        passive_noise(_two_joint(16), bad, q=MID)


def test_the_oracle_on_a_simulated_passive_session_shows_the_computed_noise():
    """The oracle AKF (the true model) on a passive two-joint session, 16-bit encoders, σ_u =
    0.02 N m: its τ̂ RMS per joint is the computed figure within a factor of two, at a slow and
    at a fast walk, and both say the fast walk cannot hold the shoulder at 0.05 N m."""
    cfg = _two_joint(16)
    ref = PerJoint(tuple(SineReference(float(m), (0.2,), (0.15 + 0.05 * j,), (0.0,)) for j, m in enumerate(MID)))
    log = run_session(cfg, 12.0, reference=ref, seed=3)
    c = with_R(cfg, measurement_noise(log, cfg, als=False)[0])
    for walk in (0.1, 3.16):
        est = dataclasses.replace(c.estimator, nis_scale=1e12, **sigma_nom_for(cfg, walk))
        r = replay(log, AKF(dataclasses.replace(c, estimator=est), dt=log.dt))
        measured = np.sqrt(np.mean(r.tau_h_act_hat[200:] ** 2, axis=0))
        computed = passive_noise(dataclasses.replace(cfg, estimator=est), walk, q=MID).rms
        assert np.all(measured / computed > 0.5) and np.all(measured / computed < 2.0), (walk, measured, computed)
        if walk > 1.0:
            assert measured[0] > 0.05 and computed[0] > 0.05


def test_bench_generalize_records_the_noise_at_the_calibrated_walk():
    pd = draw_plant_joints(2)
    cfg = dataclasses.replace(pd.nominal, estimator=dataclasses.replace(pd.nominal.estimator, tau_m_noise=pd.torque_noise))
    rec = passive_noise_record(cfg, {"q_tau": 3.16, "q_tau_per_joint": [3.16, 0.1]}, pd)
    q = np.array([0.5 * (w.q_min + w.q_max) for w in pd.working_range])
    assert rec["rms"] == pytest.approx(passive_noise(cfg, [3.16, 0.1], q=q).rms.tolist(), rel=1e-4)
    assert rec["target"] == DONE_WHEN["passive_rmse"]
    w = walk_for_noise(cfg, DONE_WHEN["passive_rmse"], q=q)
    assert rec["walk_for_target"] == pytest.approx(w.tolist())
    assert passive_noise_record(cfg, {"given": [1.0] * 10}, pd) is None            # Sigma_nom given: no walk
    integ = dataclasses.replace(cfg, estimator=cfg.estimator.with_tau_model("integrated", 2))
    assert passive_noise_record(integ, {"q_tau": 3.16}, pd) is None
