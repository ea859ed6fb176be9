"""Files: what the project reads and writes, validated on the way in.

Configuration YAML (:mod:`.configfile`), measured-log CSV (:mod:`.logcsv`), model files
(:mod:`.modelfile`, :mod:`.gpmodel`) and simulator scenarios (:mod:`.scenario`).  Bad input is
an :class:`sea_daemon.errors.InputError` naming the file, the place and what was expected.
May import :mod:`sea_daemon.core` and :mod:`sea_daemon.errors`.
"""
