"""The measured log in memory and its schema: the columns of docs/interfaces.md §1, defined here once.

* :data:`REQUIRED`, :data:`OPTIONAL`, :data:`ESTIMATE`, :data:`LOOP` — the column names (per
  joint, :func:`column_names`; the loop's columns once per row);
* :class:`DaemonLogLayout` — the daemon log's row: its columns and the named index or slice of
  each quantity in a row (what the fixed-rate loop fills, :mod:`sea_daemon.runtime.loop`);
* :class:`DaemonColumns` — those columns of a daemon log read back, by name;
* :class:`MeasuredLog` — a log in memory.

Files are read and written by :mod:`sea_daemon.io.logcsv`.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


#: the per-joint columns every measured log has, in this order after ``t``
REQUIRED = ("q", "theta_m", "tau_m")
#: the optional per-joint column: the true active human torque, where it is known
OPTIONAL = ("tau_h_act",)
#: the estimate's per-joint columns (EST.csv of ``replay`` and the daemon's log)
ESTIMATE = ("tau_h_act_hat", "tau_h_act_bound", "tau_h_act_sigma")
#: the daemon log's columns after the estimate, one each per row: validity, the latched fault
#: code, the cycle, the loop's timing [s] (period: start to start of cycles; compute: start of
#: the read to the log row; read: ``hw.read()``), ``measured`` (1: the row holds this cycle's
#: sample) and ``bound_cycle`` (the cycle whose sample the row's bound belongs to, −1: none)
LOOP = ("valid", "fault", "cycle", "period", "compute", "read", "measured", "bound_cycle")
#: the loop's row after the log's columns, not in the CSV, for the log writer's other outputs
#: (the LSL stream and the MCAP recording, docs/interfaces.md §7): the loop's clock at the
#: cycle's start [s], once per row
SINK_LOOP = ("cycle_start",)
#: the daemon log's last per-joint column, after :data:`LOOP`, in the CSV and the other outputs:
#: the assistance τ_assist [N m] (the assist-as-needed controller's, computed and not commanded
#: in a dry run; 0 without one and while a fault is latched)
SINK_JOINT = ("tau_assist",)


def column_names(base: str, n: int) -> list[str]:
    """``q`` for one joint, ``q_1 … q_n`` for n > 1 (docs/interfaces.md §1)."""
    return [base] if n == 1 else [f"{base}_{i + 1}" for i in range(n)]


@dataclass(frozen=True)
class DaemonLogLayout:
    """The daemon log's row for ``n`` joints: ``t``, :data:`REQUIRED` and :data:`ESTIMATE` per
    joint, then :data:`LOOP` and :data:`SINK_JOINT` per joint (``columns``, the CSV's); the
    loop's row goes on with :data:`SINK_LOOP` (``sink_columns``; ``width`` values in all).  Each per-joint quantity is a ``slice`` of the row, each loop column an index,
    ``estimate`` the slice of all three estimate blocks: ``row[layout.tau_m] = tau``."""

    n: int
    columns: tuple[str, ...]
    t: int
    q: slice
    theta_m: slice
    tau_m: slice
    tau_h_act_hat: slice
    tau_h_act_bound: slice
    tau_h_act_sigma: slice
    estimate: slice
    valid: int
    fault: int
    cycle: int
    period: int
    compute: int
    read: int
    measured: int
    bound_cycle: int
    sink_columns: tuple[str, ...]
    cycle_start: int
    tau_assist: slice

    @property
    def width(self) -> int:
        """Values in the loop's row: the CSV's columns, then :attr:`sink_columns`."""
        return len(self.columns) + len(self.sink_columns)

    @classmethod
    def of(cls, n: int) -> "DaemonLogLayout":
        at: dict = {"t": 0}
        columns = ["t"]
        for base in REQUIRED + ESTIMATE:
            at[base] = slice(len(columns), len(columns) + n)
            columns += column_names(base, n)
        at["estimate"] = slice(at[ESTIMATE[0]].start, at[ESTIMATE[-1]].stop)
        for name in LOOP:
            at[name] = len(columns)
            columns.append(name)
        at["tau_assist"] = slice(len(columns), len(columns) + n)
        columns += column_names(SINK_JOINT[0], n)
        sink = list(SINK_LOOP)
        at["cycle_start"] = len(columns)
        return cls(n=n, columns=tuple(columns), sink_columns=tuple(sink), **at)


def log_columns(n: int) -> list[str]:
    """The daemon log's columns for ``n`` joints (:class:`DaemonLogLayout`)."""
    return list(DaemonLogLayout.of(n).columns)


@dataclass
class DaemonColumns:
    """The daemon's own columns of a daemon log read back (:meth:`of`): the estimate blocks
    (N, n) and the loop's columns (N,), by name."""

    tau_h_act_hat: np.ndarray
    tau_h_act_bound: np.ndarray
    tau_h_act_sigma: np.ndarray
    valid: np.ndarray
    fault: np.ndarray
    cycle: np.ndarray
    period: np.ndarray
    compute: np.ndarray
    read: np.ndarray
    measured: np.ndarray
    bound_cycle: np.ndarray

    @classmethod
    def of(cls, log: "MeasuredLog") -> "DaemonColumns":
        """The columns from ``log.extra`` (KeyError naming a column the log lacks)."""
        n, x = log.n, log.extra
        blocks = {b: np.stack([x[c] for c in column_names(b, n)], axis=1) for b in ESTIMATE}
        return cls(**blocks, **{c: x[c] for c in LOOP})


@dataclass
class MeasuredLog:
    """One measured log: time (N,), per-joint arrays (N, n)."""

    t: np.ndarray
    q: np.ndarray
    theta_m: np.ndarray
    tau_m: np.ndarray
    tau_h_act: np.ndarray | None = None
    extra: dict[str, np.ndarray] = field(default_factory=dict)
    path: str = "<memory>"

    @property
    def n(self) -> int:
        return self.q.shape[1]

    def __len__(self) -> int:
        return self.t.shape[0]

    @property
    def dt(self) -> float:
        """Median sample period [s]."""
        return float(np.median(np.diff(self.t)))

    def slice(self, start: int, stop: int | None = None) -> "MeasuredLog":
        s = slice(start, stop)
        return MeasuredLog(self.t[s], self.q[s], self.theta_m[s], self.tau_m[s],
                           None if self.tau_h_act is None else self.tau_h_act[s],
                           {k: v[s] for k, v in self.extra.items()}, self.path)
