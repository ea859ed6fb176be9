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
_n_warm = 0          # warmers already run (modules imported later register more)


#: LLVM may reassociate sums and contract a·b + c into one FMA: lets the O(N²)/O(N³) reductions
#: of the GP kernels vectorise (a serial sum is bound by the add latency, ~4× slower).  No
#: 'nnan'/'ninf': NaN and inf checks keep working.  Deterministic for given compiled code.
FAST = frozenset({"reassoc", "contract"})


def njit(fn: Callable | None = None, *, fast: bool = False) -> Callable:
    """``numba.njit(cache=True)`` (``fast``: with the :data:`FAST` math flags); in-memory
    compilation when no cache directory is writable."""
    def wrap(f: Callable) -> Callable:
        opts = {"fastmath": set(FAST)} if fast else {}
        try:
            return numba.njit(cache=True, **opts)(f)
        except RuntimeError:          # "cannot cache function ...: no locator available"
            return numba.njit(cache=False, **opts)(f)
    return wrap if fn is None else wrap(fn)


def warmer(fn: Callable[[], None]) -> Callable[[], None]:
    """Register ``fn`` (no arguments) to run once in :func:`warm_up`: it calls compiled
    functions with the argument types the estimators use, so their code is ready."""
    _WARMERS.append(fn)
    return fn


def warm_up() -> None:
    """Compile (or load from the cache) every registered kernel not yet warmed, once each."""
    global _n_warm
    while _n_warm < len(_WARMERS):
        fn = _WARMERS[_n_warm]
        _n_warm += 1
        fn()
