"""Buffers that are resident before a real-time path writes them.

A freshly allocated buffer (``np.zeros``: calloc, mmap) has no pages yet: the kernel maps each
one at its first write, a page fault on whichever path writes it first.  On a machine where that
costs a few microseconds it is jitter; on a virtual machine whose host backs guest memory only
when the guest first touches it, a first touch has been measured at 1–16 ms (docs/daemon.md,
"Memory on the real-time path").  A buffer that the loop, the device model or the bound worker
fills one sample per cycle is made resident here, at start-up, instead.  ``mlockall``
(``sea_daemon.runtime.realtime``) does the same for the whole process where it is permitted;
this works without the permission.
"""
from __future__ import annotations

import numpy as np

#: the stride of the touches: the smallest page size of the CPUs the daemon runs on (x86-64,
#: aarch64 with 4 KiB pages); larger pages (16 or 64 KiB) are touched more than once
PAGE = 4096


def make_resident(a: np.ndarray) -> np.ndarray:
    """Write one byte of every page of ``a`` back onto itself (a C-contiguous array; its values
    are unchanged): every page is mapped now, not at the real-time path's first write.  Returns ``a``."""
    if not a.flags.c_contiguous:
        raise ValueError("make_resident: the array must be C-contiguous")
    b = a.reshape(-1).view(np.uint8)
    if b.size:
        b[::PAGE] = b[::PAGE].copy()
    return a


def resident_zeros(shape, dtype=np.float64) -> np.ndarray:
    """``np.zeros(shape, dtype)`` with every page mapped (:func:`make_resident`)."""
    return make_resident(np.zeros(shape, dtype))
