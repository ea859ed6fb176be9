"""Simulated logs for the diagnose tests: the passive scenario (Sec. V-B) with undeclared effects.

The *declared* model is the passive scenario's true plant (nominal model + every hidden effect
of configs/scenarios/passive.yaml), so the only thing the configuration lacks is what a test
adds.  Motion, noise and quantisation are the scenario's (min-jerk 10°→75° moves tracked by
the PID, 19-bit encoders, motor-torque noise); only the number of moves is shortened.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from _paths import repo_root
from sea_daemon.core.effects import Gravity
from sea_daemon.runtime import sim_runner as runner
from sea_daemon.core.sim.plant import Plant
from sea_daemon.io.scenario import load_scenario


def passive_log(extra=(), moves: int = 2, seed: int = 1, gravity_compensated: bool = False,
                plant_cls=None, pid: dict | None = None):
    """(estimation log, declared config) of a shortened passive run with ``extra`` undeclared.

    ``gravity_compensated``: the link and arm weights are balanced (gravity 0 in plant and
    model), so the spring deflection changes sign with the human's stiffness about q_h0.
    ``plant_cls``: a Plant subclass for effects outside the vocabulary.
    ``pid``: other PID gains (kp, ki, kd) for the same moves.
    """
    sc = load_scenario(repo_root() / "configs" / "scenarios" / "passive.yaml")
    tr = dataclasses.replace(sc.controller.trajectory, moves=moves)
    ctrl = dataclasses.replace(sc.controller, trajectory=tr, **(pid or {}))
    effects = tuple(sc.plant.effects)
    nominal = sc.nominal
    if gravity_compensated:
        effects = tuple(e for e in effects if not isinstance(e, Gravity))
        g0 = np.zeros_like(nominal.model.gravity)
        g0.setflags(write=False)
        nominal = dataclasses.replace(nominal, model=dataclasses.replace(nominal.model, gravity=g0))
    n = int(round(moves * tr.move_s * nominal.rate_hz))
    declared = dataclasses.replace(sc, nominal=nominal, plant=dataclasses.replace(sc.plant, effects=effects))
    run = dataclasses.replace(declared, controller=ctrl, training_samples=2, estimation_samples=n,
                              plant=dataclasses.replace(sc.plant, effects=effects + tuple(extra)))
    if plant_cls is None:
        log = runner.simulate(run, seed).estimation
    else:
        orig = runner.make_plant

        def make(s, seed=None):
            return plant_cls(s.true_config(), q0=s.controller.q0, seed=s.seed if seed is None else seed,
                             substep_hz=s.plant.substep_hz, sign_eps=s.plant.sign_eps,
                             torque_noise=s.plant.torque_noise)
        runner.make_plant = make
        try:
            log = runner.simulate(run, seed).estimation
        finally:
            runner.make_plant = orig
    return log, declared.true_config()


class PositionFrictionPlant(Plant):
    """Outside the vocabulary: load friction that exists only over a band of positions,
    F(q) = F0 · exp(−((q − q_c)/w)²) · sign(q̇) (a cuff or cable rubbing at mid-range)."""

    F0, q_c, w = 0.6, math.radians(42.0), math.radians(8.0)

    def __init__(self, *args, **kwargs):
        super().__init__(*args, extra_load_torque=self._band, **kwargs)

    def _band(self, q, dq):
        return self.F0 * np.exp(-((q - self.q_c) / self.w) ** 2) * np.tanh(dq / self.sign_eps)
