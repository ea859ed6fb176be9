"""Reading and writing files safely: bounded, strictly decoded input; atomic output that never
replaces one of the command's own inputs.

* :func:`read_text` — a file as text: at most ``max_bytes``, UTF-8 (a leading byte-order mark is
  dropped), a byte that is not UTF-8 is an :class:`~sea_daemon.errors.InputError` naming the
  line and column.
* :func:`atomic_write_bytes` / :func:`atomic_write_text` — a temporary file in the target's
  directory, fsync, rename over the target, fsync of the directory: a crash or a full disk
  leaves the old file or the new one, never a torn or empty one.
* :func:`check_outputs` — before any long work: every output path is writable (its directory
  exists, it is not a directory) and is none of the inputs.

Outputs only ever replace regular files: a device, a FIFO, a socket or a directory at the
output's path (or at the end of the symbolic link there) is refused with an InputError, before
any work and again by the writer.  A symbolic link to a regular file (or to nothing) is
replaced by the new file; the file it pointed to stays as it was.  The temporary files of a write
that was killed (``.NAME.XXXXXXXX.tmp`` beside ``NAME``) are removed by the next command that
writes ``NAME`` — only files of that pattern, regular, owned by this user and older than this
process.
"""
from __future__ import annotations

import contextlib
import os
import re
import stat
import tempfile
import time
from pathlib import Path
from typing import BinaryIO, Iterable, Iterator

from sea_daemon.errors import InputError, shown

#: the largest configuration or scenario file read [bytes]
MAX_CONFIG_BYTES = 1 << 20


def decode_utf8(data: bytes, source: str) -> str:
    """``data`` as UTF-8 text without a leading byte-order mark; InputError at the first byte
    that is not UTF-8, naming its line and column."""
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        line = data.count(b"\n", 0, e.start) + 1
        col = e.start - (data.rfind(b"\n", 0, e.start) + 1) + 1
        raise InputError(f"{shown(source)}:{line}: byte 0x{data[e.start]:02X} at column {col} is not UTF-8 "
                         "(save the file as UTF-8)") from None


def read_text(path: str | Path, max_bytes: int = MAX_CONFIG_BYTES, what: str = "file") -> str:
    """The whole file as UTF-8 text; InputError when it is missing, larger than ``max_bytes`` or
    not UTF-8."""
    p = str(path)
    try:
        with open(p, "rb") as fh:
            data = fh.read(max_bytes + 1)
    except OSError as e:
        raise InputError(f"{shown(p)}: cannot read the {what}: {e.strerror or e}") from None
    if len(data) > max_bytes:
        raise InputError(f"{shown(p)}: the {what} is larger than {max_bytes} bytes, allowed <= {max_bytes}")
    return decode_utf8(data, p)


def _process_start() -> float:
    """This process's start as a ``time.time()`` value (/proc/self/stat; now, where unreadable)."""
    now = time.time()
    try:
        raw = Path("/proc/self/stat").read_bytes()
        ticks = int(raw[raw.rindex(b")") + 2:].split()[19])
        return now - (time.clock_gettime(time.CLOCK_BOOTTIME) - ticks / os.sysconf("SC_CLK_TCK"))
    except (OSError, ValueError, IndexError, AttributeError):
        return now


PROCESS_START = _process_start()
#: the names :func:`atomic_file` gives its temporary files (``tempfile.mkstemp``'s 8 characters)
_TEMP_NAME = r"\.{}\.[a-z0-9_]{{8}}\.tmp"

