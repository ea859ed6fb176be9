"""TEST-ONLY stand-in with the API of ``sea_daemon.sim.plant.Plant`` (until the simulator lands).

A linear SEA (eq:sea without effects) integrated with semi-implicit Euler substeps.  It lives in
tests/ on purpose: the product uses the simulator's Plant.
"""
from __future__ import annotations

import numpy as np


class StandInPlant:
    def __init__(self, n=1, q0=0.0, theta_m0=None, M=0.12, J=0.08, D_m=0.6, K_s=110.0, D_s=0.25, gravity=0.0):
        self.n = n
        self.t = 0.0
        self.q = np.full(n, float(q0))
        self.theta_m = self.q.copy() if theta_m0 is None else np.full(n, float(theta_m0))
        self.dq = np.zeros(n)
        self.dtheta_m = np.zeros(n)
        self.M, self.J, self.D_m, self.K_s, self.D_s, self.g = M, J, D_m, K_s, D_s, gravity
        self.steps = []          # (t, tau_m, tau_h_act, q, theta_m) at the start of every step

    def step(self, tau_m, dt, tau_h_act):
        tau_m = np.asarray(tau_m, float)
        self.steps.append((self.t, tau_m.copy(), np.asarray(tau_h_act, float).copy(), self.q.copy(),
                           self.theta_m.copy()))
        h = dt / 10
        for _ in range(10):
            tau_s = self.K_s * (self.theta_m - self.q) + self.D_s * (self.dtheta_m - self.dq)
            ddq = (tau_s - self.g * np.sin(self.q) + tau_h_act) / self.M
            ddth = (tau_m - tau_s - self.D_m * self.dtheta_m) / self.J
            self.dq = self.dq + h * ddq
            self.dtheta_m = self.dtheta_m + h * ddth
            self.q = self.q + h * self.dq
            self.theta_m = self.theta_m + h * self.dtheta_m
        self.t += dt
