"""CLI sub-commands, one module each (discovered by :mod:`sea_daemon.cli`)."""
