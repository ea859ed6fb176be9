"""Choosing the effects the evidence supports (issue 6, item 2).

Forward selection on the stacked two-channel residual y = [r_load, r_motor] (flattened):

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
   When none passes, selection stops.
   Then the low-speed stage (:mod:`.lowspeed`) tries friction on every sample, set-valued
   while a side sticks.  A candidate that is not physical (:meth:`Candidate.implausible`),
   or pulls an effect already chosen out of its physical range, is rejected.
3. The chosen effects' natural parameters (F_c, v_s, δ, width, ...) are refined jointly by
   nonlinear least squares on the exact residual of the augmented model
   (scipy.optimize.least_squares) over every sample of the fit; confidence intervals from the
   Gauss–Newton covariance s²(JᵀJ)⁻¹ inflated by τ_int of the final residual (Wald, 95 %),
   profile-likelihood intervals for static-friction amplitudes the log bounds loosely.  Two
   effects that trade against each other (:meth:`Selector._conflict`): the sensible one is
   kept and the selection reruns without the other; then effects the log does not determine
   are dropped.
4. Explained fractions: sequential decrease of the mean square, in the order chosen, at the
   final parameters, divided by the initial mean square; the rest is unexplained.
5. What remains is checked for structure that no candidate took: bin means of the final
   residual against q, q̇, θ_s, θ_m and (q, sign q̇); the largest share of the remaining
   mean square such a lookup explains (less its chance level) is reported as
   ``structured_unexplained_fraction`` of the initial mean square, with the signals it
   follows.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares, minimize_scalar

from sea_daemon.analysis.diagnose.candidates import Candidate, Context
from sea_daemon.analysis.diagnose.lowspeed import LowSpeedStage
from sea_daemon.analysis.diagnose.prepare import MAX_ROWS
from sea_daemon.analysis.diagnose.residuals import Z95, integrated_autocorr_time



#: [N m] the size floor's cap (an effect of 0.01 N m RMS is worth a term on any hardware)
DEFAULT_MIN_EFFECT_RMS = 0.01
#: the size floor relative to the RMS commanded torque of the log
MIN_EFFECT_RMS_REL = 0.1


def size_floor(tau_m: np.ndarray) -> float:
    """Default ``min_effect_rms`` [N m]: a tenth of the RMS commanded torque, at most 0.01 N m
    (an effect much smaller than what the motor applies is not worth a model term; 0.01 N m
    is on an exoskeleton applying newton metres, a tenth of that on a bench applying 0.03)."""
    r = float(np.sqrt(np.mean(np.square(tau_m)))) if np.size(tau_m) else 0.0
    return min(DEFAULT_MIN_EFFECT_RMS, MIN_EFFECT_RMS_REL * r) if r > 0 else DEFAULT_MIN_EFFECT_RMS


@dataclass
class SelectOptions:
    """Thresholds of the selection (see the module docstring)."""

    min_fraction: float = 0.05      # of the initial mean square, per accepted effect ...
    min_fraction_current: float = 0.3   # ... or of the mean square still unexplained
    min_cv_gain: float = 0.05       # relative decrease of the held-out mean square
    folds: int = 5                  # blocked CV segments
    max_effects: int = 6
    #: [N m] smallest effect worth a model term (RMS of its share); None: scaled to the
    #: hardware, a tenth of the RMS commanded torque of the log, at most DEFAULT_MIN_EFFECT_RMS
    min_effect_rms: float | None = None
    ambiguity: float = 0.9          # alternatives explaining ≥ this share of the best's ΔRSS
    ambiguity_bic: float = 10.0     # ... and with a BIC within this of the best's
    structure_threshold: float = 0.10   # structured unexplained share that triggers the warning
    edge: int | None = None         # samples dropped at each end (default: the smoothing window)
    #: samples with |q̇| or |θ̇_m| below this [rad/s] are left out of the fit (stiction: the
    #: smoothed sign of the model cannot follow sticking); default 3 × the model's sign_eps
    v_min: float | None = None
    max_masked: float = 0.5         # never leave out more than this share of the samples
    #: a longer log is diagnosed on segments of it (prepare.segment_log); None: never
    max_rows: int | None = MAX_ROWS
    #: the linear stage fits at most this many samples: a longer log every k-th (Selector.fit_stride)
    max_fit_rows: int | None = 20000
    #: try friction on every sample, set-valued while a side sticks (:mod:`.lowspeed`)
    low_speed: bool = True
    #: an undetermined effect whose parameters correlate beyond this with another chosen one:
    #: the pair is reported and only the sensible one kept
    max_correlation: float = 0.9
    #: share of the log at its end kept back from the fit and scored separately (time-blocked
    #: validation); 0: fit and score the whole log
    holdout: float = 0.25
    #: the validation also repeats the whole selection on the fit block (slower, stricter)
    validate_selection: bool = True
    #: the validation also scores the GP-AKF (learned on the fit block; slower)
    validate_gp_akf: bool = False


@dataclass
class CandidateFit:
    """One candidate fitted at one step: θ, coefficients, RSS, its design, BIC and CV score."""

    cand: Candidate
    theta: float | None
    beta: np.ndarray               # coefficients of [selected X ..., this X]
    rss: float
    o: np.ndarray | None
    X: np.ndarray
    bic: float = math.inf
    cv: float = math.inf
    params: dict = field(default_factory=dict)
    frac_all: float = 0.0          # share of the initial mean square (whole log) it removes
    #: chosen by the low-speed stage: its parameters are held (``params``) until the refinement
    fixed: bool = False


@dataclass
class StepRecord:
    """The candidate table of one selection step and the decision taken."""

    step: int
    rows: list[dict]               # one per candidate tried at this step
    chosen: str | None
    reason: str


@dataclass
class Selection:
    """What the selection found: effects with parameters, CIs and shares, and the record."""

    chosen: list[tuple[Candidate, dict]]          # (candidate, natural params)
    ci: list[dict]                                # per chosen: {param: (lo, hi)}
    explained: list[float]
    unexplained: float
    steps: list[StepRecord]
    alternatives: list[list[str]]
    tau_int: float
    structure: dict
    rss0: float
    rss_final: float
    r_final: np.ndarray
    dropped: list = field(default_factory=list)   # (candidate name, params, CI) not determined
    corr: np.ndarray | None = None                # correlation of the refined parameters
    param_index: list = field(default_factory=list)   # (effect index, name) per row of corr
    correlated: list = field(default_factory=list)    # pairs resolved (see Selector._conflict)
    profiled: set = field(default_factory=set)    # (effect index, param) with a profile interval


def _lstsq(A: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Least squares of y on the columns of A.  A tall design (rows ≫ columns, a long log) is
    solved through its small Gram matrix with the columns scaled to unit norm (the same
    minimum-norm solution, at a cost linear in the rows and without a copy of A)."""
    k = A.shape[1]
    if k == 0:
        return np.zeros(0)
    if A.shape[0] < 50 * k:
        return np.linalg.lstsq(A, y, rcond=None)[0]
    s = np.sqrt(np.einsum("ij,ij->j", A, A))
    s[s == 0] = 1.0
    G = (A.T @ A) / np.outer(s, s)
    b = (A.T @ y) / s
    return np.linalg.lstsq(G, b, rcond=1e-13)[0] / s


