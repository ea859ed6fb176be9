"""Benchmarks run by ``sea-daemon bench NAME``, one module each (discovered).

A module defines ``NAME``, ``HELP``, ``add_arguments(parser)`` and ``run(args) -> int``.
Every benchmark prints what it measured, on what (machine, data), with how many runs, as
medians and percentiles.  :func:`summarize` gives the figures in one place.
"""
from __future__ import annotations

import os
import platform

import numpy as np


def machine() -> str:
    """One line naming the machine the figures were measured on."""
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    return f"{cpu}, {os.cpu_count()} cores, Python {platform.python_version()}, numpy {np.__version__}"


def choose(text: str | None, allowed, flag: str) -> list[str]:
    """Labels named in a comma-separated option (all of ``allowed`` when empty), validated.

    An unknown label is an InputError naming the flag, the value and the allowed ones.
    """
    from ..errors import InputError
    allowed = list(allowed)
    labels = [s.strip() for s in (text or "").split(",") if s.strip()] or allowed
    unknown = [s for s in labels if s not in allowed]
    if unknown:
        raise InputError(f"{flag} {','.join(unknown)}: unknown; allowed: {', '.join(allowed)}")
    return labels


def summarize(samples_s, scale: float = 1e6, unit: str = "us") -> str:
    """'median …, p99 …, p99.9 …, max … (n runs)' of times given in seconds."""
    a = np.asarray(samples_s, dtype=float) * scale
    if a.size == 0:
        return "no samples"
    p50, p99, p999 = np.percentile(a, [50, 99, 99.9])
    return (f"median {p50:.1f} {unit}, p99 {p99:.1f} {unit}, p99.9 {p999:.1f} {unit}, "
            f"max {a.max():.1f} {unit} ({a.size} runs)")
