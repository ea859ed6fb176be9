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



def _profiled_static_friction(upper_bounded: bool):
    """:meth:`Refinement._lower_bounded` on one Coulomb amplitude x̂ = 1 whose residual is
    r0 + g·min(v − 1, 0) (the log bounds it from below only) or r0 + g·(v − 1) (from both sides),
    r0 ⟂ g, |r0|² = 1, 100 independent samples: −2 log L rises by 100 ln(1 + |g|²(v − 1)²)."""
    rng = np.random.default_rng(3)
    r0, g = rng.normal(size=100), rng.normal(size=100)
    g -= (g @ r0) / (r0 @ r0) * r0
    r0 /= np.linalg.norm(r0)
    g *= 0.2 / np.linalg.norm(g)

    def fun(x):
        d = x[0] - 1.0
        return r0 + g * (d if upper_bounded else min(d, 0.0))
    x = np.array([1.0])
    chosen = [CandidateFit(CoulombC("load"), None, np.zeros(0), math.nan, None, np.zeros((1, 0)))]
    ref = Refinement.__new__(Refinement)
    out = ref._lower_bounded(fun, x, [(0, "F_c")], chosen, fun(x), 1.0, np.array([1.0]),
                             np.array([0.0]), np.array([100.0]), np.array([1.0]))
    return out, x


def edge(level):
    """Where 100 ln(1 + 0.04 (v − 1)²) reaches ``level`` below 1."""
    return 1.0 - math.sqrt(math.expm1(level / 100) / 0.04)


def test_static_friction_bounded_from_below_only_is_at_least_its_one_sided_95_bound():
    """The "at least" of a static friction (no upper end) is its one-sided 95 % lower bound: the
    rise of −2 log L there is z₀.₉₅² ≈ 2.71 (not 1, a 68 % level); the amplitude moves to it."""
    out, x = _profiled_static_friction(upper_bounded=False)
    lower, upper = out[0]
    assert upper == math.inf
    assert lower == pytest.approx(edge(1.6448536269514722 ** 2), abs=1e-3)
    assert x[0] == pytest.approx(lower)


def test_static_friction_with_both_ends_gets_a_two_sided_95_interval():
    """With an upper end, the interval is two-sided 95 %: its lower edge where the rise is
    Z95² ≈ 3.84, its upper end the first tried multiple of the value beyond that (outward)."""
    out, x = _profiled_static_friction(upper_bounded=True)
    lower, upper = out[0]
    assert lower == pytest.approx(edge(1.959963984540054 ** 2), abs=1e-3)
    assert upper == 2.0 * 1.0 and 2.0 - 1.0 > 1.0 - edge(1.959963984540054 ** 2)
    assert x[0] == 1.0
