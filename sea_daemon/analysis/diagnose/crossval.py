"""Cross-validation over contiguous time blocks: an effect is kept only where it helps unseen data.

The log's scored samples are cut into K contiguous time blocks (:func:`time_blocks`).  For
each block k the effects are fitted on the other blocks alone (half a smoothing window either
side of block k belongs to neither: the smoother reaches across) and scored on block k: the
residual RMS and, when the log's truth is used (``estimate``), the AKF's τ̂_h,act error on
that block.  :meth:`CrossValidation.prune` then keeps an effect only if the model with it
errs less on the blocks its fit did not see than the model without it (pooled over the
blocks), and only a set of effects that errs no more than the input model on **every**
held-out block: the effect whose removal helps the worst block most leaves until that holds.

The criterion is the AKF's held-out error when the estimate is scored (a diagnosis is for the
estimator: an effect can lower the residual and still make the filter worse), else the
held-out residual.  Each AKF run covers a block and a warm-up before it (:data:`WARM_S`),
with the input model and with each fold's model alike.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sea_daemon.core.config import ModelConfig
from sea_daemon.errors import EstimatorFault
from sea_daemon.analysis.diagnose.evaluate import akf_run
from sea_daemon.analysis.diagnose.residuals import rms
from sea_daemon.analysis.diagnose.select import Selector

#: [s] the AKF run that scores a block starts this long before it (its transient)
WARM_S = 1.0
#: a held-out block counts as worse with the effects when its error rises by more than this
#: share: an effect that does not act in a block still shifts the others' refitted values a
#: little (chosen on the development logs: the passive scenario's spring stop, which acts in
#: two of four blocks and leaves the others within 1 %)
WORSE_TOL = 0.05
#: iterations of a fold's refit (it starts from the whole log's values, a few Gauss–Newton
#: steps away; the whole log's own refinement allows 60 per parameter)
REFIT_STEPS = 6


def _g(v: float) -> str:
    return f"{v:.4g} N m" if math.isfinite(v) else "not measurable (the filter failed)"


def time_blocks(score: np.ndarray, k: int, need: int) -> list[np.ndarray]:
    """Up to ``k`` contiguous blocks (N,) bool of the samples of ``score``, each of at least
    ``need`` of them; [] when fewer than two such blocks fit."""
    idx = np.flatnonzero(score)
    k = min(int(k), idx.size // max(int(need), 1))
    if k < 2:
        return []
    out = []
    for part in np.array_split(idx, k):
        m = np.zeros(score.size, dtype=bool)
        m[part] = True
        out.append(m)
    return out


def without(score: np.ndarray, block: np.ndarray, guard: int) -> np.ndarray:
    """The samples of ``score`` at least ``guard`` samples away from ``block``."""
    near = block.copy()
    if guard > 0:
        near = np.convolve(block.astype(float), np.ones(2 * guard + 1), mode="same") > 0
    return score & ~near


@dataclass
class BlockFigures:
    """Errors per held-out block [N m]: residual RMS and AKF RMSE, before (input model) and after."""

    residual_before: list[float]
    residual_after: list[float]
    estimate_before: list[float] | None
    estimate_after: list[float] | None

    def criterion(self) -> tuple[list[float], list[float]]:
        """(before, after) per block of what decides: the AKF's error when scored, else the residual."""
        if (self.estimate_after is not None and all(v is not None for v in self.estimate_after)
                and all(v is not None for v in self.estimate_before)):
            return self.estimate_before, self.estimate_after
        return self.residual_before, self.residual_after


def pooled(values: list[float], weights: list[int]) -> float:
    """RMS over the union of blocks from per-block RMS values."""
    w = np.asarray(weights, float)
    v = np.asarray(values, float)
    return float(math.sqrt(np.sum(w * v ** 2) / max(np.sum(w), 1.0)))


class BlockScorer:
    """The AKF's error on one block of a log, from a run that starts :data:`WARM_S` before it."""

    def __init__(self, log, spans=None):
        self.log = log
        self.spans = spans
        self.truth = log.tau_h_act if log.tau_h_act is not None else np.zeros_like(log.q)
        self.warm = max(int(round(WARM_S / log.dt)), 1)

    def _window(self, block: np.ndarray) -> tuple[int, int]:
        idx = np.flatnonzero(block)
        a, b = int(idx[0]), int(idx[-1]) + 1
        lo = max(a - self.warm, 0)
        for s, e in (self.spans or []):
            if s <= a < e:           # a segmented log: never across a seam
                lo = max(lo, s)
        return lo, b

    def rmse(self, cfg: ModelConfig, block: np.ndarray) -> float | None:
        lo, hi = self._window(block)
        try:
            hat = akf_run(self.log.slice(lo, hi), cfg)["hat"]
        except (EstimatorFault, np.linalg.LinAlgError, FloatingPointError):
            return None
        if not np.all(np.isfinite(hat)):
            return None
        m = block[lo:hi]
        e = hat[m] - self.truth[lo:hi][m]
        return float(np.sqrt(np.mean(e ** 2))) if e.size else None


