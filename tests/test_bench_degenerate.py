"""bench generalize --degenerate: the degenerate calibration logs are what they claim, and the
verdict flags nan/inf, internal errors, invented effects, a worse estimate and a bound that
does not hold (sea_daemon.apps.bench._family, sea_daemon.apps.bench._degenerate)."""
import math
import sys

import numpy as np
import pytest

from sea_daemon.apps.bench import _degenerate as dg
from sea_daemon.apps.bench._family import (DEGENERATE, SATURATED_SHARE, SHORT_S, STILL_S, degenerate_calibration,
                                           draw_plant)

SEED = 400          # a development seed of the generalisation benchmark


@pytest.fixture(scope="module")
def plant():
    return draw_plant(SEED, 100.0)


def test_still_log_has_no_motion(plant):
    dl = degenerate_calibration(plant, "still")
    assert dl.log.t[-1] == pytest.approx(STILL_S - 0.01)
    q_true = dl.log.extra["q_true"]
    assert np.ptp(q_true) < math.radians(0.1), np.ptp(q_true)
    m = dg.motion_of(dl.log)
    assert not m["moves"] and not m["reverses"]
    assert np.all(dl.log.tau_h_act == 0.0)                    # passive


def test_one_direction_log_never_reverses_and_spans_the_range(plant):
    dl = degenerate_calibration(plant, "one_direction")
    wr = plant.working_range
    dq = dl.log.extra["dq_true"]
    assert dq.min() > -dg.REVERSE_SPEED and np.percentile(dq, 1) > -0.01, dq.min()
    q = dl.log.q[:, 0]
    assert q[-1] - q[0] > 0.9 * wr.width
    m = dg.motion_of(dl.log)
    assert m["moves"] and not m["reverses"]


def test_short_log_lasts_its_seconds_and_moves_both_ways(plant):
    dl = degenerate_calibration(plant, "short")
    assert len(dl.log) == round(SHORT_S * plant.nominal.rate_hz)
    m = dg.motion_of(dl.log)
    assert m["moves"] and m["reverses"]


def test_wrong_rate_log_is_at_the_other_rate(plant):
    dl = degenerate_calibration(plant, "wrong_rate", cal_s=1.0)
    assert dl.config.rate_hz == 100.0
    assert dl.log.dt == pytest.approx(1e-3)
    assert len(dl.log) == 1000
    p1k = draw_plant(SEED, 1000.0)
    dl1k = degenerate_calibration(p1k, "wrong_rate", cal_s=1.0)
    assert dl1k.config.rate_hz == 1000.0 and dl1k.log.dt == pytest.approx(1e-2)


def test_saturated_log_sits_at_the_configured_torque_limit(plant):
    dl = degenerate_calibration(plant, "saturated", cal_s=2.0)
    lim = dl.config.hardware.torque_limit
    at = np.isclose(np.abs(dl.log.tau_m[:, 0]), lim)
    assert at.mean() == pytest.approx(SATURATED_SHARE, abs=0.01)
    assert np.abs(dl.log.tau_m).max() <= lim
    assert plant.nominal.hardware.torque_limit > lim          # the user's file says the smaller limit


def test_every_case_is_built_and_an_unknown_one_is_refused(plant):
    assert set(DEGENERATE) == {"still", "short", "one_direction", "saturated", "wrong_rate"}
    with pytest.raises(ValueError):
        degenerate_calibration(plant, "tilted")


# ------------------------------------------------------------------ the rule


def test_invented_effects_follow_the_motion_the_log_shows():
    still = {"moves": False, "reverses": False}
    one_way = {"moves": True, "reverses": False}
    both = {"moves": True, "reverses": True}
    eff = ["coulomb(load)", "stribeck(motor)", "gravity(load)"]
    assert dg.invented_effects(eff, still) == eff
    assert dg.invented_effects(eff, one_way) == ["coulomb(load)", "stribeck(motor)"]
    assert dg.invented_effects(eff, both) == []


def test_nonfinite_figures_are_found_and_words_are_not():
    assert dg.nonfinite_tokens("Expected accuracy: RMSE nan N m")
    for text in ('{"rmse": NaN}', "bound inf N m", '"x": -Infinity', "R: .nan", "a -inf"):
        assert dg.nonfinite_tokens(text), text
    for text in ("information", "infer the nanoseconds", "sea-daemon fit: error: log too short", "Inertia(load)"):
        assert not dg.nonfinite_tokens(text), text


def _session(rmse, cov, finite=True):
    return {"rmse": rmse, "finite": finite, "bound": {"coverage_valid": cov, "valid_share": 1.0}}