class Selector:
    """Forward selection over ``cands`` (see the module docstring).

    ``fit_t`` (N,) bool: the time samples the fit may use (the fit block of a held-out
    validation; default all).  ``v_min`` (load, motor) [rad/s]: the speeds below which a side
    counts as slow (default ``opts.v_min``, else 3 × sign_eps on both sides).
    """

    def __init__(self, ctx: Context, cands: list[Candidate], opts: SelectOptions | None = None,
                 fit_t: np.ndarray | None = None, v_min: tuple[float, float] | None = None):
        self.ctx = ctx
        self.cands = cands
        self.opts = dataclasses.replace(opts) if opts is not None else SelectOptions()
        kin = ctx.kin
        if self.opts.min_effect_rms is None:
            self.opts.min_effect_rms = size_floor(kin.tau_m)
        N, c = ctx.r0.shape
        edge = self.opts.edge if self.opts.edge is not None else kin.window
        edge = min(edge, max(0, (N - 10) // 4))
        self.edge = edge
        keep_t = np.zeros(N, dtype=bool)
        keep_t[edge:N - edge] = True
        if fit_t is not None:
            keep_t &= np.asarray(fit_t, dtype=bool)
        # every sample of the fit block: the exact (stick-aware) evaluations use these
        self.all_t = keep_t.copy()
        if self.opts.v_min is not None:
            v_min = (self.opts.v_min, self.opts.v_min)
        elif v_min is None:
            v_min = (3.0 * ctx.cfg.estimator.sign_eps,) * 2
        self.v_min = tuple(float(v) for v in v_min)
        slow0 = np.any((np.abs(kin.dq) < self.v_min[0]) | (np.abs(kin.dtheta_m) < self.v_min[1]), axis=1)
        # the smoother S spreads what happens while sticking over half a window either side
        half = kin.window // 2
        slow = slow0
        if half and slow.any():
            slow = np.convolve(slow.astype(float), np.ones(2 * half + 1), mode="same") > 0
        if np.mean(slow & keep_t) > self.opts.max_masked * np.mean(keep_t):
            slow = slow0       # a slow log: the slow samples themselves, not their surroundings
        self.slow_t = slow & self.all_t
        if np.mean(slow & keep_t) <= self.opts.max_masked * np.mean(keep_t):
            keep_t &= ~slow
        self.masked_share = 1.0 - float(np.sum(keep_t)) / max(float(np.sum(self.all_t)), 1.0)
        # a long log: the linear stage fits every k-th sample (the smoothed residual is correlated
        # over a smoothing window, so a stride below it loses little; BIC's effective sample size
        # follows, its autocorrelation time shrinks by the same k)
        stride = self.fit_stride(int(np.sum(keep_t)), self.opts.max_fit_rows, kin.window)
        grid = (np.arange(N) % stride) == 0
        keep_t = keep_t & grid
        self.stride, self._grid = stride, np.flatnonzero(grid)
        self.keep_t = keep_t
        mask = np.repeat(keep_t[:, None], c, axis=1)
        self.valid = mask.reshape(-1)
        self.time_index = np.repeat(np.arange(N), c)[self.valid]
        self.y0 = ctx.r0.reshape(-1)[self.valid]
        self.M = self.y0.size
        self._cache: dict = {}
        self._full: dict = {}
        # rows of the cached designs that the fit uses: the fit's samples among the grid's
        self._valid_in_grid = np.repeat(keep_t[self._grid][:, None], c, axis=1).reshape(-1)
        # blocked CV folds over time
        K = max(2, self.opts.folds)
        edges = np.linspace(self.time_index.min(), self.time_index.max() + 1, K + 1)
        self.fold = np.clip(np.searchsorted(edges, self.time_index, side="right") - 1, 0, K - 1)

    @staticmethod
    def fit_stride(rows: int, max_rows: int | None, window: int) -> int:
        """Every how many samples the linear stage fits: 1 up to ``max_rows`` samples, else the
        stride that brings them down to it (at most half a smoothing window)."""
        if not max_rows or rows <= max_rows:
            return 1
        return int(min(max(math.ceil(rows / max_rows), 1), max(window // 2, 1)))

    # ---------------------------------------------------------------- designs
    def design(self, cand: Candidate, theta):
        key = (id(cand), None if theta is None else round(float(theta), 12))
        if key not in self._cache:
            o, X = cand.design(self.ctx, theta)
            c = self.ctx.r0.shape[1]
            # kept on the grid's samples only (every sample of a log up to max_fit_rows)
            if self.stride > 1:
                o = None if o is None else o.reshape(-1, c)[self._grid].reshape(-1)
                X = X.reshape(self.ctx.kin.N, c, X.shape[1])[self._grid].reshape(self._grid.size * c, X.shape[1])
            v = self._valid_in_grid
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
        return float(np.sqrt(np.sum(d**2) / self._grid.size))

    def _fit_with(self, y, base_X, o, X, nonneg=()):
        """Least squares of y − o on [base_X, X]; coefficients of X listed in ``nonneg`` are
        held at 0 when they come out negative (the vocabulary's sign constraints)."""
        yy = y if o is None else y - o
        A = np.hstack([base_X, X]) if base_X.shape[1] else X
        beta = _lstsq(A, yy)
        k0 = base_X.shape[1]
        bad = [k0 + i for i in nonneg if beta[k0 + i] < 0]
        if bad:
            keep = [i for i in range(A.shape[1]) if i not in bad]
            beta = np.zeros(A.shape[1])
            beta[keep] = _lstsq(A[:, keep], yy)
        res = yy - (A @ beta if A.shape[1] else 0.0)
        return beta, float(res @ res)

    def _gauss_newton(self, cand: Candidate, y, base_X, iters: int = 6) -> CandidateFit:
        """Δr(θ) exact, θ by Gauss–Newton from 0 with the chosen columns refitted each step."""
        lo, hi = cand.bounds(self.ctx)[cand.nonlinear]
        th = 0.0
        h = getattr(cand, "H", 1e-4)
        for _ in range(iters):
            o_p, _ = self.design(cand, th + h)
            o_m, _ = self.design(cand, th - h)
            o, _ = self.design(cand, th) if th != 0.0 else (None, None)
            J = ((o_p - o_m) / (2 * h))[:, None]
            beta, _ = self._fit_with(y, base_X, o, J)
            step = float(beta[-1])
            th_new = float(np.clip(th + step, lo, hi))
            done = abs(th_new - th) < 1e-7 + 1e-4 * abs(th_new)
            th = th_new
            if done:
                break
        o, X = self.design(cand, th)
        beta, rss = self._fit_with(y, base_X, o, X)
        fit = CandidateFit(cand, th, beta, rss, o, X)
        fit.params = cand.natural(beta[base_X.shape[1]:], th)
        return fit

    def fit_candidate(self, cand: Candidate, y, base_X) -> CandidateFit:
        if getattr(cand, "gauss_newton", False):
            return self._gauss_newton(cand, y, base_X)
        grid = cand.grid(self.ctx)
        fast = getattr(cand, "fast_design", None)
        if fast is not None and len(grid) > 40:
            # cheap scan (additive effect: columns straight from the signal), exact design after
            scores = []
            for th in grid:
                cols = np.column_stack([c[self.valid] for c in fast(self.ctx, th)])
                _, rss = self._fit_with(y, base_X, None, cols, cand.nonneg)
                scores.append(rss)
            order = np.argsort(scores)[:3]
            grid_eval = [grid[i] for i in order]
        else:
            grid_eval = grid
        results = []
        if not grid_eval:
            return CandidateFit(cand, None, np.zeros(0), math.inf, None, np.zeros((self.M, 0)))
        for th in grid_eval:
            o, X = self.design(cand, th)
            beta, rss = self._fit_with(y, base_X, o, X, cand.nonneg)
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
                    o = None if o is None else o[self.valid]
                    return self._fit_with(y, base_X, o, X[self.valid], cand.nonneg)[1]
                r = minimize_scalar(f, bounds=(lo, hi), method="bounded", options={"xatol": (hi - lo) * 1e-3, "maxiter": 20})
                if r.fun < rss:
                    th = float(r.x)
                    o, X = self.design(cand, th)
                    beta, rss = self._fit_with(y, base_X, o, X, cand.nonneg)
        o, X = self.design(cand, th)
        fit = CandidateFit(cand, th, beta, rss, o, X)
        fit.params = cand.natural(beta[base_X.shape[1]:], th)
        return fit

    def cv_mse(self, y, base_X, o=None, X=None) -> float:
        yy = y if o is None else y - o
        A = base_X if X is None else (np.hstack([base_X, X]) if base_X.shape[1] else X)
        err = 0.0
        for f in range(self.fold.max() + 1):
            te = self.fold == f
            tr = ~te
            beta = _lstsq(A[tr], yy[tr])
            pred = A[te] @ beta if A.shape[1] else 0.0
            e = yy[te] - pred
            err += float(e @ e)
        return err / yy.size

    # ---------------------------------------------------------------- forward selection
    def _select(self, excluded: frozenset = frozenset()):
        """Forward selection (linear stage, then the low-speed stage) over the candidates not
        in ``excluded`` (names); returns (chosen fits, stepwise params, steps, alternatives, rss0)."""
        o_cfg = self.opts
        y = self.y0.copy()                 # target minus chosen structural offsets
        base_X = np.zeros((self.M, 0))
        chosen: list[CandidateFit] = []
        n_par = 0
        rss0 = float(self.y0 @ self.y0)
        all0 = self.rss_all([])
        steps: list[StepRecord] = []
        alternatives: list[list[str]] = []
        remaining = [c for c in self.cands if c.name not in excluded]
        step = 0
        y_lin = y              # the target without the effects the low-speed stage holds
        while True:
            y, base_X, chosen, n_par, remaining, step = self._linear_stage(
                y_lin, base_X, chosen, n_par, remaining, step, steps, alternatives, rss0, all0)
            # initial natural parameters from the joint linear solution (held ones as held)
            init = self._initial(chosen, base_X, y)
            # friction where it acts: every sample of the fit block, set-valued while sticking;
            # what it adds is held while the linear stage runs again (a pair such as friction and
            # an offset is weak one at a time in the linear stage)
            if not (o_cfg.low_speed and len(chosen) < o_cfg.max_effects):
                break
            stage = LowSpeedStage(self)
            new, lsteps, lalts = stage.run([(f.cand, p) for f, p in zip(chosen, init)],
                                           [c for c in self.cands if c.name not in excluded],
                                           all0, o_cfg.max_effects - len(chosen))
            for rows, name, reason in lsteps:
                step += 1
                steps.append(StepRecord(step, rows, name, reason))
            for (cand, p), alts in zip(new, lalts):
                chosen.append(CandidateFit(cand, p.get(cand.nonlinear) if cand.nonlinear else None,
                                           np.zeros(0), math.nan, None, np.zeros((self.M, 0)), params=p, fixed=True))
                init.append(p)
                alternatives.append(alts)
                remaining = [c for c in remaining if not (c.type == cand.type and c.side == cand.side
                                                          and c.joint == cand.joint)]
                n_par += len(cand.params)
            if not new or not remaining or len(chosen) >= o_cfg.max_effects:
                break
            held = [f.cand.effect(f.params) for f in chosen if f.fixed]
            o_held = (self.ctx.r0 - self.ctx.residual(held)).reshape(-1)[self.valid]
            y_lin = self.y0 - o_held - sum((f.o for f in chosen if f.o is not None), np.zeros_like(self.y0))
            y = y_lin
        return chosen, init, steps, alternatives, rss0

    def _linear_stage(self, y, base_X, chosen, n_par, remaining, step, steps, alternatives, rss0, all0):
        """Forward selection over the moving samples (see the module docstring) from the chosen
        effects on; returns the updated (y, base_X, chosen, n_par, remaining, step)."""
        o_cfg = self.opts
        for _ in range(o_cfg.max_effects - len(chosen)):
            step += 1
            beta_cur = _lstsq(base_X, y)
            res_cur = y - (base_X @ beta_cur if base_X.shape[1] else 0.0)
            rss_cur = float(res_cur @ res_cur)
            tau = integrated_autocorr_time(self._as_channels(res_cur))
            n_eff = max(self.M / tau, 2.0)
            bic_cur = n_eff * math.log(rss_cur / self.M) + n_par * math.log(n_eff)
            cv_cur = self.cv_mse(y, base_X)
            all_cur = self.rss_all(self._effects_from(chosen, beta_cur)) if chosen else all0
            fits = []
            for cand in remaining:
                fit = self.fit_candidate(cand, y, base_X)
                k = n_par + len(cand.linear) + (1 if cand.nonlinear else 0)
                # a parameter chosen from G grid values costs ≈ 2 ln G more (the best of G
                # tries fits noise better: Bonferroni-style look-elsewhere penalty)
                look = (2.0 * math.log(max(len(cand.grid(self.ctx)), 1))
                        if cand.nonlinear and not getattr(cand, "gauss_newton", False) else 0.0)
                fit.bic = n_eff * math.log(max(fit.rss, 1e-300) / self.M) + k * math.log(n_eff) + look
                fits.append(fit)
            fits = [f for f in fits if np.isfinite(f.rss)]
            if not fits:
                steps.append(StepRecord(step, [], None, "no candidate applicable"))
                break
            # rank by BIC: of two that fit equally well, the one with fewer parameters
            fits.sort(key=lambda f: f.bic)
            rows = []
            for f in fits:
                rows.append({"candidate": f.cand.name, "type": f.cand.type, "side": f.cand.side,
                             "params": {k: round(v, 6) for k, v in f.params.items()},
                             "explains": (rss_cur - f.rss) / rss0, "delta_bic": f.bic - bic_cur})

            def reasons_against(f: CandidateFit) -> list[str]:
                out = []
                if not f.bic < bic_cur:
                    out.append(f"BIC does not fall ({f.bic - bic_cur:+.1f})")
                    return out
                why = self._unphysical(f, chosen)
                if why:
                    out.append(why)
                    return out
                f.cv = self.cv_mse(y, base_X, f.o, f.X)
                if not f.cv < cv_cur * (1.0 - o_cfg.min_cv_gain):
                    out.append(f"held-out mean square falls only {100 * (1 - f.cv / cv_cur):.1f} % "
                               f"(< {100 * o_cfg.min_cv_gain:.0f} %)")
                eff_rms = self.contribution_rms(f)
                if eff_rms < o_cfg.min_effect_rms:
                    out.append(f"its share of the residual is {eff_rms:.4f} N m RMS (< {o_cfg.min_effect_rms} N m)")
                # its size, on the fitted samples and on the whole log (sticking phases included,
                # which the fit leaves out): worth a term if it takes a good part of either
                gain_all = all_cur - self.rss_all(self._effects_from(chosen + [f], f.beta))
                fr, fr_cur = gain_all / all0, gain_all / all_cur
                fit_fr, fit_cur = (rss_cur - f.rss) / rss0, (rss_cur - f.rss) / rss_cur
                f.frac_all = fr
                if max(fr, fit_fr) < o_cfg.min_fraction and max(fr_cur, fit_cur) < o_cfg.min_fraction_current:
                    out.append(f"explains {100 * max(fr, fit_fr):.1f} % of the initial mean square "
                               f"(< {100 * o_cfg.min_fraction:.0f} %) and {100 * max(fr_cur, fit_cur):.1f} % of "
                               f"what is left (< {100 * o_cfg.min_fraction_current:.0f} %)")
                return out

            # the best by BIC that passes every test; candidates whose BIC does not fall end the search
            best, rejected = None, []
            for f in fits:
                why = reasons_against(f)
                if not why:
                    best = f
                    break
                rejected.append(f"{f.cand.name}: " + "; ".join(why))
                if not f.bic < bic_cur:
                    break
            if best is None:
                steps.append(StepRecord(step, rows, None, "no candidate accepted — " + " | ".join(rejected[:3])))
                break
            frac = best.frac_all
            gain = rss_cur - best.rss
            # nearly as good: explains ≥ 90 % as much and BIC not worse by 10 or more (Kass &
            # Raftery: ΔBIC > 10 is very strong evidence for the better one)
            alts = [f.cand.name for f in fits if f is not best and gain > 0 and (rss_cur - f.rss) >= o_cfg.ambiguity * gain
                    and f.bic - best.bic < o_cfg.ambiguity_bic and not self._unphysical(f, chosen)]
            alternatives.append(alts)
            steps.append(StepRecord(step, rows, best.cand.name,
                                    f"{best.cand.name} explains {100 * frac:.1f} % of the initial mean square; "
                                    f"ΔBIC {best.bic - bic_cur:+.1f}; held-out mean square −{100 * (1 - best.cv / cv_cur):.1f} %"
                                    + (f"; nearly as good: {', '.join(alts)}" if alts else "")
                                    + (f"; ranked above it but rejected — {' | '.join(rejected)}" if rejected else "")))
            chosen.append(best)
            n_par += len(best.cand.linear) + (1 if best.cand.nonlinear else 0)
            if best.o is not None:
                y = y - best.o
            base_X = np.hstack([base_X, best.X]) if best.X.shape[1] else base_X
            # no second copy of the same type on the same side and joint
            remaining = [c for c in remaining if not (c.type == best.cand.type and c.side == best.cand.side
                                                      and c.joint == best.cand.joint)]
            if not remaining:
                break
        return y, base_X, chosen, n_par, remaining, step

    def _initial(self, chosen, base_X, y) -> list[dict]:
        """Natural parameters of the chosen effects from the joint linear solution of their
        columns (the low-speed stage's held ones as held)."""
        beta_all = _lstsq(base_X, y)
        init, col = [], 0
        for f in chosen:
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
            chosen, init, steps, alternatives, rss0 = self._select(frozenset(excluded))
            self.stepwise = [dict(p) for p in init]
            sel = self._finish(chosen, init, steps, alternatives, rss0)
            # joint refinement: two correlated effects can trade one for the other (the log
            # does not tell them apart).  One that the refinement pushes out of its physical
            # range or takes away, or an undetermined one correlated with another: the
            # physically sensible one is kept (:meth:`_conflict`), the other leaves the
            # candidates and the selection runs again without it
            conflict = self._conflict(sel) if len(sel.chosen) > 1 else None
            if conflict is None:
                break
            i_drop, i_keep, rho, why = conflict
            correlated.append({"kept": sel.chosen[i_keep][0].name, "dropped": sel.chosen[i_drop][0].name,
                               "correlation": float(rho), "reason": why,
                               "kept_params": dict(self.stepwise[i_keep]),
                               "dropped_params": dict(self.stepwise[i_drop])})
            excluded.add(sel.chosen[i_drop][0].name)
        # an effect whose parameters this log does not determine (95 % CI wider than the
        # value on both sides) is not added: refit without it
        dropped = []
        while True:
            # (angles and rest positions — phi, q_h0 — may rightly be near 0: not judged this way)
            # (a friction amplitude with a profile interval — asymmetric, or bounded from below
            # only — is undetermined when that interval reaches 0)
            bad = [i for i in range(len(sel.chosen)) if self._undetermined(sel, i)]
            if not bad:
                break
            i = bad[0]
            dropped.append((sel.chosen[i][0].name, sel.chosen[i][1], sel.ci[i]))
            keep = [k for k in range(len(chosen)) if k != i]
            chosen = [chosen[k] for k in keep]
            init = [sel.chosen[k][1] for k in keep]
            alternatives = [alternatives[k] for k in keep]
            sel = self._finish(chosen, init, steps, alternatives, rss0)
        sel.dropped = dropped
        sel.correlated = correlated
        return sel

    def refit(self, pairs: list[tuple[Candidate, dict]]) -> list[tuple[Candidate, dict]]:
        """The given effects' parameters refitted jointly (nonlinear least squares on the exact
        residual) over this selector's samples, from the given values: the same model
        structure fitted to another part of the log."""
        if not pairs:
            return []
        stubs = [CandidateFit(c, None, np.zeros(0), math.nan, None, np.zeros((0, 0))) for c, _ in pairs]
        x0, lo, hi, idx = self._pack(stubs, [p for _, p in pairs])

        def fun(x):
            eff, _ = self._effects(stubs, x, idx)
            return self._resid(eff)
        try:
            sol = least_squares(fun, x0, bounds=(lo, hi), x_scale=np.maximum(np.abs(x0), 1e-3), diff_step=1e-4,
                                max_nfev=60 * len(x0))
            x = sol.x if float(sol.fun @ sol.fun) <= float(fun(x0) @ fun(x0)) else x0
        except (ValueError, np.linalg.LinAlgError):
            x = x0
        _, params = self._effects(stubs, x, idx)
        return [(c, p) for (c, _), p in zip(pairs, params)]

    def _conflict(self, sel: "Selection"):
        """A pair of chosen effects the joint refinement cannot keep both of, or None.

        Returns (index to drop, index kept, correlation, reason).  An effect is in conflict
        when the refinement left it physically implausible (:meth:`Candidate.implausible`),
        took it away (its magnitude below a fifth of its stepwise value) or pushed it to the
        edge of its physical range, with another effect correlated with it; or when the log
        does not determine it (interval wider than its value) and its parameters correlate
        beyond ``max_correlation`` with another's.  Of the pair, the one kept is the
        physically sensible one: plausible at its own stepwise fit, then the one with the
        higher physical prior (:attr:`.candidates.Candidate.prior`: an arm's weight over an
        elbow's stiffness), then the earlier chosen (it explained more when it was chosen); the
        other is dropped.
        """
        corr = sel.corr
        if corr is None:
            return None
        idx = sel.param_index
        K = len(sel.chosen)

        def rho(i, j):
            vals = [corr[a, b] for a, (ia, _) in enumerate(idx) for b, (ib, _) in enumerate(idx)
                    if ia == i and ib == j and np.isfinite(corr[a, b])]
            return max(vals, key=abs) if vals else 0.0

        def trouble(i):
            cand, p = sel.chosen[i]
            p0 = self.stepwise[i]
            why = cand.implausible(self.ctx, p)
            if why:
                return why
            mag, mag0 = cand.magnitude(p), cand.magnitude(p0)
            if mag is not None and mag0 and abs(mag) < 0.2 * abs(mag0):
                return f"the joint refinement took it away ({cand.describe(p0)} → {cand.describe(p)})"
            for name, (lo, hi) in cand.bounds(self.ctx).items():
                for b in (lo, hi):
                    if not np.isfinite(b) or name not in p:
                        continue
                    tol = 1e-3 * max(abs(b), abs(p0.get(name, b)), 1e-9)
                    if abs(p[name] - b) <= tol and abs(p0.get(name, np.inf) - b) > tol:
                        return (f"the joint refinement pushed it to the edge of its physical range "
                                f"({cand.describe(p0)} → {cand.describe(p)})")
            return None

        def partner(i, min_rho):
            """The effect most correlated with i, if beyond ``min_rho``, and the pair's
            (drop, keep): the physically sensible one — plausible at its stepwise fit, then the
            earlier chosen — is kept."""
            j = max((j for j in range(K) if j != i), key=lambda j: abs(rho(i, j)))
            r = float(rho(i, j))
            if abs(r) < min_rho:
                return None
            bad_i = sel.chosen[i][0].implausible(self.ctx, self.stepwise[i])
            bad_j = sel.chosen[j][0].implausible(self.ctx, self.stepwise[j])
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

        for i in range(K):
            why = trouble(i)
            # below 0.5 it is not a trade between two effects: left to the interval test
            pair = partner(i, 0.5) if why else None
            if pair is not None:
                return pair[0], pair[1], pair[2], f"{sel.chosen[i][0].name}: {why}"
        # an effect the log does not determine (interval wider than its value) because it
        # trades against another one: the pair is reported and the sensible one kept (the
        # interval test alone would drop it, and a clear effect with it)
        for i in range(K):
            pair = partner(i, self.opts.max_correlation) if self._undetermined(sel, i) else None
            if pair is not None:
                drop, keep, r, j = pair
                return drop, keep, r, (f"{sel.chosen[i][0].name}'s interval is wider than its value, its "
                                       f"parameters correlated {r:+.2f} with {sel.chosen[j][0].name}'s")
        return None

    @staticmethod
    def _undetermined(sel: "Selection", i: int) -> bool:
        """The interval test: an effect whose 95 % interval is wider than its value (a profile
        interval: reaches 0).  Angles and rest positions (phi, q_h0) are not judged this way."""
        cand, p = sel.chosen[i]
        for k, (lo, hi) in sel.ci[i].items():
            if not np.isfinite(lo) or k in ("phi", "q_h0"):
                continue
            if (lo <= 0.0) if (i, k) in sel.profiled else (abs(hi - lo) / 2 > abs(p[k])):
                return True
        return False

    def _unphysical(self, f: CandidateFit, chosen: list[CandidateFit]) -> str | None:
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

    def _effects_from(self, fits: list[CandidateFit], beta: np.ndarray):
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
        r = self.ctx.residual(list(effects))[self.all_t]
        return float(np.sum(r * r))

    def _as_channels(self, v: np.ndarray) -> np.ndarray:
        c = self.ctx.r0.shape[1]
        return v.reshape(-1, c)

    # ---------------------------------------------------------------- refinement, CIs
    def _pack(self, chosen, params_list):
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

    def _effects(self, chosen, x, idx):
        ps = [dict() for _ in chosen]
        for v, (i, name) in zip(x, idx):
            ps[i][name] = float(v)
        return [f.cand.effect(p) for f, p in zip(chosen, ps)], ps

    def _resid(self, effects) -> np.ndarray:
        """Exact residual over every sample of the fit block (flattened): the joint refinement
        sees the sticking phases too, with declared and chosen friction set-valued there."""
        return self.ctx.residual(effects)[self.all_t].reshape(-1)

    def _finish(self, chosen, init, steps, alternatives, rss0) -> Selection:
        if not chosen:
            r = self.y0
            return Selection([], [], [], 1.0, steps, [], integrated_autocorr_time(self._as_channels(r)),
                             self.structure(r, rss0), rss0, self.rss_all([]), self.ctx.r0)
        x0, lo, hi, idx = self._pack(chosen, init)

        def fun(x):
            eff, _ = self._effects(chosen, x, idx)
            return self._resid(eff)

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
        effects, params = self._effects(chosen, x, idx)
        explained, unexplained, rss_all_final = self.shares(effects)
        r_final = self.ctx.residual(effects)
        # leftover structure on the moving samples (those the linear stage fitted)
        res_keep = r_final.reshape(-1)[self.valid]
        return Selection(list(zip([f.cand for f in chosen], params)), ci, explained, unexplained, steps,
                         alternatives, tau, self.structure(res_keep, rss0), rss0, rss_all_final, r_final,
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

    def _lower_bounded(self, fun, x, idx, chosen, res, tau, se, lo, hi, scale) -> dict[int, tuple]:
        """Friction amplitudes whose Gauss–Newton interval is wider than their value, from the
        profile likelihood instead (the others refitted): {index: (lower edge, upper edge)}.

        A sticking phase bounds static friction from below only, and a Stribeck hump trades
        its height against its width along a valley, so the linearised interval says little.
        The profile interval is where −2 log L rises by less than 1 (about 68 %) ... the
        amplitude is kept when removing it raises it by more; when the interval has no upper
        end the amplitude is moved to its lower edge (the least static friction the log
        requires) and reported as "at least".  ``x`` is updated in place."""
        out: dict[int, tuple] = {}
        rss = float(res @ res)
        if rss <= 0:
            return out
        n_eff = max(res.size / max(tau, 1.0), 2.0)
        for k, (i, name) in enumerate(idx):
            if (chosen[i].cand.type, name) not in self._STATIC or x[k] <= 0:
                continue
            if not (np.isfinite(se[k]) and Z95 * se[k] > x[k]):
                continue
            d0, _ = self._profile_dev(fun, x, k, 0.0, lo, hi, scale, rss, n_eff)
            if d0 <= 1.0:
                continue                      # not needed at all: the interval test drops it
            a, b = 0.0, float(x[k])
            for _ in range(14):
                mid = 0.5 * (a + b)
                if self._profile_dev(fun, x, k, mid, lo, hi, scale, rss, n_eff)[0] > 1.0:
                    a = mid
                else:
                    b = mid
            lower = b
            upper = math.inf
            for f in (1.5, 2.0, 4.0, 8.0):
                if self._profile_dev(fun, x, k, f * x[k], lo, hi, scale, rss, n_eff)[0] > 1.0:
                    upper = f * float(x[k])
                    break
            if upper == math.inf:
                _, xx = self._profile_dev(fun, x, k, lower, lo, hi, scale, rss, n_eff)
                x[:] = xx
            out[k] = (lower, upper)
        return out

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
            v[mask] = self.rss_all([effects[i] for i in range(K) if mask >> i & 1])
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

    # ---------------------------------------------------------------- leftover structure
    def structure(self, res: np.ndarray, rss0: float) -> dict:
        """Share of the leftover explained by bin means against state signals (chance-corrected),
        as a fraction of the initial sum of squares over the whole log."""
        all0 = max(self.rss_all([]), 1e-300)
        ctx = self.ctx
        kin = ctx.kin
        q, th = ctx.angles()
        c = ctx.r0.shape[1]
        n = ctx.n
        valid_t = np.unique(self.time_index)
        R = np.full((kin.N, c), np.nan)
        R.reshape(-1)[np.flatnonzero(self.valid)] = res
        R = R[valid_t]
        best = {"fraction": 0.0, "signals": [], "channel": None}
        for j in range(n):
            sig = {
                "q": q[valid_t, j], "q̇": kin.dq[valid_t, j], "θ_s": (q - th)[valid_t, j],
                "θ_m": th[valid_t, j],
            }
            sgn = np.sign(kin.dq[valid_t, j])
            for ch in range(c):
                r = R[:, ch]
                ss = float(r @ r)
                if ss <= 0:
                    continue
                for name, s in list(sig.items()) + [("q, sign q̇", None)]:
                    if s is None:
                        bins = self._bins(sig["q"], 10) * 2 + (sgn > 0)
                        nb = 20
                    else:
                        bins = self._bins(s, 16)
                        nb = 16
                    sums = np.bincount(bins, weights=r, minlength=nb)
                    cnt = np.bincount(bins, minlength=nb)
                    means = np.divide(sums, cnt, out=np.zeros(nb), where=cnt > 0)
                    expl = float(np.sum(cnt * means**2))
                    # chance level: with N/τ independent samples, nb bin means of structureless
                    # noise explain ≈ nb·τ/N of its sum of squares (τ of what the bins leave)
                    tau = integrated_autocorr_time((r - means[bins])[:, None])
                    chance = min(1.0, nb * tau / len(r))
                    share_ss = max(expl / ss - chance, 0.0) * ss
                    if share_ss / all0 > best["fraction"]:
                        chname = ("load" if ch < n else "motor") + (f"[{ch % n + 1}]" if n > 1 else "")
                        best = {"fraction": share_ss / all0, "signals": [name], "channel": chname,
                                "rms": math.sqrt(share_ss / max(len(valid_t), 1))}
        # RMS [N m] of the structured part (over the fitted samples): a share of pure noise is no news
        best.setdefault("rms", 0.0)
        best["warn"] = bool(best["fraction"] >= self.opts.structure_threshold
                            and best["rms"] >= self.opts.min_effect_rms)
        return best

    @staticmethod
    def _bins(s: np.ndarray, k: int) -> np.ndarray:
        qs = np.quantile(s, np.linspace(0, 1, k + 1)[1:-1])
        return np.searchsorted(qs, s)
