"""diagnose's 95 % intervals say what the log supports: never a near-zero width for a parameter
the log does not determine, never "high" confidence without a measured interval.

The joint refinement's Gauss–Newton covariance s²(JᵀJ)⁻¹ drops a direction the log does not
determine (a Jacobian column that is ~0 next to others): the pseudo-inverse reports a variance
of ~0 there, an interval x ± 1e-14.  Such an interval is replaced by the profile-likelihood
one, whose ends are where the fit, the other parameters refitted, has become worse by Z95²
(a parameter's bound, or no end, when it never does).  Small seeded logs (600–700 samples).
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from sea_daemon.analysis.diagnose.candidates import CoggingC, CoulombC
from sea_daemon.analysis.diagnose.conflict import undetermined
from sea_daemon.analysis.diagnose.context import Context
from sea_daemon.analysis.diagnose.fitting import LinearFits
from sea_daemon.analysis.diagnose.options import SelectOptions
from sea_daemon.analysis.diagnose.records import CandidateFit, Selection
from sea_daemon.analysis.diagnose.refine import Refinement
from sea_daemon.analysis.diagnose.residuals import kinematics_from_log
from sea_daemon.analysis.diagnose.samples import FitSamples
from sea_daemon.analysis.diagnose.summary import effects_json
from sea_daemon.core.effects import make_effect
from sea_daemon.io.configfile import load_config

from diagnose_sim import passive_log
from test_diagnose_offpath import EXO, constant_log

V_STICK = (0.03, 0.03)


def refine(log, cfg, pairs, passive=True):
    """The joint refinement (:meth:`Refinement.finish`) of ``pairs`` (candidate, initial
    parameters) on ``log``, as the selection runs it; the Refinement and the Selection."""
    ctx = Context(cfg, kinematics_from_log(log), None, passive=passive, v_stick=V_STICK)
    ctx.r0 = ctx.residual()
    opts = SelectOptions(min_effect_rms=0.01)
    samples = FitSamples.build(ctx, opts, None, V_STICK)
    ref = Refinement(LinearFits(ctx, samples), opts)
    fits = [CandidateFit(c, None, np.zeros(0), math.nan, None, np.zeros((samples.M, 0)), params=dict(p), fixed=True)
            for c, p in pairs]
    sel = ref.finish(fits, [dict(p) for _, p in pairs], [], [[]] * len(pairs), float(samples.y0 @ samples.y0))
    return ref, sel


@pytest.fixture(scope="module")
def plain():
    """The passive scenario's log against its true plant: nothing undeclared."""
    return passive_log([])


def test_a_direction_the_log_does_not_determine_gets_no_near_zero_interval(plain):
    # a ripple of 1 nN m on a log without one: the period and the phase change nothing the log
    # can see (their Jacobian columns ~1e-9 of the amplitude's); s²(JᵀJ)⁻¹ gave them ±1e-14
    log, cfg = plain
    _, sel = refine(log, cfg, [(CoggingC("motor"), {"A": 1e-9, "periods": 50.0, "phi": 0.3})])
    (_, p), ci = sel.chosen[0], sel.ci[0]
    for name in ("periods", "phi"):
        lo, hi = ci[name]
        assert hi - lo > 1.0, (name, ci)           # not x ± 1e-14: the log does not tell it
    assert ci["periods"][1] == math.inf            # no period is excluded from above
    assert ci["A"][0] <= 0.0                       # nor the ripple's absence
    assert undetermined(sel, 0)                    # not added
    d = effects_json(sel, 1, False)[0]
    assert d["confidence"] == "low" and "periods" in d["ci95_not_measurable"], d
    assert "lower_bound_only" not in d


def test_coulomb_on_constant_angles_is_not_bounded_away_from_zero():
    # the log: a joint that never moved.  Friction held within its static band changes
    # nothing on it, so F_c = 0 fits as well as any value up to the largest torque the log puts
    # on the load side (the refinement's bound); the Wald interval claimed F_c > 0.012 N m and
    # reached twice that bound
    cfg = load_config(EXO)
    ref, sel = refine(constant_log(), cfg, [(CoulombC("load"), {"F_c": 3.84})], passive=False)
    lo, hi = sel.ci[0]["F_c"]
    top = CoulombC("load").bounds(ref.ctx)["F_c"][1]
    assert lo <= 0.0 and hi <= top + 1e-9, (lo, hi, top)
    assert undetermined(sel, 0)
    assert effects_json(sel, 1, False)[0]["confidence"] == "low"


def test_an_interval_the_log_supports_stays_the_gauss_newton_one():
    # a load Coulomb friction the log holds (moves both ways): x ± Z95 se, the truth inside
    log, cfg = passive_log([make_effect("coulomb", "load", F_c=0.3)])
    _, sel = refine(log, cfg, [(CoulombC("load"), {"F_c": 0.3})])
    F_c = sel.chosen[0][1]["F_c"]
    lo, hi = sel.ci[0]["F_c"]
    assert lo < 0.3 < hi and hi - lo < 0.05
    assert (F_c - lo) == pytest.approx(hi - F_c, rel=1e-9)          # symmetric: Wald
    assert not undetermined(sel, 0)
    assert effects_json(sel, 1, False)[0]["confidence"] == "high"


def test_an_interval_without_an_end_is_not_measured_nor_high_confidence():
    # only a static friction's profile interval means "at least"; any other interval without an
    # end is one the log does not measure
    sel = Selection(chosen=[(CoulombC("load"), {"F_c": 0.3})], ci=[{"F_c": (0.29, math.inf)}], explained=[0.95],
                    unexplained=0.05, steps=[], alternatives=[[]], tau_int=1.0, structure={}, rss0=1.0,
                    rss_final=0.05, r_final=np.zeros((1, 2)))
    d = effects_json(sel, 1, False)[0]
    assert d["confidence"] == "low" and d["ci95_not_measurable"] == ["F_c"], d
    assert "lower_bound_only" not in d
    assert undetermined(sel, 0)
    sel.profiled = {(0, "F_c")}                    # the sticking phases' lower bound
    d = effects_json(sel, 1, False)[0]
    assert d["lower_bound_only"] == ["F_c"] and not undetermined(sel, 0)

