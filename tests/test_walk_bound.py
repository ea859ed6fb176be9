"""The calibration's τ_h,act walk chosen for the estimate, or for the bound as well (apps/calibration/walk_bound.py)."""
from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np

from sea_daemon.apps.calibration.pipeline import HumanSpec, synthetic_sessions
from sea_daemon.apps.calibration.walk_bound import RMSE_TOL, bound_figures, bound_score, common_walk
from sea_daemon.core.effects import make_effect
from sea_daemon.core.rates import at_rate
from sea_daemon.core.sim.session import run_session
from sea_daemon.io.configfile import default_config_path, load_config

ACTIVE = {"synthetic_moving": None, "synthetic_still": None}     # the logs: never replayed here


class FakeScan:
    """A walk scan whose synthetic RMS and bound figures are functions of q_τ (no filter runs)."""

    def __init__(self, rms, rho, cov, walk_for="bound"):
        self.rms, self.rho, self.cov = rms, rho, cov
        self.opts = SimpleNamespace(walk_for=walk_for)
        self.table: dict = {}
        self.evaluated: list[float] = []

    def evaluate(self, q, eps, logs):
        q = float(q)
        self.evaluated.append(q)
        b = {k: {"rho": [self.rho(q)], "coverage": [self.cov(q)], "valid": 1.0} for k in logs}
        return self.table.setdefault((q, eps), {"q_tau": q, "sign_eps": eps, "bound": b,
                                                **{k: self.rms(q) for k in logs}})

    @staticmethod
    def objective(row, logs):
        return float(np.sqrt(np.mean([row[k] ** 2 for k in logs])))


def scanned(scan, grid):
    for q in grid[::2]:
        scan.evaluate(q, 0.003, ACTIVE)
    return scan


def test_the_walk_with_the_smallest_covering_bound_within_the_rmse_tolerance():
    """RMS flat from q_τ = 1 on (the estimate's rule takes 1); the bound shrinks with the walk up to
    10 and the RMS at 31.6 is beyond the tolerance: the bound's rule takes 10, after trying the
    half-decades around it."""
    grid = np.geomspace(1e-3, 1e2, 11)

    def rms(q):
        return 0.1 if 1.0 <= q <= 10.0 + 1e-9 else (0.1 * (1 + 2 * RMSE_TOL) if q > 10 else 0.5)

    def rho(q):
        return 1.0 / (1.0 + math.log10(max(q, 1e-3)) + 3.0)
    scan = scanned(FakeScan(rms, rho, lambda q: 1.0), grid)
    q, rec = common_walk(scan, 0.003, ACTIVE, grid)
    assert math.isclose(q, 10.0) and rec["rule"] == "bound"
    assert math.isclose(rec["rmse_rule_walk"], 1.0)
    assert any(math.isclose(g, 10 ** 1.5) for g in scan.evaluated)      # the half-decade above was tried
    # calibration.walk_for: estimate (the default): the smallest q_τ within 2 % of the best RMS, no bound run
    scan = scanned(FakeScan(rms, rho, lambda q: 1.0, walk_for="estimate"), grid)
    n = len(scan.evaluated)
    q, rec = common_walk(scan, 0.003, ACTIVE, grid)
    assert math.isclose(q, 1.0) and rec["rule"] == "rmse" and len(scan.evaluated) == n


def test_walk_for_in_the_configuration():
    """``calibration.walk_for`` is estimate by default, bound when asked, refused otherwise; the
    calibration's options carry it."""
    import pytest

    from sea_daemon.apps.calibration.pipeline import options_from_config
    from sea_daemon.core.config import CalibrationConfig
    from sea_daemon.errors import ConfigError
    cfg = load_config(default_config_path())
    assert cfg.calibration.walk_for == "estimate" and options_from_config(cfg).walk_for == "estimate"
    c = CalibrationConfig.from_dict({"walk_for": "bound"}, 1, "m.yaml")
    assert c.walk_for == "bound" and CalibrationConfig.from_dict(c.to_dict(), 1, "m.yaml") == c
    with pytest.raises(ConfigError, match="calibration.walk_for.*estimate, bound.*'tight'"):
        CalibrationConfig.from_dict({"walk_for": "tight"}, 1, "m.yaml")


def test_a_bound_that_does_not_cover_is_not_chosen():
    """The fast walks' bound is smaller but covers 0.9 of the valid samples: the covering one is taken;
    when none covers, the estimate's rule (the smallest q_τ within 2 % of the best RMS)."""
    grid = np.geomspace(1e-3, 1e2, 11)

    def rms(q):
        return 0.1 if q >= 1.0 else 0.5
    scan = scanned(FakeScan(rms, lambda q: 1.0 / q, lambda q: 0.9 if q > 3.2 else 0.97), grid)
    q, rec = common_walk(scan, 0.003, ACTIVE, grid)
    assert math.isclose(q, 10 ** 0.5) and rec["rule"] == "bound"
    scan = scanned(FakeScan(rms, lambda q: 1.0 / q, lambda q: 0.9), grid)
    q, rec = common_walk(scan, 0.003, ACTIVE, grid)
    assert math.isclose(q, 1.0) and rec["rule"] == "rmse"


def test_bound_figures_and_score_over_the_valid_samples():
    """Mean ρ and coverage over the valid samples only; a session valid on too few samples, or whose
    bound does not cover, makes the walk ineligible."""
    truth = np.zeros((4, 1))
    res = SimpleNamespace(valid=np.array([False, True, True, True]),
                          tau_h_act_bound=np.array([[100.0], [1.0], [2.0], [3.0]]),
                          tau_h_act_hat=np.array([[50.0], [0.5], [2.5], [0.0]]))
    f = bound_figures(res, truth)
    assert f["rho"] == [2.0] and math.isclose(f["coverage"][0], 2 / 3) and f["valid"] == 0.75
    assert bound_score({"a": f}, ["a"]) == math.inf
    ok = {"rho": [0.4], "coverage": [0.96], "valid": 0.99}
    assert math.isclose(bound_score({"a": ok, "b": {**ok, "rho": [0.6]}}, ["a", "b"]), 0.5)
    assert bound_score({"a": {**ok, "valid": 0.9}}, ["a"]) == math.inf
    assert bound_score({"a": None}, ["a"]) == math.inf


def test_the_synthetic_sessions_of_a_stiff_identified_friction_run_at_1khz():
    """A load friction sharp enough to make a mode the 1 kHz plant step cannot hold (F/ε M⁻¹ beyond
    2.5 per ms): the walk scan's synthetic sessions still run (at a finer internal rate), so the walk
    is chosen by the scan, not left at the declared one."""
    cfg = at_rate(load_config(default_config_path()), 1000.0)
    stiff = cfg.with_effects([make_effect("coulomb", "load", F_c=3.0)])
    log = run_session(cfg, 1.0, hold_q=0.6, seed=3)
    out = synthetic_sessions(stiff, log, HumanSpec(), 0.0, 1.0, seed=0)
    assert len(out) == 2
    for lg in out:
        assert len(lg) == len(log) - 1 or len(lg) == len(log)
        assert np.all(np.isfinite(lg.q)) and np.all(np.isfinite(lg.tau_h_act))
