"""Friction found where it acts: the low-speed stage of the selection (stick-aware).

The linear forward selection (:mod:`.select`) fits on the samples where both sides move:
near zero velocity a smooth friction model cannot follow a joint that sticks, and the
smoother spreads a turning point over half a window either side, so those samples are left
out.  That is right for every effect but friction — and wrong for friction that lives at low
speed: a Stribeck hump with v_s well below the log's speeds acts only on the samples the
linear stage leaves out (its parameters come out right and the kept samples hardly see it).

This stage therefore tries the friction candidates (Coulomb and Stribeck on the load and the
motor side) on **every** sample of the fit block with the exact residual of the model, in
which declared friction is *set-valued* while a side sticks (|v| below the stick speed):
Coulomb's law at rest, any torque up to the static limit Σ F_c + F_s
(:func:`.residuals.residual_channels`).  A sticking phase then tells how large the static
friction at least is (the torque it held), a slow phase how friction varies with speed.

Each candidate's parameters are fitted by bounded 1-D minimisation of the sum of squares
(Stribeck's v_s on a grid from the stick speed to the log's speeds, then refined), with the
effects already chosen held at their values.  It is accepted on the same tests as in the
linear stage, all computed on every sample of the fit block: BIC falls (effective sample size
from the residual's autocorrelation, 2 ln G for a grid-searched v_s), the blocked
cross-validated mean square (amplitudes refitted on the other time blocks) falls by
``min_cv_gain``, the share is ≥ ``min_fraction`` of the initial mean square or
``min_fraction_current`` of what is left, and the effect's RMS is ≥ ``min_effect_rms``.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.optimize import minimize_scalar

from sea_daemon.core.effects import Effect
from sea_daemon.analysis.diagnose.candidates import Candidate
from sea_daemon.analysis.diagnose.context import Context
from sea_daemon.analysis.diagnose.options import SelectOptions
from sea_daemon.analysis.diagnose.residuals import integrated_autocorr_time
from sea_daemon.analysis.diagnose.samples import FitSamples

#: friction types this stage tries
FRICTION = ("coulomb", "stribeck")


class LowSpeedStage:
    """Forward selection of friction on every sample of the fit block (see module docstring)."""

    def __init__(self, ctx: Context, opts: SelectOptions, samples: FitSamples):
        self.ctx = ctx
        self.opts = opts
        #: [rad/s] (load, motor) stick speeds
        self.v_min = samples.v_min
        self.t_idx = np.flatnonzero(samples.all_t)
        K = max(2, self.opts.folds)
        edges = np.linspace(0, self.t_idx.size, K + 1).astype(int)
        self.fold = np.zeros(self.t_idx.size, dtype=int)
        for k in range(K):
            self.fold[edges[k]:edges[k + 1]] = k
        self.K = K

    # ------------------------------------------------------------------ evaluations
    def resid(self, effects) -> np.ndarray:
        """Exact residual (M, 2n) on the fit block's samples."""
        return self.ctx.residual(list(effects))[self.t_idx]

    def _ss(self, r, where=None) -> float:
        if where is not None:
            r = r[where]
        return float(np.sum(r * r))

    def _amp_max(self, cand: Candidate, r_cur: np.ndarray) -> float:
        """Largest friction amplitude worth searching: 3 × the largest residual on that side."""
        n = self.ctx.n
        ch = cand.joint if cand.side == "load" else n + cand.joint
        return max(3.0 * float(np.max(np.abs(r_cur[:, ch]))), 1e-6)

    def _fit_amp(self, make, base, hi, where=None) -> tuple[float, float]:
        """Amplitude A ∈ [0, hi] minimising the sum of squares of base + make(A)."""
        def f(a):
            return self._ss(self.resid(base + [make(a)]), where)
        r = minimize_scalar(f, bounds=(0.0, hi), method="bounded", options={"xatol": hi * 1e-4, "maxiter": 40})
        a, v = float(r.x), float(r.fun)
        v0 = f(0.0)
        return (a, v) if v <= v0 else (0.0, v0)

    def v_grid(self, cand: Candidate) -> list[float]:
        """Stribeck speeds: from the stick speed of that side to twice its 99th-percentile speed."""
        _, v, _ = cand.side_signals(self.ctx)
        vmax = max(float(np.percentile(np.abs(v[self.t_idx]), 99)), 1e-3)
        lo = max(self.v_min[0 if cand.side == "load" else 1] / 3.0, 1e-3)
        return list(np.geomspace(lo, max(2.0 * vmax, 2 * lo), 24))

    def fit(self, cand: Candidate, base: list[Effect], r_cur: np.ndarray, where=None,
            v_s: float | None = None) -> tuple[dict, float]:
        """(params, sum of squares) of ``cand`` added to ``base`` (fixed)."""
        hi = self._amp_max(cand, r_cur)
        if cand.type == "coulomb":
            a, ss = self._fit_amp(lambda x: cand.effect({"F_c": x}), base, hi, where)
            return {"F_c": a}, ss
        grid = [v_s] if v_s is not None else self.v_grid(cand)
        best = None
        for vs in grid:
            a, ss = self._fit_amp(lambda x, vs=vs: cand.effect({"F_s": x, "v_s": vs}), base, hi, where)
            if best is None or ss < best[2]:
                best = (a, vs, ss)
        a, vs, ss = best
        if v_s is None and len(grid) > 1:
            g = np.asarray(grid)
            i = int(np.argmin(np.abs(g - vs)))
            lo_, hi_ = g[max(i - 1, 0)], g[min(i + 1, len(g) - 1)]

            def f(lv):
                return self._fit_amp(lambda x: cand.effect({"F_s": x, "v_s": math.exp(lv)}), base, hi, where)[1]
            r = minimize_scalar(f, bounds=(math.log(lo_), math.log(hi_)), method="bounded",
                                options={"xatol": 1e-3, "maxiter": 20})
            if r.fun < ss:
                vs = math.exp(float(r.x))
                a, ss = self._fit_amp(lambda x: cand.effect({"F_s": x, "v_s": vs}), base, hi, where)
        return {"F_s": a, "v_s": vs}, ss

    def cv(self, cand: Candidate | None, base: list[Effect], params: dict | None, r_cur: np.ndarray) -> float:
        """Blocked CV mean square: amplitude refitted on the other blocks (v_s kept)."""
        if cand is None:
            return self._ss(r_cur) / r_cur.size
        err = 0.0
        for k in range(self.K):
            tr = self.fold != k
            p, _ = self.fit(cand, base, r_cur, where=tr, v_s=params.get("v_s"))
            r = self.resid(base + [cand.effect(p)])
            err += self._ss(r, self.fold == k)
        return err / r_cur.size

    # ------------------------------------------------------------------ selection
    def run(self, chosen: list[tuple[Candidate, dict]], cands: list[Candidate], rss0: float,
            max_new: int) -> tuple[list[tuple[Candidate, dict]], list, list]:
        """Add friction candidates to ``chosen`` while the evidence supports it.

        Returns (new (candidate, params) pairs, one (rows, chosen name or None, reason) per step,
        alternatives per new pair).
        ``rss0``: sum of squares of the configured model over the fit block (the shares'
        denominator)."""
        o = self.opts
        base = [c.effect(p) for c, p in chosen]
        taken = {(c.type, c.side, c.joint) for c, _ in chosen}
        pool = [c for c in cands if c.type in FRICTION and c.side in ("load", "motor")
                and (c.type, c.side, c.joint) not in taken]
        new, steps, alts = [], [], []
        M = self.t_idx.size * 2 * self.ctx.n
        for _ in range(max_new):
            if not pool:
                break
            r_cur = self.resid(base)
            ss_cur = self._ss(r_cur)
            tau = integrated_autocorr_time(r_cur)
            n_eff = max(M / tau, 2.0)
            bic_cur = n_eff * math.log(max(ss_cur, 1e-300) / M)
            cv_cur = self.cv(None, base, None, r_cur)
            fits = []
            for c in pool:
                p, ss = self.fit(c, base, r_cur)
                k = len(c.params)
                look = 2.0 * math.log(len(self.v_grid(c))) if c.type == "stribeck" else 0.0
                bic = n_eff * math.log(max(ss, 1e-300) / M) + k * math.log(n_eff) + look
                fits.append((bic, c, p, ss))
            fits.sort(key=lambda f: f[0])
            rows = [{"candidate": c.name, "type": c.type, "side": c.side,
                     "params": {k: round(v, 6) for k, v in p.items()},
                     "explains": (ss_cur - ss) / rss0, "delta_bic": bic - bic_cur} for bic, c, p, ss in fits]
            best, rejected = None, []
            for bic, c, p, ss in fits:
                why = []
                if not bic < bic_cur:
                    why.append(f"BIC does not fall ({bic - bic_cur:+.1f})")
                elif c.implausible(self.ctx, p):
                    why.append(f"not physical: {c.implausible(self.ctx, p)}")
                else:
                    cvv = self.cv(c, base, p, r_cur)
                    if not cvv < cv_cur * (1.0 - o.min_cv_gain):
                        why.append(f"held-out mean square falls only {100 * (1 - cvv / cv_cur):.1f} % "
                                   f"(< {100 * o.min_cv_gain:.0f} %)")
                    d = r_cur - self.resid(base + [c.effect(p)])
                    eff_rms = math.sqrt(float(np.sum(d * d)) / self.t_idx.size)
                    if eff_rms < o.min_effect_rms:
                        why.append(f"its share of the residual is {eff_rms:.4f} N m RMS (< {o.min_effect_rms:.3g} N m)")
                    gain = ss_cur - ss
                    if gain / rss0 < o.min_fraction and gain / ss_cur < o.min_fraction_current:
                        why.append(f"explains {100 * gain / rss0:.1f} % of the initial mean square "
                                   f"(< {100 * o.min_fraction:.0f} %) and {100 * gain / ss_cur:.1f} % of what is left "
                                   f"(< {100 * o.min_fraction_current:.0f} %)")
                if not why:
                    best = (bic, c, p, ss, cvv)
                    break
                rejected.append(f"{c.name}: " + "; ".join(why))
                if not bic < bic_cur:
                    break
            if best is None:
                steps.append((rows, None, "low speed, every sample (friction set-valued while sticking): "
                                          "no candidate accepted — " + " | ".join(rejected[:3])))
                break
            bic, c, p, ss, cvv = best
            gain = ss_cur - ss
            near = [f[1].name for f in fits if f[1] is not c and gain > 0 and (ss_cur - f[3]) >= o.ambiguity * gain
                    and f[0] - bic < o.ambiguity_bic]
            steps.append((rows, c.name,
                          f"low speed, every sample (friction set-valued while sticking): {c.name} explains "
                          f"{100 * gain / rss0:.1f} % of the initial mean square; ΔBIC {bic - bic_cur:+.1f}; "
                          f"held-out mean square −{100 * (1 - cvv / cv_cur):.1f} %"
                          + (f"; nearly as good: {', '.join(near)}" if near else "")))
            new.append((c, p))
            alts.append(near)
            base = base + [c.effect(p)]
            pool = [q for q in pool if not (q.type == c.type and q.side == c.side and q.joint == c.joint)]
        return new, steps, alts
