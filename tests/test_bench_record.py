"""Smoke run of `sea-daemon bench record` (the soak of the record through faults): each attack
leaves a log with a row for every cycle, or the rows lost counted and the fault reported."""
from __future__ import annotations

import numpy as np

from sea_daemon.apps.bench.record import run_rounds, table


def test_one_round_of_every_attack_keeps_the_record(monkeypatch):
    import sea_daemon.apps.bench.record as rec
    monkeypatch.setattr(rec.os, "geteuid", lambda: 1000)     # the portable path: RLIMIT_FSIZE, not a mount
    res = run_rounds(1, 300, seed=3)
    for attack, rs in res["attacks"].items():
        assert all(r["ok"] for r in rs), (attack, [r["checks"] for r in rs])
    full = res["attacks"]["disk_full"][0]
    assert full["disk"] == "RLIMIT_FSIZE" and full["rows_lost"] == 300 - full["rows"] > 0
    assert res["attacks"]["device_model_stopped"][0]["placeholder_rows"] > 0
    assert "device_model_stopped" in table(res) and np.isfinite(full["disk_bytes"])
