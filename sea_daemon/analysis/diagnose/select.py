"""Choosing the effects the evidence supports: the selection and its stages.

Forward selection on the stacked two-channel residual y = [r_load, r_motor] (flattened):

The stages, each in its module: the samples fitted (:mod:`.samples`), one candidate's fit
(:mod:`.fitting`), the linear stage (:mod:`.linear`), the low-speed stage (:mod:`.lowspeed`),
the joint refinement with intervals and shares (:mod:`.refine`), conflicts between correlated
effects (:mod:`.conflict`) and the leftover structure (:mod:`.structure`); :class:`Selector`
runs them in turn.

1. At each step every remaining candidate is fitted jointly with the effects already
   chosen: its nonlinear parameter θ on a grid (plus a bounded 1-D refinement between the
   best grid neighbours), all linear coefficients by least squares.
2. Candidates are ranked by BIC; the best one that passes every test is accepted:
   * BIC falls, with the *effective* sample size N_eff = M / τ_int (τ_int the integrated
     autocorrelation time of the current residual: smoothed derivatives make neighbouring
     samples dependent, so M samples carry fewer independent observations);
   * blocked cross-validation (K contiguous time segments held out in turn, the linear
     coefficients refitted on the rest) lowers the held-out mean square by at least
     ``min_cv_gain`` (relative);
   * the step explains at least ``min_fraction`` of the *initial* mean square or
     ``min_fraction_current`` of what is still unexplained (on the fitted samples or on the
     whole log, sticking phases included), and its share of the residual is
     at least ``min_effect_rms`` N m RMS over the whole log (a practical size floor:
     statistically real but negligible structure is not worth a model term; by default a
     tenth of the RMS commanded torque, at most 0.01 N m: :func:`size_floor`).
   When none passes, the linear stage stops (:mod:`.linear`).
   Then the low-speed stage (:mod:`.lowspeed`) tries friction on every sample, set-valued
   while a side sticks.  A candidate that is not physical (:meth:`Candidate.implausible`),
   or pulls an effect already chosen out of its physical range, is rejected.
3. The chosen effects' natural parameters (F_c, v_s, δ, width, ...) are refined jointly by
   nonlinear least squares on the exact residual of the augmented model
   (scipy.optimize.least_squares) over every sample of the fit; confidence intervals from the
   Gauss–Newton covariance s²(JᵀJ)⁻¹ inflated by τ_int of the final residual (Wald, 95 %),
   profile-likelihood intervals for static-friction amplitudes the log bounds loosely
   (:mod:`.refine`).  Two effects that trade against each other
   (:func:`.conflict.find_conflict`): the sensible one is kept and the selection reruns without
   the other; then effects the log does not determine are dropped.
4. Explained fractions: sequential decrease of the mean square, in the order chosen, at the
   final parameters, divided by the initial mean square; the rest is unexplained.
5. What remains is checked for structure that no candidate took: bin means of the final
   residual against q, q̇, θ_s, θ_m and (q, sign q̇); the largest share of the remaining
   mean square such a lookup explains (less its chance level) is reported as
   ``structured_unexplained_fraction`` of the initial mean square, with the signals it
   follows (:mod:`.structure`).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from sea_daemon.analysis.diagnose.candidates import Candidate
from sea_daemon.analysis.diagnose.conflict import find_conflict, undetermined
from sea_daemon.analysis.diagnose.context import Context
from sea_daemon.analysis.diagnose.fitting import LinearFits
from sea_daemon.analysis.diagnose.linear import LinearStage, SelectionState
from sea_daemon.analysis.diagnose.lowspeed import LowSpeedStage
from sea_daemon.analysis.diagnose.options import SelectOptions, size_floor
from sea_daemon.analysis.diagnose.records import CandidateFit, Selection, SelectionStep
from sea_daemon.analysis.diagnose.refine import Refinement
from sea_daemon.analysis.diagnose.samples import FitSamples, fit_stride, lstsq

__all__ = ["Selector", "SelectOptions", "Selection", "SelectionStep", "CandidateFit", "size_floor"]


class Selector:
    """Forward selection over ``cands`` (see the module docstring).

    ``fit_t`` (N,) bool: the time samples the fit may use (the fit block of a held-out
    validation; default all).  ``v_min`` (load, motor) [rad/s]: the speeds below which a side
    counts as slow (default ``opts.v_min``, else 3 × sign_eps on both sides).
    """

    #: every how many samples the linear stage fits (:func:`.samples.fit_stride`)
    fit_stride = staticmethod(fit_stride)

    def __init__(self, ctx: Context, cands: list[Candidate], opts: SelectOptions | None = None,
                 fit_t: np.ndarray | None = None, v_min: tuple[float, float] | None = None):
        self.ctx = ctx
        self.cands = cands
        self.opts = dataclasses.replace(opts) if opts is not None else SelectOptions()
        if self.opts.min_effect_rms is None:
            self.opts.min_effect_rms = size_floor(ctx.kin.tau_m)
        self.samples = FitSamples.build(ctx, self.opts, fit_t, v_min)
        self.fits = LinearFits(ctx, self.samples)
        self.refinement = Refinement(self.fits, self.opts)
        #: the natural parameters of the last selection's effects before the joint refinement
        self.stepwise: list[dict] = []
        self.final = None

    # ---------------------------------------------------------------- the samples
    @property
    def edge(self) -> int:
        """Samples dropped at each end of the log."""
        return self.samples.edge

    @property
    def keep_t(self) -> np.ndarray:
        """(N,) the samples the linear stage fits."""
        return self.samples.keep_t

    @property
    def all_t(self) -> np.ndarray:
        """(N,) every sample of the fit block."""
        return self.samples.all_t

    @property
    def stride(self) -> int:
        """The linear stage fits every stride-th sample."""
        return self.samples.stride

    @property
    def masked_share(self) -> float:
        """Share of the fit block the linear stage leaves out (slow samples)."""
        return self.samples.masked_share

    @property
    def v_min(self) -> tuple[float, float]:
        """[rad/s] (load, motor) speeds below which a side counts as slow."""
        return self.samples.v_min

    # ---------------------------------------------------------------- forward selection
    def _select(self, excluded: frozenset = frozenset()):
        """Forward selection (linear stage, then the low-speed stage, in turn) over the
        candidates not in ``excluded`` (names); returns (state, stepwise params, rss0)."""
        o_cfg = self.opts
        s = self.samples
        rss0 = float(s.y0 @ s.y0)
        all0 = self.fits.rss_all([])
        st = SelectionState(s.y0.copy(), np.zeros((s.M, 0)), [], [c for c in self.cands if c.name not in excluded])
        linear = LinearStage(self.fits, o_cfg, rss0, all0)
        y_lin = st.y           # the target without the effects the low-speed stage holds
        while True:
            st.y = y_lin
            linear.run(st)
            # initial natural parameters from the joint linear solution (held ones as held)
            init = self._initial(st)
            # friction where it acts: every sample of the fit block, set-valued while sticking;
            # what it adds is held while the linear stage runs again (a pair such as friction and
            # an offset is weak one at a time in the linear stage)
            if not (o_cfg.low_speed and len(st.chosen) < o_cfg.max_effects):
                break
            new = self._low_speed(st, init, excluded, all0)
            if not new or not st.remaining or len(st.chosen) >= o_cfg.max_effects:
                break
            held = [f.cand.effect(f.params) for f in st.chosen if f.fixed]
            o_held = (self.ctx.r0 - self.ctx.residual(held)).reshape(-1)[s.valid]
            y_lin = s.y0 - o_held - sum((f.o for f in st.chosen if f.o is not None), np.zeros_like(s.y0))
        return st, init, rss0

    def _low_speed(self, st: SelectionState, init: list[dict], excluded: frozenset, all0: float) -> list:
        """The low-speed stage (:mod:`.lowspeed`) from ``st``: what it adds is appended to ``st``
        (held at its parameters) and to ``init``; returns the new (candidate, params) pairs."""
        o_cfg = self.opts
        stage = LowSpeedStage(self.ctx, o_cfg, self.samples)
        new, lsteps, lalts = stage.run([(f.cand, p) for f, p in zip(st.chosen, init)],
                                       [c for c in self.cands if c.name not in excluded],
                                       all0, o_cfg.max_effects - len(st.chosen))
        for rows, name, reason in lsteps:
            st.step += 1
            st.steps.append(SelectionStep(st.step, rows, name, reason))
        for (cand, p), alts in zip(new, lalts):
            st.chosen.append(CandidateFit(cand, p.get(cand.nonlinear) if cand.nonlinear else None,
                                          np.zeros(0), math.nan, None, np.zeros((self.samples.M, 0)),
                                          params=p, fixed=True))
            init.append(p)
            st.alternatives.append(alts)
            st.drop_same_kind(cand)
            st.n_par += len(cand.params)
        return new

    def _initial(self, st: SelectionState) -> list[dict]:
        """Natural parameters of the chosen effects from the joint linear solution of their
        columns (the low-speed stage's held ones as held)."""
        beta_all = lstsq(st.base_X, st.y)
        init, col = [], 0
        for f in st.chosen:
            k = f.X.shape[1]
            init.append(dict(f.params) if f.fixed else f.cand.natural(beta_all[col:col + k], f.theta))
            col += k
        return init

    def run(self) -> Selection:
        """Forward selection, joint refinement, conflicts between correlated effects, and the
        effects the log does not determine (see the module docstring)."""
        excluded: set[str] = set()
        correlated = []
        for _ in range(4):
            st, init, rss0 = self._select(frozenset(excluded))
            self.stepwise = [dict(p) for p in init]
            sel = self.refinement.finish(st.chosen, init, st.steps, st.alternatives, rss0)
            # joint refinement: two correlated effects can trade one for the other (the log
            # does not tell them apart).  One that the refinement pushes out of its physical
            # range or takes away, or an undetermined one correlated with another: the
            # physically sensible one is kept (:func:`.conflict.find_conflict`), the other leaves
            # the candidates and the selection runs again without it
            conflict = (find_conflict(self.ctx, sel, self.stepwise, self.opts.max_correlation)
                        if len(sel.chosen) > 1 else None)
            if conflict is None:
                break
            i_drop, i_keep, rho, why = conflict
            correlated.append({"kept": sel.chosen[i_keep][0].name, "dropped": sel.chosen[i_drop][0].name,
                               "correlation": float(rho), "reason": why,
                               "kept_params": dict(self.stepwise[i_keep]),
                               "dropped_params": dict(self.stepwise[i_drop])})
            excluded.add(sel.chosen[i_drop][0].name)
        sel = self._drop_undetermined(sel, st, rss0)
        sel.correlated = correlated
        return sel

    def _drop_undetermined(self, sel: Selection, st: SelectionState, rss0: float) -> Selection:
        """An effect whose parameters this log does not determine (95 % CI wider than the
        value on both sides) is not added: refit without it, until none is left."""
        chosen, alternatives = st.chosen, st.alternatives
        dropped = []
        while True:
            # (angles and rest positions — phi, q_h0 — may rightly be near 0: not judged this way)
            # (a friction amplitude with a profile interval — asymmetric, or bounded from below
            # only — is undetermined when that interval reaches 0)
            # (and one whose refined parameters the log's motion does not reach: Candidate.unidentified)
            why = [undetermined(sel, i) or c.unidentified(self.ctx, p) for i, (c, p) in enumerate(sel.chosen)]
            bad = [i for i, w in enumerate(why) if w]
            if not bad:
                break
            i = bad[0]
            dropped.append((sel.chosen[i][0].name, sel.chosen[i][1], sel.ci[i],
                            why[i] if isinstance(why[i], str) else None))
            keep = [k for k in range(len(chosen)) if k != i]
            chosen = [chosen[k] for k in keep]
            init = [sel.chosen[k][1] for k in keep]
            alternatives = [alternatives[k] for k in keep]
            sel = self.refinement.finish(chosen, init, st.steps, alternatives, rss0)
        sel.dropped = dropped
        #: what :meth:`restrict` refines again: the fits, alternatives and record of ``sel``
        self.final = (chosen, alternatives, st.steps, rss0)
        return sel

    def restrict(self, sel: Selection, keep: list[int]) -> Selection:
        """``sel`` (the last :meth:`run`'s) with only its effects ``keep`` (indices), refined
        jointly again: parameters, intervals and shares of the effects kept."""
        chosen, alternatives, steps, rss0 = self.final
        out = self.refinement.finish([chosen[k] for k in keep], [sel.chosen[k][1] for k in keep], steps,
                                     [alternatives[k] for k in keep], rss0)
        out.dropped, out.correlated = sel.dropped, sel.correlated
        return out

    def refit(self, pairs: list[tuple[Candidate, dict]], steps: int | None = None) -> list[tuple[Candidate, dict]]:
        """The given effects' parameters refitted jointly (nonlinear least squares on the exact
        residual; at most ``steps`` iterations, default 60 per parameter) over this selector's
        samples, from the given values: the same model structure fitted to another part of the log."""
        return self.refinement.refit(pairs, steps)
