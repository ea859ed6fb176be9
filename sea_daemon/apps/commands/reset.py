"""``sea-daemon reset [--log-dir DIR | --state-dir DIR]``: clear a latched fault (operator action).

Sends SIGUSR1 to the ``sea-daemon run`` / ``calibrate`` that holds the directory: only to a
process proven to be that daemon — the directory's lock (``sea-daemon.lock``) is held, the pid
of ``sea-daemon.pid`` has the start time recorded there, and that process has the lock file
open; the signal goes through a pidfd opened before the checks.  The loop clears the fault at
the start of its next cycle, re-arms the drives (``reset_fault``) and restarts the estimator
(docs/safety.md).  Exit 2 with one line when no daemon runs there or it cannot be proven.
"""
from __future__ import annotations

import signal

from sea_daemon.runtime.service import StateFile

DESCRIPTION = __doc__


def add_arguments(p) -> None:
    g = p.add_mutually_exclusive_group()
    g.add_argument("--state-dir", metavar="DIR", default=None, help="the daemon's --state-dir")
    g.add_argument("--log-dir", metavar="DIR", default=None,
                   help="the daemon's --log-dir (where its pid file is without --state-dir)")


def run(args) -> int:
    d = args.state_dir or args.log_dir or "/var/log/sea-daemon"
    pid = StateFile(d).signal(signal.SIGUSR1)
    print(f"sent reset (SIGUSR1) to sea-daemon pid {pid}")
    return 0
