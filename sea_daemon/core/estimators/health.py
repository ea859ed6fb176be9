"""Estimator hygiene: NIS monitor, positive-definiteness check, bounded GP inputs.

The daemon's fault policy (docs/safety.md) needs the estimator to *fail loudly* rather than
drift into nonsense or NaN.  Three cheap checks, all pure (no I/O, no clock), preallocated:

* :class:`NISMonitor` — the normalised innovation squared ``ε_k = νᵀ S⁻¹ ν`` of a consistent
  Kalman filter is χ² with ``m = 4n`` degrees of freedom (Bar-Shalom, Li & Kirubarajan,
  *Estimation with Applications to Tracking and Navigation*, §5.4.2).  The mean over a
  window of ``W`` steps, ``ε̄ = (1/W) Σ ε``, then has ``W ε̄ ~ χ²_{W m}``: its two-sided band at
  level α is ``[χ²_{Wm}(α/2)/W, χ²_{Wm}(1 − α/2)/W]``.  A real plant is never the model, and
  the paper's R is conservative, so a healthy filter sits far *below* the band (measured:
  windowed mean 0.01–3 for m = 4), and a filter with a mismatched model above it by a small
  factor.  *Divergence* is the windowed mean above ``scale`` × the upper band edge for
  ``sustain`` consecutive steps: it raises :class:`EstimatorFault` ("NIS divergence"),
  which the loop maps to ``Fault.NIS_DIVERGENCE``.  ``inside`` / ``ratio`` are published for
  monitoring (being outside the band alone is not a fault).
* :func:`check_pd` — Cholesky of P (LAPACK ``dpotrf``): fails unless P is symmetric positive
  definite; raises :class:`EstimatorFault` ("not positive definite") → ``Fault.COVARIANCE_NOT_PD``.
* :class:`InputBox` — the GP's inputs are clipped to the box of its training inputs widened by
  ``margin`` × its width on each side (at least ``min_margin``) before ``predict``.  Outside
  its data a GP only reverts to its prior, but its gradient (eq:moejac, the linearisation
  eq:linearization) and the LoG-GP's routing are not meant to be evaluated at, say, a
  velocity spike of 1e3 rad/s; the clipped prediction is constant along the clipped
  coordinates (their Jacobian columns are zeroed).
"""
from __future__ import annotations

import math

import numpy as np
from scipy.linalg.lapack import dpotrf as _dpotrf

from sea_daemon.core.bounds.ellipsoid import chi2_quantile
from sea_daemon.core.jit import njit, warmer
from sea_daemon.errors import Fault
from sea_daemon.errors import EstimatorFault
from sea_daemon.core.linalg import is_pd


class NISDivergence(EstimatorFault):
    """The windowed mean NIS stayed far above its χ² band: the filter diverges."""

    fault = Fault.NIS_DIVERGENCE


class EstimatorNonFinite(EstimatorFault):
    """The state, its covariance or the innovation became NaN/inf."""

    fault = Fault.ESTIMATOR_NONFINITE


class CovarianceNotPD(EstimatorFault):
    """The state covariance P lost symmetry, finiteness or positive definiteness."""

    fault = Fault.COVARIANCE_NOT_PD


class CovarianceDiverged(EstimatorFault):
    """The predicted covariance grew far beyond its physical caps: the linearised model diverges."""

    fault = Fault.COVARIANCE_NOT_PD


def check_pd(P: np.ndarray, what: str = "P", step: int | None = None, full: bool = True) -> None:
    """Raise :class:`EstimatorFault` unless ``P`` is finite, symmetric and positive definite.

    ``full=False``: the Cholesky attempt only, for a P the caller has already checked finite
    and symmetrised (the AKF's Joseph-form update does both).
    """
    where = f" at step {step}" if step is not None else ""
    if not full:
        info = is_pd(P)                     # compiled Cholesky attempt (linalg_small)
        if info != 0:
            raise CovarianceNotPD(f"covariance {what}{where} is not positive definite "
                                  f"(Cholesky fails at pivot {info}, diagonal min {float(np.min(np.diag(P))):.3g})")
        return
    if not np.isfinite(P).all():
        raise EstimatorNonFinite(f"covariance {what}{where} is not finite")
    asym = float(np.max(np.abs(P - P.T)))
    scale = float(np.max(np.abs(P))) or 1.0
    if asym > 1e-9 * scale:
        raise CovarianceNotPD(f"covariance {what}{where} is not positive definite: not symmetric "
                             f"(max |P - P^T| = {asym:.3g}, allowed <= {1e-9 * scale:.3g})")
    _, info = _dpotrf(P, lower=1)
    if info != 0:
        raise CovarianceNotPD(f"covariance {what}{where} is not positive definite "
                             f"(Cholesky fails at pivot {info}, diagonal min {float(np.min(np.diag(P))):.3g})")


