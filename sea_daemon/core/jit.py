"""Compilation of the hot numerics with numba (the filter step of the 1 kHz loop).

:func:`njit` is ``numba.njit(cache=True)``: the machine code is cached next to the source
(``__pycache__``) or, if that is not writable, in numba's user-wide cache directory
(``NUMBA_CACHE_DIR`` overrides both).  When no cache directory is writable at all the
function is compiled in memory instead (numba raises ``RuntimeError`` at decoration then);
the code runs the same, only each new process compiles again.

Compilation is lazy (first call); :func:`warm_up` is the one place that triggers it ahead of
use: it imports every module of :data:`KERNEL_MODULES` and runs each module's example calls
(registered with :func:`warmer`: the kernels with the argument types the estimators pass)
once.  The estimators call it at construction and the runtime before it starts the hardware,
so a daemon is compiled (or has loaded its cache) before it reports READY, never in a loop
cycle.  Numba uses no threads here (no ``parallel=True``).
"""
from __future__ import annotations

import importlib
from typing import Callable

import numba

#: every module with compiled kernels, imported by :func:`warm_up` by name (they import this
#: module for :func:`njit`)
KERNEL_MODULES = (
    "sea_daemon.core.linalg",
    "sea_daemon.core.control",
    "sea_daemon.core.effects",
    "sea_daemon.core.dynamics",
    "sea_daemon.core.model_core",
    "sea_daemon.core.kinematics",
    "sea_daemon.core.estimators.akf_core",
    "sea_daemon.core.estimators.health",
    "sea_daemon.core.estimators.gp_hook",
    "sea_daemon.core.estimators.gpakf_core",
    "sea_daemon.core.gp.gp_core",
    "sea_daemon.core.gp.exact",
    "sea_daemon.core.gp.hyper",
    "sea_daemon.core.gp.routing",
    "sea_daemon.core.gp.pack",
    "sea_daemon.core.bounds.setmember",
    "sea_daemon.core.bounds.zonotope",
    "sea_daemon.core.bounds.bound_core",
    "sea_daemon.core.bounds.rigid_box",
    "sea_daemon.core.sim.plant",
)

_WARMERS: list[Callable[[], None]] = []
_n_warm = 0          # warmers already run


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


def _register_all() -> None:
    """Import every module of :data:`KERNEL_MODULES`: each registers its example calls."""
    for name in KERNEL_MODULES:
        importlib.import_module(name)


def warm_up() -> None:
    """Compile (or load from the cache) every kernel of :data:`KERNEL_MODULES`, once;
    later calls return at once."""
    global _n_warm
    if _n_warm and _n_warm == len(_WARMERS):
        return
    _register_all()
    while _n_warm < len(_WARMERS):
        fn = _WARMERS[_n_warm]
        _n_warm += 1
        fn()


def warm_modules(names) -> None:
    """Compile (or load from the cache) the kernels whose example calls the modules ``names``
    of :data:`KERNEL_MODULES` registered -- a part of :func:`warm_up`, for compiling the parts
    in separate processes at once (``.ci/compile.py``)."""
    unknown = set(names) - set(KERNEL_MODULES)
    if unknown:
        raise ValueError(f"not modules of KERNEL_MODULES: {sorted(unknown)}")
    _register_all()
    for fn in _WARMERS:
        if fn.__module__ in names:
            fn()
