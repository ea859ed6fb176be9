"""Small synthetic SEA logs for the estimator tests (independent of the simulator).

RK4 integration of the true plant ``SEAModel(true_params)`` with ``tau_h_act`` as a known
signal, encoders quantised to ``bits`` per turn, motor torque held over each sample.
"""
from __future__ import annotations

import numpy as np

from sea_daemon.core.log import MeasuredLog
from sea_daemon.core.model import SEAModel


def simulate(model: SEAModel, T: float = 3.0, rate: float = 100.0, tau_m=None, tau_h=None,
             substeps: int = 4, bits: int | None = 19, seed: int = 0, x0=None) -> MeasuredLog:
    """Simulate; ``tau_m(t)``/``tau_h(t)`` callables returning (n,) arrays (default: sines / 0).

    Deterministic: no noise is added, so ``seed`` does not change the log (kept for the callers).
    """
    n = model.n
    N = int(round(T * rate)) + 1
    dt = 1.0 / rate
    h = dt / substeps
    if tau_m is None:
        tau_m = lambda t: np.full(n, 1.5 * np.sin(2 * np.pi * 0.5 * t) + 0.5 * np.sin(2 * np.pi * 1.3 * t))
    if tau_h is None:
        tau_h = lambda t: np.zeros(n)
    x = np.zeros(5 * n) if x0 is None else np.array(x0, dtype=float)
    t = np.arange(N) * dt
    q = np.zeros((N, n)); th = np.zeros((N, n)); um = np.zeros((N, n)); uh = np.zeros((N, n))
    # the delay effect: applied torque tau_m(t - delay), tau_m a zero-order-hold sequence
    delay = model.delay
    for k in range(N):
        q[k] = x[:n] + x[n:2 * n]
        th[k] = x[:n]
        um[k] = tau_m(t[k])
        uh[k] = tau_h(t[k])
        for s in range(substeps):
            ts = t[k] + s * h

            def u_at(tt):
                out = np.empty(n)
                for j in range(n):
                    kk = int(np.floor((tt - delay[j]) / dt + 1e-9))
                    out[j] = um[max(min(kk, k), 0), j]
                return out

            def f(xx, tt):
                xx = xx.copy()
                xx[4 * n:] = tau_h(tt)
                return model.f_nom(xx, u_at(tt))

            k1 = f(x, ts); k2 = f(x + h / 2 * k1, ts + h / 2)
            k3 = f(x + h / 2 * k2, ts + h / 2); k4 = f(x + h * k3, ts + h)
            x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    qm = q + model.offset_load
    thm = th + model.offset_motor
    if bits:
        res = 2 * np.pi / 2**bits
        qm = np.round(qm / res) * res
        thm = np.round(thm / res) * res
    return MeasuredLog(t=t, q=qm, theta_m=thm, tau_m=um, tau_h_act=uh)
