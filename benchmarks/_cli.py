"""Command line of a research benchmark: ``python -m benchmarks.NAME [options]``.

Each benchmark module defines ``NAME``, ``HELP``, ``add_arguments(parser)`` and ``run(args)``; the
exit-status policy is the ``sea-daemon`` command line's (:func:`sea_daemon.apps.commands.guarded`).
"""
from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")   # tiny matrices: no BLAS threads (as the CLI)

from sea_daemon.apps.commands import Parser, guarded  # noqa: E402


def main(module, argv: list[str] | None = None) -> int:
    """Parse ``argv`` with the module's options and run it."""
    spec = getattr(module, "__spec__", None)
    name = (spec.name if spec is not None else module.__name__).rsplit(".", 1)[-1]
    parser = Parser(prog=f"python -m benchmarks.{name}", description=getattr(module, "DESCRIPTION", module.HELP))
    module.add_arguments(parser)
    args = parser.parse_args(argv)
    return guarded(parser.prog, module.run, args)
