"""Compilation of the hot numerics with numba (issue 3's latency target).

:func:`njit` is ``numba.njit(cache=True)``: the machine code is cached next to the source
(``__pycache__``) or, if that is not writable, in numba's user-wide cache directory
(``NUMBA_CACHE_DIR`` overrides both).  When no cache directory is writable at all the
function is compiled in memory instead (numba raises ``RuntimeError`` at decoration then);
the code runs the same, only each new process compiles again.

Compilation is lazy (first call).  The estimators call :func:`warm_up` at construction, so
a daemon is compiled (or has loaded its cache) before it reports READY, never in its first
loop cycle.  Numba uses no threads here (no ``parallel=True``).
"""
from __future__ import annotations

from typing import Callable

import numba

_WARMERS: list[Callable[[], None]] = []
_warm = False


def njit(fn: Callable) -> Callable:
    """``numba.njit(cache=True)``; in-memory compilation when no cache directory is writable."""
    try:
        return numba.njit(cache=True)(fn)
    except RuntimeError:          # "cannot cache function ...: no locator available"
        return numba.njit(cache=False)(fn)


def warmer(fn: Callable[[], None]) -> Callable[[], None]:
    """Register ``fn`` (no arguments) to run once in :func:`warm_up`: it calls compiled
    functions with the argument types the estimators use, so their code is ready."""
    _WARMERS.append(fn)
    return fn


def warm_up() -> None:
    """Compile (or load from the cache) every registered kernel, once per process."""
    global _warm
    if _warm:
        return
    for fn in _WARMERS:
        fn()
    _warm = True