class NISMonitor:
    """Windowed mean NIS against its χ² band; sustained divergence raises EstimatorFault.

    ``dof``: innovation dimension m (4n for the AKF).  ``window``: W steps.  ``alpha``: the
    band's two-sided level.  ``scale``: divergence is a windowed mean above ``scale`` × the
    upper band edge.  ``sustain``: consecutive steps it must stay there (default W // 2).
    """

    def __init__(self, dof: int, window: int = 100, alpha: float = 1e-3, scale: float = 10.0,
                 sustain: int | None = None):
        if window < 1 or not 0 < alpha < 1 or scale < 1:
            raise ValueError(f"NIS monitor: window {window} (>= 1), alpha {alpha} (in (0, 1)), "
                             f"scale {scale} (>= 1)")
        self.dof, self.window, self.alpha, self.scale = int(dof), int(window), float(alpha), float(scale)
        self.sustain = max(1, self.window // 2) if sustain is None else int(sustain)
        W, m = self.window, self.dof
        # W ε̄ ~ χ²_{W m} for a consistent filter (Bar-Shalom et al. §5.4.2)
        self.lower = chi2_quantile(0.5 * self.alpha, W * m) / W
        self.upper = chi2_quantile(1.0 - 0.5 * self.alpha, W * m) / W
        self.threshold = self.scale * self.upper
        self._buf = np.zeros(W)
        self.reset()

    def reset(self) -> None:
        self._buf[:] = 0.0
        self._i = 0
        self._n = 0
        self._sum = 0.0
        self._above = 0
        self.mean = 0.0          # windowed mean NIS (over the samples seen, until the window is full)
        self.inside = True       # mean inside [lower, upper] (monitoring only)
        self.ratio = 0.0         # mean / upper

    def update(self, nis: float, step: int | None = None) -> float:
        """Add one NIS value; returns the windowed mean; raises on sustained divergence."""
        if not math.isfinite(nis):
            raise NISDivergence(f"NIS divergence{'' if step is None else f' at step {step}'}: "
                                 f"NIS is {nis} (not finite)")
        W = self.window
        old = self._buf[self._i]
        self._buf[self._i] = nis
        self._i = (self._i + 1) % W
        if self._n < W:
            self._n += 1
            self._sum += nis
        else:
            self._sum += nis - old
        if self._i == 0:                     # re-sum once per window: no drift of the running sum
            self._sum = float(self._buf.sum())
        self.mean = self._sum / self._n
        self.ratio = self.mean / self.upper
        self.inside = self.lower <= self.mean <= self.upper
        if self._n == W and self.mean > self.threshold:
            self._above += 1
            if self._above >= self.sustain:
                raise NISDivergence(
                    f"NIS divergence{'' if step is None else f' at step {step}'}: mean NIS over {W} steps "
                    f"{self.mean:.4g} above {self.threshold:.4g} (= {self.scale:g} x the chi2 band's upper edge "
                    f"{self.upper:.4g}, dof {self.dof}, alpha {self.alpha:g}) for {self._above} steps")
        else:
            self._above = 0
        return self.mean


class EstimatorHealth:
    """The per-step checks of an AKF: NIS monitor and Cholesky of P, every step."""

    def __init__(self, dof: int, window: int = 100, alpha: float = 1e-3, scale: float = 10.0,
                 sustain: int | None = None):
        self.nis = NISMonitor(dof, window, alpha, scale, sustain)

    def reset(self) -> None:
        self.nis.reset()

    def check(self, nis: float, P: np.ndarray, step: int | None = None) -> None:
        check_pd(P, "P", step, full=False)     # the AKF checked finiteness and symmetrised
        self.nis.update(nis, step)


class InputBox:
    """Bounding box of the GP's training inputs; :meth:`clip` before every prediction.

    ``margin``: widening on each side as a fraction of the box width per coordinate;
    ``min_margin`` (absolute, per coordinate, default 0) keeps a degenerate box (one point, a
    constant coordinate) from pinning the input exactly.  Without training data nothing is
    clipped (the GP returns its prior there anyway).

    Learned: ``lo_``, ``hi_`` the box of the training inputs.  ``clip_lo``, ``clip_hi``: that box
    widened, what an input is clipped into; ``clipped_z`` the last input clipped, ``clipped``
    which of its coordinates were.
    """

    def __init__(self, dim: int, margin: float = 0.1, min_margin=0.0):
        self.dim = int(dim)
        self.margin = float(margin)
        self.min_margin = np.broadcast_to(np.asarray(min_margin, dtype=float), (self.dim,)).copy()
        self.lo_ = np.full(self.dim, np.inf)
        self.hi_ = np.full(self.dim, -np.inf)
        self.clip_lo = np.full(self.dim, -np.inf)
        self.clip_hi = np.full(self.dim, np.inf)
        self.clipped = np.zeros(self.dim, dtype=bool)
        self.any_clipped = False
        self.n_clipped = 0
        self.clipped_z = np.zeros(self.dim)

    @classmethod
    def of_residual(cls, gp, margin: float = 0.1) -> "InputBox":
        """The box of the training inputs a residual's GPs (``gp.gps``, LoG-GP leaves) already
        hold — a loaded model's — widened by ``margin``."""
        box = cls(3 * gp.n, margin)
        for g in gp.gps:
            for leaf in g.leaves():
                lg = g.leaf(leaf)
                if lg.n_:
                    box.add_many(lg.X_[:lg.n_])
        return box

    @property
    def empty(self) -> bool:
        return not np.isfinite(self.lo_[0])

    def add(self, z: np.ndarray) -> None:
        """Widen the box to contain the training input ``z`` (non-finite inputs are ignored)."""
        _box_add(np.ascontiguousarray(z, dtype=float), self.lo_, self.hi_, self.margin, self.min_margin,
                 self.clip_lo, self.clip_hi)

    def add_many(self, Z: np.ndarray) -> None:
        Z = np.asarray(Z, dtype=float).reshape(-1, self.dim)
        Z = Z[np.isfinite(Z).all(axis=1)]
        if len(Z):
            self.add(Z.min(axis=0))
            self.add(Z.max(axis=0))

    def clip(self, z: np.ndarray) -> np.ndarray:
        """``z`` clipped into the widened box (a work array, overwritten by the next call);
        :attr:`clipped` marks the coordinates that were clipped.  Non-finite inputs are
        clipped to the box too (NaN → the box centre), never passed to the GP."""
        self.any_clipped = box_clip(np.ascontiguousarray(z, dtype=float), self.clip_lo, self.clip_hi,
                                    self.clipped_z, self.clipped)
        if self.any_clipped:
            self.n_clipped += 1
        return self.clipped_z


@njit
def _box_add(z, lo_, hi_, margin, min_margin, lo, hi):
    """lo_, hi_ ← the box widened to contain z (skipped if z is not finite); lo, hi ← the box
    padded by max(margin × width, min_margin) on each side."""
    d = z.shape[0]
    for j in range(d):
        if not math.isfinite(z[j]):
            return
    for j in range(d):
        lo_[j] = min(lo_[j], z[j])
        hi_[j] = max(hi_[j], z[j])
        pad = max(margin * (hi_[j] - lo_[j]), min_margin[j])
        lo[j] = lo_[j] - pad
        hi[j] = hi_[j] + pad


@njit
def box_clip(z, lo, hi, out, clipped) -> bool:
    """out ← z clipped into [lo, hi] (NaN → the box centre; an empty box: ±inf → ±1e6, NaN → 0);
    clipped[j] ← whether coordinate j changed.  Returns whether any did."""
    any_ = False
    for j in range(z.shape[0]):
        v = z[j]
        if not math.isfinite(lo[j]):                 # no training data yet: nothing to clip to
            if math.isnan(v):
                o = 0.0
            elif math.isinf(v):
                o = 1e6 if v > 0 else -1e6
            else:
                o = v
        elif math.isnan(v):
            o = 0.5 * (lo[j] + hi[j])
        else:
            o = min(max(v, lo[j]), hi[j])
        out[j] = o
        c = not (o == v)
        clipped[j] = c
        any_ = any_ or c
    return any_


@warmer
def _warm() -> None:
    box = InputBox(3, 0.1)
    box.clip(np.zeros(3))
    box.add(np.zeros(3))
    box.clip(np.ones(3))
    box.add_many(np.ones((2, 3)))
