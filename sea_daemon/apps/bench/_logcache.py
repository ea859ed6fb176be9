"""A benchmark's cache of simulated logs: numbers only, in a directory only its user can write.

Each entry is one ``.npz`` archive (read with ``allow_pickle=False``: no file can run code)
holding every log's arrays and one ``__meta__`` entry of UTF-8 JSON naming the logs, their
columns and the key the entry was made for.  An entry that is unreadable, made for another key
or of another format is simulated again.  The cache is used only in a directory owned by the
user running the benchmark and not writable by group or others (a symbolic link is refused), so
nobody else can put logs in it.

A key names what made its logs, not only which logs they are: :func:`producer` digests the
source of the modules that simulate them and of every ``sea_daemon`` module those import (at
the top or inside a function, read from the files, transitively), the data files they start
from (a plant family's base YAML and URDF) and the versions of the installed packages they use
(numpy's random streams, scipy's solvers, numba's compiled code).  A change to the plant
simulator, the dynamics, the model, the family or its base configuration, or an upgrade of one
of those packages, makes every entry made before it stale.
"""
from __future__ import annotations

import ast
import functools
import hashlib
import importlib.util
import io
import json
import os
import platform
import stat
import sys
from importlib import metadata
from pathlib import Path
from typing import Iterable, Mapping

import numpy as np

from sea_daemon.core.log import MeasuredLog
from sea_daemon.io.files import atomic_write_bytes

FORMAT = "sea-daemon-log-cache"
VERSION = 1
_META = "__meta__"
_FIELDS = ("t", "q", "theta_m", "tau_m", "tau_h_act")
_PACKAGE = "sea_daemon"
_ROOT = Path(__file__).resolve().parents[3]          # the directory holding sea_daemon/


def producer(modules: Iterable[str], files: Iterable[Path] = ()) -> str:
    """SHA-256 (hex) of what makes a benchmark's logs: the source of each module of ``modules``
    (dotted names under ``sea_daemon``) and of every ``sea_daemon`` module they import,
    transitively (with the packages' ``__init__`` files); the bytes of ``files``; the Python
    version and the versions of the installed packages those modules import.  A file that is
    missing counts as missing.  Taken once per process for given arguments."""
    return _producer(tuple(modules), tuple(str(Path(f).resolve()) for f in files))


@functools.lru_cache(maxsize=None)
def _producer(modules: tuple[str, ...], files: tuple[str, ...]) -> str:
    sources, packages = import_closure(modules)
    h = hashlib.sha256(f"python {platform.python_version()}\0".encode())
    for name in sorted(sources):
        h.update(name.encode() + b"\0" + _read(sources[name]) + b"\0")
    for path in files:
        h.update(path.encode() + b"\0" + _read(Path(path)) + b"\0")
    for top in sorted(packages):
        h.update(f"{top} {_installed(top)}\0".encode())
    return h.hexdigest()


def import_closure(modules: Iterable[str], root: Path = _ROOT) -> tuple[dict[str, Path], set[str]]:
    """({module: source file} of ``modules`` and of every module of their package that they
    import, transitively, with the packages' ``__init__`` files; {top-level name} of the other
    packages they import, standard library left out).  Imports are read from the files under
    ``root`` (``import`` and ``from ... import`` statements anywhere in a module, relative ones
    too), nothing is imported."""
    todo = list(modules)
    pkg = todo[0].split(".")[0] if todo else _PACKAGE
    found: dict[str, Path] = {}
    others: set[str] = set()
    while todo:
        name = todo.pop()
        top = name.split(".")[0]
        if top != pkg:
            if top and top not in sys.stdlib_module_names:
                others.add(top)
            continue
        path = _source(root, name)
        if name in found or path is None:
            continue
        found[name] = path
        parts = name.split(".")
        todo += [".".join(parts[:i]) for i in range(1, len(parts))]
        todo += _imports(name, path)
    return found, others


def _source(root: Path, name: str) -> Path | None:
    """The source file of module ``name`` under ``root`` (a module or a package), or None."""
    base = root.joinpath(*name.split("."))
    for path in (base.with_suffix(".py"), base / "__init__.py"):
        if path.is_file():
            return path
    return None


def _imports(name: str, path: Path) -> list[str]:
    """Every module name the source of module ``name`` (at ``path``) may import: each ``import
    a.b``, and for ``from a import b`` both ``a`` and ``a.b`` (b may be a module)."""
    try:
        tree = ast.parse(_read(path))
    except (SyntaxError, ValueError):
        return []
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")
                parent = ".".join(parts[:len(parts) - node.level + 1])
                base = f"{parent}.{base}" if base else parent
            out.append(base)
            out += [f"{base}.{a.name}" for a in node.names if a.name != "*"]
    return out


def _read(path: Path) -> bytes:
    try:
        return path.read_bytes()
    except OSError:
        return b"<missing>"


@functools.lru_cache(maxsize=None)
def _distributions() -> dict[str, list[str]]:
    return metadata.packages_distributions()


def _installed(top: str) -> str:
    """What is installed as package ``top``: its distributions' versions, or (a package installed
    outside the metadata's reach) the size and time of its file; "none" if it is not installed."""
    dists = sorted(set(_distributions().get(top, ())))
    if dists:
        return ", ".join(f"{d} {metadata.version(d)}" for d in dists)
    try:
        spec = importlib.util.find_spec(top)
        st = os.stat(spec.origin)
    except (ImportError, ValueError, TypeError, AttributeError, OSError):
        return "none"
    return f"{spec.origin} {st.st_size} {st.st_mtime_ns}"


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
