"""Controllers of the experiments (paper Sec. V-B, V-C), pure and reusable.

Used by the simulator (:mod:`sea_daemon.core.sim`) and by the daemon's ``calibrate`` command on
the real bus, so nothing here knows about plants, files or clocks: the caller passes the
measured (quantised) angles and the time, and gets the motor torque command back.

* :class:`MinJerkTrajectory` — sequences of minimum-jerk (sigmoid) moves between two
  angles, forwards and backwards (Sec. V-B: 10° → 75° in 3.5 s, 6 moves, N = 2100 at 100 Hz).
* :class:`PID` — PID position controller on the load angle q producing the motor torque,
  with a torque limit and anti-windup.
* :class:`OpenLoopTorque` — Sec. V-C: τ_m = τ_des(t) + τ_comp with the desired-torque
  profile τ_des = −A cos(2π f t) + offset and a compensation torque τ_comp calibrated once.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sea_daemon.core.jit import njit, warmer

_F8 = np.dtype(float)


@njit
def min_jerk(s: float) -> tuple[float, float, float]:
    """Minimum-jerk blend σ(s) = 10s³ − 15s⁴ + 6s⁵ on s ∈ [0, 1], with σ' and σ'' (Flash & Hogan 1985)."""
    s = min(max(s, 0.0), 1.0)
    return (s**3.0 * (10.0 - 15.0 * s + 6.0 * s * s),
            30.0 * s * s * (1.0 - s) ** 2.0,
            60.0 * s * (1.0 - s) * (1.0 - 2.0 * s))


