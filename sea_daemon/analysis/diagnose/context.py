"""What the candidate effects are fitted to: the log's kinematics, the model, its residual.

:class:`Context` holds them for :mod:`.candidates` and the selection (:mod:`.select`): the
residual of the configured model with effects added (:func:`.residuals.residuals_for`), what
one additive effect removes from it without recomputing the model, the fast command gain and
the torques the log puts on each side.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from sea_daemon.core.config import ModelConfig
from sea_daemon.core.effects import Coulomb, Effect, Inertia, Stribeck
from sea_daemon.core.model import SEAModel
from sea_daemon.analysis.diagnose.residuals import (FastGain, Kinematics, fast_command_gain, inertia_and_bias,
                                                    residuals_for, stick_velocity)


@dataclass
class Context:
    """What the candidates need: the log's kinematics, the configured model, its residual."""

    cfg: ModelConfig
    kin: Kinematics
    r0: np.ndarray                      # (N, 2n) residual of cfg
    passive: bool = False
    zoh: bool = True
    #: speed [rad/s] below which a side counts as sticking, per side (load, motor); None: 3 ε
    v_stick: tuple[float, float] | None = None
    _model: SEAModel | None = field(default=None, repr=False)
    _fast: FastGain | None = field(default=None, repr=False)

    @property
    def fast_gain(self) -> FastGain:
        """The drive's gain from the fast part of the command (:func:`.residuals.fast_command_gain`),
        over the samples where the motor moves faster than its stick speed."""
        if self._fast is None:
            v = self.v_stick[1] if self.v_stick is not None else stick_velocity(self.cfg)
            self._fast = fast_command_gain(self.model, self.kin, v, self.zoh)
        return self._fast

    def largest_torque(self, side: str, j: int) -> float:
        """The largest torque [N m] the log's balance puts on ``side`` of joint ``j``: the sum of
        the largest spring torque, inertial torque (smoothed acceleration), gravity, commanded
        torque (motor) and human torque (load, when the log has it).  A friction that held more
        than this at rest would never have let that side move as the log shows."""
        kin, m = self.kin, self.model
        q, th = self.angles()
        tau_s = float(np.max(np.abs((q - th) @ m.K_s.T)[:, j]))
        if side == "load":
            if m.rigid is None:
                out = tau_s + float(np.max(np.abs(kin.ddq @ m.M.T)[:, j])) + float(np.max(np.abs(m.C(q))[:, j]))
            else:
                out = tau_s + float(np.max(np.abs(inertia_and_bias(m, q, kin.dq, kin.ddq))[:, j]))
            if kin.tau_h_act is not None and not self.passive:
                out += float(np.max(np.abs(kin.tau_h_act[:, j])))
            return out
        return (tau_s + float(np.max(np.abs(kin.ddtheta_m @ m.J.T)[:, j]))
                + float(m.kappa[j]) * float(np.max(np.abs(kin.tau_m[:, j]))))

    def stick_speed(self, side: str) -> float:
        """The speed [rad/s] below which ``side`` counts as sticking (3 ε without encoder data)."""
        if self.v_stick is None:
            return stick_velocity(self.cfg)
        return float(self.v_stick[0 if side == "load" else 1])

    @property
    def model(self) -> SEAModel:
        if self._model is None:
            self._model = SEAModel.from_config(self.cfg)
        return self._model

    @property
    def n(self) -> int:
        return self.kin.n

    def residual(self, effects=()) -> np.ndarray:
        kw = {} if self.v_stick is None else {"v_stick": self.v_stick}
        return residuals_for(self.cfg, self.kin, effects, zoh=self.zoh, passive=self.passive, **kw)

    def delta_r(self, effects) -> np.ndarray:
        """Δr = r(cfg) − r(cfg + effects), flattened (N·2n,)."""
        if len(effects) == 1:
            d = self._additive_delta(effects[0])
            if d is not None:
                return d.reshape(-1)
        return (self.r0 - self.residual(effects)).reshape(-1)

    def _additive_delta(self, e: Effect) -> np.ndarray | None:
        """Δr of one additive effect without recomputing the model (None for structural ones).

        The balances of :func:`.residuals.residual_channels` are linear in an added torque:
        a load-side e adds S(e) to r_load's explained part, a motor-side one S(e) to r_motor's,
        a spring one S(e) and −S(e); an inertia dI·(second difference) likewise.
        ``tests/test_diagnose_residuals.py`` checks this against the full recomputation.  (The
        one difference: while a side sticks inside its declared static-friction band the full
        residual takes up the added torque there; the fit leaves those samples out.)
        """
        if not e.additive or isinstance(e, (Coulomb, Stribeck)):
            return None      # structural, or friction (set-valued while sticking): recompute
        kin = self.kin
        n = self.n
        j = e.joint
        q, th = self.angles()
        if isinstance(e, Inertia):
            col = e.dI * (kin.d2q if e.side == "load" else kin.d2theta_m)[:, j]
        else:
            if hasattr(e, "eps"):  # declared friction uses the estimator's sign smoothing (SEAModel)
                e = dataclasses.replace(e, eps=self.cfg.estimator.sign_eps)
            if e.side == "load":
                a, v = q[:, j], kin.dq[:, j]
            elif e.side == "motor":
                a, v = th[:, j], kin.dtheta_m[:, j]
            else:
                a, v = q[:, j] - th[:, j], np.zeros(kin.N)
            col = e.torque_array(a, v, np.zeros(kin.N))
        out = np.zeros((kin.N, 2 * n))
        if e.side in ("load", "spring"):
            out[:, j] = col
        if e.side == "motor":
            out[:, n + j] = col
        if e.side == "spring":
            out[:, n + j] = -col
        return kin.smooth(out)

    # signals with the declared offsets removed
    def angles(self):
        return self.model.correct_measurement(self.kin.q, self.kin.theta_m)
