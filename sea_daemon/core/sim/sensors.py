"""Sensors of the exoskeleton (paper Sec. V-A): two 19-bit absolute encoders, motor torque.

Encoders
--------
* The **load encoder** sits on the joint: one count is exactly ``2π / 2^bits`` rad of q
  (``bits`` = ``hardware.encoder_bits`` = 19 → 1.198e-5 rad).
* The **motor encoder** sits on the motor shaft, *before* the 1:``gear_ratio`` reduction.
  One count is ``2π / 2^bits`` rad of the motor shaft, i.e. ``2π / (2^bits · gear_ratio)``
  rad of θ_m on the joint side (1.198e-7 rad for 1:100).  The shaft turns ``gear_ratio``
  times per joint turn, so the single-turn absolute reading wraps; :func:`raw_counts`
  returns the single-turn count together with the number of whole shaft turns, and a
  device driver (CANopen) reconstructs θ_m from them with the gear ratio and multi-turn
  unwrapping: θ_m = (turns · 2^bits + count) · 2π / (2^bits · gear_ratio).
* Quantisation is ``floor`` (a real encoder reports the count it has passed), so it is
  deterministic; the reading is therefore biased by −½ count on average.
* An ``encoder_offset`` effect (docs/interfaces.md §2) makes that encoder read ``angle + delta``;
  the offset is added before quantisation.

Motor torque
------------
The torque the motor really applies is the commanded torque plus white Gaussian noise of
standard deviation ``hardware.torque_noise`` (joint side, each joint's own), drawn once per sample and held
for the sample (current-loop ripple, torque-constant error).  The *log* records the
commanded torque: like the paper (τ_m "computed from the control input and torque
constant"), the controller knows only what it commanded.  The simulator writes the
applied torque as an extra column ``tau_m_applied`` for debugging.
"""
from __future__ import annotations

import math

import numpy as np

from sea_daemon.core.config import HardwareConfig


def load_quantum(bits: int = 19) -> float:
    """One count of the load encoder [rad of q]: exactly 2π / 2^bits."""
    return 2.0 * math.pi / 2**bits


def motor_quantum(bits: int = 19, gear_ratio: float = 100.0) -> float:
    """One count of the motor encoder, expressed on the joint side [rad of θ_m]: 2π / (2^bits · gear)."""
    return 2.0 * math.pi / (2**bits * gear_ratio)


def quantize(angle: np.ndarray, quantum: float) -> np.ndarray:
    """Total encoder counts (floor quantisation), int64."""
    return np.floor(np.asarray(angle, dtype=float) / quantum).astype(np.int64)


class Encoders:
    """The two absolute encoders of each of ``n`` joints, with optional offsets (``encoder_offset``).

    Each joint's counts per turn (``hardware.encoder_counts``, else 2^``encoder_bits``) and gear
    ratio (``hardware.gear_ratio``, one or per joint) give its quanta :attr:`q_loads`,
    :attr:`q_motors` [rad, joint side]; :attr:`q_load`, :attr:`q_motor` are the first joint's.
    ``read(q, theta_m)`` returns the joint-side angles the daemon sees; ``raw(q, theta_m)``
    the counts a device would put on the bus.
    """

    def __init__(self, hardware: HardwareConfig, offset_load: np.ndarray | float = 0.0,
                 offset_motor: np.ndarray | float = 0.0, n: int = 1):
        self.bits = int(hardware.encoder_bits)
        self.counts_load, self.counts_motor = hardware.encoder_counts(n)
        self.gear_ratios = hardware.gear_ratios(n)
        self.q_loads = 2.0 * math.pi / self.counts_load.astype(float)
        self.q_motors = 2.0 * math.pi / (self.counts_motor.astype(float) * self.gear_ratios)
        self.gear_ratio = float(self.gear_ratios[0])
        self.q_load = float(self.q_loads[0])
        self.q_motor = float(self.q_motors[0])
        self.offset_load = np.asarray(offset_load, dtype=float)
        self.offset_motor = np.asarray(offset_motor, dtype=float)

    def counts(self, q: np.ndarray, theta_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Total (unwrapped) counts of the load and motor encoders."""
        return (quantize(np.asarray(q) + self.offset_load, self.q_loads),
                quantize(np.asarray(theta_m) + self.offset_motor, self.q_motors))

    def read(self, q: np.ndarray, theta_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Measured joint-side angles (q_meas, θ_m,meas) = counts · quantum."""
        cl, cm = self.counts(q, theta_m)
        return cl * self.q_loads, cm * self.q_motors

    def raw(self, q: np.ndarray, theta_m: np.ndarray) -> dict[str, np.ndarray]:
        """What the hardware reports: single-turn counts in [0, counts per turn) and motor shaft turns.

        ``load_count``: load encoder single-turn count; ``motor_count``: motor encoder
        single-turn count; ``motor_turns``: whole motor-shaft turns (multi-turn counter).
        """
        cl, cm = self.counts(q, theta_m)
        return {"load_count": np.mod(cl, self.counts_load), "motor_count": np.mod(cm, self.counts_motor),
                "motor_turns": np.floor_divide(cm, self.counts_motor)}

    def angles_from_raw(self, load_count, motor_count, motor_turns) -> tuple[np.ndarray, np.ndarray]:
        """Inverse of :meth:`raw` (without offsets): q in [0, 2π), θ_m unwrapped, joint side."""
        full = self.counts_motor
        q = np.asarray(load_count, dtype=np.int64) * self.q_loads
        th = (np.asarray(motor_turns, dtype=np.int64) * full + np.asarray(motor_count, dtype=np.int64)) * self.q_motors
        return q, th


def torque_noise(rng: np.random.Generator, std, n: int) -> np.ndarray:
    """One sample of the motor-torque noise [N m, joint side]; ``std`` every joint's or each joint's (n,)."""
    if np.all(np.asarray(std) <= 0):
        return np.zeros(n)
    return rng.normal(0.0, std, n)