@njit
def min_jerk_reference(t: float, q_start: float, q_end: float, move_s: float, hold_s: float, moves: int,
                       cyclic: bool) -> tuple[float, float, float]:
    """:meth:`MinJerkTrajectory.reference` of the trajectory with these fields: (q_ref, q̇_ref, q̈_ref) at t [s]."""
    if t <= 0.0:
        return q_start, 0.0, 0.0
    step = hold_s + move_s
    i = int(t // step)
    if not cyclic:
        i = min(i, moves - 1)
    tau = min(max(t - i * step - hold_s, 0.0) / move_s, 1.0)
    if i % 2 == 0:
        a, b = q_start, q_end
    else:
        a, b = q_end, q_start
    s, ds, dds = min_jerk(tau)
    d = b - a
    return a + d * s, d * ds / move_s, d * dds / move_s**2.0


@dataclass(frozen=True)
class MinJerkTrajectory:
    """``moves`` minimum-jerk moves alternating q_start → q_end → q_start …, each ``move_s`` long.

    Angles in rad.  Each move is preceded by a hold of ``hold_s`` at its start (default 0: the
    moves follow each other directly).  Before t = 0 the reference is q_start; after the last
    move it holds the last target, unless ``cyclic``: then the moves go on back and forth
    forever (so a run of any length continues seamlessly).
    """

    q_start: float
    q_end: float
    move_s: float
    moves: int
    cyclic: bool = False
    hold_s: float = 0.0

    @property
    def duration(self) -> float:
        return (self.hold_s + self.move_s) * self.moves

    def reference(self, t: float) -> tuple[float, float, float]:
        """(q_ref, q̇_ref, q̈_ref) at time t [s]."""
        return min_jerk_reference(float(t), float(self.q_start), float(self.q_end), float(self.move_s),
                                  float(self.hold_s), int(self.moves), bool(self.cyclic))

    @property
    def fields(self) -> np.ndarray:
        """The fields :meth:`PID.track_into` takes: q_start, q_end, move_s, hold_s, moves, cyclic."""
        return np.array([self.q_start, self.q_end, self.move_s, self.hold_s, self.moves, 1.0 if self.cyclic else 0.0])


@dataclass(frozen=True)
class PIDGains:
    """The gains of :class:`PID`: kp [N m/rad], ki [N m/(rad s)], kd [N m s/rad], the velocity
    low-pass [Hz] and the angle the derivative acts on (``motor`` or ``load``).  The scenario
    file's controller (:class:`sea_daemon.io.scenario.PIDSpec`) is these gains and a trajectory."""

    kp: float
    ki: float
    kd: float
    velocity_filter_hz: float = 20.0
    derivative: str = "motor"


class PID:
    """PID position controller: τ_m = K_p e + K_i ∫e + K_d (q̇_ref − v), e = q_ref − q.

    * Runs on measured angles.  v is the velocity of the load (``derivative="load"``: v = q̇)
      or of the motor (``derivative="motor"``: v = θ̇_m, collocated damping — PD on the link
      with motor-velocity damping is the classical stable choice for elastic joints, Tomei
      1991; a D term on q̇ through the spring excites the spring mode at usable gains).
      v is the backward difference of the measured angle through a first-order low-pass of
      cut-off ``velocity_filter_hz`` (quantisation noise).
    * Output clipped to ±``torque_limit`` (one, or each joint's); anti-windup by conditional
      integration (the integral freezes while the output saturates in the error's direction)
      and a clamp |K_i ∫e| ≤ torque_limit.
    * ``reset(q, u0)`` starts bumplessly: the integrator is preset so that the first output
      equals u0 (e.g. the torque already holding the arm).

    Vectorised over joints: gains may be scalars or arrays of n.
    """

    def __init__(self, kp, ki, kd, dt: float, torque_limit, velocity_filter_hz: float = 20.0,
                 derivative: str = "motor"):
        self.kp = np.asarray(kp, dtype=float)
        self.ki = np.asarray(ki, dtype=float)
        self.kd = np.asarray(kd, dtype=float)
        self.dt = float(dt)
        self.limit = np.asarray(torque_limit, dtype=float)
        self._limits = np.array(np.atleast_1d(self.limit))          # per joint, the compiled step's
        if derivative not in ("load", "motor"):
            raise ValueError(f"derivative must be 'load' or 'motor', got {derivative!r}")
        self.derivative = derivative
        # first-order low-pass, discretised exactly: α = 1 − exp(−2π f_c dt)
        self.alpha = 1.0 - math.exp(-2.0 * math.pi * velocity_filter_hz * self.dt)
        self.integral = np.zeros(1)
        self._q_prev = None
        self._dq = np.zeros(1)
        self._gains = None               # (3, n) kp, ki, kd of the compiled step
        self._u_fast = None              # the command array once the state arrays exist (step_into)
        self._ref = np.zeros((2, 1))     # the last step's q_ref, q̇_ref (2, n)

    def reset(self, q: np.ndarray, u0=0.0) -> None:
        """Start at rest with output u0 (bumpless); q is the measured angle the D term differentiates."""
        q = np.atleast_1d(np.asarray(q, dtype=float))
        self._q_prev = q.copy()
        self._dq = np.zeros_like(q)
        ki = np.broadcast_to(self.ki, q.shape)
        u0 = np.broadcast_to(np.asarray(u0, dtype=float), q.shape)
        self.integral = np.where(ki > 0, u0 / np.where(ki > 0, ki, 1.0), 0.0)
        self._gains = None
        self._u_fast = None

    def step(self, q_ref, q_meas, dq_ref=0.0, theta_m_meas=None) -> np.ndarray:
        """One control period: the motor-torque command [N m] for the measured q (and θ_m)."""
        return self.step_into(q_ref, q_meas, dq_ref, theta_m_meas).copy()

    def _fast_v(self, q_meas, theta_m_meas):
        """The angle the D term differentiates when the compiled step can take the arrays as they
        are (the state arrays exist; float64 arrays of n, as the loop's measurement is), else None."""
        u = self._u_fast
        if u is not None and type(q_meas) is np.ndarray and q_meas.shape == u.shape and q_meas.dtype == _F8:
            v = q_meas if self.derivative == "load" else theta_m_meas
            if type(v) is np.ndarray and v.shape == u.shape and v.dtype == _F8:
                return v
        return None

    def step_into(self, q_ref, q_meas, dq_ref=0.0, theta_m_meas=None) -> np.ndarray:
        """:meth:`step` without the copy: the command in the PID's own array (overwritten by the
        next step; the loop's per-cycle call, no allocation once the state arrays exist)."""
        v = self._fast_v(q_meas, theta_m_meas)
        if v is not None:
            u = self._u_fast
            ref = self._ref
            ref[0] = q_ref
            ref[1] = dq_ref
            _pid_step(ref, q_meas, v, self._gains, self.alpha, self.dt, self._limits, self._dq, self._q_prev,
                      self.integral, u)
            return u
        q = np.atleast_1d(np.asarray(q_meas, dtype=float))
        if self.derivative == "motor" and theta_m_meas is None:
            raise ValueError("PID(derivative='motor') needs theta_m_meas")
        v = q if self.derivative == "load" else np.atleast_1d(np.asarray(theta_m_meas, dtype=float))
        if self._q_prev is None:
            self.reset(v)
        n = q.shape[0]
        if self._gains is None or self._gains.shape[1] != n:
            # gains per joint, the state arrays of n (the compiled step updates them in place)
            self._gains = np.ascontiguousarray(np.vstack([np.broadcast_to(g, (n,)) for g in (self.kp, self.ki,
                                                                                              self.kd)]))
            self._dq = np.array(np.broadcast_to(self._dq, (n,)), dtype=float)
            self._q_prev = np.array(np.broadcast_to(self._q_prev, (n,)), dtype=float)
            self.integral = np.array(np.broadcast_to(self.integral, (n,)), dtype=float)
            self._ref = np.zeros((2, n))
            self._u = np.zeros(n)
            self._limits = np.array(np.broadcast_to(self.limit, (n,)))
        ref = self._ref
        ref[0] = q_ref
        ref[1] = dq_ref
        _pid_step(ref, q, v, self._gains, self.alpha, self.dt, self._limits, self._dq, self._q_prev, self.integral,
                  self._u)
        self._u_fast = self._u
        return self._u

    def track_into(self, traj: np.ndarray, t: float, q_meas, theta_m_meas=None) -> np.ndarray:
        """:meth:`step_into` on the minimum-jerk reference at t of the trajectory with the
        :attr:`MinJerkTrajectory.fields` ``traj``, the reference and the step in one compiled
        call; afterwards :attr:`ref` holds (q_ref, q̇_ref) per joint."""
        v = self._fast_v(q_meas, theta_m_meas)
        if v is not None:
            u = self._u_fast
            _track_step(float(t), traj, self._ref, q_meas, v, self._gains, self.alpha, self.dt, self._limits,
                        self._dq, self._q_prev, self.integral, u)
            return u
        q_ref, dq_ref, _ = min_jerk_reference(float(t), traj[0], traj[1], traj[2], traj[3], int(traj[4]),
                                              traj[5] != 0.0)
        return self.step_into(q_ref, q_meas, dq_ref, theta_m_meas)

    @property
    def ref(self) -> np.ndarray:
        """The last step's reference, rows q_ref and q̇_ref per joint (2, n)."""
        return self._ref


@njit
def _track_step(t, traj, ref, q, v, gains, alpha, dt, limits, dq, q_prev, integral, out):
    """:meth:`PID.track_into`: the reference of :func:`min_jerk_reference` at t into ``ref``,
    then :func:`_pid_step`."""
    q_ref, dq_ref, _ = min_jerk_reference(t, traj[0], traj[1], traj[2], traj[3], int(traj[4]), traj[5] != 0.0)
    for j in range(ref.shape[1]):
        ref[0, j] = q_ref
        ref[1, j] = dq_ref
    _pid_step(ref, q, v, gains, alpha, dt, limits, dq, q_prev, integral, out)


@njit
def _pid_step(ref, q, v, gains, alpha, dt, limits, dq, q_prev, integral, out):
    """:meth:`PID.step` per joint, the same operations in the same order as its numpy form
    (no fast-math: the same numbers): low-passed backward difference, P + D, conditional
    integration, integral clamp, output clip.  ``ref`` rows q_ref, q̇_ref; ``gains`` rows
    kp, ki, kd; ``limits`` each joint's torque limit; ``dq``, ``q_prev``, ``integral`` updated in
    place; the command into ``out``."""
    for j in range(q.shape[0]):
        kp, ki, kd = gains[0, j], gains[1, j], gains[2, j]
        limit = limits[j]
        dq[j] = dq[j] + alpha * ((v[j] - q_prev[j]) / dt - dq[j])
        q_prev[j] = v[j]
        e = ref[0, j] - q[j]
        de = ref[1, j] - dq[j]
        u_p = kp * e + kd * de
        i_new = integral[j] + e * dt
        u = u_p + ki * i_new
        se = 1 if e > 0.0 else (-1 if e < 0.0 else 0)           # np.sign
        su = 1 if u > 0.0 else (-1 if u < 0.0 else 0)
        if not (abs(u) > limit and se == su):
            integral[j] = i_new
        i_max = limit / ki if ki > 0 else 0.0
        integral[j] = min(max(integral[j], -i_max), i_max)
        out[j] = min(max(u_p + ki * integral[j], -limit), limit)


@warmer
def _warm() -> None:
    """The PID's compiled step, and with the minimum-jerk reference, with the argument types :class:`PID` passes."""
    _pid_step(np.zeros((2, 1)), np.zeros(1), np.zeros(1), np.ones((3, 1)), 0.5, 0.01, np.full(1, 10.0), np.zeros(1),
              np.zeros(1), np.zeros(1), np.zeros(1))
    traj = MinJerkTrajectory(0.1, 1.0, 3.5, 6, cyclic=True)
    traj.reference(1.0)
    _track_step(1.0, traj.fields, np.zeros((2, 1)), np.zeros(1), np.zeros(1), np.ones((3, 1)), 0.5, 0.01,
                np.full(1, 10.0), np.zeros(1), np.zeros(1), np.zeros(1), np.zeros(1))
    min_jerk(0.5)


def cosine_torque(t: float, amplitude: float = 2.0, frequency_hz: float = 0.1, offset: float = 2.0) -> float:
    """Sec. V-C desired torque τ_des(t) = −A cos(2π f t) + offset (0 at t = 0 for A = offset)."""
    return -amplitude * math.cos(2.0 * math.pi * frequency_hz * t) + offset


@dataclass(frozen=True)
class OpenLoopTorque:
    """Sec. V-C open-loop torque control: τ_m = τ_des(t) + τ_comp.

    ``tau_comp`` is the experimenter's calibration: the static torque that holds the
    human-exoskeleton system at q0 against gravity and passive stiffness (static friction
    needs none at rest).  ``tau_des`` follows :func:`cosine_torque`; ``active=False`` gives
    the training phase, τ_des = 0.
    """

    tau_comp: np.ndarray
    amplitude: float = 2.0
    frequency_hz: float = 0.1
    offset: float = 2.0

    def tau_des(self, t: float, active: bool = True) -> float:
        return cosine_torque(t, self.amplitude, self.frequency_hz, self.offset) if active else 0.0

    def command(self, t: float, active: bool = True) -> np.ndarray:
        """Motor torque command [N m] at phase time t."""
        return self.tau_des(t, active) + np.asarray(self.tau_comp, dtype=float)


class ReferenceTracker:
    """The :class:`PID` tracking a reference from a bumpless start: ``update(t, q, θ_m)`` → τ_m [N m].

    ``reference``: any object with ``reference(t) -> (q, q̇, q̈)``; a :class:`MinJerkTrajectory`
    runs its reference and the PID step in one compiled call (:meth:`PID.track_into`), the same
    numbers.  :meth:`start` presets the integrator so that the first command is ``u0`` (the
    torque already holding the arm).  The command is within ±``torque_limit`` (the PID clips)
    and is the PID's own array, overwritten by the next update.  After each update
    :attr:`q_ref` [rad] holds the reference the command was computed for.
    """

    def __init__(self, gains: PIDGains, reference, dt: float, torque_limit):
        self.pid = PID(gains.kp, gains.ki, gains.kd, dt, torque_limit, gains.velocity_filter_hz,
                       derivative=gains.derivative)
        self.reference = reference
        self._track = reference.fields if isinstance(reference, MinJerkTrajectory) else None
        self.q_ref = 0.0

    def start(self, q, theta_m, u0) -> None:
        """Start at rest from this measurement with the command ``u0``."""
        self.pid.reset(q if self.pid.derivative == "load" else theta_m, u0)

    def update(self, t: float, q, theta_m) -> np.ndarray:
        if self._track is not None:
            u = self.pid.track_into(self._track, t, q, theta_m)
            self.q_ref = self.pid.ref.item(0)
            return u
        self.q_ref, dq_ref, _ = self.reference.reference(t)
        return self.pid.step_into(self.q_ref, q, dq_ref, theta_m)


class StillArm:
    """The still-arm open loop (Sec. V-C): τ_m = clip(τ_comp + τ_des(t), ±torque_limit), and the
    subject resists, τ_h,act = −τ_des, so that the arm stays at rest.

    ``tau_comp``: the torque holding the arm at rest (n,) [N m]; ``tau_des``: t [s] → τ_des [N m].
    After each update :attr:`tau_des` holds the desired torque of the command (the subject's
    torque is its negative) and :attr:`q_ref` the angle the arm is held at.  The command is the
    controller's own array, overwritten by the next update.
    """

    def __init__(self, tau_comp, tau_des, torque_limit, q_ref: float = 0.0):
        self.tau_comp = np.asarray(tau_comp, dtype=float)
        self.profile = tau_des
        self.limit = np.asarray(torque_limit, dtype=float)        # one, or each joint's
        self.q_ref = q_ref
        self.tau_des = 0.0
        self._out = np.zeros(self.tau_comp.shape)

    def update(self, t: float, q=None, theta_m=None) -> np.ndarray:
        self.tau_des = self.profile(t)
        # Sec. V-C: τ_m = τ_comp + τ_des
        np.add(self.tau_comp, self.tau_des, out=self._out)
        np.clip(self._out, -self.limit, self.limit, out=self._out)
        return self._out

    def subject(self, t: float = 0.0) -> float:
        """The resisting subject's torque τ_h,act = −τ_des of the last update [N m]."""
        return -self.tau_des
