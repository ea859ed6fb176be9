"""``sea-daemon bench NAME``: benchmarks (see :mod:`sea_daemon.apps.bench`)."""
from __future__ import annotations

import importlib
import pkgutil

from sea_daemon.apps import bench as _bench

NAME = "bench"
HELP = "run a benchmark (accuracy, latency, bounds, ...) and print what it measured"
ORDER = 90


def _modules():
    out = {}
    for info in pkgutil.iter_modules(_bench.__path__):
        if info.name.startswith("_"):
            continue
        mod = importlib.import_module(f"{_bench.__name__}.{info.name}")
        if hasattr(mod, "NAME") and hasattr(mod, "run"):
            out[mod.NAME] = mod
    return out


def add_arguments(p):
    sub = p.add_subparsers(dest="bench", metavar="NAME", parser_class=type(p))
    for name, mod in sorted(_modules().items()):
        sp = sub.add_parser(name, help=mod.HELP, description=getattr(mod, "DESCRIPTION", mod.HELP))
        mod.add_arguments(sp)
        sp.set_defaults(_bench_run=mod.run)


def run(args) -> int:
    if not getattr(args, "_bench_run", None):
        names = ", ".join(sorted(_modules())) or "none yet"
        print(f"sea-daemon bench: name a benchmark: {names}")
        return 2
    return int(args._bench_run(args) or 0)
