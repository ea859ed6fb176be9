"""``sea-daemon identify-noise``: ALS on a measured log (Sec. V-B)."""
import dataclasses
import json

import numpy as np
import pytest

from sea_daemon.apps.cli import main
from sea_daemon.io.configfile import default_config_path, load_config
from sea_daemon.io.logcsv import write_log
from sea_daemon.core.model import SEAModel

from synth import simulate

SIGMA = 1e-3     # white encoder noise added to both encoders [rad]


@pytest.fixture(scope="module")
def noisy_log(tmp_path_factory):
    cfg = load_config(default_config_path())
    log = simulate(SEAModel.from_config(cfg), T=30.0, substeps=2, bits=None, seed=4,
                   tau_h=lambda t: np.array([0.5 * np.sin(2 * np.pi * 0.2 * t)]))
    rng = np.random.default_rng(5)
    log = dataclasses.replace(log, q=log.q + SIGMA * rng.standard_normal(log.q.shape),
                              theta_m=log.theta_m + SIGMA * rng.standard_normal(log.q.shape))
    p = tmp_path_factory.mktemp("als") / "noisy.csv"
    write_log(p, log)
    return p


def test_identify_noise_recovers_encoder_noise_and_writes_config(noisy_log, tmp_path, capsys):
    # the differentiator of the paper ('ma'), whose noise relations are asserted below
    from sea_daemon.io.configfile import save_config
    cfg = load_config(default_config_path())
    ma = tmp_path / "ma.yaml"
    save_config(dataclasses.replace(cfg, kinematics=dataclasses.replace(cfg.kinematics, method="ma")), ma)
    out = tmp_path / "identified.yaml"
    rc = main(["identify-noise", str(noisy_log), "--config", str(ma), "--write", str(out)])
    assert rc == 0
    res = json.loads(capsys.readouterr().out)
    R = np.array(res["R"])
    # both encoders: σ² each (within 15 %: 2950 samples)
    assert res["encoder_variances"]["theta_m"][0] == pytest.approx(SIGMA ** 2, rel=0.15)
    assert res["encoder_variances"]["q"][0] == pytest.approx(SIGMA ** 2, rel=0.15)
    # θ_m: σ_m², θ_s = q − θ_m: σ_q² + σ_m², Cov(θ_m, θ_s) = −σ_m²
    assert R[0, 0] == pytest.approx(SIGMA ** 2, rel=0.15)
    assert R[1, 1] == pytest.approx(2 * SIGMA ** 2, rel=0.15)
    assert R[0, 1] == pytest.approx(-R[0, 0])
    # velocities: the 'ma' differentiator (W = 5, 100 Hz): ‖c_v‖² = 2/(W dt)², c_a·c_v = 1/(W dt)
    W_dt = 5 * 0.01
    np.testing.assert_allclose(R[2:, 2:], 2 / W_dt ** 2 * R[:2, :2])
    np.testing.assert_allclose(R[:2, 2:], 1 / W_dt * R[:2, :2])
    assert np.all(np.linalg.eigvalsh(R) > 0)
    cfg2 = load_config(out)
    np.testing.assert_allclose(cfg2.estimator.R, R)
    np.testing.assert_allclose(cfg2.estimator.P0[:4, :4], R)      # Sec. V-B: P0 = R


def test_identify_noise_bad_input_exits_2(noisy_log, tmp_path, capsys):
    cfg = str(default_config_path())
    assert main(["identify-noise", str(tmp_path / "missing.csv"), "--config", cfg]) == 2
    short = tmp_path / "short.csv"
    short.write_text("\n".join(noisy_log.read_text().splitlines()[:40]) + "\n")
    assert main(["identify-noise", str(short), "--config", cfg]) == 2
    assert "samples" in capsys.readouterr().err
    assert main(["identify-noise", str(noisy_log), "--config", cfg, "--lags", "1"]) == 2


@pytest.mark.parametrize("edit, pattern", [
    ("rate", r"recorded at 250 Hz, the configuration runs at 100 Hz \(rate_hz\); allowed: 100 Hz or a whole multiple"),
    ("tau_m", r"column tau_m is 0 N m in all \d+ rows while the joint moves"),
    ("theta_m", r"column theta_m is 0 rad in all \d+ rows while q spans .*the motor encoder reports nothing"),
    ("q", r"column q is 0 rad in all \d+ rows while theta_m spans .*the load encoder reports nothing"),
])
def test_identify_noise_refuses_a_log_at_another_rate_or_with_a_dead_column(noisy_log, tmp_path, capsys, edit,
                                                                             pattern):
    # R is per sample at the configuration's rate: identified on a 250 Hz log it was written into
    # the 100 Hz configuration as if it were its own; a column of zeros gave an R without a word
    from _cli import refused, run
    from sea_daemon.io.logcsv import read_log
    log = read_log(noisy_log)
    if edit == "rate":
        log = dataclasses.replace(log, t=log.t * 0.4)
    else:
        log = dataclasses.replace(log, **{edit: np.zeros_like(getattr(log, edit))})
    p = tmp_path / f"{edit}.csv"
    write_log(p, log)
    out = tmp_path / "out.yaml"
    code, _, err = run(["identify-noise", p, "--config", default_config_path(), "--write", out], capsys)
    refused(code, err, pattern)
    assert not out.exists()


