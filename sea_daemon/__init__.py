"""sea-daemon: GP-enhanced augmented-state Kalman filter for series elastic actuators.

The estimator core (``model``, ``estimators``, ``gp``, ``loggp``, ``bounds``) is pure:
no I/O, no clock, no threads.  The daemon, the replay tool and the benchmarks all call it.
"""
__version__ = "0.1.0"
