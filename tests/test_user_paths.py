"""A new user's first steps off the golden path: every bad input refused with exit 2 and one line
naming the value and what is allowed, no traceback, no nan."""
from __future__ import annotations

import numpy as np
import pytest

from _cli import refused, run
from sea_daemon.io.configfile import default_config_path

CFG = default_config_path()


def _dead_q_log(p, samples: int = 400):
    """A log at 100 Hz whose load encoder column q reads 0 in every row while the motor turns 30 deg."""
    t = np.arange(samples) * 0.01
    th = 0.3 * np.sin(t)
    rows = "\n".join(f"{a:.4f},0,{b:.6f},{0.5 * np.cos(a):.5f}" for a, b in zip(t, th))
    p.write_text("t,q,theta_m,tau_m\n" + rows + "\n")
    return p


@pytest.mark.parametrize("argv", [
    ["replay", "LOG", "--config", CFG, "--estimator", "akf", "--out", "OUT/est.csv"],
    ["replay", "LOG", "--config", CFG, "--estimator", "spring", "--out", "OUT/est.csv"],
    ["calibrate-bound", "LOG", "--config", CFG, "--model", "OUT/m.npz"],
    ["diagnose", "GOOD", "--config", CFG, "--apply", "LOG", "--out", "OUT/diag", "--no-plots"],
])
def test_a_dead_encoder_column_is_named_before_any_estimator_runs(tmp_path, capsys, argv):
    # the AKF used to run into it and stop on an NIS divergence a few hundred samples in
    from _cli import passive_log
    log = _dead_q_log(tmp_path / "dead.csv")
    good = passive_log(tmp_path / "good.csv", 600)
    (tmp_path / "m.npz").write_bytes(b"")
    sub = {"LOG": log, "GOOD": good}
    args = [sub.get(a, str(a).replace("OUT", str(tmp_path))) for a in argv]
    code, _, err = run(args, capsys)
    refused(code, err, r"column q is 0 rad in all 400 rows while theta_m spans 30\.1 deg: the load encoder reports nothing")
    assert not (tmp_path / "est.csv").exists()
