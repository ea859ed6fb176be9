"""sea-daemon: GP-enhanced augmented-state Kalman filter for series elastic actuators.

The estimator core (``model``, ``estimators``, ``gp``, ``loggp``, ``bounds``) is pure:
no I/O, no clock, no threads.  The daemon, the replay tool and the benchmarks all call it.
"""
import os as _os

# The estimator works on tiny matrices (5n x 5n): a multi-threaded BLAS only adds
# synchronisation cost (measured: scipy expm of a 7x7 matrix 46 us single-threaded vs
# ~1 ms with OpenBLAS threads on a loaded 2-core machine).  Must be set before numpy is
# imported; an explicit user setting wins.
for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    _os.environ.setdefault(_v, "1")

__version__ = "0.1.0"
