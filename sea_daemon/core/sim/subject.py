"""A simulated subject that performs a task with muscle torque: the closed-loop human of the assistance benchmark.

The true plant (:mod:`.plant`) already holds the subject's *passive* arm — forearm inertia and
gravity, elbow tissue stiffness and damping (``human_viscoelastic``) — so what this module adds
is the *active* torque τ_h,act that the subject's muscles produce to do a task: track a target
elbow angle q*(t) that moves between two angles by minimum-jerk moves, with holds in between.

Neuromuscular model (one joint each, joint side, SI units):

    e      = q*(t) − q(t − d),   ė = q̇*(t) − q̇(t − d)              sensed with the delay d
    u_ff  ← u_ff + k_i e Δt                                          motor adaptation (|u_ff| ≤ τ_max)
    u      = u_ff + k_p e + k_d ė                                    descending command
    τ_h,act ← τ_h,act + (u − τ_h,act)(1 − exp(−Δt / T_a))            activation, |τ_h,act| ≤ τ_max

``u_ff`` is the feed-forward the subject learns while doing the task: it takes over the
torque the task needs at steady state (gravity and tissue at the held angle), so an
assistance that provides part of that torque is met by a subject that produces less of it —
the behaviour an assist-as-needed controller relies on.  ``k_p``, ``k_d`` are the reflex and
voluntary feedback, ``d`` the sensory delay, ``T_a`` the muscle's activation time constant.

The subject is called once per plant step with the plant time t at the start of the step
(:class:`sea_daemon.hw.device_model.DeviceModel` and :class:`sea_daemon.hw.sim_hw.SimHardware` do), reads
the plant's true state at t, and returns τ_h,act held over the step.  A second call with the same
t returns the same torque without stepping (a recorder may ask what the subject applies).
Pure numerics: no clock, no I/O.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sea_daemon.core.control import min_jerk


@dataclass(frozen=True)
class TrackingTask:
    """The task and the subject's neuromuscular parameters (scenario key ``task``).

    Target: hold ``q_deg[0]`` for ``hold_s``, move to ``q_deg[1]`` in ``move_s`` (minimum
    jerk), hold, move back, … for as long as the run goes.
    """

    q_deg: tuple[float, float] = (20.0, 70.0)    # the two target angles [deg]
    move_s: float = 2.0                          # [s] duration of one move
    hold_s: float = 2.0                          # [s] hold at each end
    kp: float = 15.0                             # [N m/rad] position feedback
    kd: float = 1.0                              # [N m s/rad] velocity feedback
    ki: float = 20.0                             # [N m/(rad s)] motor adaptation of the feed-forward
    activation_s: float = 0.04                   # [s] muscle activation time constant T_a
    delay_s: float = 0.03                        # [s] sensory delay d
    max_torque: float = 15.0                     # [N m] the subject's strength

    @property
    def period_s(self) -> float:
        """One back-and-forth cycle of the target [s]."""
        return 2.0 * (self.hold_s + self.move_s)

    def target(self, t: float) -> tuple[float, float]:
        """(q*, q̇*) [rad, rad/s] at task time t [s] (t < 0: the first hold)."""
        a, b = math.radians(self.q_deg[0]), math.radians(self.q_deg[1])
        if t <= 0.0:
            return a, 0.0
        s = t % self.period_s
        half = self.hold_s + self.move_s
        if s >= half:                     # second half: from b back to a
            a, b = b, a
            s -= half
        if s < self.hold_s:
            return a, 0.0
        sigma, dsigma, _ = min_jerk((s - self.hold_s) / self.move_s)
        return a + (b - a) * sigma, (b - a) * dsigma / self.move_s


class TrackingSubject:
    """τ_h,act(t) of a subject doing :class:`TrackingTask` on ``plant`` (see the module docstring).

    ``dt``: the plant step the caller uses [s] (the delay is ``round(delay_s / dt)`` steps).
    ``tau0``: the active torque the subject holds the arm with at t = 0 (the feed-forward's start,
    so the task starts at rest).  ``t0``: plant time of task time 0.  After each call
    :attr:`tau`, :attr:`q_target` and :attr:`error` hold what the step was computed with.
    """

    def __init__(self, task: TrackingTask, plant, dt: float, tau0=0.0, t0: float = 0.0):
        if not dt > 0:
            raise ValueError(f"subject step dt must be > 0 s, got {dt!r}")
        self.task, self.plant, self.dt, self.t0 = task, plant, float(dt), float(t0)
        self.n = n = int(np.atleast_1d(plant.q).shape[0])
        self.delay_steps = int(round(task.delay_s / self.dt))
        size = self.delay_steps + 1
        self._q = np.zeros((size, n))
        self._dq = np.zeros((size, n))
        self._i = 0
        self._filled = 0
        self._beta = 1.0 - math.exp(-self.dt / task.activation_s) if task.activation_s > 0 else 1.0
        self.tau = np.clip(np.broadcast_to(np.asarray(tau0, dtype=float), (n,)).copy(),
                           -task.max_torque, task.max_torque)
        self.u_ff = self.tau.copy()
        self.q_target = np.zeros(n)
        self.error = np.zeros(n)
        self._t_last: float | None = None
        self._u = np.zeros(n)

    def __call__(self, t: float) -> np.ndarray:
        if self._t_last is not None and t <= self._t_last + 1e-12:
            return self.tau                       # the same step asked again: no second update
        first = self._t_last is None
        self._t_last = t
        task = self.task
        q, dq = np.atleast_1d(self.plant.q), np.atleast_1d(self.plant.dq)
        # the sensed state, d steps old (the oldest sample until the history is full)
        self._q[self._i] = q
        self._dq[self._i] = dq
        self._filled = min(self._filled + 1, self._q.shape[0])
        j = (self._i - min(self.delay_steps, self._filled - 1)) % self._q.shape[0]
        self._i = (self._i + 1) % self._q.shape[0]
        qt, dqt = task.target(t - self.t0)
        self.q_target[:] = qt
        e = self.error
        e[:] = qt - self._q[j]
        de = dqt - self._dq[j]
        if not first:
            self.u_ff += task.ki * e * self.dt
            np.clip(self.u_ff, -task.max_torque, task.max_torque, out=self.u_ff)
        u = self._u
        u[:] = self.u_ff + task.kp * e + task.kd * de
        if not first:
            self.tau += self._beta * (u - self.tau)
        np.clip(self.tau, -task.max_torque, task.max_torque, out=self.tau)
        return self.tau
