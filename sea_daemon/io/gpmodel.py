"""The calibrated model file of ``sea-daemon calibrate`` / ``run --model``.

On top of :mod:`sea_daemon.io.modelfile` (versioned, checksummed ``.npz``, atomic write, no
pickle): the learned residual (one LoG-GP per joint, :class:`~sea_daemon.core.learning.ResidualGP`)
with its training points as numeric arrays and the tree / hyperparameters as JSON metadata,
plus the model configuration it was learned with.

Compatibility: a residual f(z) is what the *nominal* model leaves unexplained
(eq:unknwn_load), computed with the configured kinematics; a model file is therefore refused
(:class:`~sea_daemon.errors.ModelFileError`, exit 2) when the configuration's ``joints`` or
``model`` section differs from the one it was learned with, or its ``rate_hz`` / ``kinematics``
unless they are the saved ones at another rate with the differentiator's span in time kept
(:func:`sea_daemon.core.rates.at_rate`: a model calibrated at 100 Hz runs at 1 kHz).  The
estimator noise (``estimator``) and ``hardware`` may differ.
"""
from __future__ import annotations

import copy
import hashlib
import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from sea_daemon.core.config import ModelConfig
from sea_daemon.errors import ModelFileError
from sea_daemon.core.learning import ResidualGP
from sea_daemon.io.modelfile import load_model, save_model
from sea_daemon.core.config import KinematicsConfig
from sea_daemon.core.rates import window_at

KIND = "gp-akf-residual"
#: configuration sections a model file must agree on (see module docstring)
COMPAT_KEYS = ("joints", "rate_hz", "model", "kinematics")


def _split(residual: ResidualGP) -> tuple[dict, dict[str, np.ndarray]]:
    """The residual's dict with every leaf's X / y moved to numeric arrays."""
    d = copy.deepcopy(residual.to_dict())
    arrays: dict[str, np.ndarray] = {}
    for j, g in enumerate(d["gps"]):
        for leaf in g["leaves"]:
            key = f"gp{j}_leaf{int(leaf['node'])}"
            gp = leaf["gp"]
            y = np.asarray(gp.pop("y"), dtype=float)
            arrays[key + "_X"] = np.asarray(gp.pop("X"), dtype=float).reshape(y.size, int(gp["input_dim"]))
            arrays[key + "_y"] = y
            gp["arrays"] = key
    return d, arrays


def _join(d: dict, arrays: dict[str, np.ndarray]) -> dict:
    d = copy.deepcopy(d)
    for g in d["gps"]:
        for leaf in g["leaves"]:
            gp = leaf["gp"]
            key = gp.pop("arrays")
            gp["X"] = arrays[key + "_X"].tolist()
            gp["y"] = arrays[key + "_y"].tolist()
    return d


def save_gp_model(path: str | Path, cfg: ModelConfig, residual: ResidualGP, provenance: dict[str, Any]) -> None:
    """Write the learned residual atomically (temp file + fsync + rename)."""
    d, arrays = _split(residual)
    meta = {"kind": KIND, "config": json.loads(json.dumps(cfg.to_dict())), "residual": d,
            "created_unix": time.time(), "provenance": provenance}
    if cfg.model.rigid is not None:
        # the URDF's path is relative to the YAML that names it: the description itself is compared
        meta["config"]["model"]["urdf_sha256"] = _urdf_hash(cfg)
    save_model(path, arrays, meta)


def _urdf_hash(cfg: ModelConfig) -> str | None:
    return None if cfg.model.rigid is None else hashlib.sha256(cfg.model.rigid.urdf.encode()).hexdigest()


def _same_model(saved: dict, cfg: ModelConfig, now: dict) -> bool:
    """The model sections agree, a URDF compared by its text (saved as ``urdf_sha256``), not its path."""
    a, b = dict(saved.get("model") or {}), dict(now.get("model") or {})
    if "urdf" not in a or "urdf" not in b:
        return a == b
    h = a.pop("urdf_sha256", None)
    a.pop("urdf"), b.pop("urdf")
    return a == b and (h is None or h == _urdf_hash(cfg))


def _compat(path: str, saved: dict, cfg: ModelConfig) -> None:
    now = json.loads(json.dumps(cfg.to_dict()))
    for key in COMPAT_KEYS:
        if saved.get(key) == now.get(key) or (key == "model" and _same_model(saved, cfg, now)):
            continue
        if key in ("rate_hz", "kinematics") and _same_in_time(saved, cfg):
            continue                      # another loop rate, the same differentiator in time
        raise ModelFileError(f"{path}: learned with a different '{key}' section than the configuration "
                             f"(saved {json.dumps(saved.get(key))[:120]}, configured "
                             f"{json.dumps(now.get(key))[:120]}); re-run calibrate with this configuration"
                             + (" (at another rate the kinematics window must keep its span in time: "
                                "sea-daemon run/calibrate --rate)" if key in ("rate_hz", "kinematics") else ""))


def _same_in_time(saved: dict, cfg: ModelConfig) -> bool:
    """The saved kinematics brought to the configuration's rate are the configuration's
    (:func:`sea_daemon.core.rates.same_in_time`)."""
    try:
        rate = float(saved["rate_hz"])
        kin = KinematicsConfig.from_dict(saved["kinematics"], cfg.joints, "model file")
    except (KeyError, TypeError, ValueError, Exception):  # noqa: BLE001 - an old or odd file: not the same
        return False
    return (kin.method, kin.degree) == (cfg.kinematics.method, cfg.kinematics.degree) and \
        window_at(kin, rate, cfg.rate_hz) == cfg.kinematics.window


def load_gp_model(path: str | Path, cfg: ModelConfig) -> tuple[ResidualGP, dict]:
    """(residual, meta) of a model file; corrupt or incompatible files raise ModelFileError."""
    arrays, meta = load_model(path)
    p = str(path)
    if meta.get("kind") != KIND:
        raise ModelFileError(f"{p}: kind {meta.get('kind')!r} is not {KIND!r}")
    try:
        _compat(p, meta["config"], cfg)
        residual = ResidualGP.from_dict(_join(meta["residual"], arrays))
    except KeyError as e:
        raise ModelFileError(f"{p}: model file lacks {e}") from None
    except ModelFileError as e:
        if str(e).startswith(p):
            raise
        raise ModelFileError(f"{p}: {e}") from None
    if residual.n != cfg.joints:
        raise ModelFileError(f"{p}: {residual.n} joint(s), the configuration has {cfg.joints}")
    return residual, meta
