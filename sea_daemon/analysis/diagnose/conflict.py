"""Two chosen effects that trade against each other, and effects the log does not determine.

After the joint refinement (:mod:`.refine`) two correlated effects can trade one for the other
(the log does not tell them apart).  :func:`find_conflict` names such a pair; the selection
(:mod:`.select`) keeps the physically sensible one and runs again without the other.
:func:`undetermined` is the interval test that drops an effect whose parameters the log does
not determine.
"""
from __future__ import annotations

import numpy as np

from sea_daemon.analysis.diagnose.context import Context
from sea_daemon.analysis.diagnose.records import Selection


def undetermined(sel: Selection, i: int) -> bool:
    """The interval test: an effect with a parameter whose 95 % interval reaches 0 (for an
    interval x ± h: wider than the value; a static friction's profile interval, bounded from
    below only: its lower end at 0), or has no end on one side (the log does not bound that
    parameter).  Angles and rest positions (phi, q_h0), which may rightly be near 0, are judged
    by the second alone."""
    for k, (lo, hi) in sel.ci[i].items():
        if np.isnan(lo) or np.isnan(hi):
            continue                   # no interval at all (the refinement failed): not judged
        if (i, k) in sel.profiled:
            if lo <= 0.0:
                return True
            continue
        if not (np.isfinite(lo) and np.isfinite(hi)):
            return True
        if k not in ("phi", "q_h0") and lo <= 0.0 <= hi:
            return True
    return False


def find_conflict(ctx: Context, sel: Selection, stepwise: list[dict], max_correlation: float):
    """A pair of chosen effects the joint refinement cannot keep both of, or None.

    Returns (index to drop, index kept, correlation, reason).  An effect is in conflict
    when the refinement left it physically implausible (:meth:`.Candidate.implausible`),
    took it away (its magnitude below a fifth of its stepwise value ``stepwise[i]``) or pushed
    it to the edge of its physical range, with another effect correlated with it; or when the
    log does not determine it (interval wider than its value) and its parameters correlate
    beyond ``max_correlation`` with another's.  Of the pair, the one kept is the
    physically sensible one: plausible at its own stepwise fit, then the one with the
    higher physical prior (:attr:`.candidates.Candidate.prior`: an arm's weight over an
    elbow's stiffness), then the earlier chosen (it explained more when it was chosen); the
    other is dropped.
    """
    if sel.corr is None:
        return None
    for i in range(len(sel.chosen)):
        why = _trouble(ctx, sel, stepwise, i)
        # below 0.5 it is not a trade between two effects: left to the interval test
        pair = _partner(ctx, sel, stepwise, i, 0.5) if why else None
        if pair is not None:
            return pair[0], pair[1], pair[2], f"{sel.chosen[i][0].name}: {why}"
    # an effect the log does not determine (interval wider than its value) because it
    # trades against another one: the pair is reported and the sensible one kept (the
    # interval test alone would drop it, and a clear effect with it)
    for i in range(len(sel.chosen)):
        pair = _partner(ctx, sel, stepwise, i, max_correlation) if undetermined(sel, i) else None
        if pair is not None:
            drop, keep, r, j = pair
            return drop, keep, r, (f"{sel.chosen[i][0].name}'s interval is wider than its value, its "
                                   f"parameters correlated {r:+.2f} with {sel.chosen[j][0].name}'s")
    return None


def _rho(sel: Selection, i: int, j: int) -> float:
    """The largest (in magnitude) correlation between a parameter of effect i and one of j."""
    corr, idx = sel.corr, sel.param_index
    vals = [corr[a, b] for a, (ia, _) in enumerate(idx) for b, (ib, _) in enumerate(idx)
            if ia == i and ib == j and np.isfinite(corr[a, b])]
    return max(vals, key=abs) if vals else 0.0


def _trouble(ctx: Context, sel: Selection, stepwise: list[dict], i: int) -> str | None:
    """What the refinement did to effect i that it should not have, or None."""
    cand, p = sel.chosen[i]
    p0 = stepwise[i]
    why = cand.implausible(ctx, p)
    if why:
        return why
    mag, mag0 = cand.magnitude(p), cand.magnitude(p0)
    if mag is not None and mag0 and abs(mag) < 0.2 * abs(mag0):
        return f"the joint refinement took it away ({cand.describe(p0)} → {cand.describe(p)})"
    for name, (lo, hi) in cand.bounds(ctx).items():
        for b in (lo, hi):
            if not np.isfinite(b) or name not in p:
                continue
            tol = 1e-3 * max(abs(b), abs(p0.get(name, b)), 1e-9)
            if abs(p[name] - b) <= tol and abs(p0.get(name, np.inf) - b) > tol:
                return (f"the joint refinement pushed it to the edge of its physical range "
                        f"({cand.describe(p0)} → {cand.describe(p)})")
    return None


def _partner(ctx: Context, sel: Selection, stepwise: list[dict], i: int, min_rho: float):
    """The effect most correlated with i, if beyond ``min_rho``, and the pair's
    (drop, keep, correlation, partner): the physically sensible one — plausible at its
    stepwise fit, then the higher prior, then the earlier chosen — is kept."""
    K = len(sel.chosen)
    j = max((j for j in range(K) if j != i), key=lambda j: abs(_rho(sel, i, j)))
    r = float(_rho(sel, i, j))
    if abs(r) < min_rho:
        return None
    bad_i = sel.chosen[i][0].implausible(ctx, stepwise[i])
    bad_j = sel.chosen[j][0].implausible(ctx, stepwise[j])
    if bad_i and not bad_j:
        keep, drop = j, i
    elif bad_j and not bad_i:
        keep, drop = i, j
    else:
        pi, pj = sel.chosen[i][0].prior, sel.chosen[j][0].prior
        if pi != pj:
            keep, drop = (i, j) if pi > pj else (j, i)
        else:
            keep, drop = (i, j) if i < j else (j, i)
    return drop, keep, r, j
