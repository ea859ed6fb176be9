"""Fitting one candidate effect to the residual on the selection's samples (:mod:`.select`).

A candidate explains Δr(θ, β) = o(θ) + X(θ) β of the stacked residual (:mod:`.candidates`):
:class:`LinearFits` fits it jointly with the effects already chosen — θ on a grid with a bounded
1-D refinement (or by Gauss–Newton), β by least squares with the vocabulary's sign constraints —
and scores it (blocked cross-validated mean square, RMS of its share, the exact residual of the
model with effects).  Designs are cached per (candidate, θ).
"""
from __future__ import annotations

import math

import numpy as np
from scipy.optimize import minimize_scalar

from sea_daemon.analysis.diagnose.candidates import Candidate
from sea_daemon.analysis.diagnose.context import Context
from sea_daemon.analysis.diagnose.records import CandidateFit
from sea_daemon.analysis.diagnose.samples import FitSamples, lstsq


class LinearFits:
    """Candidate fits on ``samples`` of ``ctx``'s residual (see the module docstring)."""

    def __init__(self, ctx: Context, samples: FitSamples):
        self.ctx = ctx
        self.samples = samples
        self._cache: dict = {}
        self._full: dict = {}

    # ---------------------------------------------------------------- designs
    def design(self, cand: Candidate, theta):
        """(o, X) of ``cand`` at θ on the fitted values (cached; see :meth:`.Candidate.design`)."""
        key = (id(cand), None if theta is None else round(float(theta), 12))
        if key not in self._cache:
            o, X = cand.design(self.ctx, theta)
            c = self.ctx.r0.shape[1]
            # kept on the grid's samples only (every sample of a log up to max_fit_rows)
            if self.samples.stride > 1:
                o = None if o is None else o.reshape(-1, c)[self.samples.grid].reshape(-1)
                g = self.samples.grid
                X = X.reshape(self.ctx.kin.N, c, X.shape[1])[g].reshape(g.size * c, X.shape[1])
            v = self.samples.valid_in_grid
            self._cache[key] = (None if o is None else o[v], X[v])
            self._full[key] = (o, X)
        return self._cache[key]

    def contribution_rms(self, fit: CandidateFit) -> float:
        """RMS [N m] over all samples (not only the fitted ones; every ``stride``-th of a long
        log) of what the candidate explains."""
        key = (id(fit.cand), None if fit.theta is None else round(float(fit.theta), 12))
        if key not in self._full:
            self.design(fit.cand, fit.theta)
        o, X = self._full.get(key, (None, np.zeros((0, 0))))
        if o is None and X.shape[0] == 0:
            return 0.0
        k = X.shape[1]
        d = (o if o is not None else 0.0) + (X @ fit.beta[len(fit.beta) - k:] if k else 0.0)
        d = np.asarray(d, dtype=float)
        return float(np.sqrt(np.sum(d**2) / self.samples.grid.size))

    def fit_with(self, y, base_X, o, X, nonneg=()):
        """Least squares of y − o on [base_X, X]; coefficients of X listed in ``nonneg`` are
        held at 0 when they come out negative (the vocabulary's sign constraints)."""
        yy = y if o is None else y - o
        A = np.hstack([base_X, X]) if base_X.shape[1] else X
        beta = lstsq(A, yy)
        k0 = base_X.shape[1]
        bad = [k0 + i for i in nonneg if beta[k0 + i] < 0]
        if bad:
            keep = [i for i in range(A.shape[1]) if i not in bad]
            beta = np.zeros(A.shape[1])
            beta[keep] = lstsq(A[:, keep], yy)
        res = yy - (A @ beta if A.shape[1] else 0.0)
        return beta, float(res @ res)

    def gauss_newton(self, cand: Candidate, y, base_X, iters: int = 6) -> CandidateFit:
        """Δr(θ) exact, θ by Gauss–Newton from 0 with the chosen columns refitted each step."""
        lo, hi = cand.bounds(self.ctx)[cand.nonlinear]
        th = 0.0
        h = getattr(cand, "H", 1e-4)
        for _ in range(iters):
            o_p, _ = self.design(cand, th + h)
            o_m, _ = self.design(cand, th - h)
            o, _ = self.design(cand, th) if th != 0.0 else (None, None)
            J = ((o_p - o_m) / (2 * h))[:, None]
            beta, _ = self.fit_with(y, base_X, o, J)
            step = float(beta[-1])
            th_new = float(np.clip(th + step, lo, hi))
            done = abs(th_new - th) < 1e-7 + 1e-4 * abs(th_new)
            th = th_new
            if done:
                break
        o, X = self.design(cand, th)
        beta, rss = self.fit_with(y, base_X, o, X)
        fit = CandidateFit(cand, th, beta, rss, o, X)
        fit.params = cand.natural(beta[base_X.shape[1]:], th)
        return fit

    def fit_candidate(self, cand: Candidate, y, base_X) -> CandidateFit:
        """``cand`` fitted to ``y`` jointly with the chosen columns ``base_X``: θ on its grid (a
        cheap scan first for a long grid) and refined between the best point's neighbours."""
        if getattr(cand, "gauss_newton", False):
            return self.gauss_newton(cand, y, base_X)
        grid = cand.grid(self.ctx)
        fast = getattr(cand, "fast_design", None)
        if fast is not None and len(grid) > 40:
            # cheap scan (additive effect: columns straight from the signal), exact design after
            scores = []
            for th in grid:
                cols = np.column_stack([c[self.samples.valid] for c in fast(self.ctx, th)])
                _, rss = self.fit_with(y, base_X, None, cols, cand.nonneg)
                scores.append(rss)
            order = np.argsort(scores)[:3]
            grid_eval = [grid[i] for i in order]
        else:
            grid_eval = grid
        results = []
        if not grid_eval:
            return CandidateFit(cand, None, np.zeros(0), math.inf, None, np.zeros((self.samples.M, 0)))
        for th in grid_eval:
            o, X = self.design(cand, th)
            beta, rss = self.fit_with(y, base_X, o, X, cand.nonneg)
            results.append((rss, th, beta))
        results.sort(key=lambda r: r[0])
        rss, th, beta = results[0]
        if th is not None and len(grid) > 1:
            # bounded 1-D refinement between the best grid point's neighbours
            g = np.asarray(grid, float)
            i = int(np.argmin(np.abs(g - th)))
            lo, hi = g[max(i - 1, 0)], g[min(i + 1, len(g) - 1)]
            if hi > lo:
                def f(t):
                    o, X = cand.design(self.ctx, t)
                    o = None if o is None else o[self.samples.valid]
                    return self.fit_with(y, base_X, o, X[self.samples.valid], cand.nonneg)[1]
                r = minimize_scalar(f, bounds=(lo, hi), method="bounded", options={"xatol": (hi - lo) * 1e-3, "maxiter": 20})
                if r.fun < rss:
                    th = float(r.x)
                    o, X = self.design(cand, th)
                    beta, rss = self.fit_with(y, base_X, o, X, cand.nonneg)
        o, X = self.design(cand, th)
        fit = CandidateFit(cand, th, beta, rss, o, X)
        fit.params = cand.natural(beta[base_X.shape[1]:], th)
        return fit

    def cv_mse(self, y, base_X, o=None, X=None) -> float:
        """Blocked cross-validated mean square of y − o on [base_X, X] (coefficients refitted
        without each time block in turn)."""
        yy = y if o is None else y - o
        A = base_X if X is None else (np.hstack([base_X, X]) if base_X.shape[1] else X)
        err = 0.0
        for f in range(self.samples.fold.max() + 1):
            te = self.samples.fold == f
            tr = ~te
            beta = lstsq(A[tr], yy[tr])
            pred = A[te] @ beta if A.shape[1] else 0.0
            e = yy[te] - pred
            err += float(e @ e)
        return err / yy.size

    def unphysical(self, f: CandidateFit, chosen: list[CandidateFit]) -> str | None:
        """Why candidate fit ``f`` is not physical — itself, or because it pulls an effect
        already chosen out of its physical range (their coefficients are refitted with it:
        two that trade against each other) — or None."""
        why = f.cand.implausible(self.ctx, f.params)
        if why:
            return f"not physical: {why}"
        col = 0
        for g in chosen:
            k = g.X.shape[1]
            pg = g.params if g.fixed else g.cand.natural(f.beta[col:col + k], g.theta)
            col += k
            why = g.cand.implausible(self.ctx, pg)
            if why:
                return f"not physical with {g.cand.name}, which it pulls to {why}"
        return None

    def effects_from(self, fits: list[CandidateFit], beta: np.ndarray):
        """Effects with natural parameters from the joint coefficients of ``fits``' columns."""
        out, col = [], 0
        for f in fits:
            k = f.X.shape[1]
            out.append(f.cand.effect(f.params if f.fixed else f.cand.natural(beta[col:col + k], f.theta)))
            col += k
        return out

    def rss_all(self, effects) -> float:
        """Sum of squares of the exact residual over every sample of the fit block (the
        smoother's ends aside), sticking phases included (friction set-valued there)."""
        r = self.ctx.residual(list(effects))[self.samples.all_t]
        return float(np.sum(r * r))

    def as_channels(self, v: np.ndarray) -> np.ndarray:
        """Flattened values as (samples, channels)."""
        c = self.ctx.r0.shape[1]
        return v.reshape(-1, c)
