"""The estimator core: pure numerics, the same code for the daemon, replay and the benchmarks.

Owns the SEA model and its effects (:mod:`.model`, :mod:`.effects`), the rigid-body dynamics
of a URDF (:mod:`.rigid`, Pinocchio), the configuration
dataclasses (:mod:`.config`), kinematics from encoder angles (:mod:`.kinematics`), the GP and
LoG-GP (:mod:`.gp`) and the learned residual (:mod:`.learning`), the estimators
(:mod:`.estimators`), the Theorem-1 bounds (:mod:`.bounds`), noise identification
(:mod:`.als`), the simulated true plant (:mod:`.sim`) and the controllers' arithmetic
(:mod:`.control`).  May import numpy, scipy, numba, pinocchio and :mod:`sea_daemon.errors` only: no file
or bus I/O, no clock, no threads.
"""
