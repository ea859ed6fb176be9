"""A benchmark's cache of simulated logs: numbers only, in a directory only its user can write.

Each entry is one ``.npz`` archive (read with ``allow_pickle=False``: no file can run code)
holding every log's arrays and one ``__meta__`` entry of UTF-8 JSON naming the logs, their
columns and the key the entry was made for.  An entry that is unreadable, made for another key
or of another format is simulated again.  The cache is used only in a directory owned by the
user running the benchmark and not writable by group or others (a symbolic link is refused), so
nobody else can put logs in it.
"""
from __future__ import annotations

import io
import json
import os
import stat
from pathlib import Path
from typing import Mapping

import numpy as np

from sea_daemon.core.log import MeasuredLog
from sea_daemon.io.files import atomic_write_bytes

FORMAT = "sea-daemon-log-cache"
VERSION = 1
_META = "__meta__"
_FIELDS = ("t", "q", "theta_m", "tau_m", "tau_h_act")


def private_dir(path: Path) -> str | None:
    """None if ``path`` is a directory (not a link) owned by this user and writable by no one
    else; else why it is not."""
    try:
        st = os.lstat(path)
    except OSError as e:
        return f"cannot read it ({e.strerror})"
    if not stat.S_ISDIR(st.st_mode):
        return "not a directory"
    if st.st_uid != os.geteuid():
        return f"owned by uid {st.st_uid}, not by this user (uid {os.geteuid()})"
    if st.st_mode & (stat.S_IWGRP | stat.S_IWOTH):
        return f"writable by group or others (mode {stat.S_IMODE(st.st_mode):04o})"
    return None


def save_logs(path: Path, key: Mapping, logs: Mapping[str, MeasuredLog]) -> None:
    """Write ``logs`` ({name: log}) under ``key`` (JSON-able) atomically."""
    arrays: dict[str, np.ndarray] = {}
    index = {}
    for i, (name, log) in enumerate(logs.items()):
        fields = [f for f in _FIELDS if getattr(log, f) is not None]
        for f in fields:
            arrays[f"l{i}_{f}"] = np.asarray(getattr(log, f), dtype=float)
        extra = list(log.extra)
        for j, col in enumerate(extra):
            arrays[f"l{i}_x{j}"] = np.asarray(log.extra[col])
        index[name] = {"i": i, "fields": fields, "extra": extra, "path": log.path}
    meta = {"format": FORMAT, "version": VERSION, "key": key, "logs": index}
    buf = io.BytesIO()
    np.savez(buf, **arrays, **{_META: np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8)})
    atomic_write_bytes(path, buf.getvalue())


def load_logs(path: Path, key: Mapping) -> dict[str, MeasuredLog] | None:
    """The logs of the entry at ``path`` if it was made for ``key``; None when there is none,
    or it is unreadable, foreign or for another key (then the caller simulates again)."""
    try:
        with np.load(path, allow_pickle=False) as z:
            meta = json.loads(bytes(z[_META]).decode())
            if meta.get("format") != FORMAT or meta.get("version") != VERSION \
                    or meta.get("key") != json.loads(json.dumps(key)):
                return None
            out = {}
            for name, d in meta["logs"].items():
                i = int(d["i"])
                f = {k: (z[f"l{i}_{k}"] if k in d["fields"] else None) for k in _FIELDS}
                extra = {col: z[f"l{i}_x{j}"] for j, col in enumerate(d["extra"])}
                out[name] = MeasuredLog(f["t"], f["q"], f["theta_m"], f["tau_m"], f["tau_h_act"], extra,
                                        str(d["path"]))
            return out
    except (OSError, ValueError, KeyError, TypeError, EOFError, AttributeError):
        return None
