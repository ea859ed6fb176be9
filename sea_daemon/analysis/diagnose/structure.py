"""Structure left in the residual that no candidate took (step 5 of :mod:`.select`).

Bin means of the final residual against q, q̇, θ_s, θ_m and (q, sign q̇): the largest share of
the remaining mean square such a lookup explains, less its chance level, as a fraction of the
initial sum of squares over the whole log, with the signal it follows.
"""
from __future__ import annotations

import math

import numpy as np

from sea_daemon.analysis.diagnose.fitting import LinearFits
from sea_daemon.analysis.diagnose.options import SelectOptions
from sea_daemon.analysis.diagnose.residuals import integrated_autocorr_time


def leftover_structure(fits: LinearFits, opts: SelectOptions, res: np.ndarray) -> dict:
    """Share of the leftover explained by bin means against state signals (chance-corrected),
    as a fraction of the initial sum of squares over the whole log."""
    all0 = max(fits.rss_all([]), 1e-300)
    ctx = fits.ctx
    kin = ctx.kin
    q, th = ctx.angles()
    c = ctx.r0.shape[1]
    n = ctx.n
    valid_t = np.unique(fits.samples.time_index)
    R = np.full((kin.N, c), np.nan)
    R.reshape(-1)[np.flatnonzero(fits.samples.valid)] = res
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
                    bins = _bins(sig["q"], 10) * 2 + (sgn > 0)
                    nb = 20
                else:
                    bins = _bins(s, 16)
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
    best["warn"] = bool(best["fraction"] >= opts.structure_threshold
                        and best["rms"] >= opts.min_effect_rms)
    return best


def _bins(s: np.ndarray, k: int) -> np.ndarray:
    qs = np.quantile(s, np.linspace(0, 1, k + 1)[1:-1])
    return np.searchsorted(qs, s)
