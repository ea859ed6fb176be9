"""Validation of configuration values: each helper returns the value in its canonical form or
raises :class:`~sea_daemon.errors.ConfigError` naming the key and what is allowed.

Every number lies within ±:data:`~sea_daemon.core.effects.MAX_ABS`; strings are never taken for
numbers (numpy would parse ``"1_0"`` as 10).
"""
from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from sea_daemon.core.effects import MAX_ABS, finite_number as _finite
from sea_daemon.errors import ConfigError

# ---------------------------------------------------------------------------- helpers

def num(source: str, key: str, v: Any, *, positive=False, non_negative=False,
         lo: float | None = None, hi: float | None = None) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not _finite(v):
        raise ConfigError(source, key, f"must be a finite number within ±{MAX_ABS:g}, got {v!r}")
    v = float(v)
    if positive and v <= 0:
        raise ConfigError(source, key, f"must be > 0, got {v}")
    if non_negative and v < 0:
        raise ConfigError(source, key, f"must be >= 0, got {v}")
    if lo is not None and v < lo or hi is not None and v > hi:
        raise ConfigError(source, key, f"must be in [{lo}, {hi}], got {v}")
    return v


def numbers(v: Any) -> np.ndarray:
    """``v`` (a number or nested lists of numbers) as a float array; ValueError for anything else
    (strings, which numpy would parse with Python's lenient float(), booleans, ragged lists)."""
    a = np.asarray(v)
    if a.dtype.kind not in "iuf":
        raise ValueError(f"not numbers: {a.dtype}")
    return a.astype(float)


def matrix(source: str, key: str, v: Any, n: int, *, positive_definite=False,
            non_negative=False) -> np.ndarray:
    """scalar -> s·I (n=1 or diagonal), list of n -> diag, n×n nested list -> matrix."""
    try:
        a = numbers(v)
    except (TypeError, ValueError, OverflowError):
        raise ConfigError(source, key, f"must be a number, a list of {n} or an {n}x{n} matrix, got {v!r}") from None
    if a.ndim == 0:
        a = np.eye(n) * float(a)
    elif a.ndim == 1 and a.shape[0] == n:
        a = np.diag(a)
    elif not (a.ndim == 2 and a.shape == (n, n)):
        raise ConfigError(source, key, f"must be a number, a list of {n} or an {n}x{n} matrix, got shape {a.shape}")
    if not np.all(np.isfinite(a)) or np.any(np.abs(a) > MAX_ABS):
        raise ConfigError(source, key, f"must be finite, within ±{MAX_ABS:g}, got {v!r}")
    if positive_definite:
        if not np.allclose(a, a.T) or np.any(np.linalg.eigvalsh(0.5 * (a + a.T)) <= 0):
            raise ConfigError(source, key, f"must be positive (symmetric positive definite), got {v!r}")
    if non_negative:
        if not np.allclose(a, a.T) or np.any(np.linalg.eigvalsh(0.5 * (a + a.T)) < -1e-12):
            raise ConfigError(source, key, f"must be >= 0 (symmetric positive semi-definite), got {v!r}")
    a.setflags(write=False)
    return a


def vector(source: str, key: str, v: Any, n: int, *, non_negative=False, positive=False) -> np.ndarray:
    """scalar -> repeated, list of n -> vector."""
    try:
        a = numbers(v)
    except (TypeError, ValueError, OverflowError):
        raise ConfigError(source, key, f"must be a number or a list of {n} numbers, got {v!r}") from None
    if a.ndim == 0:
        a = np.full(n, float(a))
    if a.ndim != 1 or a.shape[0] != n:
        raise ConfigError(source, key, f"must be a number or a list of {n} numbers, got {v!r}")
    if not np.all(np.isfinite(a)) or np.any(np.abs(a) > MAX_ABS):
        raise ConfigError(source, key, f"must be finite, within ±{MAX_ABS:g}, got {v!r}")
    if positive and np.any(a <= 0):
        raise ConfigError(source, key, f"every entry must be > 0, got {v!r}")
    if non_negative and np.any(a < 0):
        raise ConfigError(source, key, f"every entry must be >= 0, got {v!r}")
    a.setflags(write=False)
    return a


def diag_or_matrix(source: str, key: str, v: Any, n: int, positive_definite: bool = False) -> np.ndarray:
    """Covariances: list of n -> diag, n×n -> matrix; must be symmetric PSD (``positive_definite``:
    PD, every variance > 0)."""
    try:
        a = numbers(v) if not isinstance(v, (str, bytes, Mapping)) else None
    except (TypeError, ValueError, OverflowError):      # ragged lists, strings inside
        a = None
    if a is None or a.ndim not in (1, 2):
        raise ConfigError(source, key, f"must be a list of {n} variances or an {n}x{n} matrix, got {v!r}")
    kind = {"positive_definite": True} if positive_definite else {"non_negative": True}
    if a.ndim == 1:
        return matrix(source, key, a if a.shape[0] == n else v, n, **kind)
    return matrix(source, key, a, n, **kind)


def check_keys(source: str, prefix: str, d: Mapping, allowed: list[str], required: list[str]) -> None:
    if not isinstance(d, Mapping):
        raise ConfigError(source, prefix or "<top level>", f"must be a mapping, got {type(d).__name__}")
    for k in d:
        if k not in allowed:
            raise ConfigError(source, f"{prefix}{k}", f"unknown key; allowed: {', '.join(allowed)}")
    for k in required:
        if k not in d:
            raise ConfigError(source, f"{prefix}{k}", f"missing required key (required: {', '.join(required)})")


# ---------------------------------------------------------------------------- sections

