"""A Stribeck hump that no moving sample reaches is not identified, and not added.

Only the samples that move (faster than the stick speed, below which friction is
set-valued) and are slower than about 2 v_s see the hump's shape; a hump with v_s above a
third of the stick speed but 2 v_s below it (two-joint plant 3's calibration: v_s 0.013 rad/s,
stick speed 0.03 rad/s, F_s 12 N m) only raises the static limit of the sticking samples, and
its height is whatever the refinement makes of that.  The seeded passive log of
``diagnose_sim`` (stick speed 0.03 rad/s on both sides) has no moving sample below 0.03 rad/s.
"""
from __future__ import annotations

import pytest

from sea_daemon.analysis.diagnose.candidates import StribeckC
from sea_daemon.analysis.diagnose.context import Context
from sea_daemon.analysis.diagnose.residuals import kinematics_from_log

from diagnose_sim import passive_log

V_STICK = (0.03, 0.03)


@pytest.fixture(scope="module")
def ctx():
    log, cfg = passive_log([])
    return Context(cfg, kinematics_from_log(log), None, passive=True, v_stick=V_STICK)


@pytest.mark.parametrize("side", ["load", "motor"])
def test_hump_below_the_stick_speed_reach_is_refused(ctx, side):
    c = StribeckC(side)
    # v_s above a third of the stick speed (physical by that test) but 2 v_s below it
    p = {"F_s": 0.5, "v_s": 0.013}
    why = c.implausible(ctx, p)
    assert why is not None and "not identified" in why, why
    assert c.unidentified(ctx, p) == why


@pytest.mark.parametrize("side", ["load", "motor"])
def test_hump_the_log_reaches_is_kept(ctx, side):
    # v_s 0.05 rad/s: the passive log moves between 0.03 and 0.1 rad/s on many samples
    c = StribeckC(side)
    p = {"F_s": 0.3, "v_s": 0.05}
    assert c.unidentified(ctx, p) is None
    assert c.implausible(ctx, p) is None