class CrossValidation:
    """Effects fitted on all blocks but one and scored on that one (see the module docstring).

    ``selectors``: one :class:`.select.Selector` per block whose fit samples leave the block out;
    ``inner``: (N,) samples away from the smoother's ends (where residuals are scored)."""

    def __init__(self, ctx, cfg: ModelConfig, blocks: list[np.ndarray], selectors: list, inner: np.ndarray,
                 scorer: BlockScorer | None):
        self.ctx = ctx
        self.cfg = cfg
        self.blocks = blocks
        self.selectors = selectors
        self.inner = inner
        self.scorer = scorer
        self.sizes = [int(np.sum(b & inner)) for b in blocks]
        self._cache: dict = {}
        r0 = ctx.r0
        self.res_before = [rms(r0[b & inner]) for b in blocks]
        self.est_before = ([scorer.rmse(cfg, b) for b in blocks] if scorer is not None else None)

    def models(self, pairs: list) -> list[list]:
        """The effects of ``pairs`` refitted per fold: one list of (candidate, params) per block."""
        return [sel.refit(list(pairs), REFIT_STEPS) for sel in self.selectors]

    def figures(self, per_fold: list[list]) -> BlockFigures:
        """Held-out errors of one model per fold (``per_fold[k]``: its (candidate, params))."""
        res, est = [], [] if self.scorer is not None else None
        for k, pairs in enumerate(per_fold):
            effects = [c.effect(p) for c, p in pairs]
            b = self.blocks[k] & self.inner
            res.append(rms(self.ctx.residual(effects)[b]) if effects else self.res_before[k])
            if est is not None:
                if not effects:
                    est.append(self.est_before[k])
                else:
                    cfg_k = self.cfg.with_effects(list(self.cfg.model.effects) + effects)
                    est.append(self.scorer.rmse(cfg_k, self.blocks[k]))
        return BlockFigures(self.res_before, res, self.est_before, est)

    def fold_fits(self, pairs: list, subset: tuple) -> list[list]:
        """The effects ``pairs[i]``, i in ``subset`` (sorted), refitted jointly per fold (cached)."""
        key = tuple(sorted(subset))
        if key not in self._cache:
            chosen = [pairs[i] for i in key]
            self._cache[key] = self.models(chosen) if chosen else [[] for _ in self.blocks]
        return self._cache[key]

    def score(self, pairs: list, subset: tuple) -> BlockFigures:
        """Held-out figures of the effects ``pairs[i]`` for i in ``subset``, refitted per fold (cached)."""
        key = ("figures",) + tuple(sorted(subset))
        if key not in self._cache:
            self._cache[key] = self.figures(self.fold_fits(pairs, subset))
        return self._cache[key]

    def _pooled(self, f: BlockFigures) -> float:
        b, a = f.criterion()
        if any(v is None for v in a):
            return math.inf
        return pooled(a, self.sizes)

    def prune(self, pairs: list) -> tuple[list[int], list[dict]]:
        """Indices of ``pairs`` kept, and why each other one left (see the module docstring).

        Backward elimination: the set is refitted per fold, and so is the set without each effect
        in turn; the effect whose absence the held-out blocks miss least leaves when they do not
        miss it at all, or when the set errs more than the input model on a held-out block; the
        rest is judged again."""
        S = list(range(len(pairs)))
        dropped = []
        base = self.score(pairs, ())
        what = "the AKF's τ̂_h,act error" if base.criterion()[0] is base.estimate_before else "the residual"
        while S:
            cur = self.score(pairs, tuple(S))
            p_cur = self._pooled(cur)
            trials = {i: self.score(pairs, tuple(x for x in S if x != i)) for i in S}
            # the effect the held-out blocks gain least from (its removal helps most)
            i_min = min(S, key=lambda i: self._pooled(trials[i]) - p_cur)
            p_wo = self._pooled(trials[i_min])
            if p_wo <= p_cur:
                dropped.append(self._why(pairs[i_min][0], what, p_cur, p_wo,
                                         "does not help the blocks its fit did not see"))
                S.remove(i_min)
                continue
            b, a = cur.criterion()
            worse = [k for k in range(len(self.blocks))
                     if b[k] is not None and (a[k] is None or a[k] > (1.0 + WORSE_TOL) * b[k])]
            if not worse:
                break

            def worst_ratio(f):
                bb, aa = f.criterion()
                return max((aa[k] / bb[k] if (bb[k] and aa[k] is not None) else math.inf)
                           for k in range(len(self.blocks)))
            i_bad = min(S, key=lambda i: worst_ratio(trials[i]))
            dropped.append(self._why(pairs[i_bad][0], what, p_cur, self._pooled(trials[i_bad]),
                                     f"with it the model errs more than the input model on held-out block(s) "
                                     f"{', '.join(str(k + 1) for k in worse)}"))
            S.remove(i_bad)
        return S, dropped

    @staticmethod
    def _why(cand, what: str, with_: float, wo: float, reason: str) -> dict:
        return {"type": cand.type, "side": cand.side, "joint": cand.joint + 1,
                "reason": f"{reason} ({what} over the held-out blocks: {_g(with_)} with it, {_g(wo)} without)"}


