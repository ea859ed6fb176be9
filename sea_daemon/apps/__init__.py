"""The applications: the ``sea-daemon`` command line and what its commands compose.

:mod:`.cli` and :mod:`.commands` (one module per command), :mod:`.diagnose` (closing the loop
on measured data) and :mod:`.bench` (the benchmarks a user runs on the target machine).  May
import every layer below: :mod:`sea_daemon.runtime`, ``sea_daemon.hw``, :mod:`sea_daemon.io`,
:mod:`sea_daemon.core`, :mod:`sea_daemon.errors`.
"""
