"""The narrow hardware interface (ros2_control style): ``start/read/write/safe_stop/stop``.

Everything the daemon sees of the exoskeleton goes through :class:`HardwareInterface`; the
CANopen implementation (:mod:`sea_daemon.hw.canopen_hw`) and the in-process simulator
(:mod:`sea_daemon.hw.sim_hw`) sit behind it.  All quantities are on the **joint side** of the gear,
in SI units (docs/interfaces.md §1).

Timing: ``read()`` in cycle k returns the state sampled at t_k (the SYNC of cycle k).  The
torque given to ``write()`` in cycle k acts over [t_k+d, t_k+d+1], d = :attr:`actuation_delay`:

* d = 0 when the drive actuates the RPDO on reception (``hardware.bus.sync_rpdo: false``, the
  default; :class:`sea_daemon.hw.sim_hw.SimHardware` by default): the torque written in cycle k acts
  over [t_k, t_k+1], like the offline simulator's zero-order hold — it is the ``tau_m`` of row
  k of a measured log (docs/interfaces.md §1), and an estimator updated in cycle k after the write gets it;
* d = 1 for a synchronous RPDO (actuated at the next SYNC, ``sync_rpdo: true``): the torque
  acting over [t_k, t_k+1] is the one written in cycle k-1, known when cycle k starts (one
  cycle more of delay in every control loop closed through the bus).

:attr:`Measurement.tau_m_applied` of cycle k is what the drive reports (0x6077): the torque
that acted over [t_k-1, t_k].
"""
from __future__ import annotations

import abc
from dataclasses import dataclass, field

import numpy as np

from sea_daemon.errors import Fault


@dataclass
class Measurement:
    """One cycle's sample, joint side.

    The arrays are preallocated by the driver and overwritten by the next ``read()``: copy what
    you keep (the real-time path allocates nothing).
    """

    n: int
    t: float = 0.0                      # [s] sample time: cycle · period since start()
    cycle: int = -1                     # cycle counter since start()
    t_mono: float = 0.0                 # [s] time.monotonic() when the SYNC was sent
    q: np.ndarray = field(default=None)             # (n,) load angle [rad]
    theta_m: np.ndarray = field(default=None)       # (n,) motor angle / gear ratio [rad]
    tau_m_applied: np.ndarray = field(default=None)  # (n,) torque the drive applied over
    #                                                   [t - period, t] (0x6077), joint side [N m]
    q_counts: np.ndarray = field(default=None)      # (n,) raw load encoder position value (0x6004)
    theta_m_counts: np.ndarray = field(default=None)  # (n,) raw drive position actual value (0x6064)
    statusword: np.ndarray = field(default=None)    # (n,) CiA 402 statusword (0x6041)
    faults: int = 0                     # the fault codes seen in this cycle, one bit each
    #                                     (``Fault.X.bit``, :class:`sea_daemon.errors.Fault`)
    valid: bool = False                 # False when values were held (missing TPDO; the loop
    #                                     passes such a sample on extrapolated, runtime/loop.py)
    late: bool = False                  # a frame arrived outside its cycle's window (docs/can.md)

    def __post_init__(self):
        n = self.n
        for name, dt in (("q", float), ("theta_m", float), ("tau_m_applied", float),
                         ("q_counts", np.int64), ("theta_m_counts", np.int64), ("statusword", np.int64)):
            if getattr(self, name) is None:
                setattr(self, name, np.zeros(n, dtype=dt))

    def saw(self, fault: Fault) -> bool:
        """Whether ``fault``'s bit is set in :attr:`faults`."""
        return bool(self.faults & fault.bit)

    def copy(self) -> "Measurement":
        return Measurement(self.n, self.t, self.cycle, self.t_mono, self.q.copy(), self.theta_m.copy(),
                           self.tau_m_applied.copy(), self.q_counts.copy(), self.theta_m_counts.copy(),
                           self.statusword.copy(), self.faults, self.valid, self.late)


class HardwareInterface(abc.ABC):
    """The exoskeleton's actuators and sensors, one joint per drive + load encoder pair.

    Life cycle: ``start(initial_torque)`` (configure, enable; raises on a device mismatch) →
    ``read()`` / ``write()`` once per cycle → ``safe_stop()`` on a fault → ``stop()``.  Faults
    raise subclasses of :class:`sea_daemon.errors.HardwareError` (see :mod:`sea_daemon.hw.errors`);
    each carries ``.fault`` for the daemon's fault policy.  Every implementation has the same
    methods and attributes: what an implementation does not need keeps the default here.
    """

    n: int
    period: float
    #: cycles from ``write()`` to the interval the torque acts over (0 or 1, see the module docstring)
    actuation_delay: int = 0

    @abc.abstractmethod
    def start(self, initial_torque: np.ndarray | None = None) -> None:
        """Bring the hardware up so that ``read``/``write`` can run.

        ``initial_torque`` (n,) [N m]: the torque in force from the start on (e.g. the one
        already holding the arm), zero when not given.
        """

    @abc.abstractmethod
    def read(self) -> Measurement:
        """This cycle's measurement (the returned object is reused by the next call)."""

    @abc.abstractmethod
    def write(self, tau_m: np.ndarray) -> None:
        """Command the motor torque for the next cycle, joint side [N m], shape (n,)."""

    @abc.abstractmethod
    def safe_stop(self) -> None:
        """Zero torque and quick stop now; must not raise when the bus is gone."""

    @abc.abstractmethod
    def stop(self) -> None:
        """Leave the hardware disabled and release the bus; idempotent."""

    def actuated(self, tau_m: np.ndarray) -> np.ndarray:
        """The torque [N m] the hardware applies for ``write(tau_m)``; here: as commanded."""
        return tau_m

    def reset_fault(self) -> None:
        """Operator reset after a latched fault: re-arm detection, re-enable; here: nothing to do."""

    def __enter__(self):
        self.start()
        return self

    def __exit__(self, *exc):
        self.stop()
