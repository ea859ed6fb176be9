"""Measured log CSV (docs/interfaces.md §1): read with validation, write.

The in-memory log is :class:`sea_daemon.core.log.MeasuredLog`.

Columns (joint side, SI; their names defined once in :mod:`sea_daemon.core.log`): ``t, q,
theta_m, tau_m`` required, ``tau_h_act`` optional; with n > 1 joints every per-joint column
carries a 1-based suffix (``q_1 … q_n``).  Other columns are kept in :attr:`MeasuredLog.extra`
and otherwise ignored.  :func:`csv_header` / :func:`csv_rows` are the project's one CSV format,
used by :func:`write_columns` and by the daemon's log writer.

A bad file raises :class:`~sea_daemon.errors.LogFormatError` naming the file, the line and
the problem (the CLI turns it into exit status 2 and one line).
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Mapping

import numpy as np

from sea_daemon.core.log import REQUIRED, MeasuredLog, column_names
from sea_daemon.errors import LogFormatError
from sea_daemon.io.files import atomic_file


#: angle columns checked for units by range (joint side, rad)
ANGLE_COLUMNS = ("q", "theta_m")
ANGLE_LIMIT = 2 * math.pi
#: torque columns bounded by what any actuator gives [N m]: larger values are a unit error
TORQUE_COLUMNS = ("tau_m", "tau_h_act")
TORQUE_LIMIT = 1e6
#: the longest line [bytes] and the longest number [characters] of a log
MAX_LINE_BYTES = 1 << 16
MAX_FIELD_CHARS = 40
#: rows parsed into one float64 block before the next is started
_BLOCK_ROWS = 1 << 14


def _number(cell: str) -> float | None:
    """A decimal number (``-1.5``, ``2e-3``, ``.5``), or None: no underscores (``1_0``), no
    non-ASCII digits, no hex; NaN and inf are refused by the caller."""
    c = cell.strip()
    if not c or len(c) > MAX_FIELD_CHARS or not c.isascii() or "_" in c:
        return None
    try:
        return float(c)
    except ValueError:
        return None


def _lines(p: str):
    """(line number, text) of the file, each line at most :data:`MAX_LINE_BYTES`, UTF-8 (a
    byte-order mark at the start is dropped)."""
    try:
        fh = open(p, "rb")
    except OSError as e:
        raise LogFormatError(p, None, f"cannot read: {e.strerror or e}") from None
    with fh:
        lineno = 0
        while True:
            try:
                raw = fh.readline(MAX_LINE_BYTES + 1)
            except OSError as e:
                raise LogFormatError(p, lineno + 1, f"cannot read: {e.strerror or e}") from None
            if not raw:
                return
            lineno += 1
            if len(raw) > MAX_LINE_BYTES:
                raise LogFormatError(p, lineno, f"line longer than {MAX_LINE_BYTES} bytes, allowed <= {MAX_LINE_BYTES} "
                                                "(not a measured log?)")
            try:
                text = raw.decode("utf-8-sig" if lineno == 1 else "utf-8")
            except UnicodeDecodeError as e:
                raise LogFormatError(p, lineno, f"byte 0x{raw[e.start]:02X} at column {e.start + 1} is not UTF-8 "
                                                "(save the file as UTF-8)") from None
            yield lineno, text.rstrip("\r\n")


def read_log(path: str | Path, n: int | None = None, min_rows: int = 2, units: bool = True) -> MeasuredLog:
    """Read and validate a measured log.

    ``n``: number of joints expected (None: inferred from the header; a header with the columns
    of another number of joints is refused).  ``min_rows``: the fewest data rows the caller's
    operation needs.  ``units``: check angles and torques for a unit error (degrees for radians, a torque beyond any actuator's); False for a log the daemon
    wrote itself, read back by its benchmarks: its values are what its hardware measured (a
    simulated arm without end stops may turn past a full turn after a fault).  Every problem is a
    :class:`~sea_daemon.errors.LogFormatError` naming the file, the line and what was expected.
    """
    p = str(path)
    lines = _lines(p)
    header = _header(p, lines)
    if n is None:
        n = max(header_joints(header), 1)
    need = ["t"] + [c for base in REQUIRED for c in column_names(base, n)]
    m = header_joints(header)
    if m and m != n:
        # another robot's log (or this robot's log with another configuration): never read in part
        cols = ", ".join(column_names("q", m))
        raise LogFormatError(p, 1, f"has the columns of {m} joint(s) ({cols}, ...); the configuration has {n} "
                                   f"(joints: {n}, columns {', '.join(need)}): give the log and the configuration "
                                   "of one robot")
    missing = [c for c in need if c not in header]
    if missing:
        raise LogFormatError(p, 1, f"missing required column(s) {', '.join(missing)} "
                                   f"(need {', '.join(need)} for {n} joint(s))")
    data = _rows(p, lines, header)
    if len(data) < min_rows:
        raise LogFormatError(p, None, f"has {len(data)} data rows; this operation needs at least {min_rows}")
    col = {h: i for i, h in enumerate(header)}
    t = data[:, col["t"]]
    bad = np.nonzero(np.diff(t) <= 0)[0]
    if bad.size:
        i = int(bad[0]) + 1
        raise LogFormatError(p, i + 2, f"time does not increase: t = {t[i]} after {t[i - 1]}")
    if units:
        _check_angles(p, data, col, n)
        _check_torques(p, data, col, n)

    def block(base):
        return np.stack([data[:, col[c]] for c in column_names(base, n)], axis=1)

    tau_h = None
    if all(c in col for c in column_names("tau_h_act", n)):
        tau_h = block("tau_h_act")
    known = set(need) | set(column_names("tau_h_act", n))
    extra = {h: data[:, i] for h, i in col.items() if h not in known}
    return MeasuredLog(t=t, q=block("q"), theta_m=block("theta_m"), tau_m=block("tau_m"),
                       tau_h_act=tau_h, extra=extra, path=p)


def header_joints(header) -> int:
    """How many joints a log's header has columns for (docs/interfaces.md section 1): 1 when it has
    ``q``, ``theta_m`` or ``tau_m``, else the highest k of its ``q_k``, ``theta_m_k`` and ``tau_m_k``;
    0 when it has none of them."""
    names = set(header)
    if any(base in names for base in REQUIRED):
        return 1
    ks = [int(h[len(base) + 1:]) for base in REQUIRED for h in names
          if h.startswith(base + "_") and h[len(base) + 1:].isdigit()]
    return max(ks, default=0)


def _header(p: str, lines) -> list[str]:
    """The header row's column names: present, not too long, none twice."""
    try:
        _, head = next(lines)
    except StopIteration:
        raise LogFormatError(p, 1, "empty file: expected a header row with t, q, theta_m, tau_m") from None
    header = [h.strip() for h in head.split(",")]
    if any(len(h) > 200 for h in header):
        raise LogFormatError(p, 1, "a column name is longer than 200 characters (not a measured log?)")
    if len(set(header)) != len(header):
        dup = sorted({h for h in header if header.count(h) > 1})
        raise LogFormatError(p, 1, f"duplicate column(s) {', '.join(dup)}")
    return header


def _rows(p: str, lines, header: list[str]) -> np.ndarray:
    """The data rows (N, columns): every field a finite decimal number, every row as wide as the
    header; parsed straight into float64 blocks (8 bytes a value, not a Python float in a list)."""
    width = len(header)
    blocks: list[np.ndarray] = []
    block = np.empty((_BLOCK_ROWS, width))
    filled = 0
    for lineno, line in lines:
        if not line.strip():
            continue
        row = line.split(",")
        if len(row) != width:
            raise LogFormatError(p, lineno, f"has {len(row)} fields, the header has {width} "
                                            "(truncated or malformed row)")
        vals = []
        for name, cell in zip(header, row):
            v = _number(cell)
            if v is None:
                raise LogFormatError(p, lineno, f"column {name}: {cell.strip()[:MAX_FIELD_CHARS]!r} is not a number "
                                                "(expected a decimal like -1.25e-3)")
            if not math.isfinite(v):
                raise LogFormatError(p, lineno, f"column {name}: {cell.strip()} is not finite")
            vals.append(v)
        block[filled] = vals
        filled += 1
        if filled == _BLOCK_ROWS:
            blocks.append(block)
            block = np.empty((_BLOCK_ROWS, width))
            filled = 0
    blocks.append(block[:filled])
    return blocks[0] if len(blocks) == 1 else np.concatenate(blocks)


def _check_angles(p: str, data: np.ndarray, col: dict[str, int], n: int) -> None:
    """Angles in degrees instead of radians, detected by range: an exoskeleton joint moves less
    than one turn, so every angle of a valid log (joint side, rad) lies within ±2π and spans
    less than 2π; a log in degrees breaks that for any motion of more than 6.3°, or any angle
    beyond ±6.3°."""
    for base in ANGLE_COLUMNS:
        for c in column_names(base, n):
            a = data[:, col[c]]
            over = np.nonzero(np.abs(a) > ANGLE_LIMIT)[0]
            span = float(a.max() - a.min())
            if over.size or span > ANGLE_LIMIT:
                i = int(over[0]) if over.size else int(np.argmax(np.abs(a - a[0]) > ANGLE_LIMIT))
                raise LogFormatError(p, i + 2, f"column {c}: {a[i]:g} rad"
                                     + (f" (|{c}| > 2π)" if over.size else f" spans {span:g} rad (> 2π)")
                                     + ": degrees instead of radians? (a joint moves less than one turn; "
                                       "angles must be in rad, within ±2π)")


def _check_torques(p: str, data: np.ndarray, col: dict[str, int], n: int) -> None:
    """Torques beyond what any actuator gives (:data:`TORQUE_LIMIT`): a unit error."""
    for base in TORQUE_COLUMNS:
        for c in column_names(base, n):
            if c in col:
                a = np.abs(data[:, col[c]])
                if a.max() > TORQUE_LIMIT:
                    i = int(np.argmax(a))
                    raise LogFormatError(p, i + 2, f"column {c}: {data[i, col[c]]:g} N m, allowed |{c}| <= "
                                                   f"{TORQUE_LIMIT:g} (joint side, N m: check the units)")


def write_log(path: str | Path, log: MeasuredLog, extra: Mapping[str, np.ndarray] | None = None,
              fmt: str = "%.9g") -> None:
    """Write a measured log (docs/interfaces.md §1) plus optional extra columns."""
    n = log.n
    cols = {"t": log.t}
    for base, arr in (("q", log.q), ("theta_m", log.theta_m), ("tau_m", log.tau_m), ("tau_h_act", log.tau_h_act)):
        if arr is None:
            continue
        for j, name in enumerate(column_names(base, n)):
            cols[name] = arr[:, j]
    for k, v in {**log.extra, **(extra or {})}.items():
        cols[k] = np.asarray(v)
    write_columns(path, cols, fmt)


def write_columns(path: str | Path, cols: Mapping[str, np.ndarray], fmt: str = "%.9g") -> None:
    """Write equal-length columns as a CSV with one header row, atomically (the target is the
    old file or the whole new one, never a torn one)."""
    names = list(cols)
    data = np.column_stack([np.asarray(cols[k], dtype=float).reshape(-1) for k in names])
    with atomic_file(path) as fh:                 # streamed: no copy of the whole text in memory
        fh.write(csv_header(names))
        for i in range(0, len(data), _BLOCK_ROWS):
            fh.write(csv_rows(data[i:i + _BLOCK_ROWS], fmt))


# ---------------------------------------------------------------------------- the CSV format
# the one CSV writer of the project: the offline outputs (write_columns) and the daemon's log
# writer (sea_daemon.runtime.logwriter) format their lines here


def csv_header(names) -> bytes:
    """The header line: the column names joined by commas, UTF-8."""
    return (",".join(names) + "\n").encode()


def csv_rows(block: np.ndarray, fmt: str) -> bytes:
    """The lines of the rows of ``block`` (rows, columns), each value formatted with ``fmt``
    (``%``-style, e.g. ``%.9g``), comma-separated, one ``\n``-terminated line a row."""
    line = ",".join([fmt] * block.shape[1]) + "\n"
    return "".join(line % tuple(r) for r in block).encode()
