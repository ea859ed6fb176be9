"""Long logs within a memory budget: diagnose analyses one contiguous excerpt.

The diagnosis holds a few kilobytes per sample (the kinematics, the residual channels and
every candidate's regressors at the log's rate: about 9 kB; 930 MB for 10⁵ samples), so a
log of hours would need gigabytes.  A log longer than :data:`MAX_SAMPLES` is therefore
analysed on the contiguous excerpt of that many samples with the most motion (the largest
path length Σ|Δq| over the joints), at the log's own rate: every formula of the residuals
(second differences, the zero-order hold of the torque at t − dt/2, the smoothing windows in
seconds) keeps the sampling it assumes, which decimation would break.  The effects a
diagnosis looks for (friction, gravity, stiffness, inertia, the subject's viscoelasticity)
are properties of the plant, present in any stretch with enough motion; the excerpt of
:data:`MAX_SAMPLES` samples is 8 min 20 s at 100 Hz.

:func:`excerpt` returns the excerpt and what was chosen; the reading of the whole log
(float64 blocks, :func:`sea_daemon.io.logcsv.read_log`) is the only cost that grows with its
length (about 8 bytes per value).
"""
from __future__ import annotations

import numpy as np

from sea_daemon.core.log import MeasuredLog

#: the most samples one diagnosis analyses (about 0.5 GB of working memory)
MAX_SAMPLES = 50_000


def excerpt(log: MeasuredLog, max_samples: int | None = None) -> tuple[MeasuredLog, dict | None]:
    """``(log, None)`` when it has at most ``max_samples`` (default :data:`MAX_SAMPLES`)
    samples; else the contiguous excerpt
    of ``max_samples`` samples with the largest Σ_j Σ_k |q_j[k+1] − q_j[k]| and a dict
    ``{"samples", "first", "last", "t_first", "t_last"}`` saying which (0-based sample indices
    of the whole log).  The excerpt's ``path`` names the log and the samples."""
    N = len(log)
    max_samples = MAX_SAMPLES if max_samples is None else int(max_samples)
    if N <= max_samples:
        return log, None
    if max_samples < 2:
        raise ValueError(f"max_samples must be >= 2, got {max_samples}")
    step = np.abs(np.diff(log.q, axis=0)).sum(axis=1)               # (N − 1,)
    path = np.concatenate([[0.0], np.cumsum(step)])                # path[k] = motion up to sample k
    L = max_samples
    score = path[L - 1:] - path[:N - L + 1]                        # motion inside [s, s + L)
    s = int(np.argmax(score))
    part = log.slice(s, s + L)
    part.path = f"{log.path} [samples {s}..{s + L - 1} of {N}]"
    return part, {"samples": N, "analysed": L, "first": s, "last": s + L - 1,
                  "t_first": float(log.t[s]), "t_last": float(log.t[s + L - 1])}
