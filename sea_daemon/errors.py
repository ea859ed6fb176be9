"""One exception hierarchy for the whole project (python-can style).

Every message names the offending value and, where there is one, the allowed range, so
that the CLI can print it as the single line a user sees (exit status 2 for
:class:`InputError`, 1 for anything else).
"""
from __future__ import annotations

import enum


def shown(value, limit: int = 120) -> str:
    """``value`` as one printable line of at most ``limit`` characters: bytes that are not UTF-8
    (e.g. in a path) escaped, line breaks escaped, long text cut with "…"."""
    text = value if isinstance(value, str) else str(value)
    try:        # a path's bytes that are not UTF-8 come as surrogate escapes: show the bytes
        text = text.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")
    except UnicodeEncodeError:
        text = text.encode("utf-8", "backslashreplace").decode("utf-8", "replace")
    text = text.replace("\n", "\\n").replace("\r", "\\r")
    return text if len(text) <= limit else text[:limit - 1] + "…"


class Fault(enum.IntEnum):
    """The fault codes of the daemon's single fault policy (:mod:`sea_daemon.runtime.safety`):
    every exception of the hierarchy below carries one as ``.fault``; the log's ``fault`` column
    and the published frames hold the code latched (docs/interfaces.md §1, §6)."""

    NONE = 0
    TPDO_MISSING = 1
    HEARTBEAT_LOST = 2
    EMCY = 3
    ENCODER_JUMP = 4
    ENCODER_STUCK = 5
    BUS_OFF = 6
    SEND_FAILED = 7
    ESTIMATOR_NONFINITE = 8
    COVARIANCE_NOT_PD = 9
    NIS_DIVERGENCE = 10
    OVERRUN_STREAK = 11
    DEVICE_FAULT = 12          # drive reports CiA 402 fault state
    INTERNAL = 13              # an unexpected exception in the loop
    LOG_FAILED = 14            # the measured log cannot be written (disk full, writer died, ring full)
    INNOVATION_OUTLIER = 15    # assist mode: one step's normalised innovation beyond assist.innovation_max
    BOUND_LOST = 16            # the bound worker died, or fell a whole ring of samples behind
    LOOP_STALL = 17            # the loop itself missed more cycles in a row than the missed-cycle tolerance allows

    @property
    def bit(self) -> int:
        """This code's bit in a set of codes seen in one cycle
        (:attr:`sea_daemon.hw.interface.Measurement.faults`): ``1 << code``."""
        return 1 << self.value


class SeaDaemonError(Exception):
    """Base class of every error raised on purpose by sea-daemon.

    ``fault``: the :class:`Fault` it stands for when it stops the fixed-rate loop (a class
    attribute; :class:`EstimatorFault` also takes it as a constructor field)."""

    fault: Fault = Fault.INTERNAL


class InputError(SeaDaemonError):
    """Bad input from a user: a file, a flag, a config value.  CLI exit status 2."""


class ConfigError(InputError):
    """A YAML configuration is malformed; the message names the key and allowed values."""

    def __init__(self, source: str, key: str, problem: str):
        self.source, self.key, self.problem = shown(source), shown(key, 80), shown(problem, 300)
        super().__init__(f"{self.source}: {self.key}: {self.problem}")


class LogFormatError(InputError):
    """A measured-log CSV is malformed; the message names the file and the line."""

    def __init__(self, path: str, line: int | None, problem: str):
        self.path, self.line, self.problem = shown(path), line, shown(problem, 300)
        where = f"{self.path}:{line}" if line is not None else self.path
        super().__init__(f"{where}: {self.problem}")


class ModelFileError(InputError):
    """A saved model file is corrupt, from an incompatible version, or unreadable."""


class EstimatorFault(SeaDaemonError):
    """The estimator lost numerical health (NaN/inf, covariance not positive definite).

    ``fault``: the code (default :attr:`Fault.ESTIMATOR_NONFINITE`, a subclass's own otherwise),
    e.g. ``EstimatorFault(msg, fault=Fault.COVARIANCE_NOT_PD)``; a wrapping fault passes on the
    wrapped one's."""

    fault: Fault = Fault.ESTIMATOR_NONFINITE

    def __init__(self, *args, fault: Fault | None = None):
        super().__init__(*args)
        if fault is not None:
            self.fault = Fault(fault)


class HardwareError(SeaDaemonError):
    """Base of faults raised by the hardware layer (``sea_daemon.hw``); each class carries its
    own ``fault`` (:mod:`sea_daemon.hw.errors`), a device fault by default."""

    fault: Fault = Fault.DEVICE_FAULT


class RunFault(SeaDaemonError):
    """A daemon run stopped with a fault latched (bus timeout, lost heartbeat, ...): the system
    did what its safety policy says, the job could not finish.  CLI exit status 1, one line."""


def fault_of(exc: BaseException) -> Fault:
    """The fault an exception raised in a cycle stands for: its ``fault`` for an exception of
    this hierarchy, :attr:`Fault.INTERNAL` for anything else (an unexpected exception)."""
    return exc.fault if isinstance(exc, SeaDaemonError) else Fault.INTERNAL
