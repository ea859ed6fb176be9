"""Kinematics from encoder angles: numerical differentiation (Sec. V-A, ass:data).

The paper obtains angular velocity and acceleration "by numerical differentiation of the
encoder signals together with a moving average filter".  Two estimators are provided:

* :class:`CausalDifferentiator` — online, causal FIR filter over the last samples in a
  preallocated ring buffer: ``update(angle) -> (angle_f, vel, acc)``.  Two methods:

  ``"ma"`` (the paper's): backward differences averaged over ``window`` = W samples,

      θ̇_k = (1/W) Σ_{i=0}^{W-1} (θ_{k-i} − θ_{k-i-1})/dt = (θ_k − θ_{k-W}) / (W dt)
      θ̈_k = (1/W) Σ_{i=0}^{W-1} (θ_{k-i} − 2θ_{k-i-1} + θ_{k-i-2})/dt²
           = (θ_k − θ_{k-1} − θ_{k-W} + θ_{k-W-1}) / (W dt²)
      angle_f = θ_k (the raw angle; encoders are precise, no smoothing is applied).

      Group delay (exact for every frequency, both are linear-phase FIRs):
      velocity W/2 samples, acceleration (W+1)/2 samples, angle 0.  E.g. W = 5 at
      100 Hz: 25 ms and 30 ms.  On a ramp θ = a t the velocity is exact; on θ = t²
      it reads 2(t − W dt/2).

  ``"savgol"``: causal Savitzky–Golay: least-squares polynomial of degree ``degree`` = d
      (≥ 2) over the last W samples, evaluated at the newest sample (end point).  It
      reproduces every polynomial of degree ≤ d exactly, so the group delay at DC is 0
      for the angle and every derivative of order < d; the d-th derivative (the
      acceleration when d = 2) is the fit's constant top coefficient, i.e. a centred
      estimate with delay (W−1)/2 samples.  With d = 3 all three are delay-free at DC.
      The price is a larger noise gain than ``"ma"`` (:meth:`CausalDifferentiator.noise_gain`:
      W = 5, dt = 0.01: velocity 28 (ma) vs 111 (savgol d=2) per rad of white angle noise).

  :meth:`CausalDifferentiator.delay_samples` returns the group delay at DC computed from
  the filter coefficients (tests check it against the analytic values above).

* :func:`smooth_derivatives` — offline, zero-phase (non-causal) Savitzky–Golay smoothing
  and differentiation for whole logs (residuals in ``diagnose``, training targets).

Pure numerics: no I/O, no clock.
"""
from __future__ import annotations

import math

import numpy as np

from sea_daemon.core.jit import njit, warmer

METHODS = ("ma", "savgol")


def _ma_coefficients(window: int, dt: float) -> np.ndarray:
    """(3, W+2) FIR rows (angle, vel, acc) over the buffer ordered oldest … newest."""
    W = window
    L = W + 2
    C = np.zeros((3, L))
    C[0, L - 1] = 1.0
    # velocity: (θ_k − θ_{k-W}) / (W dt)
    C[1, L - 1] += 1.0 / (W * dt)
    C[1, L - 1 - W] -= 1.0 / (W * dt)
    # acceleration: (θ_k − θ_{k-1} − θ_{k-W} + θ_{k-W-1}) / (W dt²)
    a = 1.0 / (W * dt * dt)
    C[2, L - 1] += a
    C[2, L - 2] -= a
    C[2, L - 1 - W] -= a
    C[2, L - 2 - W] += a
    return C


def _savgol_coefficients(window: int, degree: int, dt: float) -> np.ndarray:
    """(3, W) rows: end-point value, first and second derivative of the LS polynomial."""
    W = window
    s = np.arange(-(W - 1), 1, dtype=float)           # sample index relative to newest
    V = np.vander(s, degree + 1, increasing=True)      # columns 1, s, s², …
    pinv = np.linalg.pinv(V)                           # (d+1, W): coefficients c = pinv θ
    # p(0) = c0, p'(0) = c1 / dt, p''(0) = 2 c2 / dt²
    return np.vstack([pinv[0], pinv[1] / dt, 2.0 * pinv[2] / dt**2])