def test_floor_is_each_encoders_own_quantisation():
    """The motor encoder sits before the 1:gear_ratio gear: its joint-side quantum is 2π/(2^bits·gear),
    so its floor is gear² below the load encoder's (2π/2^bits)²/12."""
    from sea_daemon.analysis.als import floored_R
    from sea_daemon.core.kinematics import CausalDifferentiator
    cfg = load_config(default_config_path())
    hw = cfg.hardware
    fir = CausalDifferentiator(cfg.dt, cfg.kinematics.window, 2, cfg.kinematics.method, cfg.kinematics.degree).C
    res = {"R": np.zeros((4, 4)), "encoder_variances": {"theta_m": [0.0], "q": [0.0]}, "fir": fir}
    R, enc, floored = floored_R(cfg, res)
    q_var = (2 * np.pi / 2 ** hw.encoder_bits) ** 2 / 12
    assert enc["q"][0] == pytest.approx(q_var, rel=1e-12)
    assert enc["theta_m"][0] == pytest.approx(q_var / hw.gear_ratio ** 2, rel=1e-12)
    assert floored == ["theta_m_1", "q_1"]
    assert R[0, 0] == pytest.approx(q_var / hw.gear_ratio ** 2, rel=1e-12)


def test_identify_noise_on_an_integrated_walk_config(noisy_log, tmp_path, capsys):
    """A model whose filter also tracks τ̇_h,act (6n state): the same encoder variances; the
    written R runs; --with-Q writes a Σ_nom of the filter's own size that loads."""
    from sea_daemon.io.configfile import save_config
    cfg = load_config(default_config_path())
    irw = tmp_path / "irw.yaml"
    save_config(dataclasses.replace(cfg, kinematics=dataclasses.replace(cfg.kinematics, method="ma"),
                                    estimator=cfg.estimator.with_tau_model("integrated", 1)), irw)
    out = tmp_path / "identified.yaml"
    assert main(["identify-noise", str(noisy_log), "--config", str(irw), "--write", str(out)]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["encoder_variances"]["theta_m"][0] == pytest.approx(SIGMA ** 2, rel=0.15)
    assert res["encoder_variances"]["q"][0] == pytest.approx(SIGMA ** 2, rel=0.15)
    assert load_config(out).estimator.tau_h_act_model == "integrated"
    assert main(["replay", str(noisy_log), "--config", str(out), "--estimator", "akf",
                 "--out", str(tmp_path / "est.csv")]) == 0
    capsys.readouterr()
    with_q = tmp_path / "with_q.yaml"
    assert main(["identify-noise", str(noisy_log), "--config", str(irw), "--with-Q", "--write", str(with_q)]) == 0
    assert len(json.loads(capsys.readouterr().out)["Q"]) == 6
    assert np.asarray(load_config(with_q).estimator.Sigma_nom).shape == (6, 6)


def test_an_identified_Q_is_written_only_if_the_filter_runs_with_it(noisy_log, tmp_path, capsys):
    """ALS identifies Q for the model linearised at the log's mean operating point.  With the
    default differentiator the AKF runs with it on this log, and it is written; with the paper's
    moving average ('ma') the AKF with it latches its innovation monitor at 4.7 s: reported, not
    written (Sigma_nom stays as configured), and the written file runs."""
    from sea_daemon.io.configfile import save_config
    cfg = load_config(default_config_path())
    kept = tmp_path / "kept.yaml"
    assert main(["identify-noise", str(noisy_log), "--config", str(default_config_path()), "--with-Q",
                 "--write", str(kept)]) == 0
    res = json.loads(capsys.readouterr().out)
    assert "Q_rejected" not in res
    np.testing.assert_allclose(np.diag(load_config(kept).estimator.Sigma_nom), res["Q"])
    ma = tmp_path / "ma.yaml"
    save_config(dataclasses.replace(cfg, kinematics=dataclasses.replace(cfg.kinematics, method="ma")), ma)
    out = tmp_path / "identified.yaml"
    assert main(["identify-noise", str(noisy_log), "--config", str(ma), "--with-Q", "--write", str(out)]) == 0
    cap = capsys.readouterr()
    res = json.loads(cap.out)
    assert "NIS" in res["Q_rejected"] and "not kept" in cap.err
    np.testing.assert_array_equal(load_config(out).estimator.Sigma_nom, cfg.estimator.Sigma_nom)
    assert main(["replay", str(noisy_log), "--config", str(out), "--estimator", "akf",
                 "--out", str(tmp_path / "est.csv")]) == 0
