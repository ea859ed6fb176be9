"""Real logs' time bases, encoders and lengths: jittered or dropped samples are resampled onto a
uniform grid, a log need not start at t = 0, a gap is a one-line input error, the encoder step
seen in the log is compared with the configured resolution, and a long log is diagnosed on
segments of it (memory and time bounded)."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from sea_daemon.apps.cli import main
from sea_daemon.apps.diagnose import SelectOptions, diagnose
from sea_daemon.analysis.diagnose.prepare import MAX_GAP, encoder_quanta, observed_quantum, prepare_log, segment_log
from sea_daemon.core.config import ModelConfig
from sea_daemon.core.log import MeasuredLog
from sea_daemon.errors import LogFormatError
from sea_daemon.io.configfile import load_config
from _paths import repo_root
from sea_daemon.io.logcsv import read_log, write_log

DATA = repo_root() / "tests" / "data" / "capstone_sea"
CONFIG = repo_root() / "configs" / "capstone_sea.yaml"
FAST = SelectOptions(holdout=0.0, validate_selection=False)


@pytest.fixture(scope="module")
def head():
    return read_log(DATA / "reference_head.csv", n=1), load_config(CONFIG)


@pytest.fixture(scope="module")
def base(head):
    log, cfg = head
    return diagnose(log, cfg, None, options=FAST, plots=False)


def _effects(res):
    return {(d["type"], d["side"]): d["params"] for d in res["effects_added"]}


def test_time_origin_does_not_matter(head, base):
    log, cfg = head
    shifted = dataclasses.replace(log, t=log.t + 1234.5)
    res = diagnose(shifted, cfg, None, options=FAST, plots=False)
    assert res["fit"]["time_grid"]["t0_s"] == pytest.approx(1234.5)
    a, b = _effects(base), _effects(res)
    assert a.keys() == b.keys()
    for k in a:
        for p, v in a[k].items():
            assert b[k][p] == pytest.approx(v, rel=1e-4, abs=1e-7), (k, p)
    assert res["residual_rms_after"] == pytest.approx(base["residual_rms_after"], rel=1e-4)
    assert res["estimate_rmse_after"] == pytest.approx(base["estimate_rmse_after"], rel=1e-4)


def test_jittered_timestamps_are_resampled(head, base):
    """Timestamps jittered by up to ±20 % of the period (a soft real-time logger) and one
    dropped sample: resampled onto the uniform grid, same diagnosis within a few per cent."""
    log, cfg = head
    rng = np.random.default_rng(7)
    t = log.t + rng.uniform(-0.2, 0.2, log.t.size) * log.dt
    keep = np.ones(log.t.size, dtype=bool)
    keep[777] = False                                  # a dropped sample
    jit = MeasuredLog(t=t[keep], q=log.q[keep], theta_m=log.theta_m[keep], tau_m=log.tau_m[keep],
                      tau_h_act=log.tau_h_act[keep], path="jittered.csv")
    res = diagnose(jit, cfg, None, options=FAST, plots=False)
    g = res["fit"]["time_grid"]
    assert g["resampled"] and g["max_interval_jitter"] > 0.3 and g["bridged_gaps"] >= 1
    assert res["samples"] == keep.sum()
    assert any("resampled onto a uniform grid" in s for s in res["statements"])
    assert _effects(res).keys() == _effects(base).keys()
    for k, ps in _effects(base).items():
        for p, v in ps.items():
            if k[0] != "encoder_offset":       # an offset of a few counts moves with the grid
                assert _effects(res)[k][p] == pytest.approx(v, rel=0.1), (k, p)
    assert res["residual_rms_after"] <= 0.5 * res["residual_rms_before"]


def test_prepare_bridges_a_dropped_sample_and_rejects_a_gap(head):
    log, _ = head
    keep = np.ones(len(log), dtype=bool)
    keep[100] = False
    lg = MeasuredLog(t=log.t[keep], q=log.q[keep], theta_m=log.theta_m[keep], tau_m=log.tau_m[keep], path="x.csv")
    p = prepare_log(lg)
    assert p.resampled and len(p.log) == len(log)
    assert np.allclose(np.diff(p.log.t), log.dt)
    # zero-order hold of the command: the grid sample at the dropped time holds the previous one
    assert p.log.tau_m[100, 0] == log.tau_m[99, 0]
    gap = MeasuredLog(t=np.concatenate([log.t[:50], log.t[53:]]), q=log.q[np.r_[:50, 53:len(log)]],
                      theta_m=log.theta_m[np.r_[:50, 53:len(log)]], tau_m=log.tau_m[np.r_[:50, 53:len(log)]],
                      path="gap.csv")
    assert 3 * log.dt > MAX_GAP * log.dt
    with pytest.raises(LogFormatError, match=r"gap.csv:52: a gap of"):
        prepare_log(gap)


def test_gap_is_exit_2_with_one_line(head, tmp_path, capsys):
    log, _ = head
    idx = np.r_[:500, 600:len(log)]
    gap = MeasuredLog(t=log.t[idx], q=log.q[idx], theta_m=log.theta_m[idx], tau_m=log.tau_m[idx])
    write_log(tmp_path / "gap.csv", gap)
    rc = main(["diagnose", str(tmp_path / "gap.csv"), "--config", str(CONFIG), "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1 and "gap" in err and "uniform" in err


def test_encoder_steps_from_the_log(head):
    log, cfg = head
    assert observed_quantum(log.q[:, 0]) == pytest.approx(2 * np.pi / 8000, rel=1e-4)
    assert observed_quantum(log.theta_m[:, 0]) == pytest.approx(2 * np.pi / 32000, rel=1e-4)
    assert observed_quantum(np.sin(np.linspace(0, 3, 500))) == 0.0       # not on a grid
    assert encoder_quanta(log, cfg)["mismatch"] == []
    # the same log against a configuration that claims 19-bit encoders
    d = cfg.to_dict()
    d["hardware"].pop("encoder_counts")
    d["hardware"]["encoder_bits"] = 19
    wrong = ModelConfig.from_dict(d)
    mism = encoder_quanta(log, wrong)["mismatch"]
    assert {m[0] for m in mism} == {"load", "motor"}
    res = diagnose(log, wrong, None, options=FAST, plots=False)
    assert any("set hardware.encoder_counts (load)" in s for s in res["statements"])
    # diagnose used the log's coarser step for the stick speed
    assert res["fit"]["encoder_step_rad"]["load"][0]["used"] == pytest.approx(2 * np.pi / 8000, rel=1e-3)


def test_segments_of_a_long_log():
    """segment_log: evenly spread contiguous segments, time running on across the seams, the
    samples near a seam marked; a log within the limit is left whole."""
    N, T = 10_000, 0.01
    t = 3.0 + np.arange(N) * T
    x = np.arange(N, dtype=float)[:, None]
    log = MeasuredLog(t=t, q=x, theta_m=x, tau_m=x, tau_h_act=x)
    assert segment_log(log, max_rows=N) is None and segment_log(log, max_rows=None) is None
    seg = segment_log(log, max_rows=2000, n_segments=4)
    assert len(seg.log) == 2000 and seg.original_rows == N
    assert seg.source_spans[0][0] == 0 and seg.source_spans[-1][1] == N
    assert np.allclose(np.diff(seg.log.t), T) and seg.log.t[0] == t[0]
    for (a, b), (sa, sb) in zip(seg.spans, seg.source_spans):
        assert np.array_equal(seg.log.q[a:b, 0], x[sa:sb, 0]) and np.array_equal(seg.log.tau_h_act[a:b, 0], x[sa:sb, 0])
    ok = seg.away_from_seams(10)
    assert not ok[490:510].any() and not ok[1490:1510].any() and ok[:490].all() and ok[1510:].all()


def test_long_log_is_diagnosed_on_segments(head):
    """A log longer than max_rows: the diagnosis runs on its segments (each estimator run starts
    at a segment's first sample), finds what the whole log gives, and says so."""
    log, cfg = head
    dist = read_log(DATA / "disturbance.csv", n=1)
    whole = diagnose(dist, cfg, None, options=FAST, plots=False)
    opts = SelectOptions(holdout=0.0, validate_selection=False, max_rows=2000)
    res = diagnose(dist, cfg, None, options=opts, plots=False)
    assert res["samples"] == len(dist)
    assert res["fit"]["time_grid"]["segments"][0][0] == 0 and res["fit"]["time_grid"]["segments"][-1][1] == len(dist)
    assert any("diagnose works on 2000 of them" in s for s in res["statements"])
    assert res["fit"]["samples_used"] < whole["fit"]["samples_used"]
    assert np.isfinite(res["estimate_rmse_before"]) and np.isfinite(res["residual_rms_before"])
    # away from the seams the segments' residual is the whole log's at the same samples
    from sea_daemon.analysis.diagnose.residuals import kinematics_from_log, residuals_for
    seg = segment_log(dist, max_rows=2000)
    w = kinematics_from_log(dist).window
    r_seg = residuals_for(cfg, kinematics_from_log(seg.log))
    r_all = residuals_for(cfg, kinematics_from_log(dist))
    ok = seg.away_from_seams(2 * w)
    for (a, b), (sa, sb) in zip(seg.spans, seg.source_spans):
        keep = ok[a:b].copy()
        keep[:w] = keep[-w:] = False          # the whole log's own ends
        if sa == 0:
            keep[:2 * w] = False
        np.testing.assert_allclose(r_seg[a:b][keep], r_all[sa:sb][keep], atol=1e-9)


def test_fit_stride_of_a_long_fit():
    from sea_daemon.analysis.diagnose.select import Selector
    assert Selector.fit_stride(1000, 20000, 51) == 1
    assert Selector.fit_stride(80000, 20000, 51) == 4
    assert Selector.fit_stride(10**6, 20000, 51) == 25          # at most half a smoothing window
    assert Selector.fit_stride(80000, None, 51) == 1
