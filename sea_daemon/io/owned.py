"""What the daemon creates or uses on the machine is its own: owned by its user (or root) and not
writable by anyone else.

A directory, lock or socket another user owns, or one that group or others may write, would
let that user plant the daemon's files (its pid file, its socket, the ipc bus's members) or
read what it publishes.  :func:`check_owned` refuses them with one line (an
:class:`~sea_daemon.errors.InputError`, exit status 2); :func:`make_private_dir` creates a
directory (mode 0700) and checks it, whether it was made now or found.
"""
from __future__ import annotations

import os
import stat
from pathlib import Path

from sea_daemon.errors import InputError, shown


def trusted_uids() -> frozenset[int]:
    """The owners the daemon accepts: itself and root."""
    return frozenset({os.geteuid(), 0})


def check_owned(what: str, path: str | Path, *, st: os.stat_result | None = None) -> os.stat_result:
    """``path`` (its final target) is owned by this user or root and writable by nobody else;
    InputError naming the owner and the mode otherwise.  Returns its ``stat``."""
    try:
        st = st if st is not None else os.stat(path)
    except OSError as e:
        raise InputError(f"{what} {shown(path)}: cannot read: {e.strerror or e}") from None
    if st.st_uid not in trusted_uids():
        raise InputError(f"{what} {shown(path)}: owned by uid {st.st_uid}, not by this user (uid "
                         f"{os.geteuid()}) or root; remove it or give a directory of this user's")
    mode = stat.S_IMODE(st.st_mode)
    if mode & 0o022:
        raise InputError(f"{what} {shown(path)}: mode {mode:04o} lets group or others write it; allowed: "
                         f"not group- or world-writable (chmod go-w {shown(path)})")
    return st


def make_private_dir(what: str, path: str | Path, mode: int = 0o700) -> Path:
    """Create ``path`` (and its missing parents, as :func:`os.makedirs` does) with ``mode`` if
    it is missing and :func:`check_owned` it; InputError when it is no directory."""
    p = Path(path)
    try:
        os.makedirs(p, mode=mode, exist_ok=True)
    except OSError as e:
        raise InputError(f"{what} {shown(p)}: cannot create: {e.strerror or e}") from None
    st = check_owned(what, p)
    if not stat.S_ISDIR(st.st_mode):
        raise InputError(f"{what} {shown(p)}: is not a directory")
    return p
