"""The linear stage of the selection: forward selection on the moving samples (:mod:`.select`).

At each step every remaining candidate is fitted jointly with the effects already chosen
(:class:`.fitting.LinearFits`) and ranked by BIC with the effective sample size M / τ_int and
a look-elsewhere penalty 2 ln G for a parameter chosen from G grid values; the best that
passes every acceptance test (:meth:`LinearStage.reasons_against`) is taken.  The stage ends
when none passes, no candidate is left or ``max_effects`` are chosen.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from sea_daemon.analysis.diagnose.candidates import Candidate
from sea_daemon.analysis.diagnose.fitting import LinearFits
from sea_daemon.analysis.diagnose.options import SelectOptions
from sea_daemon.analysis.diagnose.records import CandidateFit, SelectionStep
from sea_daemon.analysis.diagnose.residuals import integrated_autocorr_time
from sea_daemon.analysis.diagnose.samples import lstsq


@dataclass
class SelectionState:
    """Where the forward selection stands (both stages update it)."""

    y: np.ndarray                       # (M,) target: the residual minus the chosen offsets o(θ)
    base_X: np.ndarray                  # (M, k) the chosen effects' columns
    chosen: list[CandidateFit]
    remaining: list[Candidate]          # candidates still to try
    n_par: int = 0                      # parameters of the chosen effects
    step: int = 0
    steps: list[SelectionStep] = field(default_factory=list)
    alternatives: list[list[str]] = field(default_factory=list)    # per chosen effect

    def drop_same_kind(self, cand: Candidate) -> None:
        """No second copy of the same type on the same side and joint."""
        self.remaining = [c for c in self.remaining if not (c.type == cand.type and c.side == cand.side
                                                            and c.joint == cand.joint)]


class Baseline(NamedTuple):
    """The scores of the model chosen so far, which a candidate must beat."""

    rss: float                          # sum of squares on the fitted values
    bic: float
    cv: float                           # blocked cross-validated mean square
    all: float                          # sum of squares over every sample of the fit block
    n_eff: float                        # effective sample size M / τ_int


#: BIC values closer than this are a tie: alternatives that explain the residual equally (an
#: encoder offset on the motor or, with the opposite sign, on the load) differ only by rounding
BIC_TIE = 1e-6


def tie_ordered(fits: list, order: list[str]) -> list:
    """``fits`` best BIC first; within a tie (:data:`BIC_TIE`) the one with fewer parameters,
    then the one declared first (``order``: candidate names), so that rounding — a shifted time
    origin, another BLAS — never decides between equivalent explanations."""
    fits = sorted(fits, key=lambda f: f.bic)
    rank = {name: i for i, name in enumerate(order)}
    out, i = [], 0
    while i < len(fits):
        j = i + 1
        while j < len(fits) and fits[j].bic - fits[i].bic < BIC_TIE:
            j += 1
        out += sorted(fits[i:j], key=lambda f: (len(f.cand.linear) + bool(f.cand.nonlinear),
                                                 rank.get(f.cand.name, len(rank))))
        i = j
    return out


class LinearStage:
    """Forward selection over the moving samples (see the module docstring).

    ``rss0``: sum of squares of the configured model on the fitted values; ``all0``: over every
    sample of the fit block (the shares' denominators)."""

    def __init__(self, fits: LinearFits, opts: SelectOptions, rss0: float, all0: float):
        self.fits = fits
        self.ctx = fits.ctx
        self.opts = opts
        self.M = fits.samples.M
        self.rss0 = rss0
        self.all0 = all0

    def run(self, st: SelectionState) -> None:
        """Add effects to ``st`` while one passes every test."""
        for _ in range(self.opts.max_effects - len(st.chosen)):
            st.step += 1
            cur = self.baseline(st)
            fits = self.ranked(st, cur)
            if not fits:
                st.steps.append(SelectionStep(st.step, [], None, "no candidate applicable"))
                break
            rows = [{"candidate": f.cand.name, "type": f.cand.type, "side": f.cand.side,
                     "params": {k: round(v, 6) for k, v in f.params.items()},
                     "explains": (cur.rss - f.rss) / self.rss0, "delta_bic": f.bic - cur.bic} for f in fits]
            # the best by BIC that passes every test; candidates whose BIC does not fall end the search
            best, rejected = None, []
            for f in fits:
                why = self.reasons_against(f, st, cur)
                if not why:
                    best = f
                    break
                rejected.append(f"{f.cand.name}: " + "; ".join(why))
                if not f.bic < cur.bic:
                    break
            if best is None:
                st.steps.append(SelectionStep(st.step, rows, None, "no candidate accepted — " + " | ".join(rejected[:3])))
                break
            self.take(best, fits, rows, rejected, st, cur)
            if not st.remaining:
                break

    def baseline(self, st: SelectionState) -> Baseline:
        """The scores of the effects chosen so far."""
        beta_cur = lstsq(st.base_X, st.y)
        res_cur = st.y - (st.base_X @ beta_cur if st.base_X.shape[1] else 0.0)
        rss_cur = float(res_cur @ res_cur)
        tau = integrated_autocorr_time(self.fits.as_channels(res_cur))
        n_eff = max(self.M / tau, 2.0)
        bic_cur = n_eff * math.log(rss_cur / self.M) + st.n_par * math.log(n_eff)
        cv_cur = self.fits.cv_mse(st.y, st.base_X)
        all_cur = self.fits.rss_all(self.fits.effects_from(st.chosen, beta_cur)) if st.chosen else self.all0
        return Baseline(rss_cur, bic_cur, cv_cur, all_cur, n_eff)

    def ranked(self, st: SelectionState, cur: Baseline) -> list[CandidateFit]:
        """Every remaining candidate fitted with its BIC, best first (of two that fit equally
        well, the one with fewer parameters)."""
        n_eff = cur.n_eff
        fits = []
        for cand in st.remaining:
            fit = self.fits.fit_candidate(cand, st.y, st.base_X)
            k = st.n_par + len(cand.linear) + (1 if cand.nonlinear else 0)
            # a parameter chosen from G grid values costs ≈ 2 ln G more (the best of G
            # tries fits noise better: Bonferroni-style look-elsewhere penalty)
            look = (2.0 * math.log(max(len(cand.grid(self.ctx)), 1))
                    if cand.nonlinear and not getattr(cand, "gauss_newton", False) else 0.0)
            fit.bic = n_eff * math.log(max(fit.rss, 1e-300) / self.M) + k * math.log(n_eff) + look
            fits.append(fit)
        fits = [f for f in fits if np.isfinite(f.rss)]
        return tie_ordered(fits, [c.name for c in st.remaining])

    def reasons_against(self, f: CandidateFit, st: SelectionState, cur: Baseline) -> list[str]:
        """Why ``f`` is not accepted (empty: accepted): BIC does not fall, not physical, the
        held-out mean square falls by less than ``min_cv_gain``, its share is below
        ``min_effect_rms``, it explains less than ``min_fraction`` of the initial and
        ``min_fraction_current`` of the current mean square.  Sets ``f.cv`` and ``f.frac_all``."""
        o_cfg = self.opts
        out = []
        if not f.bic < cur.bic:
            out.append(f"BIC does not fall ({f.bic - cur.bic:+.1f})")
            return out
        why = self.fits.unphysical(f, st.chosen)
        if why:
            out.append(why)
            return out
        f.cv = self.fits.cv_mse(st.y, st.base_X, f.o, f.X)
        if not f.cv < cur.cv * (1.0 - o_cfg.min_cv_gain):
            out.append(f"held-out mean square falls only {100 * (1 - f.cv / cur.cv):.1f} % "
                       f"(< {100 * o_cfg.min_cv_gain:.0f} %)")
        eff_rms = self.fits.contribution_rms(f)
        if eff_rms < o_cfg.min_effect_rms:
            out.append(f"its share of the residual is {eff_rms:.4f} N m RMS (< {o_cfg.min_effect_rms} N m)")
        # its size, on the fitted samples and on the whole log (sticking phases included,
        # which the fit leaves out): worth a term if it takes a good part of either
        gain_all = cur.all - self.fits.rss_all(self.fits.effects_from(st.chosen + [f], f.beta))
        fr, fr_cur = gain_all / self.all0, gain_all / cur.all
        fit_fr, fit_cur = (cur.rss - f.rss) / self.rss0, (cur.rss - f.rss) / cur.rss
        f.frac_all = fr
        if max(fr, fit_fr) < o_cfg.min_fraction and max(fr_cur, fit_cur) < o_cfg.min_fraction_current:
            out.append(f"explains {100 * max(fr, fit_fr):.1f} % of the initial mean square "
                       f"(< {100 * o_cfg.min_fraction:.0f} %) and {100 * max(fr_cur, fit_cur):.1f} % of "
                       f"what is left (< {100 * o_cfg.min_fraction_current:.0f} %)")
        return out

    def take(self, best: CandidateFit, fits: list[CandidateFit], rows: list[dict], rejected: list[str],
             st: SelectionState, cur: Baseline) -> None:
        """Add ``best`` to ``st``, with the step's record and the near-ties as alternatives."""
        o_cfg = self.opts
        frac = best.frac_all
        gain = cur.rss - best.rss
        # nearly as good: explains ≥ 90 % as much and BIC not worse by 10 or more (Kass &
        # Raftery: ΔBIC > 10 is very strong evidence for the better one)
        alts = [f.cand.name for f in fits if f is not best and gain > 0 and (cur.rss - f.rss) >= o_cfg.ambiguity * gain
                and f.bic - best.bic < o_cfg.ambiguity_bic and not self.fits.unphysical(f, st.chosen)]
        st.alternatives.append(alts)
        st.steps.append(SelectionStep(st.step, rows, best.cand.name,
                                   f"{best.cand.name} explains {100 * frac:.1f} % of the initial mean square; "
                                   f"ΔBIC {best.bic - cur.bic:+.1f}; held-out mean square −{100 * (1 - best.cv / cur.cv):.1f} %"
                                   + (f"; nearly as good: {', '.join(alts)}" if alts else "")
                                   + (f"; ranked above it but rejected — {' | '.join(rejected)}" if rejected else "")))
        st.chosen.append(best)
        st.n_par += len(best.cand.linear) + (1 if best.cand.nonlinear else 0)
        if best.o is not None:
            st.y = st.y - best.o
        st.base_X = np.hstack([st.base_X, best.X]) if best.X.shape[1] else st.base_X
        st.drop_same_kind(best.cand)
