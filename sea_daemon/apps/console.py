"""What the command line says on stderr: the ``sea_daemon`` logger, with levels.

Every command reports through ``logging.getLogger("sea_daemon")`` (or a child of it, e.g.
``sea_daemon.run``); :func:`setup` gives that logger one handler on stderr at the level the
command line asks for (``--log-level``, ``-v``, ``-q``; INFO by default):

* an INFO or DEBUG message is written as it is (what a command reports while it works);
* a WARNING or ERROR message as ``sea-daemon CMD: warning: …`` / ``… error: …``;
* when stderr is the systemd journal (``JOURNAL_STREAM`` names stderr's device and inode, as
  systemd sets it for a service's output), every line starts with its syslog priority
  (``<4>`` warning, ``<6>`` info, … as sd-daemon(3)'s ``SD_WARNING``): journald stores the level
  and ``journalctl -p warning`` filters on it.

The exit-2 refusal of bad input stays one line of its own (:func:`say`), with the error
priority in the journal.  Standard library only: the CLI loads this before any command.
"""
from __future__ import annotations

import logging
import os
import sys

#: the project's logger; commands use it or a child of it
LOGGER = "sea_daemon"
#: syslog priorities of the logging levels (sd-daemon(3): SD_ERR "<3>", SD_WARNING "<4>", ...)
PRIORITY = {logging.CRITICAL: 2, logging.ERROR: 3, logging.WARNING: 4, logging.INFO: 6, logging.DEBUG: 7}
#: the names --log-level takes
LEVELS = ("debug", "info", "warning", "error")


def journal_stream(stream=None) -> bool:
    """True when ``stream`` (stderr) is connected to the systemd journal: ``JOURNAL_STREAM``
    (``DEVICE:INODE``, set by systemd for a service's stdout/stderr) names its file."""
    value = os.environ.get("JOURNAL_STREAM", "")
    try:
        dev, ino = (int(x) for x in value.split(":"))
        st = os.fstat((stream or sys.stderr).fileno())
    except (ValueError, OSError, AttributeError):
        return False
    return st.st_dev == dev and st.st_ino == ino


def priority(levelno: int) -> int:
    """The syslog priority of a logging level (between the named ones: the next more severe)."""
    for lvl in sorted(PRIORITY):
        if levelno <= lvl:
            return PRIORITY[lvl]
    return PRIORITY[logging.CRITICAL]


def journal_lines(text: str, levelno: int) -> str:
    """``text`` with the priority prefix on each of its lines."""
    p = f"<{priority(levelno)}>"
    return "\n".join(p + line for line in text.split("\n"))


class Formatter(logging.Formatter):
    """INFO/DEBUG as they are, WARNING+ as ``PROG: warning: …``; the journal's priority prefix
    on every line when ``journal``."""

    def __init__(self, prog: str, journal: bool):
        super().__init__()
        self.prog, self.journal = prog, journal

    def format(self, record: logging.LogRecord) -> str:
        text = record.getMessage()
        if record.exc_info:
            text += "\n" + self.formatException(record.exc_info)
        if record.levelno >= logging.WARNING:
            text = f"{self.prog}: {record.levelname.lower()}: {text}"
        return journal_lines(text, record.levelno) if self.journal else text


class StderrHandler(logging.StreamHandler):
    """A handler on whatever ``sys.stderr`` is when a record is written (a test's capture, a
    redirected stream); a closed stderr is no error."""

    def __init__(self):
        super().__init__(sys.stderr)

    @property
    def stream(self):
        return sys.stderr

    @stream.setter
    def stream(self, value):      # set by StreamHandler.__init__: always sys.stderr
        pass

    def handleError(self, record):  # a closed or broken stderr: the message is lost, not the command
        pass


def level_of(name: str | None, verbose: int = 0, quiet: int = 0) -> int | None:
    """The level of ``--log-level NAME`` (wins), else DEBUG for ``-v``, WARNING for ``-q``, ERROR
    for ``-qq``; None when none was given."""
    if name:
        return getattr(logging, name.upper())
    if verbose:
        return logging.DEBUG
    if quiet:
        return logging.WARNING if quiet == 1 else logging.ERROR
    return None


def current() -> tuple[str, int] | None:
    """(prog, level) of the handler :func:`setup` gave the logger, None before."""
    log = logging.getLogger(LOGGER)
    for h in log.handlers:
        if isinstance(h, StderrHandler):
            return h.formatter.prog, log.level
    return None


def setup(prog: str = "sea-daemon", level: int | None = None) -> logging.Logger:
    """The ``sea_daemon`` logger on stderr at ``level`` for the command ``prog`` (replaces the
    handler an earlier call gave it; messages do not propagate to the root logger).  ``level``
    None: the earlier call's (a command run by another one, e.g. the demo's steps), else INFO."""
    log = logging.getLogger(LOGGER)
    before = current()
    if level is None:
        level = before[1] if before else logging.INFO
    for h in list(log.handlers):
        if isinstance(h, StderrHandler):
            log.removeHandler(h)
    h = StderrHandler()
    h.setFormatter(Formatter(prog, journal_stream()))
    log.addHandler(h)
    log.setLevel(level)
    log.propagate = False
    return log


def say(line: str) -> None:
    """One line on stderr as it is (the error priority prefixed in the journal); a closed
    stderr is no error."""
    try:
        text = journal_lines(line, logging.ERROR) if journal_stream() else line
        print(text, file=sys.stderr, flush=True)
    except (OSError, ValueError, AttributeError):
        pass
