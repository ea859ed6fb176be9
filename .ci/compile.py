"""Compile sea-daemon's numba kernels into numba's cache: the warmers of the modules of
``sea_daemon.core.jit.KERNEL_MODULES`` whose index is ``PART`` modulo ``PARTS``.

``.ci/run`` runs the parts at once before the tests: a clean clone has no cache, and compiling
every kernel in one process takes about 100 s of one core; the tests then load the cache.
Usage: ``python .ci/compile.py PART PARTS``.
"""
import sys

from sea_daemon.core import jit

part, parts = int(sys.argv[1]), int(sys.argv[2])
jit.warm_modules({name for i, name in enumerate(jit.KERNEL_MODULES) if i % parts == part})
