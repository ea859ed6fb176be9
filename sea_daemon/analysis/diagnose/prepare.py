"""A measured log made ready for diagnosis: a uniform time grid and the encoders' resolution.

Real loggers do not always write a clean grid: a soft real-time loop jitters, a sample is
dropped now and then, and the clock seldom starts at zero.  The residuals use second
differences and zero-phase filters on a uniform grid, so :func:`prepare_log`

* keeps the log's own time origin (nothing in diagnose depends on t₀; the plots show the
  log's times);
* **resamples** a log whose sample intervals differ from their median T by more than
  :data:`JITTER_TOL` (relative) onto the uniform grid t₀ + kT: the encoder angles and a
  ``tau_h_act`` column by linear interpolation, the torque command as a zero-order hold (the
  value last commanded: the amplifier holds it until the next sample).  Intervals up to
  :data:`MAX_GAP` × T (a dropped sample, plus jitter) are bridged this way;
* rejects a longer gap with a :class:`~sea_daemon.errors.LogFormatError` naming its line:
  interpolating over it would invent the motion.

:func:`encoder_quanta` compares the encoder steps seen in the log with the configured
resolution (``hardware.encoder_counts`` / ``encoder_bits``): the coarser of the two is what
the velocity estimates are made of, and a log coarser than its configuration is reported.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from sea_daemon.core.config import ModelConfig
from sea_daemon.errors import LogFormatError
from sea_daemon.core.log import MeasuredLog

#: relative deviation of a sample interval from the median above which the log is resampled
JITTER_TOL = 0.01
#: longest interval [median periods] bridged by resampling; a longer one is a gap (error)
MAX_GAP = 2.5


@dataclass
class Prepared:
    """The log diagnose works on and what was done to get it."""

    log: MeasuredLog                 # on a uniform grid (the input itself when it already was)
    original_samples: int
    period: float                    # T [s]
    resampled: bool = False
    max_jitter: float = 0.0          # largest |Δt − T| / T of the input
    dropped: int = 0                 # intervals of ≥ 1.5 T (dropped samples bridged)
    notes: list[str] = field(default_factory=list)

    def summary(self) -> dict:
        return {"resampled": self.resampled, "period_s": self.period, "t0_s": float(self.log.t[0]),
                "max_interval_jitter": self.max_jitter, "bridged_gaps": self.dropped,
                "samples_in_log": self.original_samples, "samples_on_grid": int(len(self.log))}


def prepare_log(log: MeasuredLog) -> Prepared:
    """The log on a uniform grid (see the module docstring); raises LogFormatError on a gap."""
    t = np.asarray(log.t, dtype=float)
    dt = np.diff(t)
    T = float(np.median(dt))
    rel = np.abs(dt - T) / T
    big = np.flatnonzero(dt > MAX_GAP * T)
    if big.size:
        i = int(big[0])
        raise LogFormatError(log.path, i + 3, f"a gap of {dt[i]:.6g} s after t = {t[i]:.6g} s, more than "
                                              f"{MAX_GAP:g} sample periods ({T:.6g} s): diagnose resamples a "
                                              "jittered log onto a uniform grid but does not invent the motion "
                                              "over a gap; split the log there")
    small = np.flatnonzero(dt < (1.0 - 0.9) * T)
    if small.size:
        i = int(small[0])
        raise LogFormatError(log.path, i + 3, f"sample interval {dt[i]:.6g} s after t = {t[i]:.6g} s is under a "
                                              f"tenth of the median {T:.6g} s (a duplicated or mistimed sample); "
                                              "diagnose needs a near-uniform rate")
    prep = Prepared(log=log, original_samples=len(log), period=T, max_jitter=float(rel.max(initial=0.0)),
                    dropped=int(np.sum(dt >= 1.5 * T)))
    if prep.max_jitter <= JITTER_TOL:
        return prep
    n_grid = int(np.floor((t[-1] - t[0]) / T + 1e-9)) + 1
    tg = t[0] + T * np.arange(n_grid)

    def lin(x):
        return np.column_stack([np.interp(tg, t, x[:, j]) for j in range(x.shape[1])])

    # zero-order hold: the last command at or before each grid time
    idx = np.clip(np.searchsorted(t, tg + 1e-9 * T, side="right") - 1, 0, len(t) - 1)
    new = MeasuredLog(t=tg, q=lin(log.q), theta_m=lin(log.theta_m), tau_m=np.asarray(log.tau_m)[idx],
                      tau_h_act=None if log.tau_h_act is None else lin(log.tau_h_act),
                      extra={k: np.interp(tg, t, v) for k, v in log.extra.items()}, path=log.path)
    prep.log = new
    prep.resampled = True
    prep.notes.append(
        f"The log's sample intervals vary by up to {100 * prep.max_jitter:.0f} % of their median {T:.6g} s"
        + (f" ({prep.dropped} dropped sample(s) bridged)" if prep.dropped else "")
        + f": it was resampled onto a uniform grid of {T:.6g} s from t = {t[0]:.6g} s ({len(tg)} samples; "
          "angles interpolated linearly, the torque command held from its last sample).")
    return prep


def observed_quantum(x: np.ndarray) -> float:
    """The grid step the signal's values lie on (an encoder's count, joint side), or 0.

    Candidates are the smallest sample-to-sample changes (the joint crawling one count at a
    time somewhere in the log), refined by least squares over the counts (a CSV prints the step
    rounded); one is accepted when ≥ 95 % of the values lie within 5 % of a multiple of it from
    the first value.  0 when the
    signal is not on a grid (filtered, interpolated) or hardly changes.
    """
    x = np.asarray(x, dtype=float)
    d = np.abs(np.diff(x))
    d = d[d > 1e-12 * max(1.0, float(np.max(np.abs(x))))]
    if d.size < 10:
        return 0.0
    y = x - x[0]
    for c in (float(d.min()), float(np.percentile(d, 1)), float(np.percentile(d, 5))):
        # the step itself is printed rounded: refine it by least squares on the counts, from
        # the values near the first one outwards (a relative error ε miscounts beyond 1/2ε)
        for lim in (20.0, 200.0, 2000.0, np.inf):
            near = np.abs(y) < lim * c
            for _ in range(3):
                k = np.round(y[near] / c)
                kk = float(k @ k)
                if kk <= 0:
                    break
                c = float(k @ y[near]) / kk
        k = y / c
        if np.mean(np.abs(k - np.round(k)) < 0.05) >= 0.95:
            return c
    return 0.0


def encoder_quanta(log: MeasuredLog, cfg: ModelConfig) -> dict:
    """Configured and observed joint-side encoder steps [rad], per side, and the step used.

    The step used for the velocity noise is the coarser of the two (a log of a 19-bit
    configuration written with 2000-line encoders moves in 2000-line steps); a log coarser
    than its configuration by more than 1.5× is flagged.
    """
    n = log.n
    dq_cfg, dm_cfg = cfg.hardware.encoder_resolution(n)
    out = {"load": [], "motor": [], "mismatch": []}
    for side, arr, conf in (("load", log.q, dq_cfg), ("motor", log.theta_m, dm_cfg)):
        for j in range(n):
            obs = observed_quantum(arr[:, j])
            used = max(float(conf[j]), obs)
            out[side].append({"configured": float(conf[j]), "observed": obs, "used": used})
            if obs > 1.5 * conf[j]:
                out["mismatch"].append((side, j, float(conf[j]), obs))
    return out


#: a log longer than this many rows is diagnosed on segments of it (:func:`segments`)
MAX_ROWS = 100_000
#: number of segments a long log is diagnosed on
SEGMENTS = 10


@dataclass
class Segmented:
    """A long log cut down to evenly spread contiguous segments (:func:`segment_log`)."""

    log: MeasuredLog                 # the segments one after another, time continued across the seams
    spans: list[tuple[int, int]]     # (start, stop) of each segment in the joined log
    source_spans: list[tuple[int, int]]   # (start, stop) of each segment in the original log
    original_rows: int

    def away_from_seams(self, guard: int) -> np.ndarray:
        """(N,) bool: samples at least ``guard`` samples from a seam (the filters reach across one)."""
        N = len(self.log)
        ok = np.ones(N, dtype=bool)
        for a, _ in self.spans[1:]:
            ok[max(a - guard, 0):min(a + guard, N)] = False
        return ok


def segment_log(log: MeasuredLog, max_rows: int | None = MAX_ROWS, n_segments: int = SEGMENTS) -> Segmented | None:
    """None for a log of at most ``max_rows`` rows; else ``n_segments`` contiguous segments of
    max_rows / n_segments rows each, spread evenly over the log (the first at its start, the last
    at its end), joined into one log whose time runs on across the seams.

    The whole diagnosis then runs on at most ``max_rows`` rows (memory and time bounded however
    long the log): the fit leaves the samples near a seam out (the smoothers reach across it), and
    the estimators run over each segment separately.  Every part of the log's range of motion
    that lasts longer than the gaps between segments is seen.
    """
    N = len(log)
    if not max_rows or N <= max_rows:
        return None
    L = max_rows // n_segments
    starts = np.linspace(0, N - L, n_segments).round().astype(int)
    src = [(int(a), int(a) + L) for a in starts]
    t = np.asarray(log.t, dtype=float)
    T = float(np.median(np.diff(t[:min(N, 10000)])))
    parts = {k: [] for k in ("t", "q", "theta_m", "tau_m", "tau_h_act")}
    spans, off = [], 0
    t_next = float(t[0])
    for a, b in src:
        parts["t"].append(t[a:b] - t[a] + t_next)
        t_next = float(parts["t"][-1][-1]) + T
        for k in ("q", "theta_m", "tau_m"):
            parts[k].append(np.asarray(getattr(log, k))[a:b])
        if log.tau_h_act is not None:
            parts["tau_h_act"].append(np.asarray(log.tau_h_act)[a:b])
        spans.append((off, off + (b - a)))
        off += b - a
    joined = MeasuredLog(t=np.concatenate(parts["t"]), q=np.concatenate(parts["q"]),
                         theta_m=np.concatenate(parts["theta_m"]), tau_m=np.concatenate(parts["tau_m"]),
                         tau_h_act=np.concatenate(parts["tau_h_act"]) if log.tau_h_act is not None else None,
                         path=log.path)
    return Segmented(log=joined, spans=spans, source_spans=src, original_rows=N)
