"""The ``sea-daemon`` sub-commands, one module each, and the machinery that runs them.

:data:`COMMANDS` names them (name, module, one line of help) in the order ``sea-daemon --help``
lists them.  A command module defines ``add_arguments(parser)`` and ``run(args) -> int``
(optional ``DESCRIPTION``, the text of ``sea-daemon NAME --help``, often the module's
docstring: :func:`plain` turns its reStructuredText markup into plain text for the help).  Only
the chosen command's module is imported (:class:`CommandParser`): ``sea-daemon --help`` and a
light command start without the estimator's libraries.  Every command takes ``--log-level``,
``-v`` and ``-q`` (:mod:`sea_daemon.apps.console`: the ``sea_daemon`` logger on stderr).
Exit status (the :func:`guarded` policy): 0 success, 2 bad input or configuration (one line on
stderr, no traceback), 1 internal fault.  ``SEA_DAEMON_DEBUG=1`` shows tracebacks.
"""
from __future__ import annotations

import argparse
import importlib
import logging
import os
import re
import sys
import textwrap
from typing import NamedTuple

from sea_daemon import __version__
from sea_daemon.apps import console
from sea_daemon.errors import EstimatorFault, InputError, SeaDaemonError, shown

#: ``:role:`target``` of reStructuredText (``~`` shows the last part of a dotted name)
_ROLE = re.compile(r":[a-z]+:`(~?)([^`]+)`")
_LITERAL = re.compile(r"``(.+?)``", re.S)
_ITEM = re.compile(r"(?:(?:[*-]|\d+\.) )?")
_STRONG = re.compile(r"\*\*(.+?)\*\*", re.S)


def plain(text: str | None) -> str | None:
    """``text`` (a docstring) as plain text: ``code`` → code, :mod:`a.b` → a.b, :func:`~a.f` → f,
    **strong** → strong, a literal block's ``::`` → ``:``."""
    if not text:
        return text
    text = _ROLE.sub(lambda m: m.group(2).rsplit(".", 1)[-1] if m.group(1) else m.group(2), text)
    text = _LITERAL.sub(r"\1", text)
    text = _STRONG.sub(r"\1", text)
    return re.sub(r"::$", ":", text, flags=re.M)


class HelpFormatter(argparse.HelpFormatter):
    """argparse's formatter keeping a description's paragraphs, bullets and indented blocks."""

    def _fill_text(self, text, width, indent):
        paras = []
        for para in textwrap.dedent(text).strip().split("\n\n"):
            if para.startswith(" "):                      # an indented block (an example): as it is
                paras.append(textwrap.indent(para, indent))
                continue
            # list items (* , - , 1. ): each wrapped with a hanging indent
            items = re.split(r"\n(?=(?:[*-]|\d+\.) )", para)
            paras.append("\n".join(
                textwrap.fill(" ".join(item.split()), width, initial_indent=indent, break_on_hyphens=False,
                              break_long_words=False,
                              subsequent_indent=indent + " " * len(_ITEM.match(item).group(0)))
                for item in items))
        return "\n\n".join(paras)


class VersionAction(argparse.Action):
    """``--version``: ``sea-daemon X.Y.Z`` from the installed package's metadata."""

    def __init__(self, option_strings, dest=argparse.SUPPRESS, default=argparse.SUPPRESS, help=None):
        super().__init__(option_strings, dest=dest, default=default, nargs=0, help=help)

    def __call__(self, parser, namespace, values, option_string=None):
        print(f"sea-daemon {package_version()}")
        parser.exit()


def package_version() -> str:
    """The version of the installed distribution ``sea-daemon`` (a checkout that is not
    installed: the package's ``__version__``)."""
    from importlib.metadata import PackageNotFoundError, version
    try:
        return version("sea-daemon")
    except PackageNotFoundError:
        return __version__


class Parser(argparse.ArgumentParser):
    """argparse with the CLI's error policy (one clear line on stderr, exit status 2) and
    plain-text help."""

    def __init__(self, *args, **kwargs):
        kwargs.setdefault("formatter_class", HelpFormatter)
        super().__init__(*args, **kwargs)

    def error(self, message):  # one clear line, exit 2
        _say(f"{self.prog}: error: {message}")
        raise SystemExit(2)


def add_output_options(p) -> None:
    """``--log-level``, ``-v`` and ``-q`` (defaults suppressed, so that a sub-command's parser
    does not undo what the main parser read)."""
    g = p.add_argument_group("messages")
    g.add_argument("--log-level", choices=console.LEVELS, default=argparse.SUPPRESS,
                   help="the least severe messages shown on stderr (default info)")
    g.add_argument("-v", "--verbose", action="count", default=argparse.SUPPRESS, help="debug messages too")
    g.add_argument("-q", "--quiet", action="count", default=argparse.SUPPRESS,
                   help="warnings and errors only, no progress (-qq: errors only)")