def kept_selection(ctx, cfg: ModelConfig, cands: list, opts, fit_t: np.ndarray, blocks: list[np.ndarray],
                   guard: int, inner: np.ndarray, scorer: BlockScorer | None, v_min) -> dict:
    """The whole selection on the samples ``fit_t``: forward selection and refinement
    (:class:`.select.Selector`), then the pruning of :meth:`CrossValidation.prune` over
    ``blocks`` (contiguous blocks of ``fit_t``), the kept effects refitted jointly.  Returns
    {"pairs": [(candidate, params)], "dropped": [...], "selector": the Selector}."""
    selector = Selector(ctx, cands, opts, fit_t=fit_t, v_min=v_min)
    sel = selector.run()
    pairs = list(sel.chosen)
    dropped: list[dict] = []
    if pairs and len(blocks) >= 2:
        sels = [Selector(ctx, cands, opts, fit_t=without(fit_t, b, guard), v_min=v_min) for b in blocks]
        keep, dropped = CrossValidation(ctx, cfg, blocks, sels, inner, scorer).prune(pairs)
        if len(keep) < len(pairs):
            pairs = selector.refit([pairs[i] for i in keep])
    return {"pairs": pairs, "dropped": dropped, "selector": selector}


def repeated_per_block(ctx, cfg: ModelConfig, candidates_for, opts, score: np.ndarray, blocks: list[np.ndarray],
                       guard: int, inner: np.ndarray, scorer: BlockScorer | None, v_min) -> list[dict]:
    """For each block: the whole selection (:func:`kept_selection`, its pruning over the other
    blocks) repeated on the other blocks alone, and its figures in and out of sample.
    ``candidates_for(mask)``: the candidates the motion of those samples can reveal."""
    out = []
    r0 = ctx.r0
    for k, blk in enumerate(blocks):
        fit_t = without(score, blk, guard)
        others = [without(b, blk, guard) for j, b in enumerate(blocks) if j != k]
        others = [b for b in others if b.any()]
        got = kept_selection(ctx, cfg, candidates_for(fit_t), opts, fit_t, others, guard, inner, scorer, v_min)
        effects = [c.effect(p) for c, p in got["pairs"]]
        r = ctx.residual(effects) if effects else r0
        cfg_k = cfg.with_effects(list(cfg.model.effects) + effects) if effects else cfg
        held, seen = blk & inner, fit_t & inner
        d = {"effects": [{"type": c.type, "side": c.side, "params": {n: float(v) for n, v in p.items()}}
                         for c, p in got["pairs"]],
             "dropped": got["dropped"],
             "in_sample": {"residual_rms_before": rms(r0[seen]), "residual_rms_after": rms(r[seen])},
             "out_of_sample": {"residual_rms_before": rms(r0[held]), "residual_rms_after": rms(r[held])}}
        if scorer is not None:
            d["in_sample"]["estimate_rmse_before"] = scorer.rmse(cfg, fit_t)
            d["in_sample"]["estimate_rmse_after"] = scorer.rmse(cfg_k, fit_t) if effects else d["in_sample"]["estimate_rmse_before"]
            d["out_of_sample"]["estimate_rmse_before"] = scorer.rmse(cfg, blk)
            d["out_of_sample"]["estimate_rmse_after"] = (scorer.rmse(cfg_k, blk) if effects
                                                        else d["out_of_sample"]["estimate_rmse_before"])
        out.append(d)
    return out
