"""The shared memory of the bound worker (:mod:`.bound_worker`, :mod:`.bound_serve`): its layout.

One block of shared memory holds, in order: a header of int64s (:data:`H_DONE` the worker's
count of samples done, :data:`H_SCHED` its SCHED_FIFO priority — 0 SCHED_OTHER, −1 not known
yet —, :data:`H_LOCKED` its memory locked, :data:`H_YIELDS` how often it gave its priority up
for being behind, :data:`H_YIELDED` 1 while it has, :data:`H_HEAD` the loop's head when the worker
polls it), a header of float64s (the worker's CPU time in bound steps and in the whole process
[s], :data:`F_FLUSH` when the loop published its newest head [s, monotonic clock]), a ring of input slots, a ring of result slots and the
worker's CPU time per sample (the first ``record`` samples).

An input slot holds a filter step's :class:`~sea_daemon.core.estimators.record.StepRecord`: its
scalars at the indices ``I_*`` (kind, the loop's cycle, k, dt, ready, gate starts, the chain's
epoch) and then its arrays, in :attr:`StepRecord.ARRAYS` order (:func:`layout`).  A result slot
holds the sample's sequence number, cycle, k, validity, status, epoch, the worker's CPU time
for it, why the estimate is not valid (``Estimate.invalid_reason``), then ρ (n).
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

# int64 header slots (read without order, bound_worker's docstring)
H_DONE, H_SCHED, H_LOCKED, H_YIELDS, H_YIELDED, H_HEAD, N_HDR = 0, 1, 2, 3, 4, 5, 8
# float64 header slots (after the int64 ones): the worker's CPU time [s]: in bound steps, whole process;
# the loop's clock when it published its newest head (heads polled: the worker's phase)
F_STEPS, F_PROC, F_FLUSH, N_FHDR = 0, 1, 2, 4
# input slot: kind, cycle, k, dt, ready, gate_starts, epoch, then the record's arrays
# (the scalars 0..6 in this order: the loop writes them in one assignment)
I_KIND, I_CYC, I_K, I_DT, I_READY, I_GATES, I_EPOCH, N_IN = 0, 1, 2, 3, 4, 5, 6, 8
#: I_KIND: a filter step / a reset
STEP, RESET = 1.0, 2.0
# result slot: seq, cycle, k, valid, status, epoch, cpu, why not valid (Estimate.invalid_reason), then ρ (n)
R_SEQ, R_CYC, R_K, R_VALID, R_STATUS, R_EPOCH, R_CPU, R_REASON, N_RES = 0, 1, 2, 3, 4, 5, 6, 7, 8
#: R_STATUS: the bound computed / the bound diverged (EstimatorFault) / a reset (no bound)
OK, FAILED, NO_BOUND = 0.0, 1.0, 2.0
#: the head that asks the worker to stop (after the samples published before it)
STOP = -1


def layout(record) -> tuple[dict, int]:
    """The input slot's arrays for a record: {name: (offset, shape)} in the slot, and the slot's
    width (float64s)."""
    o = N_IN
    out = {}
    for name, a in record.arrays():
        out[name] = (o, a.shape)
        o += a.size
    return out, o


class Shared(NamedTuple):
    """The views of the block of shared memory (module docstring)."""

    hdr: np.ndarray       # (N_HDR,) int64
    fhdr: np.ndarray      # (N_FHDR,) float64
    ring: np.ndarray      # (capacity, width) input slots
    res: np.ndarray       # (capacity, rwidth) result slots
    cpu: np.ndarray       # (max(record, 1),) the worker's CPU time per sample [s]


def shared_size(cap: int, width: int, rwidth: int, record: int) -> int:
    """Bytes of the block for ``cap`` slots of these widths and ``record`` recorded samples."""
    return (N_HDR + N_FHDR) * 8 + cap * (width + rwidth) * 8 + max(record, 1) * 8


def map_shared(buf, cap: int, width: int, rwidth: int, record: int) -> Shared:
    """The views of the block ``buf`` (a SharedMemory's ``buf``)."""
    hdr = np.ndarray((N_HDR,), dtype=np.int64, buffer=buf)
    fhdr = np.ndarray((N_FHDR,), dtype=np.float64, buffer=buf, offset=N_HDR * 8)
    o = (N_HDR + N_FHDR) * 8
    ring = np.ndarray((cap, width), dtype=np.float64, buffer=buf, offset=o)
    o += cap * width * 8
    res = np.ndarray((cap, rwidth), dtype=np.float64, buffer=buf, offset=o)
    o += cap * rwidth * 8
    cpu = np.ndarray((max(record, 1),), dtype=np.float64, buffer=buf, offset=o)
    return Shared(hdr, fhdr, ring, res, cpu)


def slot_arrays(slot: np.ndarray, lay: dict) -> tuple[tuple[str, np.ndarray], ...]:
    """(name, view) of a slot's arrays, each shaped as the record's (:func:`layout`)."""
    out = []
    for name, (o, shape) in lay.items():
        size = int(np.prod(shape, dtype=np.int64))
        out.append((name, slot[o:o + size].reshape(shape)))
    return tuple(out)
