"""Joint refinement of the chosen effects, their intervals and shares (step 3–4 of :mod:`.select`).

The chosen effects' natural parameters are refined jointly by nonlinear least squares on the
exact residual of the augmented model (scipy.optimize.least_squares) over every sample of the
fit block; 95 % intervals from the Gauss–Newton covariance s²(JᵀJ)⁻¹ inflated by τ_int of the
final residual (Wald), profile-likelihood intervals for static-friction amplitudes the log
bounds loosely; the shares of the initial mean square as Shapley values.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.optimize import least_squares

from sea_daemon.analysis.diagnose.candidates import Candidate
from sea_daemon.analysis.diagnose.fitting import LinearFits
from sea_daemon.analysis.diagnose.options import SelectOptions
from sea_daemon.analysis.diagnose.records import CandidateFit, Selection
from sea_daemon.analysis.diagnose.residuals import Z95, integrated_autocorr_time
from sea_daemon.analysis.diagnose.structure import leftover_structure


class Refinement:
    """Joint refinement on the samples of ``fits`` (see the module docstring)."""

    def __init__(self, fits: LinearFits, opts: SelectOptions):
        self.fits = fits
        self.ctx = fits.ctx
        self.opts = opts

    def refit(self, pairs: list[tuple[Candidate, dict]], steps: int | None = None) -> list[tuple[Candidate, dict]]:
        """The given effects' parameters refitted jointly (nonlinear least squares on the exact
        residual; at most ``steps`` iterations, default 60 per parameter) over this selector's
        samples, from the given values: the same model structure fitted to another part of the log."""
        if not pairs:
            return []
        stubs = [CandidateFit(c, None, np.zeros(0), math.nan, None, np.zeros((0, 0))) for c, _ in pairs]
        x0, lo, hi, idx = self.pack(stubs, [p for _, p in pairs])

        def fun(x):
            eff, _ = self.effects(stubs, x, idx)
            return self.resid(eff)
        try:
            sol = least_squares(fun, x0, bounds=(lo, hi), x_scale=np.maximum(np.abs(x0), 1e-3), diff_step=1e-4,
                                max_nfev=steps or 60 * len(x0))
            x = sol.x if float(sol.fun @ sol.fun) <= float(fun(x0) @ fun(x0)) else x0
        except (ValueError, np.linalg.LinAlgError):
            x = x0
        _, params = self.effects(stubs, x, idx)
        return [(c, p) for (c, _), p in zip(pairs, params)]

    def pack(self, chosen, params_list):
        """The parameters of ``chosen`` at ``params_list`` as one vector x0 (clipped into their
        bounds), the bounds lo, hi and (effect index, name) per entry."""
        x0, lo, hi, idx = [], [], [], []
        for i, (f, p) in enumerate(zip(chosen, params_list)):
            b = f.cand.bounds(self.ctx)
            for name in f.cand.params:
                v = float(p[name])
                l, h = b.get(name, (-np.inf, np.inf))
                v = min(max(v, l + 1e-12 if np.isfinite(l) else v), h - 1e-12 if np.isfinite(h) else v)
                x0.append(v)
                lo.append(l)
                hi.append(h)
                idx.append((i, name))
        return np.array(x0), np.array(lo), np.array(hi), idx

    def effects(self, chosen, x, idx):
        """The effects of ``chosen`` at the parameter vector ``x`` (see :meth:`pack`), and their
        parameter dicts."""
        ps = [dict() for _ in chosen]
        for v, (i, name) in zip(x, idx):
            ps[i][name] = float(v)
        return [f.cand.effect(p) for f, p in zip(chosen, ps)], ps

    def resid(self, effects) -> np.ndarray:
        """Exact residual over every sample of the fit block (flattened): the joint refinement
        sees the sticking phases too, with declared and chosen friction set-valued there."""
        return self.ctx.residual(effects)[self.fits.samples.all_t].reshape(-1)

    def finish(self, chosen, init, steps, alternatives, rss0) -> Selection:
        """The :class:`.records.Selection` of ``chosen`` refined jointly from ``init``: parameters,
        intervals, correlations, shares and the leftover structure."""
        if not chosen:
            r = self.fits.samples.y0
            return Selection([], [], [], 1.0, steps, [], integrated_autocorr_time(self.fits.as_channels(r)),
                             leftover_structure(self.fits, self.opts, r), rss0, self.fits.rss_all([]), self.ctx.r0)
        x0, lo, hi, idx = self.pack(chosen, init)

        def fun(x):
            eff, _ = self.effects(chosen, x, idx)
            return self.resid(eff)

        scale = np.maximum(np.abs(x0), 1e-3)
        try:
            sol = least_squares(fun, x0, bounds=(lo, hi), x_scale=scale, diff_step=1e-4, max_nfev=60 * len(x0))
            x, J, res = sol.x, sol.jac, sol.fun
            if float(res @ res) > float(fun(x0) @ fun(x0)):
                x, res = x0, fun(x0)
        except (ValueError, np.linalg.LinAlgError):
            x, res, J = x0, fun(x0), None
        c = self.ctx.r0.shape[1]
        tau = integrated_autocorr_time(res.reshape(-1, c))
        rss = float(res @ res)
        ci = [dict() for _ in chosen]
        corr = None
        se = np.full(x.size, np.nan)
        if J is not None and J.shape[1]:
            p = J.shape[1]
            s2 = rss / max(res.size - p, 1)
            try:
                cov = np.linalg.pinv(J.T @ J) * s2 * tau
                se = np.sqrt(np.maximum(np.diag(cov), 0.0))
                with np.errstate(invalid="ignore", divide="ignore"):
                    corr = cov / np.outer(se, se)
            except np.linalg.LinAlgError:
                se = np.full(p, np.nan)
            for k, (i, name) in enumerate(idx):
                ci[i][name] = (float(x[k] - Z95 * se[k]), float(x[k] + Z95 * se[k]))
        # static friction is set-valued: a sticking phase shows only that the friction at rest
        # is at least the torque it held (see _lower_bounded)
        prof = self._lower_bounded(fun, x, idx, chosen, res, tau, se, lo, hi, scale)
        for k, (a, b) in prof.items():
            i, name = idx[k]
            ci[i][name] = (a, b)
        if prof:
            res = fun(x)
            rss = float(res @ res)
        # a Gauss–Newton interval narrower than the log supports: the profile interval instead
        for k, (a, b) in self._unsupported_wald(fun, x, se, prof, res, tau, lo, hi, scale).items():
            i, name = idx[k]
            ci[i][name] = (a, b)
        effects, params = self.effects(chosen, x, idx)
        explained, unexplained, rss_all_final = self.shares(effects)
        r_final = self.ctx.residual(effects)
        # leftover structure on the moving samples (those the linear stage fitted)
        res_keep = r_final.reshape(-1)[self.fits.samples.valid]
        return Selection(list(zip([f.cand for f in chosen], params)), ci, explained, unexplained, steps,
                         alternatives, tau, leftover_structure(self.fits, self.opts, res_keep), rss0, rss_all_final, r_final,
                         corr=corr, param_index=list(idx), profiled={idx[k] for k in prof})

    #: friction amplitudes that a sticking phase can bound from below only
    _STATIC = {("coulomb", "F_c"), ("stribeck", "F_s")}

    def _profile_dev(self, fun, x, k, v, lo, hi, scale, rss, n_eff) -> tuple[float, np.ndarray]:
        """−2 log-likelihood rise (n_eff ln RSS/RSS_best) with parameter k held at v and every
        other parameter refitted; and those parameters."""
        free = [j for j in range(x.size) if j != k]
        xx = x.copy()
        xx[k] = v

        def f(z):
            xx[free] = z
            return fun(xx)
        if free:
            try:
                sol = least_squares(f, x[free], bounds=(lo[free], hi[free]), x_scale=scale[free], diff_step=1e-4,
                                    max_nfev=30 * len(free))
                xx[free] = sol.x
            except (ValueError, np.linalg.LinAlgError):
                xx[free] = x[free]
        r = fun(xx)
        return n_eff * math.log(max(float(r @ r), 1e-300) / rss), xx

    #: −2 log L rise at the lower edge of a static friction the log bounds from below only: its
    #: "at least" is a one-sided 95 % bound, z₀.₉₅² = χ²₁(0.90) ≈ 2.71.  An interval with both
    #: ends is two-sided 95 %: its edges where the rise is Z95² ≈ 3.84
    ONE_SIDED = 1.6448536269514722 ** 2
    TWO_SIDED = Z95 * Z95
    #: factors of the value tried for the upper edge of a static-friction profile interval
    UPPER_FACTORS = (1.5, 2.0, 4.0, 8.0)

    def _lower_bounded(self, fun, x, idx, chosen, res, tau, se, lo, hi, scale) -> dict[int, tuple]:
        """Friction amplitudes whose Gauss–Newton interval is wider than their value, from the
        profile likelihood instead (the others refitted): {index: (lower edge, upper edge)}.

        A sticking phase bounds static friction from below only, and a Stribeck hump trades
        its height against its width along a valley, so the linearised interval says little.
        The upper edge is the first of :attr:`UPPER_FACTORS` × the value at which −2 log L has
        risen by more than :attr:`TWO_SIDED` (a 95 % interval, its upper end rounded outward);
        the lower edge is where it has risen by that much.  When there is no upper edge, the log
        bounds the amplitude from below only and the interval is one-sided 95 %: its lower edge
        where the rise is :attr:`ONE_SIDED`.  The amplitude is kept when removing it raises
        −2 log L by more than the level of its lower edge; with no upper end it is moved to its
        lower edge (the least static friction the log requires) and reported as "at least".
        ``x`` is updated in place."""
        out: dict[int, tuple] = {}
        rss = float(res @ res)
        if rss <= 0:
            return out
        n_eff = max(res.size / max(tau, 1.0), 2.0)

        def dev(k, v):
            return self._profile_dev(fun, x, k, v, lo, hi, scale, rss, n_eff)[0]
        for k, (i, name) in enumerate(idx):
            if (chosen[i].cand.type, name) not in self._STATIC or x[k] <= 0:
                continue
            if not (np.isfinite(se[k]) and Z95 * se[k] > x[k]):
                continue
            d0 = dev(k, 0.0)
            if d0 <= self.ONE_SIDED:
                continue                      # not needed at all: the interval test drops it
            upper = next((f * float(x[k]) for f in self.UPPER_FACTORS if dev(k, f * x[k]) > self.TWO_SIDED), math.inf)
            level = self.ONE_SIDED if upper == math.inf else self.TWO_SIDED
            if d0 <= level:
                continue
            a, b = 0.0, float(x[k])
            for _ in range(14):
                mid = 0.5 * (a + b)
                if dev(k, mid) > level:
                    a = mid
                else:
                    b = mid
            lower = b
            if upper == math.inf:
                _, xx = self._profile_dev(fun, x, k, lower, lo, hi, scale, rss, n_eff)
                x[:] = xx
            out[k] = (lower, upper)
        return out

    #: −2 log L rise at a Gauss–Newton interval's edge (that parameter moved there, the others
    #: held) below which the interval is narrower than the log supports.  For a residual linear in
    #: the parameters the rise there is Z95² ≈ 3.84 at least (holding the others can only raise
    #: it); below 1 (the 68 % level) the edge is inside what the log cannot tell from the value
    NARROW_EDGE = 1.0
    #: outward steps (each 4× the last) and bisections of a profile interval's edge search
    EDGE_STEPS, EDGE_BISECT = 12, 8

    def _unsupported_wald(self, fun, x, se, skip, res, tau, lo, hi, scale) -> dict[int, tuple]:
        """Parameters whose Gauss–Newton interval x ± Z95 se the log does not support, with their
        profile-likelihood 95 % interval instead: {index: (lower edge, upper edge)}, an edge ±inf
        where the fit never gets worse by Z95² on that side (the log does not bound it).

        The linearised covariance s²(JᵀJ)⁻¹ shrinks to nothing in a direction the log does not
        determine: a column of J that is (nearly) zero — a friction parameter acting only where
        friction is set-valued, a hump no moving sample reaches — or two that are (nearly) the same;
        the pseudo-inverse then drops that direction and reports a near-zero width.  Moving the
        parameter to such an interval's edge, even with the others held, leaves the fit almost as
        it was (a rise of −2 log L below :attr:`NARROW_EDGE`): the interval is replaced by the
        values at which −2 log L, the others refitted, has risen by Z95².  ``skip``: indices that
        have a profile interval already."""
        out: dict[int, tuple] = {}
        rss = float(res @ res)
        if rss <= 0:
            return out
        n_eff = max(res.size / max(tau, 1.0), 2.0)
        for k in range(x.size):
            if k in skip or not np.isfinite(se[k]):
                continue
            half = Z95 * float(se[k])
            narrow = False
            for s in (-1.0, 1.0):
                v = min(max(float(x[k]) + s * half, lo[k]), hi[k])
                if v == x[k] and half > 0:
                    continue                  # at its bound on this side: nothing beyond to test
                xx = x.copy()
                xx[k] = v
                r = fun(xx)
                narrow |= n_eff * math.log(max(float(r @ r), 1e-300) / rss) < self.NARROW_EDGE
            if narrow:
                step = max(half, 1e-3 * float(scale[k]))
                out[k] = tuple(self._profile_edge(fun, x, k, s, step, lo, hi, scale, rss, n_eff)
                               for s in (-1.0, 1.0))
        return out

    def _profile_edge(self, fun, x, k, s, step, lo, hi, scale, rss, n_eff) -> float:
        """The edge on side ``s`` (−1, +1) of parameter k's profile 95 % interval: where −2 log L,
        the others refitted, first exceeds Z95², searched outward from ``x[k]`` in steps growing
        4× from ``step`` and then bisected; the parameter's bound when it does not exceed it
        before, ±inf when it does not within :attr:`EDGE_STEPS` steps."""
        level = Z95 * Z95
        bound = float(lo[k] if s < 0 else hi[k])
        inside, outside = float(x[k]), None
        for j in range(self.EDGE_STEPS):
            v = float(x[k]) + s * step * 4.0 ** j
            at_bound = (v <= bound) if s < 0 else (v >= bound)
            if at_bound:
                v = bound
            if self._profile_dev(fun, x, k, v, lo, hi, scale, rss, n_eff)[0] > level:
                outside = v
                break
            if at_bound:
                return bound
            inside = v
        if outside is None:
            return s * math.inf
        for _ in range(self.EDGE_BISECT):
            mid = 0.5 * (inside + outside)
            if self._profile_dev(fun, x, k, mid, lo, hi, scale, rss, n_eff)[0] > level:
                outside = mid
            else:
                inside = mid
        return outside

    def shares(self, effects) -> tuple[list[float], float, float]:
        """Shares of the initial mean square (whole log) per effect, and the unexplained share.

        Shapley values (Shapley 1953; the usual attribution of R² among correlated
        regressors, Lipovetsky & Conklin 2001): each effect's decrease of the sum of squares
        averaged over every order of adding the effects, so the shares do not depend on the
        order chosen and add up to 1 − unexplained = 1 − RMS_after² / RMS_before².
        """
        K = len(effects)
        v = {}
        for mask in range(1 << K):
            v[mask] = self.fits.rss_all([effects[i] for i in range(K) if mask >> i & 1])
        full = (1 << K) - 1
        v0 = v[0] if v[0] > 0 else 1.0
        out = []
        for i in range(K):
            phi = 0.0
            for mask in range(1 << K):
                if mask >> i & 1:
                    continue
                m = bin(mask).count("1")
                w = math.factorial(m) * math.factorial(K - m - 1) / math.factorial(K)
                phi += w * (v[mask] - v[mask | 1 << i])
            out.append(phi / v0)
        # a negative Shapley share (an effect that only helps together with others) is shown
        # as 0; the others are scaled so the shares still add up to 1 − unexplained
        total = sum(out)
        pos = [max(x, 0.0) for x in out]
        if sum(pos) > 0 and total > 0:
            pos = [x * total / sum(pos) for x in pos]
        return pos, v[full] / v0, v[full]
