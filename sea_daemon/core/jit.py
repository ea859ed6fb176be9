"""Compilation of the hot numerics with numba (the filter step of the 1 kHz loop).

:func:`njit` is ``numba.njit(cache=True)``: the machine code is cached next to the source
(``__pycache__``) or, if that is not writable, in numba's user-wide cache directory
(``NUMBA_CACHE_DIR`` overrides both).  When no cache directory is writable at all the
function is compiled in memory instead (numba raises ``RuntimeError`` at decoration then);
the code runs the same, only each new process compiles again.

A kernel's machine code includes the kernels it calls from other modules (e.g. the bound's
``bound_core`` compiles ``gp.pack.gp_points`` into itself), so its cache is valid only while
every one of those sources is unchanged.  numba alone checks the function's own file; here the
cache's source stamp is that file's *and* a SHA-256 over the sources of every module of
:data:`KERNEL_MODULES` and of this module: a change to any of them (an edit, an upgrade of the
package) makes every cached kernel stale, so each is compiled again on first use and its
cache rewritten.  The digest is taken once per process, from the files as they are when the
first kernel is decorated.

Compilation is lazy (first call); :func:`warm_up` is the one place that triggers it ahead of
use: it imports every module of :data:`KERNEL_MODULES` and runs each module's example calls
(registered with :func:`warmer`: the kernels with the argument types the estimators pass)
once.  The estimators call it at construction and the runtime before it starts the hardware,
so a daemon is compiled (or has loaded its cache) before it reports READY, never in a loop
cycle.  Numba uses no threads here (no ``parallel=True``).
"""
from __future__ import annotations

import hashlib
import importlib
import os
from typing import Callable

import numba
from numba.core import caching

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
    "sea_daemon.core.sim.endstops",
    "sea_daemon.core.sim.plant",
)

_WARMERS: list[Callable[[], None]] = []
_n_warm = 0          # warmers already run


#: LLVM may reassociate sums and contract a·b + c into one FMA: lets the O(N²)/O(N³) reductions
#: of the GP kernels vectorise (a serial sum is bound by the add latency, ~4× slower).  No
#: 'nnan'/'ninf': NaN and inf checks keep working.  Deterministic for given compiled code.
FAST = frozenset({"reassoc", "contract"})


_digest: dict[tuple[str, ...], str] = {}     # KERNEL_MODULES -> digest of their sources


def sources_digest() -> str:
    """SHA-256 (hex) over the sources of this module and of every module of
    :data:`KERNEL_MODULES` (by path under the package; a missing file counts as missing),
    taken once per process."""
    names = tuple(KERNEL_MODULES)
    if names not in _digest:
        # the directory holding sea_daemon/
        root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
        h = hashlib.sha256(_read(__file__))
        for name in names:
            h.update(name.encode() + b"\0")
            h.update(_read(os.path.join(root, *name.split(".")) + ".py"))
        _digest[names] = h.hexdigest()
    return _digest[names]


def _read(path: str) -> bytes:
    try:
        with open(path, "rb") as f:
            return f.read()
    except OSError:
        return b"<missing>"


class _SourcesStamp:
    """A numba cache locator's source stamp extended by :func:`sources_digest`: an index
    written under other kernel sources no longer matches, so numba compiles again."""

    def get_source_stamp(self):
        return (super().get_source_stamp(), sources_digest())


def _locator(name: str) -> type:
    """numba's cache locator ``name`` (numba before 0.61 spells it with a leading underscore)."""
    return getattr(caching, name, None) or getattr(caching, "_" + name)


class _UserProvided(_SourcesStamp, _locator("UserProvidedCacheLocator")):
    pass


class _InTree(_SourcesStamp, _locator("InTreeCacheLocator")):
    pass


class _UserWide(_SourcesStamp, _locator("UserWideCacheLocator")):
    pass


class _KernelCacheImpl(caching.CompileResultCacheImpl):
    _locator_classes = [_UserProvided, _InTree, _UserWide]


class _KernelCache(caching.FunctionCache):
    """numba's per-function cache with the stamp of :class:`_SourcesStamp`."""
    _impl_class = _KernelCacheImpl


def njit(fn: Callable | None = None, *, fast: bool = False) -> Callable:
    """``numba.njit(cache=True)`` (``fast``: with the :data:`FAST` math flags) with the cache
    keyed on every kernel module's source (see the module docstring); in-memory compilation
    when no cache directory is writable."""
    def wrap(f: Callable) -> Callable:
        opts = {"fastmath": set(FAST)} if fast else {}
        dispatcher = numba.njit(**opts)(f)
        try:
            # what numba.njit(cache=True) does (Dispatcher.enable_caching), with this stamp
            dispatcher._cache = _KernelCache(f)
        except RuntimeError:          # "cannot cache function ...: no locator available"
            pass                      # numba's NullCache: compiled in memory
        return dispatcher
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
