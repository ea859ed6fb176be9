"""The ``sea-daemon`` sub-commands, one module each, and the machinery that runs them.

A command module defines ``NAME``, ``HELP``, ``add_arguments(parser)`` and ``run(args) -> int``
(optional ``ORDER``, ``DESCRIPTION``); :func:`main` finds them by discovery.  Exit status (the
:func:`guarded` policy): 0 success, 2 bad input or configuration (one line on stderr, no
traceback), 1 internal fault.  ``SEA_DAEMON_DEBUG=1`` shows tracebacks.
"""
from __future__ import annotations

import argparse
import importlib
import os
import pkgutil
import sys

from sea_daemon import __version__
from sea_daemon.errors import EstimatorFault, InputError, SeaDaemonError, shown


class Parser(argparse.ArgumentParser):
    """argparse with the CLI's error policy: one clear line on stderr, exit status 2."""

    def error(self, message):  # one clear line, exit 2
        _say(f"{self.prog}: error: {message}")
        raise SystemExit(2)


def _discover():
    mods = []
    for info in pkgutil.iter_modules(__path__):
        if info.name.startswith("_"):
            continue
        mod = importlib.import_module(f"{__name__}.{info.name}")
        if hasattr(mod, "NAME") and hasattr(mod, "run"):
            mods.append(mod)
    return sorted(mods, key=lambda m: getattr(m, "ORDER", 50))


def add_log_and_config(p, log_help: str = "measured log") -> None:
    """The LOG.csv positional and --config MODEL.yaml of the commands that work on a log."""
    p.add_argument("log", metavar="LOG.csv", help=f"{log_help} (docs/interfaces.md §1)")
    p.add_argument("--config", metavar="MODEL.yaml", required=True, help="model configuration (docs/interfaces.md §2)")


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(prog="sea-daemon", description="Active human torque estimation for SEA exoskeletons "
                     "(GP-enhanced augmented-state Kalman filter with guaranteed bounds).")
    parser.add_argument("--version", action="version", version=f"sea-daemon {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=Parser)
    for mod in _discover():
        p = sub.add_parser(mod.NAME, help=mod.HELP, description=getattr(mod, "DESCRIPTION", mod.HELP))
        mod.add_arguments(p)
        p.set_defaults(_run=mod.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "_run", None):
        parser.print_help(sys.stderr)
        return 2
    return guarded(f"sea-daemon {args.command}", args._run, args)


def guarded(prog: str, run, args) -> int:
    """``run(args)`` under the exit-status policy: 0 success, 2 bad input (one line on stderr,
    no traceback), 130 interrupted, 1 a typed fault of the system (e.g. a run that stopped on a
    latched fault) or an internal fault (one line; SEA_DAEMON_DEBUG=1 re-raises).

    An estimator fault that reaches here (a filter diverging on a log in replay, identify-noise,
    diagnose, ...) is bad input too: the log does not fit the model or its settings.  The service
    commands latch estimator faults in their loop instead (docs/safety.md)."""
    debug = os.environ.get("SEA_DAEMON_DEBUG") == "1"
    try:
        return int(run(args) or 0)
    except InputError as e:
        if debug:
            raise
        _say(f"{prog}: error: {e}")
        return 2
    except EstimatorFault as e:
        if debug:
            raise
        _say(f"{prog}: error: estimator fault ({type(e).__name__}): {e}")
        return 2
    except SeaDaemonError as e:     # a typed fault of the system (not the user's input): exit 1
        if debug:
            raise
        _say(f"{prog}: error: {type(e).__name__}: {e}")
        return 1
    except KeyboardInterrupt:
        _say(f"{prog}: interrupted")
        return 130
    except Exception as e:  # internal fault: one line, details with SEA_DAEMON_DEBUG=1
        if debug:
            raise
        _say(f"{prog}: internal error: {type(e).__name__}: {shown(e, 500)} (set SEA_DAEMON_DEBUG=1 for a traceback)")
        return 1


def _say(line: str) -> None:
    """One line on stderr, printable whatever bytes a path held; a closed stderr is no error."""
    try:
        print(shown(line, 2000), file=sys.stderr, flush=True)
    except (OSError, ValueError, AttributeError):
        pass
