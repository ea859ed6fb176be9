"""Configuration files: read and write the model YAML, the project's paths.

The configuration itself is the validated, frozen dataclasses of
:mod:`sea_daemon.core.config`; this module is where they meet the file system.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from sea_daemon.core.config import ModelConfig
from sea_daemon.errors import ConfigError


def load_yaml(path: str | Path) -> Any:
    """Read a YAML file; a missing file or a syntax error is an InputError naming the file."""
    p = Path(path)
    try:
        text = p.read_text()
    except OSError as e:
        raise ConfigError(str(p), "<file>", f"cannot read: {e.strerror or e}") from None
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f"line {mark.line + 1}" if mark is not None else "<file>"
        raise ConfigError(str(p), where, f"not valid YAML: {getattr(e, 'problem', e)}") from None


def load_config(path: str | Path) -> ModelConfig:
    """Load and validate a model configuration (docs/interfaces.md §2)."""
    return ModelConfig.from_dict(load_yaml(path), source=str(path))


def save_config(cfg: ModelConfig, path: str | Path, header: str | None = None) -> None:
    """Write a configuration that :func:`load_config` reads back to an equal object."""
    text = yaml.safe_dump(cfg.to_dict(), sort_keys=False, default_flow_style=None)
    if header:
        text = "".join(f"# {line}\n" for line in header.splitlines()) + text
    Path(path).write_text(text)


def repo_root() -> Path:
    """The project checkout (configs/ lives beside the package)."""
    return Path(__file__).resolve().parent.parent.parent


def default_config_path() -> Path:
    return repo_root() / "configs" / "exo_1dof.yaml"
