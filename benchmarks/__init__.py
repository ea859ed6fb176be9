"""Research benchmarks (outside the installed package): accuracy, bounds, LoG-GP against
lgrt4gps, simulator speed, hardware-in-the-loop accuracy.  Run from the repository root, e.g.
``python -m benchmarks.accuracy --out DIR``.  Each prints what it measured, on what, with how many
runs.  May import everything in ``sea_daemon`` and ``sea_daemon.hw``; nothing imports them.
"""
