"""The analysis layer: what is computed from a measured log and a model, with no I/O.

Above the core (it imports only :mod:`sea_daemon.core` and :mod:`sea_daemon.errors`), below the
applications that read the logs and write the results:

* :mod:`.diagnose` — the diagnose engine: residuals of the model, candidate effects, their
  selection, the AKF's error before and after (docs/diagnose.md);
* :mod:`.noise` — the measurement and process noise of a log (docs/calibration.md);
* :mod:`.als` — autocovariance least squares: Q and R from the innovations of a filter.
"""
