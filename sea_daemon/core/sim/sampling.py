"""One sample of a simulated run: the true plant stepped and read like the hardware, and the row it records.

Every simulated run — the offline simulator's scenarios (the daemon's loop over
:class:`sea_daemon.hw.sim_hw.SimHardware`) and the sessions built from parts
(:func:`sea_daemon.core.sim.session.run_session`) — goes sample by sample through the same
steps, at t_k = k·dt:

1. :meth:`SampledPlant.read`: the plant stepped over [t_k−1, t_k] with the motor torque and the
   subject's torque τ_h,act of sample k−1 held (zero-order hold), then the encoders at t_k
   (quantised, with their offsets);
2. the controller's command τ_m from the measured angles (a
   :class:`~sea_daemon.core.control.ReferenceTracker`, a :class:`~sea_daemon.core.control.StillArm`,
   or the scenario's controller, which runs them);
3. the subject's torque over [t_k, t_k+1] (a function of time, or −τ_des of the still arm);
4. :class:`SampleRecorder`: row k (t_k, the measured angles, τ_m, the reference and the true
   state at t_k); what acted over [t_k, t_k+1] — τ_h,act and the applied motor torque (limit
   and noise) — comes into row k with the read of sample k+1, so a run of N rows reads N+1 samples.

Pure numerics: no clock, no I/O.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from sea_daemon.core.log import MeasuredLog

#: the columns of a measured log (docs/interfaces.md §1); every other column is an extra (joint 0,
#: and with n > 1 joints each joint's, suffixed: :meth:`SampleRecorder.log`)
BASE = ("t", "q", "theta_m", "tau_m", "tau_h_act")

#: the extras a :class:`SampleRecorder` fills at sample k: name → value from the sampled plant and the controller
TRUTH = {
    "q_ref": lambda sp, ctl: ctl.q_ref,
    "tau_des": lambda sp, ctl: ctl.tau_des,
    "q_true": lambda sp, ctl: sp.plant.q,
    "theta_m_true": lambda sp, ctl: sp.plant.theta_m,
    "dq_true": lambda sp, ctl: sp.plant.dq,
    "dtheta_m_true": lambda sp, ctl: sp.plant.dtheta_m,
    "tau_s_true": lambda sp, ctl: sp.plant.tau_s,
}


class SampledPlant:
    """The true plant sampled every ``period`` [s] like the hardware samples it (module docstring, step 1).

    After :meth:`read` of sample k: :attr:`k`, :attr:`t` = k·period, and the torques that acted
    over [t_k−1, t_k]: :attr:`tau_m` (commanded) and :attr:`tau_h_act`, each (n,) [N m].
    """

    def __init__(self, plant, period: float):
        self.plant = plant
        self.n = int(np.atleast_1d(plant.q).shape[0])
        self.period = float(period)
        self.k = -1
        self.tau_m = np.zeros(self.n)
        self.tau_h_act = np.zeros(self.n)

    @property
    def t(self) -> float:
        """The sample time t_k = k·period [s] (a whole number of periods since sample 0)."""
        return self.k * self.period

    def read(self, tau_m=None, tau_h_act=0.0) -> tuple[np.ndarray, np.ndarray]:
        """Sample k: the plant stepped over [t_k−1, t_k] with ``tau_m`` and ``tau_h_act`` held
        (not for sample 0), then the encoders' (q, θ_m) at t_k."""
        if self.k >= 0:
            self.tau_m[:] = tau_m
            self.tau_h_act[:] = tau_h_act
            self.plant.step(self.tau_m.copy(), self.period, tau_h_act)
        self.k += 1
        measure = getattr(self.plant, "measure", None)
        if measure is not None:
            return measure()
        return self.plant.q, self.plant.theta_m


class SampleRecorder:
    """The rows of a sampled run: ``cols[name]`` (rows, n) for the :data:`BASE` columns and
    ``extra``, in that order (module docstring, step 4).

    :meth:`sample` fills row k from the measurement, the command, the controller and the plant
    (the extras named in :data:`TRUTH`); :meth:`acted` fills row k−1 from the read of sample k:
    τ_h,act and ``tau_m_applied`` (when an extra), the applied torque.  A lock-step run whose
    rows it does not fill itself (the hardware-in-the-loop session) writes into :attr:`cols`.
    """

    def __init__(self, rows: int, n: int, extra: Sequence[str] = ()):
        self.rows = rows
        self.cols = {k: np.zeros((rows, n)) for k in (*BASE, *extra)}
        self._truth = tuple((k, TRUTH[k]) for k in extra if k in TRUTH)

    def acted(self, sp: SampledPlant) -> None:
        """Row k−1 after the read of sample k: what acted over [t_k−1, t_k]."""
        k = sp.k
        if k < 1:
            return
        c = self.cols
        c["tau_h_act"][k - 1] = sp.tau_h_act
        if "tau_m_applied" in c:
            c["tau_m_applied"][k - 1] = sp.plant.applied_torque

    def sample(self, k: int, t: float, q, theta_m, tau_m, sp: SampledPlant, ctl) -> None:
        """Row k: the sample time, the measured angles, the command, and the :data:`TRUTH` extras."""
        c = self.cols
        c["t"][k] = t
        c["q"][k] = q
        c["theta_m"][k] = theta_m
        c["tau_m"][k] = tau_m
        for name, value in self._truth:
            c[name][k] = value(sp, ctl)

    def log(self, rows: slice) -> MeasuredLog:
        """The measured log of ``rows`` (copies): t, the measured columns per joint, each extra
        of joint 0 under its name and, with n > 1 joints, of every joint with the 1-based suffix
        of docs/interfaces.md §1 (``q_true`` is ``q_true_1``; ``q_true_1 … q_true_n``)."""
        c = self.cols
        extra = {}
        for k, v in c.items():
            if k in BASE:
                continue
            extra[k] = v[rows, 0].copy()
            if v.shape[1] > 1:
                for j in range(v.shape[1]):
                    extra[f"{k}_{j + 1}"] = v[rows, j].copy()
        return MeasuredLog(t=c["t"][rows, 0].copy(), q=c["q"][rows].copy(), theta_m=c["theta_m"][rows].copy(),
                           tau_m=c["tau_m"][rows].copy(), tau_h_act=c["tau_h_act"][rows].copy(), extra=extra)

    def phases(self, training: int) -> tuple[MeasuredLog, MeasuredLog]:
        """(training log, estimation log): the first ``training`` rows, then the rest."""
        return self.log(slice(0, training)), self.log(slice(training, self.rows))
