"""Saved models: versioned, checksummed, written atomically, no pickle.

A model file is a NumPy ``.npz`` archive (read with ``allow_pickle=False``) holding named
numeric arrays plus one ``__meta__`` entry: UTF-8 JSON with the format name, the format
version, free metadata (config, hyperparameters, provenance) and a SHA-256 checksum over
the metadata and every array's name, dtype, shape and bytes.  It is written to a temporary
file in the same directory, fsynced, renamed over the target and the directory fsynced, so
a crash leaves either the old or the new file, never a torn one.
"""
from __future__ import annotations

import hashlib
import io
import json
import zipfile
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from sea_daemon.errors import ModelFileError, shown
from sea_daemon.io.files import atomic_write_bytes

FORMAT = "sea-daemon-model"
VERSION = 1
_META = "__meta__"
#: the most a model file may hold once decompressed [bytes] (a LoG-GP of 10⁶ points per joint
#: is about 60 MB) and the most its metadata may hold
MAX_UNPACKED_BYTES = 1 << 30
MAX_META_BYTES = 64 << 20


def _digest(meta: Mapping[str, Any], arrays: Mapping[str, np.ndarray]) -> str:
    h = hashlib.sha256()
    h.update(json.dumps({k: v for k, v in meta.items() if k != "sha256"}, sort_keys=True).encode())
    for name in sorted(arrays):
        a = np.ascontiguousarray(arrays[name])
        h.update(f"{name}|{a.dtype.str}|{a.shape}".encode())
        h.update(a.tobytes())
    return h.hexdigest()


def save_model(path: str | Path, arrays: Mapping[str, np.ndarray], meta: Mapping[str, Any]) -> None:
    """Write ``arrays`` (numeric NumPy arrays) and JSON-serialisable ``meta`` atomically."""
    for name, a in arrays.items():
        if name == _META:
            raise ValueError(f"array name {_META!r} is reserved")
        if np.asarray(a).dtype == object:
            raise ValueError(f"array {name!r} has dtype object; only numeric arrays are stored (no pickle)")
    arrays = {k: np.asarray(v) for k, v in arrays.items()}
    full = {"format": FORMAT, "version": VERSION, **meta}
    full["sha256"] = _digest(full, arrays)
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays, **{_META: np.frombuffer(json.dumps(full).encode(), dtype=np.uint8)})
    atomic_write_bytes(path, buf.getvalue())


def load_model(path: str | Path) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """Read a model file; corrupt, foreign or incompatible files raise ModelFileError."""
    p = str(path)
    _check_sizes(p)
    try:
        with np.load(p, allow_pickle=False) as z:
            if _META not in z.files:
                raise ModelFileError(f"{p}: not a sea-daemon model file (no {_META} entry)")
            meta = json.loads(bytes(z[_META]).decode())
            arrays = {k: z[k] for k in z.files if k != _META}
    except ModelFileError:
        raise
    except FileNotFoundError:
        raise ModelFileError(f"{shown(p)}: no such model file") from None
    except Exception as e:  # zlib, zipfile, numpy header, JSON, OS errors: all mean 'unreadable'
        raise ModelFileError(f"{p}: corrupt or not a model file ({type(e).__name__}: {e})") from None
    if meta.get("format") != FORMAT:
        raise ModelFileError(f"{p}: format {meta.get('format')!r} is not {FORMAT!r}")
    if meta.get("version") != VERSION:
        raise ModelFileError(f"{p}: model file version {meta.get('version')!r} is incompatible; "
                             f"this sea-daemon reads version {VERSION} (re-run calibrate)")
    if meta.get("sha256") != _digest(meta, arrays):
        raise ModelFileError(f"{p}: checksum mismatch: the file is corrupt")
    return arrays, meta


def _check_sizes(p: str) -> None:
    """Refuse an archive whose members would decompress to more than the limits, before reading
    any of them (the zip directory states each member's size; reading stops at it)."""
    try:
        with zipfile.ZipFile(p) as zf:
            infos = zf.infolist()
    except FileNotFoundError:
        raise ModelFileError(f"{shown(p)}: no such model file") from None
    except (OSError, zipfile.BadZipFile, ValueError) as e:
        raise ModelFileError(f"{shown(p)}: corrupt or not a model file ({type(e).__name__}: {shown(e)})") from None
    total = sum(i.file_size for i in infos)
    if total > MAX_UNPACKED_BYTES:
        raise ModelFileError(f"{shown(p)}: unpacks to {total} bytes, allowed <= {MAX_UNPACKED_BYTES}")
    for i in infos:
        if i.filename.startswith(_META) and i.file_size > MAX_META_BYTES:
            raise ModelFileError(f"{shown(p)}: metadata of {i.file_size} bytes, allowed <= {MAX_META_BYTES}")