class CausalDifferentiator:
    """Online causal differentiator of ``n`` angle channels (see module docstring).

    ``update(angle)`` returns views ``(angle_f, vel, acc)`` of internal preallocated arrays
    (n,) that the next call overwrites — copy them if you keep them.

    The buffer is primed with the first sample (so velocities start at 0).

    The ring's state is public for estimators that run :func:`fir_push` inside their own
    compiled step: ``buf`` (2L, n) the doubled ring buffer, ``head`` the row of the newest
    sample, ``out`` (3, n) the last (angle_f, vel, acc), ``primed`` whether the buffer holds
    samples (:meth:`forget` clears it: the next :meth:`update` primes it again).
    """

    def __init__(self, dt: float, window: int = 5, n: int = 1, method: str = "ma", degree: int = 2):
        if not dt > 0:
            raise ValueError(f"dt must be > 0, got {dt}")
        if method not in METHODS:
            raise ValueError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
        self.dt, self.window, self.n, self.method, self.degree = float(dt), int(window), int(n), method, degree
        if method == "ma":
            if self.window < 1:
                raise ValueError(f"window must be >= 1 for 'ma', got {window}")
            self.C = _ma_coefficients(self.window, self.dt)
        else:
            if not 2 <= degree < self.window:
                raise ValueError(f"savgol needs 2 <= degree < window, got degree {degree}, window {window}")
            self.C = _savgol_coefficients(self.window, degree, self.dt)
        self.L = self.C.shape[1]
        # doubled ring buffer: buf[i] and buf[i+L] hold the same sample, so the L newest
        # samples are always the contiguous view buf[head+1 : head+1+L] (oldest … newest)
        self.buf = np.zeros((2 * self.L, self.n))
        self.head = self.L - 1
        self.out = np.zeros((3, self.n))
        self.primed = False

    # -- analysis ---------------------------------------------------------------------

    def delay_samples(self) -> tuple[float, float, float]:
        """Group delay at DC [samples] of (angle_f, vel, acc), from the FIR coefficients.

        With per-sample coefficients c_j at sample times s_j = −lag_j, an r-th-derivative
        estimator exact on s^r (Σ c s^r = r!) returns, for the signal s^{r+1}, the true
        r-th derivative at s = −τ with τ = −(Σ c s^{r+1}/(r+1)!) / (Σ c s^r / r!).
        """
        s = -(self.L - 1 - np.arange(self.L)).astype(float)      # 0 = newest sample
        out = []
        for r in range(3):
            c = self.C[r] * self.dt**r                              # per-sample units
            m_r = float(np.sum(c * s**r)) / math.factorial(r)
            m_r1 = float(np.sum(c * s**(r + 1))) / math.factorial(r + 1)
            out.append(-m_r1 / m_r + 0.0)
        return tuple(out)

    def noise_gain(self) -> tuple[float, float, float]:
        """Std of (angle_f, vel, acc) per unit std of white angle noise: ‖c‖₂."""
        return tuple(float(np.linalg.norm(r)) for r in self.C)

    # -- online -----------------------------------------------------------------------

    def reset(self, angle) -> None:
        """Prime the whole buffer with ``angle`` (velocity and acceleration read 0)."""
        a = np.asarray(angle, dtype=float).reshape(self.n)
        self.buf[:] = a
        self.head = self.L - 1
        self.primed = True

    def forget(self) -> None:
        """Forget the samples: the next :meth:`update` primes the buffer with its angle."""
        self.primed = False

    def update(self, angle) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Push one sample; return (angle_f, vel, acc) as views of preallocated arrays."""
        if not self.primed:
            self.reset(angle)
        a = np.ascontiguousarray(angle, dtype=float).reshape(self.n)
        self.head = fir_push(self.buf, self.head, self.C, a, self.out)
        return self.out[0], self.out[1], self.out[2]


@njit
def fir_push(buf, head, C, angle, out) -> int:
    """Push ``angle`` into the doubled ring buffer and apply the FIR rows ``C`` to the L newest
    samples (oldest … newest): out = C · buf[h+1 : h+1+L].  Returns the new head."""
    L = C.shape[1]
    n = angle.shape[0]
    h = head + 1
    if h >= L:
        h = 0
    for j in range(n):
        buf[h, j] = angle[j]
        buf[h + L, j] = angle[j]
    for r in range(3):
        for j in range(n):
            s = 0.0
            for i in range(L):
                s += C[r, i] * buf[h + 1 + i, j]
            out[r, j] = s
    return h


@warmer
def _warm() -> None:
    CausalDifferentiator(0.01, 5, 2).update(np.zeros(2))



def smooth_derivatives(t, angle, window: int = 11, degree: int = 3):
    """Offline zero-phase smoothing and differentiation of a whole log.

    ``t`` (N,) sample times (assumed uniform; the median step is used), ``angle`` (N,) or
    (N, n).  Returns ``(angle, vel, acc)`` arrays of the same shape as ``angle``, from a
    centred Savitzky–Golay filter (scipy.signal.savgol_filter, ``mode='interp'`` at the
    ends): no phase lag, for residuals and training data, not for online use.
    ``window`` is clipped to the log length (odd, > degree).
    """
    from scipy.signal import savgol_filter   # lazy: scipy.signal is slow to import

    t = np.asarray(t, dtype=float)
    x = np.asarray(angle, dtype=float)
    N = x.shape[0]
    if N < 3:
        raise ValueError(f"smooth_derivatives needs at least 3 samples, got {N}")
    dt = float(np.median(np.diff(t)))
    w = min(int(window), N if N % 2 else N - 1)
    if w % 2 == 0:
        w -= 1
    deg = min(int(degree), w - 1)
    if deg < 2:   # tiny logs: plain central differences
        v = np.gradient(x, dt, axis=0)
        return x.copy(), v, np.gradient(v, dt, axis=0)
    kw = dict(window_length=w, polyorder=deg, delta=dt, axis=0, mode="interp")
    return (savgol_filter(x, deriv=0, **kw), savgol_filter(x, deriv=1, **kw),
            savgol_filter(x, deriv=2, **kw))
