"""The rows of a lock-step run of both phases (training, then estimation) as two measured logs.

The offline simulator (:mod:`.sim_runner`) and the hardware-in-the-loop session
(:mod:`.hil_session`) fill one row per loop cycle from the loop's ``on_cycle`` hook into the
preallocated columns of a :class:`PhaseRecorder`, then split them at the training length.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from sea_daemon.core.log import MeasuredLog

#: the columns of a measured log (docs/interfaces.md §1); every other column is an extra (joint 0)
BASE = ("t", "q", "theta_m", "tau_m", "tau_h_act")


class PhaseRecorder:
    """``cols[name]`` (rows, n) for the :data:`BASE` columns and ``extra``, in that order."""

    def __init__(self, rows: int, n: int, extra: Sequence[str]):
        self.rows = rows
        self.cols = {k: np.zeros((rows, n)) for k in (*BASE, *extra)}

    def log(self, rows: slice) -> MeasuredLog:
        """The measured log of ``rows`` (copies): t and the extras of joint 0, the others per joint."""
        c = self.cols
        return MeasuredLog(t=c["t"][rows, 0].copy(), q=c["q"][rows].copy(), theta_m=c["theta_m"][rows].copy(),
                           tau_m=c["tau_m"][rows].copy(), tau_h_act=c["tau_h_act"][rows].copy(),
                           extra={k: v[rows, 0].copy() for k, v in c.items() if k not in BASE})

    def phases(self, training: int) -> tuple[MeasuredLog, MeasuredLog]:
        """(training log, estimation log): the first ``training`` rows, then the rest."""
        return self.log(slice(0, training)), self.log(slice(training, self.rows))
