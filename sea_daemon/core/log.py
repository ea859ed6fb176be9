"""The measured log in memory: time and per-joint arrays (docs/interfaces.md §1 columns).

Files are read and written by :mod:`sea_daemon.io.logcsv`.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


def column_names(base: str, n: int) -> list[str]:
    """``q`` for one joint, ``q_1 … q_n`` for n > 1 (docs/interfaces.md §1)."""
    return [base] if n == 1 else [f"{base}_{i + 1}" for i in range(n)]


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
