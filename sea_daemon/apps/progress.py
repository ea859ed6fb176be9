"""Progress of a command that runs longer than a few seconds, on stderr.

The long computations take a callback ``progress(done, total, what)`` (the calibration
pipeline, diagnose, the demo's and benchmarks' steps); they print nothing themselves (the
analysis layer does no I/O).  :class:`Progress` is the callback the commands pass:

* on a terminal, a tqdm bar (refreshed at most 4 times a second), removed when done;
* anywhere else (a file, a pipe, the journal), a plain line through the ``sea_daemon`` logger
  at INFO at most every ``interval`` seconds, the first after ``interval`` seconds (a command
  that ends sooner prints none), e.g. ``fit: 4/6 the active-torque random walk (35 s)``;
* nothing when that logger is above INFO (``-q``, ``--log-level warning``).
"""
from __future__ import annotations

import logging
import shutil
import sys
import time

from tqdm import tqdm

from sea_daemon.apps.console import LOGGER

log = logging.getLogger(LOGGER)


class Progress:
    """A progress callback ``progress(done, total=None, what="")`` for the command ``desc``."""

    def __init__(self, desc: str, total: float | None = None, unit: str = "step", interval: float = 5.0,
                 stream=None, enabled: bool | None = None, clock=time.monotonic):
        self.desc, self.total, self.unit, self.interval, self.clock = desc, total, unit, interval, clock
        self.enabled = log.isEnabledFor(logging.INFO) if enabled is None else enabled
        stream = stream if stream is not None else sys.stderr
        self.bar = None
        if self.enabled and _isatty(stream):
            # a terminal that reports a size of 0 x 0 would hide the bar (tqdm): fall back to 100 x 20
            size = shutil.get_terminal_size((100, 20))
            self.bar = tqdm(total=total, desc=desc, unit=unit, file=stream, mininterval=0.25, leave=False,
                            ncols=size.columns or 100, nrows=size.lines or 20)
        self.start = clock()
        self.next_line = self.start + interval
        self.lines = 0

    def __call__(self, done: float, total: float | None = None, what: str = "") -> None:
        if not self.enabled:
            return
        if total is not None:
            self.total = total
        if self.bar is not None:
            if self.bar.total != self.total:
                self.bar.total = self.total
            self.bar.set_postfix_str(what, refresh=False)
            self.bar.update(done - self.bar.n)
            return
        now = self.clock()
        if now < self.next_line:
            return
        self.next_line = now + self.interval
        self.lines += 1
        of = f"{done:g}/{self.total:g}" if self.total else f"{done:g}"
        log.info("%s: %s %s (%.0f s)", self.desc, of, what or self.unit, now - self.start)

    def part(self, offset: float, total: float, prefix: str = ""):
        """A callback for a part of the work: its ``(done, n, what)`` reported as ``offset + done``
        of ``total``, ``what`` after ``prefix``."""
        def report(done: float, _n: float | None = None, what: str = "") -> None:
            self(offset + done, total, prefix + what)
        return report

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
            self.bar = None

    def __enter__(self) -> "Progress":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _isatty(stream) -> bool:
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError, OSError):
        return False
