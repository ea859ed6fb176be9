"""The ``sea-daemon`` console script (docs/interfaces.md, "Command line").

The commands and their exit-status policy are :mod:`sea_daemon.apps.commands`; this module is
only the program's entry point.
"""
from __future__ import annotations

import os
import sys

# The estimator works on tiny matrices (5n x 5n): a multi-threaded BLAS only adds
# synchronisation cost.  Set before numpy is first imported (the command modules import it);
# an explicit user setting wins.
for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

from sea_daemon.apps.commands import main  # noqa: E402

__all__ = ["main"]

if __name__ == "__main__":
    sys.exit(main())