class Command(NamedTuple):
    """A sub-command: its name on the command line, the module that implements it (in the
    package ``COMMANDS`` belongs to) and its line in the list of commands."""
    name: str
    module: str
    help: str


#: the commands of ``sea-daemon``, in the order ``sea-daemon --help`` lists them
COMMANDS = (
    Command("demo", "demo",
            "device model + daemon on a virtual CAN bus: calibration, estimation, RMSE table and plots"),
    Command("simulate", "simulate",
            "offline physics simulation of a scenario to measured logs (training + estimation phase)"),
    Command("replay", "replay",
            "run an estimator (gp-akf, akf, spring) over a measured log; EST.csv + JSON summary"),
    Command("diagnose", "diagnose",
            "find effects the model lacks in a measured log; write diagnosis.json, model_augmented.yaml, report.md"),
    Command("calibrate", "calibrate",
            "training phase on the bus: PID moves, GP learned online, model file + measured log"),
    Command("fit", "fit",
            "calibrate from a passive log offline: noise, physical effects, residual GP -> complete model"),
    Command("identify-noise", "identify_noise",
            "identify the measurement noise R (and Q) from a log by autocovariance least squares"),
    Command("run", "run",
            "estimation service on the CAN bus (GP-AKF from a calibrated model; systemd notify)"),
    Command("calibrate-bound", "calibrate_bound",
            "split-conformal beta of the GP error bound from a held-out passive log (estimator.gp_beta)"),
    Command("watch", "watch",
            "live view of the published estimate, its bound, validity and faults (terminal)"),
    Command("reset", "reset", "clear a latched fault of the running daemon (SIGUSR1)"),
    Command("device-model", "device_model",
            "run the simulated drive + load encoder as CANopen slaves on a CAN bus (HIL tests, demo)"),
    Command("bench", "bench", "run a benchmark (accuracy, latency, bounds, ...) and print what it measured"),
)


class CommandParser(Parser):
    """The parser of one sub-command, its module imported only when the command is chosen.

    ``module`` (a dotted name) defines ``add_arguments(parser)``, ``run(args)`` and optionally
    ``DESCRIPTION``; when the command line names this command, the module is imported, its
    arguments are added and ``func`` is set to its ``run`` before parsing."""

    def __init__(self, *args, module: str | None = None, **kwargs):
        super().__init__(*args, **kwargs)
        self.module = module

    def parse_known_args(self, args=None, namespace=None):
        if self.module is not None:
            mod = importlib.import_module(self.module)
            self.module = None
            self.description = plain(getattr(mod, "DESCRIPTION", self.description))
            mod.add_arguments(self)
            add_output_options(self)
            self.set_defaults(func=mod.run)
        return super().parse_known_args(args, namespace)


def add_commands(parser, commands, package: str, dest: str, metavar: str) -> None:
    """Sub-commands ``commands`` (:class:`Command`, modules in ``package``) of ``parser``; the
    chosen one's name goes to ``args.<dest>``, its ``run`` to ``args.func``."""
    sub = parser.add_subparsers(dest=dest, metavar=metavar, parser_class=CommandParser)
    for c in commands:
        sub.add_parser(c.name, help=c.help, description=c.help, module=f"{package}.{c.module}")


def add_log_and_config(p, log_help: str = "measured log") -> None:
    """The LOG.csv positional and --config MODEL.yaml of the commands that work on a log."""
    p.add_argument("log", metavar="LOG.csv", help=f"{log_help} (docs/interfaces.md §1)")
    p.add_argument("--config", metavar="MODEL.yaml", required=True, help="model configuration (docs/interfaces.md §2)")


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(prog="sea-daemon", description="Active human torque estimation for SEA exoskeletons "
                     "(GP-enhanced augmented-state Kalman filter with guaranteed bounds).")
    parser.add_argument("--version", action=VersionAction, help="print the version and exit")
    add_output_options(parser)
    add_commands(parser, COMMANDS, __name__, dest="command", metavar="COMMAND")
    return parser


#: the commands running in this process, outermost first (the demo runs others through main)
_RUNNING: list[str] = []


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help(sys.stderr)
        return 2
    level = console.level_of(getattr(args, "log_level", None), getattr(args, "verbose", 0), getattr(args, "quiet", 0))
    # a command run by another one (the demo's steps) keeps the caller's level; a command of its own INFO
    before = console.current() if _RUNNING else None
    console.setup(f"sea-daemon {args.command}", level if level is not None or _RUNNING else logging.INFO)
    _RUNNING.append(args.command)
    try:
        return guarded(f"sea-daemon {args.command}", args.func, args)
    finally:
        _RUNNING.pop()
        if before is not None:
            console.setup(*before)


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
    console.say(shown(line, 2000))
