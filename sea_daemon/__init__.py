"""sea-daemon: real-time estimation of the torque a human actively applies to a series-elastic
actuator exoskeleton, with a guaranteed error bound (the GP-AKF of Tesfazgi, Keßler et al.).

The package is layered; each layer imports only the layers below it (checked in CI by the
import contract in ``.importlinter``):

* :mod:`sea_daemon.core` — model and effects, kinematics, GP and LoG-GP, estimators, bounds,
  the simulated plant: numpy/scipy/numba only, no I/O, no clock, no threads;
* :mod:`sea_daemon.io` — configuration files, measured logs, model files, scenarios;
* :mod:`sea_daemon.hw` — the hardware behind one narrow interface: simulated and CANopen;
* :mod:`sea_daemon.runtime` — the fixed-rate loop, the fault policy, the log writer, the service;
* :mod:`sea_daemon.apps` — the ``sea-daemon`` command line: calibration, run, replay, diagnose,
  the benchmarks a user runs on the target machine.

:mod:`sea_daemon.errors` (the one exception hierarchy and the fault codes) sits below all of them.
``docs/architecture.md`` has the picture.  :mod:`sea_daemon.data` holds the package data: the
example configurations and scenarios, the CANopen EDS files and the systemd unit.
"""

__version__ = "0.1.0"
