"""Position counts from the TPDOs → joint-side angles, with the encoder fault checks.

:class:`Positions` keeps, per joint, what turns the raw counts of a cycle into q and θ_m: the
load encoder's position value 0x6004 (single-turn on the first sample, centred on (-π, π],
then unwrapped across its range) and the drive's position actual value 0x6064 (a multi-turn
int32 count of the motor shaft, its wraps undone), through the gear ratio, minus the
configured offsets.  From the second sample on it raises :class:`~sea_daemon.hw.errors.EncoderJump`
when a count moves by more than the joint's ``max_joint_speed`` allows in a period (plus two
counts), and :class:`~sea_daemon.hw.errors.EncoderStuck` when a count stays unchanged for
``stuck_cycles`` while the other encoder of the joint moves by more than the joint's ``stuck_motion``.
"""
from __future__ import annotations

import math

import numpy as np

from sea_daemon.core.config import BusConfig

from sea_daemon.errors import Fault
from sea_daemon.hw.errors import EncoderJump, EncoderStuck
from sea_daemon.hw.interface import Measurement


def _wrap(delta: int, span: int) -> int:
    """Shortest signed difference of two counters that wrap at ``span``."""
    return (delta + span // 2) % span - span // 2


class Positions:
    """Counts → angles of ``n`` joints, per joint: ``res_load`` / ``res_motor`` counts per turn of
    the load encoder's joint and the motor encoder's shaft, ``gear`` motor turns per joint turn."""

    def __init__(self, n: int, res_load, res_motor, gear, bus_cfg: BusConfig, period: float):
        self.bus_cfg = bus_cfg
        # conversions (joint side) per joint            counts → rad
        self.k_q = [2 * math.pi / res_load[j] for j in range(n)]                  # load encoder
        self.k_m = [2 * math.pi / (res_motor[j] * gear[j]) for j in range(n)]     # motor encoder through the gear
        # largest motion in a period [rad] per joint (its own max_joint_speed)
        self.step_max = [float(v) * period for v in bus_cfg.max_joint_speeds(n)]
        self.allowed_q = [self.step_max[j] + 2 * self.k_q[j] for j in range(n)]   # largest step in a period [rad]
        self.allowed_m = [self.step_max[j] + 2 * self.k_m[j] for j in range(n)]
        self.stuck_motion = [float(v) for v in bus_cfg.stuck_motions(n)]          # per joint [rad]
        self.q_offset = np.array(bus_cfg.q_offset, dtype=float)
        self.theta_m_offset = np.array(bus_cfg.theta_m_offset, dtype=float)
        self._q_off = [float(v) for v in self.q_offset]           # the same as floats (every cycle)
        self._m_off = [float(v) for v in self.theta_m_offset]
        self.enc_range = list(res_load)   # counts the load encoder's position value spans (from start-up)
        self._u_q = [0] * n            # unwrapped load counts
        self._u_m = [0] * n            # unwrapped motor counts (int32 wraps undone)
        self._raw_q = [0] * n
        self._raw_m = [0] * n
        self._stuck_q = [[0, 0.0] for _ in range(n)]   # [unchanged cycles, other angle at run start]
        self._stuck_m = [[0, 0.0] for _ in range(n)]
        self._prev_q = [0] * n         # raw counts of the last cycle (stuck detection)
        self._prev_m = [0] * n

    def reference(self, m: Measurement, j: int, qc: int, pos: int) -> None:
        """The first sample (after start-up or a reset): sets the unwrapping reference, no checks."""
        rng = self.enc_range[j]
        # load: single-turn absolute, centred on (-range/2, range/2]
        self._u_q[j] = qc - rng if qc >= rng // 2 else qc
        # motor: multi-turn count (single-turn count + 2^bits per shaft turn), int32
        self._u_m[j] = pos
        self._angles(m, j, qc, pos)
        self._stuck_q[j][:] = [0, m.theta_m[j]]
        self._stuck_m[j][:] = [0, m.q[j]]
        self._prev_q[j], self._prev_m[j] = int(qc), int(pos)

    def update(self, m: Measurement, j: int, qc: int, pos: int, enc_node: int, drive_node: int, cycle: int,
               periods: float = 1.0) -> None:
        """A later sample, ``periods`` periods after the one before (more than 1 after held
        cycles or a stall of the loop): unwrap, check for jumps (``max_joint_speed`` over that
        time), set ``m.q[j]`` / ``m.theta_m[j]``, check for a stuck encoder."""
        dq = _wrap(qc - self._raw_q[j], self.enc_range[j])
        dm = _wrap(pos - self._raw_m[j], 1 << 32)
        k_q, k_m = self.k_q[j], self.k_m[j]
        if periods > 1.0:
            more = self.step_max[j] * (periods - 1.0)
            lim_q, lim_m = self.allowed_q[j] + more, self.allowed_m[j] + more
        else:
            lim_q, lim_m = self.allowed_q[j], self.allowed_m[j]
        if abs(dq * k_q) > lim_q:
            m.faults |= Fault.ENCODER_JUMP.bit
            raise EncoderJump(enc_node, "0x6004 load position value", dq * k_q, lim_q, cycle)
        if abs(dm * k_m) > lim_m:
            m.faults |= Fault.ENCODER_JUMP.bit
            raise EncoderJump(drive_node, "0x6064 motor position actual value", dm * k_m, lim_m, cycle)
        self._u_q[j] += dq
        self._u_m[j] += dm
        q, th = self._angles(m, j, qc, pos)
        # a stuck encoder: its count unchanged while the other encoder of the joint moves
        if qc == self._prev_q[j]:
            self._stuck(m, j, self._stuck_q[j], th, enc_node, "0x6004 load position value", qc)
        else:
            run = self._stuck_q[j]
            run[0], run[1] = 0, th
        if pos == self._prev_m[j]:
            self._stuck(m, j, self._stuck_m[j], q, drive_node, "0x6064 motor position actual value", pos)
        else:
            run = self._stuck_m[j]
            run[0], run[1] = 0, q
        self._prev_q[j], self._prev_m[j] = qc, pos

    def _angles(self, m: Measurement, j: int, qc: int, pos: int) -> tuple[float, float]:
        self._raw_q[j], self._raw_m[j] = qc, pos
        q = self._u_q[j] * self.k_q[j] - self._q_off[j]
        th = self._u_m[j] * self.k_m[j] - self._m_off[j]
        m.q[j] = q
        m.theta_m[j] = th
        return q, th

    def _stuck(self, m: Measurement, j: int, run: list, other: float, node: int, obj: str, count: int) -> None:
        """One more cycle of an unchanged count of joint ``j``; raises once it has lasted
        ``stuck_cycles`` while the other encoder moved by more than the joint's ``stuck_motion``."""
        run[0] += 1
        moved = abs(other - run[1])
        limit = self.stuck_motion[j]
        if run[0] >= self.bus_cfg.stuck_cycles and moved > limit:
            m.faults |= Fault.ENCODER_STUCK.bit
            raise EncoderStuck(node, obj, count, run[0], moved, limit)
