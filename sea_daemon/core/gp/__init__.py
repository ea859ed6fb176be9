"""Gaussian-process regression (Sec. III-B) and the locally growing random tree of GPs (LoG-GP).

:mod:`.exact` — the exact GP with an incremental Cholesky factor (the local model of every
leaf); :mod:`.gp_core` — its compiled numerics; :mod:`.hyper` — bounded online
hyperparameter steps; :mod:`.routing` — the compiled tree routing; :mod:`.loggp` — the LoG-GP
(public face: :mod:`sea_daemon.loggp`), saved and loaded by :mod:`.loggp_state`.
Part of :mod:`sea_daemon.core`: numpy/scipy/numba only.
"""