_KINDS = ((stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"), (stat.S_ISFIFO, "a FIFO"),
          (stat.S_ISSOCK, "a socket"), (stat.S_ISDIR, "a directory"))


def check_replaceable(flag: str, path: str | Path) -> None:
    """InputError unless ``path`` is absent, a regular file, or a symbolic link to a regular
    file or to nothing: an output never replaces a device, a FIFO, a socket or a directory."""
    try:
        st = os.stat(path)
    except OSError:
        return                                   # absent, or a link to nothing: a new file
    if stat.S_ISREG(st.st_mode):
        return
    what = next((name for test, name in _KINDS if test(st.st_mode)), "not a regular file")
    via = " (through its symbolic link)" if os.path.islink(path) else ""
    raise InputError(f"{flag} {shown(path)}: is {what}{via}; an output replaces only a regular file "
                     "(give a file path)")


def remove_stale_temps(path: str | Path) -> list[Path]:
    """Remove the temporary files an interrupted write of ``path`` left beside it (module
    docstring); returns those removed."""
    path = Path(path)
    directory = path.parent if str(path.parent) else Path(".")
    pattern = re.compile(_TEMP_NAME.format(re.escape(path.name)))
    removed = []
    try:
        names = [e.name for e in os.scandir(directory) if e.name.startswith(f".{path.name}.")]
    except OSError:
        return removed
    for name in names:
        if not pattern.fullmatch(name):
            continue
        p = directory / name
        try:
            st = os.lstat(p)
            if stat.S_ISREG(st.st_mode) and st.st_uid == os.geteuid() and st.st_mtime < PROCESS_START:
                os.unlink(p)
                removed.append(p)
        except OSError:
            pass
    return removed


def _fsync_dir(directory: Path) -> None:
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


@contextlib.contextmanager
def atomic_file(path: str | Path) -> Iterator[BinaryIO]:
    """``with atomic_file(path) as fh: fh.write(...)`` — written to a temporary file in the
    target's directory, fsynced and renamed over ``path`` when the block ends (module docstring);
    InputError when the target cannot be written (missing or read-only directory, full disk),
    with the target left as it was and no temporary file left behind; an exception in the block
    likewise leaves the target untouched."""
    path = Path(path)
    directory = path.parent if str(path.parent) else Path(".")
    check_replaceable("output", path)
    remove_stale_temps(path)
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=directory)
    except OSError as e:
        raise InputError(f"{shown(path)}: cannot write: {e.strerror or e}") from None
    try:
        with os.fdopen(fd, "wb") as fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        check_replaceable("output", path)           # not swapped for a device meanwhile
        os.replace(tmp, path)
    except BaseException as e:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        if isinstance(e, OSError):
            raise InputError(f"{shown(path)}: cannot write: {e.strerror or e}") from None
        raise
    _fsync_dir(directory)


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically (:func:`atomic_file`)."""
    with atomic_file(path) as fh:
        fh.write(data)


def atomic_write_text(path: str | Path, text: str) -> None:
    """:func:`atomic_write_bytes` of ``text`` encoded as UTF-8; a lone surrogate (the bytes of a
    path that are not UTF-8) is written as its escape ``\\udcXX`` (valid in JSON), never an error."""
    atomic_write_bytes(path, text.encode("utf-8", "backslashreplace"))


def _same(a: Path, b: Path) -> bool:
    try:
        return a.exists() and b.exists() and os.path.samefile(a, b)
    except OSError:
        return False


def _resolved(p: Path) -> Path:
    try:
        return p.resolve()
    except (OSError, RuntimeError):          # a symlink loop: compare as given
        return p.absolute()


def check_outputs(outputs: Iterable[tuple[str, str | Path | None]],
                  inputs: Iterable[str | Path | None] = ()) -> None:
    """Refuse, before any work, an output that cannot be written or that is one of the inputs.

    ``outputs``: (flag, path) pairs, e.g. ``("--out", "est.csv")`` (None paths are skipped);
    ``inputs``: the paths the command reads.  An output directory is checked likewise with
    :func:`check_output_dir`.
    """
    ins = [Path(p) for p in inputs if p is not None]
    seen: list[tuple[str, Path]] = []
    for flag, out in outputs:
        if out is None:
            continue
        o = Path(out)
        for i in ins:
            if _same(o, i) or _resolved(o) == _resolved(i):
                raise InputError(f"{flag} {shown(o)}: is also an input of this command ({shown(i)}); "
                                 "choose another output path")
        for other_flag, other in seen:
            if _same(o, other) or _resolved(o) == _resolved(other):
                raise InputError(f"{flag} {shown(o)}: is also the output of {other_flag}; choose another path")
        seen.append((flag, o))
        if o.is_dir():
            raise InputError(f"{flag} {shown(o)}: is a directory, expected a file path")
        check_replaceable(flag, o)
        d = o.parent if str(o.parent) else Path(".")
        if not d.is_dir():
            raise InputError(f"{flag} {shown(o)}: directory {shown(d)} does not exist")
        _probe(flag, o, d)
        remove_stale_temps(o)


def check_output_dir(flag: str, directory: str | Path, inputs: Iterable[str | Path | None] = ()) -> Path:
    """Create ``directory`` if needed and check it is a writable directory holding none of the
    inputs' paths as itself; returns it."""
    d = Path(directory)
    for i in (Path(p) for p in inputs if p is not None):
        if _same(d, i):
            raise InputError(f"{flag} {shown(d)}: is also an input of this command")
    if d.exists() and not d.is_dir():
        raise InputError(f"{flag} {shown(d)}: is not a directory")
    try:
        d.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise InputError(f"{flag} {shown(d)}: cannot create: {e.strerror or e}") from None
    _probe(flag, d, d)
    return d


def _probe(flag: str, target: Path, directory: Path) -> None:
    """Create and remove a temporary file in ``directory``, as the atomic writer will: the
    honest test of "writable" (permissions, a read-only file system, a full inode table; the
    permission bits alone say nothing to root)."""
    try:
        fd, tmp = tempfile.mkstemp(prefix=".probe.", suffix=".tmp", dir=directory)
    except OSError as e:
        raise InputError(f"{flag} {shown(target)}: directory {shown(directory)} is not writable: "
                         f"{e.strerror or e}") from None
    os.close(fd)
    try:
        os.unlink(tmp)
    except OSError:
        pass