def test_verdict():
    refused = {"outcome": "refused", "line": "sea-daemon fit: error: the arm does not move", "nonfinite": [],
               "invented": []}
    assert dg.verdict(refused) == {"verdict": "refused", "ok": True, "why": []}
    held = {"outcome": "calibrated", "nonfinite": [], "invented": [],
            "sessions": {"slow": {"gp-akf": _session(0.1, 0.99), "akf-robot": {"rmse": 1.0, "finite": True}}}}
    assert dg.verdict(held)["verdict"] == "held"
    # nan printed, internal error, invented effects: each fails
    for bad in ({**refused, "nonfinite": ["RMSE nan N m"]},
                {"outcome": "internal_error", "line": "sea-daemon fit: internal error: ZeroDivisionError",
                 "nonfinite": [], "invented": []},
                {**held, "invented": ["coulomb(load)"]},
                {**held, "sessions": {"slow": {"gp-akf": _session(1.2, 0.99), "akf-robot": {"rmse": 1.0}}}},
                {**held, "sessions": {"slow": {"gp-akf": _session(0.1, 0.911), "akf-robot": {"rmse": 1.0}}}},
                {**held, "sessions": {"slow": {"gp-akf": _session(0.1, 0.99, finite=False), "akf-robot": {}}}},
                {**held, "sessions": {"slow": {"gp-akf": {"internal_error": "KeyError: 'x'"}, "akf-robot": {}}}},
                {**held, "sessions": {"slow": {"gp-akf": {"fault": "NIS_DIVERGENCE"}, "akf-robot": {}}}}):
        v = dg.verdict(bad)
        assert v["verdict"] == "FAIL" and not v["ok"] and v["why"], bad
    # no sample marked valid: the bound claims nothing, there is nothing to cover
    assert dg.verdict({**held, "sessions": {"slow": {"gp-akf": _session(0.1, None),
                                                     "akf-robot": {"rmse": 1.0}}}})["ok"]


@pytest.mark.parametrize("script, outcome", [
    ("import sys; print('sea-daemon fit: error: the arm never moves: record sea-daemon calibrate --excitation', "
     "file=sys.stderr); sys.exit(2)", "refused"),
    ("import sys; print('sea-daemon fit: internal error: ZeroDivisionError: x', file=sys.stderr); sys.exit(1)",
     "internal_error"),
    ("import json; print(json.dumps({'effects': ['coulomb(load)'], 'expected_rmse': {'passive_log': float('nan')}}))",
     "calibrated"),
])
def test_run_fit_reads_the_exit_status_and_what_was_printed(tmp_path, monkeypatch, plant, script, outcome):
    monkeypatch.setattr(dg, "fit_command", lambda log, cfg, prefix: [sys.executable, "-c", script])
    dl = degenerate_calibration(plant, "still")
    row = dg.run_fit(dl, tmp_path / "still")
    assert row["outcome"] == outcome
    assert (tmp_path / "still" / "calibration.csv").is_file() and (tmp_path / "still" / "robot.yaml").is_file()
    header = (tmp_path / "still" / "calibration.csv").read_text().splitlines()[0]
    assert "tau_h_act" not in header and "q_true" not in header        # the user's columns only
    import yaml
    user = yaml.safe_load((tmp_path / "still" / "robot.yaml").read_text())
    assert set(user) == {"joints", "rate_hz", "model", "hardware", "calibration"}   # nothing "given" to fit
    if outcome == "refused":
        assert row["line"].startswith("sea-daemon fit: error: the arm never moves") and not row["nonfinite"]
    if outcome == "calibrated":
        assert row["effects"] == ["coulomb(load)"] and row["nonfinite"]     # the NaN the summary printed
        row["invented"] = dg.invented_effects(row["effects"], dg.motion_of(dl.log))
        assert row["invented"] == ["coulomb(load)"]
        assert dg.verdict(row)["verdict"] == "FAIL"


# ------------------------------------------------------------------ held-out seeds: the targets per rate


def _row(seed, rate, sessions):
    return {"seed": seed, "rate_hz": rate, "plant": {"rate_hz": rate},
            "session_kinds": {"slow": "passive", "active_low": "active"}, "sessions": sessions}


def _gp(rmse, cov, rho, valid=1.0):
    return {"rmse": rmse, "finite": True, "bound": {"coverage": cov, "coverage_valid": cov, "mean_rho": rho,
                                                    "mean_rho_valid": rho, "valid_share": valid, "rmse_valid": rmse}}


def test_by_rate_gives_each_rate_its_targets_and_the_smallest_coverage():
    from sea_daemon.apps.bench.generalize import by_rate, seed_roles
    rows = [_row(420, 100.0, {"slow": {"gp-akf": _gp(0.02, 1.0, 0.2), "oracle": {"rmse": 0.02}},
                              "active_low": {"gp-akf": _gp(0.04, 0.93, 0.25), "oracle": {"rmse": 0.035}}}),
            _row(421, 1000.0, {"slow": {"gp-akf": _gp(0.02, 0.99, 0.15), "oracle": {"rmse": 0.01}},
                               "active_low": {"gp-akf": {"fault": "NIS"}, "oracle": {"rmse": 0.03}}})]
    d = by_rate(rows)
    assert set(d) == {"100", "1000"}
    h = d["100"]
    assert h["coverage"]["min"] == 0.93 and h["coverage"]["min_at"] == "plant 420 active_low"
    assert h["held"] == {"median": True, "p90": True, "coverage": False, "valid": True, "tight": True}
    k = d["1000"]
    # 1 kHz: a passive session's mean bound above 0.1 N m is loose; a session without an estimate fails coverage
    assert k["loose"] == [[421, "slow", 0.15, 0.1]] and k["held"]["tight"] is False
    assert k["held"]["coverage"] is False and k["no_estimate"] == [[421, "active_low", "fault"]]
    assert k["gp_over_oracle"]["median"] == 2.0 and k["held"]["median"] is False
    assert seed_roles([0, 420, 401]) == {"development": [0, 401], "held_out": [420]}
