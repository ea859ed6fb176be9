"""Test-session setup.

Single-threaded BLAS before numpy is first imported (the same default as the console script,
``sea_daemon/apps/cli.py``): the estimator's matrices are tiny and a threaded OpenBLAS on a
shared 2-core machine makes each expm ~20x slower.
"""
import os

for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")
