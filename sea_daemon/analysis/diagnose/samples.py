"""The samples the selection fits and scores (:class:`FitSamples`), and its least squares.

Of a log's N time samples, the selection leaves out the smoother's ends (``edge``), the
samples outside the fit block of a held-out validation and, for its linear stage, the slow
ones (a side slower than its stick speed, spread by half a smoothing window: smooth friction
cannot follow sticking); a long log is fitted on every ``stride``-th sample.  The stacked
residual y = [r_load, r_motor] of the kept samples is flattened to ``y0`` (``M`` values), and
cut into ``folds`` contiguous time blocks for the blocked cross-validation.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sea_daemon.analysis.diagnose.context import Context
from sea_daemon.analysis.diagnose.options import SelectOptions


def lstsq(A: np.ndarray, y: np.ndarray) -> np.ndarray:
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


def fit_stride(rows: int, max_rows: int | None, window: int) -> int:
    """Every how many samples the linear stage fits: 1 up to ``max_rows`` samples, else the
    stride that brings them down to it (at most half a smoothing window)."""
    if not max_rows or rows <= max_rows:
        return 1
    return int(min(max(math.ceil(rows / max_rows), 1), max(window // 2, 1)))


@dataclass
class FitSamples:
    """Which samples the selection uses (time masks (N,) bool unless said otherwise)."""

    edge: int                      # samples dropped at each end of the log
    all_t: np.ndarray              # every sample of the fit block (the exact, stick-aware fits)
    v_min: tuple[float, float]     # [rad/s] (load, motor) speeds below which a side is slow
    slow_t: np.ndarray             # the slow samples of the fit block
    masked_share: float            # share of the fit block the linear stage leaves out
    stride: int                    # the linear stage fits every stride-th sample
    grid: np.ndarray               # (N / stride,) indices of the stride's samples
    keep_t: np.ndarray             # the samples the linear stage fits
    valid: np.ndarray              # (N·2n,) keep_t per channel, flattened
    time_index: np.ndarray         # (M,) time sample of each fitted value
    y0: np.ndarray                 # (M,) the configured model's residual on them
    valid_in_grid: np.ndarray      # rows of a design on the grid that the fit uses
    fold: np.ndarray               # (M,) blocked-CV segment of each fitted value

    @property
    def M(self) -> int:
        """Number of fitted values (samples × channels)."""
        return self.y0.size

    @classmethod
    def build(cls, ctx: Context, opts: SelectOptions, fit_t: np.ndarray | None = None,
              v_min: tuple[float, float] | None = None) -> "FitSamples":
        """The samples for ``ctx``'s residual under ``opts`` (see the module docstring);
        ``fit_t`` the fit block (default all), ``v_min`` the stick speeds (default
        ``opts.v_min``, else 3 × sign_eps on both sides)."""
        kin = ctx.kin
        N, c = ctx.r0.shape
        edge = opts.edge if opts.edge is not None else kin.window
        edge = min(edge, max(0, (N - 10) // 4))
        keep_t = np.zeros(N, dtype=bool)
        keep_t[edge:N - edge] = True
        if fit_t is not None:
            keep_t &= np.asarray(fit_t, dtype=bool)
        all_t = keep_t.copy()
        if opts.v_min is not None:
            v_min = (opts.v_min, opts.v_min)
        elif v_min is None:
            v_min = (3.0 * ctx.cfg.estimator.sign_eps,) * 2
        v_min = tuple(float(v) for v in v_min)
        slow_t, keep_t = cls._leave_out_slow(ctx, opts, v_min, keep_t, all_t)
        masked_share = 1.0 - float(np.sum(keep_t)) / max(float(np.sum(all_t)), 1.0)
        # a long log: the linear stage fits every k-th sample (the smoothed residual is correlated
        # over a smoothing window, so a stride below it loses little; BIC's effective sample size
        # follows, its autocorrelation time shrinks by the same k)
        stride = fit_stride(int(np.sum(keep_t)), opts.max_fit_rows, kin.window)
        on_grid = (np.arange(N) % stride) == 0
        keep_t = keep_t & on_grid
        grid = np.flatnonzero(on_grid)
        valid = np.repeat(keep_t[:, None], c, axis=1).reshape(-1)
        time_index = np.repeat(np.arange(N), c)[valid]
        y0 = ctx.r0.reshape(-1)[valid]
        # rows of the cached designs that the fit uses: the fit's samples among the grid's
        valid_in_grid = np.repeat(keep_t[grid][:, None], c, axis=1).reshape(-1)
        # blocked CV folds over time
        K = max(2, opts.folds)
        edges = np.linspace(time_index.min(), time_index.max() + 1, K + 1)
        fold = np.clip(np.searchsorted(edges, time_index, side="right") - 1, 0, K - 1)
        return cls(edge, all_t, v_min, slow_t, masked_share, stride, grid, keep_t, valid, time_index, y0,
                   valid_in_grid, fold)

    @staticmethod
    def _leave_out_slow(ctx: Context, opts: SelectOptions, v_min, keep_t, all_t):
        """(the slow samples of the fit block, ``keep_t`` without the slow samples unless they are
        more than ``opts.max_masked`` of it)."""
        kin = ctx.kin
        slow0 = np.any((np.abs(kin.dq) < v_min[0]) | (np.abs(kin.dtheta_m) < v_min[1]), axis=1)
        # the smoother S spreads what happens while sticking over half a window either side
        half = kin.window // 2
        slow = slow0
        if half and slow.any():
            slow = np.convolve(slow.astype(float), np.ones(2 * half + 1), mode="same") > 0
        if np.mean(slow & keep_t) > opts.max_masked * np.mean(keep_t):
            slow = slow0       # a slow log: the slow samples themselves, not their surroundings
        slow_t = slow & all_t
        if np.mean(slow & keep_t) <= opts.max_masked * np.mean(keep_t):
            keep_t = keep_t & ~slow
        return slow_t, keep_t
