"""n uncoupled joints as n one-joint plants: the device model's plant for ``--joints N``.

A plant of n joints without coupling between them (constant inertia, each joint's effects its
own) is n one-joint plants side by side.  Each one-joint :class:`sea_daemon.core.sim.plant.Plant`
steps on its compiled scalar path (tens of µs), where one n-joint plant steps through numpy (a
few hundred µs per step for two joints): fast enough for the device model at 1 kHz.
"""
from __future__ import annotations

import numpy as np


class SplitPlant:
    """The n-joint plant API the device model uses (``t, q, theta_m, dq, dtheta_m, hold_torque,
    step(tau_m, dt, tau_h_act)``) over ``plants``, one-joint plants stepped in lock-step."""

    def __init__(self, plants):
        self.plants = list(plants)
        self.n = len(self.plants)
        self.hold_torque = np.array([float(np.asarray(p.hold_torque).reshape(-1)[0]) for p in self.plants])
        self._tau = [np.zeros(1) for _ in self.plants]
        self._tau_h = [np.zeros(1) for _ in self.plants]

    @property
    def t(self) -> float:
        return self.plants[0].t

    def _joined(self, name: str) -> np.ndarray:
        return np.array([float(np.asarray(getattr(p, name)).reshape(-1)[0]) for p in self.plants])

    @property
    def q(self) -> np.ndarray:
        return self._joined("q")

    @property
    def theta_m(self) -> np.ndarray:
        return self._joined("theta_m")

    @property
    def dq(self) -> np.ndarray:
        return self._joined("dq")

    @property
    def dtheta_m(self) -> np.ndarray:
        return self._joined("dtheta_m")

    def step(self, tau_m, dt: float, tau_h_act=0.0) -> None:
        tau_h = np.broadcast_to(np.asarray(tau_h_act, dtype=float), (self.n,))
        for j, p in enumerate(self.plants):
            self._tau[j][0] = tau_m[j]
            self._tau_h[j][0] = tau_h[j]
            p.step(self._tau[j], dt, self._tau_h[j])
