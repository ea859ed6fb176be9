"""Smoke run of `sea-daemon bench soak` (the full soak is a benchmark): every cycle's row is
written, none dropped, the GP-AKF learns online, the figures are reported."""
from __future__ import annotations

from sea_daemon.apps.bench.soak import soak


def test_short_soak_writes_every_row(tmp_path):
    r = soak(cycles=600, rate=1000.0, warmup=300, max_leaves=5, overrun_streak=0, rotate_bytes=20000,
             out_dir=tmp_path, samples=3)
    lg = r["log"]
    assert r["cycles"] == 600 and r["fault"] == "NONE"
    assert lg["appended"] == lg["written"] == lg["counted_in_files"] == 600 and lg["dropped"] == 0
    assert lg["files"] > 1                                   # rotated at 20 kB
    # one training pair per configuration step (10 ms) at 1 kHz: every 10th cycle
    assert r["learned"] > 50 and r["gp_end"]["leaves"] <= 5
    assert r["rss_kb"]["end"] > 0 and r["rss_kb"]["writer_end"] > 0
